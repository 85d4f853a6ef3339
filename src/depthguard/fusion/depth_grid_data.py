"""The lazy depth grid's model and data as the kernels take them (R10–R12; pinocchio's split).

:class:`LazyModel` is what a camera set fixes (built once with the grid): the principal's pose
and intrinsics, the slices, the other cameras' corner rays and pyramid layout.
:class:`LazyFrame` is what one set of frames gives (remade with every set of frames): the
principal's free depths and kinds, their tile minima, the other cameras' free depths and
pyramids (tables of where they lie, :mod:`~depthguard.fusion.camera_views`), the robot's capsules and their intervals per principal pixel, the band of slices
the other cameras can judge. :class:`LazyMemo` is the per-frame memo the kernels fill in place:
the frame's number, the classified / obstacle bits per principal pixel, the free stretch per
pixel, and the other cameras' clearing memo (:mod:`depthguard.fusion.depth_grid_memo`).

The kernels (:func:`~depthguard.fusion.depth_grid_lazy.ensure_cells`,
:func:`~depthguard.fusion.depth_grid_lazy_lookup.grid_distances_lazy`) take these three and a
few per-call arguments, and unpack them; the shapes and units of each field are given below.
The scalars are converted to Python ``float`` / ``int`` here so that numba compiles one
signature.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["LazyModel", "LazyFrame", "LazyMemo", "lazy_model", "lazy_frame", "lazy_memo"]


class LazyModel(NamedTuple):
    """A camera set's tables (R10–R12)."""
    pint: np.ndarray     # (8,) float64 principal fx, fy, cx, cy, W, H, min range m, max range m
    Rp: np.ndarray       # (3, 3) float64 world -> principal rotation
    tp: np.ndarray       # (3,) float64 world -> principal translation, m
    dmin: float          # m, the first slice's near depth
    dd: float            # m, slice thickness (delta_d)
    nd: int              # number of slices
    koff: np.ndarray     # (K, levels) int64 other cameras' pyramid level offsets
    kdims: np.ndarray    # (K, levels, 2) int64 their level sizes
    rays: np.ndarray     # (K, H+1, W+1, 3) float64 principal pixel-corner rays in each other camera
    origins: np.ndarray  # (K, 3) float64 principal centre in each other camera, m
    kint: np.ndarray     # (K, 8) float64 other cameras' intrinsics rows
    nk: int              # number of other cameras (K >= 1 arrays even when 0)


class LazyFrame(NamedTuple):
    """What one set of frames gives (R11, R12, R30)."""
    pfree: np.ndarray    # (H, W) float64 principal free depth per pixel, m
    pkind: np.ndarray    # (H, W) int8 its kind (surface, robot, invalid, ...)
    tmin: np.ndarray     # (H/TILE, W/TILE) float64 tile minima of pfree, m
    kfree: np.ndarray    # (K, 3) int64 the other cameras' free depths (H_k, W_k) float64 m, where they lie
    kpmin: np.ndarray    # (K, 2) int64 their min pyramids (flat float64 m), where they lie
    kpmax: np.ndarray    # (K, 2) int64 their max pyramids (camera_views.CameraViews' tables)
    caps: np.ndarray     # (C, 7) float64 robot capsules in the principal frame (a, b, r), m
    ncaps: int           # capsules in use
    cap_lo: np.ndarray   # (H, W, MAX_CAPS_PER_PIXEL) float64 capsule intervals' near depth, m
    cap_hi: np.ndarray   # (H, W, MAX_CAPS_PER_PIXEL) float64 their far depth, m
    cap_n: np.ndarray    # (H, W) int64 intervals per pixel
    band: np.ndarray     # (H, W, 2) int32 slices the other cameras can judge


class LazyMemo(NamedTuple):
    """The per-frame memo the kernels fill (R12)."""
    frame: int           # the frame's number (older stamps are reset on first touch)
    stamp: np.ndarray    # (H, W) int64 frame a pixel's bits belong to
    obits: np.ndarray    # (H, W, n_w) uint64 obstacle bits
    cbits: np.ndarray    # (H, W, n_w) uint64 classified bits
    clear: np.ndarray    # (H, W) int32 last slice of the free stretch from r(df)
    free_to: np.ndarray  # (H, W) float64 depth up to which the column is known free, m
    kmemo: tuple         # the other cameras' clearing memo (depth_grid_memo.new_memo)


def lazy_model(grid) -> LazyModel:
    """The :class:`LazyModel` of a :class:`~depthguard.fusion.depth_grid.DepthGridMap`."""
    return LazyModel(grid._pint, grid._Rp, grid._tp, float(grid.d_min), float(grid.delta_d), int(grid.n_d),
                     grid._koff, grid._kdims, grid._rays_arg, grid._orig_arg, grid._kint_arg, len(grid.others))


def lazy_frame(grid) -> LazyFrame:
    """The grid's current :class:`LazyFrame` (views of its buffers)."""
    views = grid._views
    return LazyFrame(grid._pfree, grid._pkind, grid._tmin, views.free, views.pmin, views.pmax, grid._caps,
                     int(grid._ncaps), grid._cap_lo, grid._cap_hi, grid._cap_n, grid._band)


def lazy_memo(grid) -> LazyMemo:
    """The grid's current :class:`LazyMemo` (its buffers, filled in place)."""
    return LazyMemo(int(grid._frame), grid._stamp, grid._obits, grid._cbits, grid._clear, grid._free_to, grid._kmemo)
