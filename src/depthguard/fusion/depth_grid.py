"""Several cameras fused in the principal camera's depth space: the depth grid map
(Flacco & De Luca 2015; SPEC §3, R10–R12).

Use::

    grid = DepthGridMap(rig.cameras, principal="cam0", d_min=0.3, d_max=3.7, delta_d=0.01)
    res = grid.distance(depths, points, rho=0.4, method="hybrid",
                        robot_depths=robot_depths, robot_capsules=robot.collision_capsules(q, 0.05))

or, in a control loop, :meth:`DepthGridMap.set_frames` once per camera frame
and :meth:`DepthGridMap.query` once per control cycle (no allocation).

The off-line map (R11) is kept compact: the principal pixels' corner rays in
every other camera's frame, ``(H+1) (W+1) 3`` float64 per camera (7.4 MB for
640x480), from which each cell's pixels and ``dstart`` / ``dend`` follow on
the fly (:mod:`~depthguard.fusion.depth_grid_offline` builds and caches it,
:mod:`~depthguard.fusion.depth_grid_kernels` states the rule);
:func:`~depthguard.fusion.depth_grid_ref.explicit_map_numpy` builds the
paper's explicit table for small grids and the tests check they agree.

On-line work is split as the paper's footnote 1 suggests (frames at 30 Hz,
distances as fast as possible): :meth:`DepthGridMap.set_frames` stores, once
per frame, the per-pixel states, the other cameras' min/max pyramids and the
robot volume's depth intervals (a few ms for two 640x480 cameras). Which
cells of a principal column are obstacles (the confirmation of R12, per cell
or per stretch of cells where the pyramids prove a whole stretch cleared or
confirmed) is worked out lazily: the first :meth:`DepthGridMap.query` of a
frame that looks at a column classifies only the slices within ``rho`` of its
points and memoises them (per-pixel frame stamp, preallocated bits); later
queries reuse them. ``set_frames(..., lazy=False)`` is the eager form (every
column's obstacle runs at once, optionally limited by ``reach``); the tests
check both give the same answers.

When no camera sees the whole workspace,
:class:`~depthguard.fusion.depth_grid_multi.MultiPrincipalDepthGrid` keeps a map per camera and evaluates each control point with a principal
that sees it (the paper's future work).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from depthguard.config import PRODUCT_INVALID, PRODUCT_ROBOT_IN_OTHERS, PRODUCT_ROBOT_OFFSET   # the product's defaults, defined once
from depthguard.camera import Camera
from depthguard.distance.gaps import GapBuffers, check_gap_px
from depthguard.distance.silhouette import SilhouetteBuffers, check_silhouette_px
from depthguard.fusion import (depth_grid_capsules, depth_grid_eager, depth_grid_kernels, depth_grid_lazy,
                               depth_grid_lookup)
from depthguard.fusion.camera_views import CameraViews
from depthguard.fusion.free32 import FREE_DTYPE
from depthguard.fusion.depth_grid_memo import new_memo
from depthguard.fusion.depth_grid_share import install_share, memo_request
from depthguard.fusion.depth_grid_data import lazy_model
from depthguard.fusion.depth_grid_load import GridLoad
from depthguard.fusion.depth_grid_query import GridQuery
from depthguard.fusion.depth_grid_robot import GridRobot
from depthguard.fusion.depth_grid_offline import corner_rays, default_cache_dir, load_map, map_key, save_map
from depthguard.fusion.depth_grid_state import StateOptions, pyramid_layout, pyramid_levels, state_pyramids

__all__ = ["DepthGridMap", "default_cache_dir"]

RUNS_PER_COLUMN = 8          # obstacle runs kept per principal column; more are merged (safe side)


def _intrinsics_row(cam: Camera) -> list[float]:
    return [cam.fx, cam.fy, cam.cx, cam.cy, float(cam.width), float(cam.height),
            cam.min_range, cam.max_range]


def touch_pages(a: np.ndarray) -> int:
    """Write one element of every 4 KiB page of the C-contiguous array ``a`` with its own value
    (:meth:`DepthGridMap.touch`); returns ``a.nbytes``."""
    if not a.flags.c_contiguous:
        raise ValueError("touch_pages needs a C-contiguous array")
    every = a.reshape(-1)[:: max(1, 4096 // a.itemsize)]
    every[...] = every.copy()
    return int(a.nbytes)


class DepthGridMap(GridRobot, GridQuery, GridLoad):
    """Depth grid map of a rig (R10–R12): principal camera's pixels x depth slices.

    Parameters
    ----------
    cameras : list[Camera]
        Every camera of the rig (ids unique); the principal among them.
    principal : str or Camera
        The camera whose depth space carries the grid. It should see the
        whole space of interest (the paper's assumption 1): obstacles outside
        its image are not considered.
    d_min, d_max, delta_d : float, metres
        Grid depths: slice ``gd = r(d) = floor((d - d_min) / delta_d)`` for
        ``d`` in ``[d_min, d_max]``; ``n_d = ceil((d_max - d_min) / delta_d)`` slices.
        Gray space outside the grid cannot be confirmed free and stays obstacle.
    cache_dir : path or None
        Where the off-line map is cached (default :func:`default_cache_dir`);
        the file name carries a key of every camera's :meth:`Camera.key` and
        the grid parameters, so a changed rig builds a new map. A file that
        cannot be read or does not match is rebuilt, never trusted.
    cache : bool
        False: always build, never write.
    quiet : bool
        No progress output while building.
    principal_bin : int >= 1
        The grid's pixel is a ``principal_bin x principal_bin`` block of the principal's
        pixels (default 1: the paper's grid, one cell column per pixel). The principal's
        per-pixel state is binned by :func:`~depthguard.fusion.depth_grid_state.bin_state`
        (a block is free up to its nearest pixel's free depth) and the grid is the binned
        camera's (:meth:`~depthguard.camera.Camera.binned`): ``principal_bin**2`` times fewer
        columns to classify and look up, the other cameras at their full resolution. Every
        obstacle cell of the pixels lies in an obstacle cell of the blocks (or in space no camera
        clears), so a distance can only come out smaller, by at most a block's width at its
        depth; ``principal`` is then the binned camera, ``principal_full`` the camera itself.

    Attributes: ``principal`` (Camera), ``others`` (list[Camera]), ``shape``
    ``(H, W, n_d)``, ``nbytes`` (the map's tables), ``build_seconds``,
    ``from_cache``, ``cache_path``.
    """

    def __init__(self, cameras, principal, d_min: float, d_max: float, delta_d: float,
                 cache_dir=None, *, cache: bool = True, quiet: bool = True, principal_bin: int = 1):
        cams = list(cameras)
        if not cams:
            raise ValueError("DepthGridMap needs at least one camera")
        for c in cams:
            if not isinstance(c, Camera):
                raise ValueError(f"cameras must be depthguard Camera objects (got {type(c).__name__})")
        ids = [c.id for c in cams]
        if len(set(ids)) != len(ids):
            raise ValueError(f"camera ids must be unique (got {ids})")
        pid = principal.id if isinstance(principal, Camera) else principal
        if pid not in ids:
            raise ValueError(f"principal camera {pid!r} is not among the cameras {ids}")
        try:
            d_min, d_max, delta_d = float(d_min), float(d_max), float(delta_d)
        except (TypeError, ValueError):
            raise ValueError("d_min, d_max and delta_d must be numbers of metres") from None
        if not all(math.isfinite(x) for x in (d_min, d_max, delta_d)):
            raise ValueError("d_min, d_max and delta_d must be finite")
        if d_min < 0 or d_max <= d_min:
            raise ValueError(f"grid depths must satisfy 0 <= d_min < d_max (got d_min={d_min}, d_max={d_max})")
        if delta_d <= 0:
            raise ValueError(f"delta_d must be > 0 metres (got {delta_d})")
        n_d = int(math.ceil((d_max - d_min) / delta_d - 1e-9))
        if n_d > 1_000_000:
            raise ValueError(f"grid has {n_d} depth slices; increase delta_d")
        if isinstance(principal_bin, bool) or not isinstance(principal_bin, (int, np.integer)) or principal_bin < 1:
            raise ValueError(f"principal_bin must be an integer >= 1 (got {principal_bin!r})")
        self.principal_bin = int(principal_bin)
        self.principal_full: Camera = cams[ids.index(pid)]
        self.principal: Camera = self.principal_full.binned(self.principal_bin)
        self.others: list[Camera] = [c for c in cams if c.id != pid]
        self.d_min, self.delta_d, self.n_d = d_min, delta_d, n_d
        self.d_max = d_min + n_d * delta_d
        P = self.principal
        self.shape = (P.height, P.width, n_d)
        self._Rp = np.ascontiguousarray(P.R)
        self._tp = np.ascontiguousarray(P.t)
        self._pint = np.asarray(_intrinsics_row(P), dtype=np.float64)
        self._kint = np.asarray([_intrinsics_row(c) for c in self.others], dtype=np.float64).reshape(-1, 8)
        self.key = map_key(self.principal, self.others, self.d_min, self.delta_d, self.n_d)
        self.cache_path = None
        if cache:
            self.cache_path = Path(cache_dir if cache_dir is not None else default_cache_dir()) / \
                f"depthgrid-{self.key}.npz"
        t0 = time.perf_counter()
        self.from_cache = False
        loaded = load_map(self.cache_path, self.key, (P.height, P.width), len(self.others))
        if loaded is not None:
            self.rays, self.origins = loaded
            self.from_cache = True
        else:
            self.rays, self.origins = corner_rays(self.principal, self.others, quiet)
            if self.cache_path is not None:
                save_map(self.cache_path, self.key, self.rays, self.origins)
        self.build_seconds = time.perf_counter() - t0
        self._alloc_frames()
        self._caps = np.zeros((0, 7))
        self._caps_buf = np.zeros((32, 7))    # the capsules in the principal's frame (grown if needed)
        self._alloc_points(16)
        self.has_frames = False
        self._loaded_options = None           # (robot_offset, invalid, robot_in_others, silhouette_px, gap_px) of the last frames
        self._loaded_with_frame: set = set()  # cameras that had a frame in the last set_frames

    @property
    def nbytes(self) -> int:
        """Bytes of the off-line map (the compact tables)."""
        return int(self.rays.nbytes + self.origins.nbytes + self._kint.nbytes)

    def r(self, d):
        """Depth slice ``r(d) = floor((d - d_min) / delta_d)`` (R10); may fall outside ``0..n_d-1``."""
        return np.floor((np.asarray(d, dtype=np.float64) - self.d_min) / self.delta_d).astype(np.int64)

    def cell_pixels(self, camera_id: str, gx: int, gy: int, gd: int):
        """The map entry of cell ``(gx, gy, gd)`` for another camera (R11).

        Returns ``(pixels (M, 2) int [u, v], dstart, dend)`` in metres; ``M = 0``
        and NaN depths when that camera does not see the whole cell.
        """
        ids = [c.id for c in self.others]
        if camera_id not in ids:
            raise ValueError(f"{camera_id!r} is not a non-principal camera of this map ({ids})")
        H, W, nd = self.shape
        if not (0 <= gx < W and 0 <= gy < H and 0 <= gd < nd):
            raise ValueError(f"cell ({gx}, {gy}, {gd}) outside the grid {W}x{H}x{nd}")
        d1 = self.d_min + gd * self.delta_d
        seen, u0, u1, v0, v1, zmin, zmax = depth_grid_kernels.cell_footprint(self.rays, self.origins, self._kint,
                                                            ids.index(camera_id), gx, gy, d1,
                                                            self.d_min + (gd + 1) * self.delta_d)
        if not seen:
            return np.zeros((0, 2), dtype=np.int64), float("nan"), float("nan")
        uu, vv = np.meshgrid(np.arange(u0, u1 + 1), np.arange(v0, v1 + 1))
        return np.stack([uu.ravel(), vv.ravel()], axis=1), float(zmin), float(zmax)

    # ------------------------------------------------------------ on-line (R12)
    def _alloc_frames(self) -> None:
        P = self.principal
        # the principal's state: these buffers when the grid works it out, else the state's own
        # arrays (made per frame off the build and never written again: no copy)
        self._pfree_own = self._pfree = np.empty(P.shape)
        self._pkind_own = self._pkind = np.empty(P.shape, dtype=np.int8)
        nk = len(self.others)
        Hk = max([c.height for c in self.others], default=1)
        Wk = max([c.width for c in self.others], default=1)
        self._kfree = np.zeros((max(nk, 1), Hk, Wk), dtype=FREE_DTYPE)   # (free32: rounded down)
        self._kkind = np.empty((Hk, Wk), dtype=np.int8)
        levels = pyramid_levels(Hk, Wk)
        self._runs = np.zeros(P.shape + (RUNS_PER_COLUMN, 2), dtype=np.int32)
        self._nruns = np.zeros(P.shape, dtype=np.int32)
        self._band = np.zeros(P.shape + (2,), dtype=np.int32)
        self._band_full = False
        self._boxes = np.zeros((32, 4), dtype=np.int64)   # capsule_boxes output (grown if needed)
        self._tile_first = np.zeros((-(-P.height // depth_grid_kernels.TILE), -(-P.width // depth_grid_kernels.TILE)), dtype=np.int32)
        self._koff = np.zeros((max(nk, 1), levels), dtype=np.int64)
        self._kdims = np.ones((max(nk, 1), levels, 2), dtype=np.int64)
        size = 1
        for k, c in enumerate(self.others):
            offs, dims, n = pyramid_layout(c.height, c.width, levels)
            self._koff[k], self._kdims[k] = offs, dims
            size = max(size, n)
        self._kpmin = np.zeros((max(nk, 1), size), dtype=FREE_DTYPE)
        self._kpmax = np.zeros((max(nk, 1), size), dtype=FREE_DTYPE)
        # what the kernels read of each other camera: these buffers where the build works its
        # state out, else the state's own arrays (camera_views: no copy)
        self._views = CameraViews(nk)
        for k in range(max(nk, 1)):
            self._views.point(k, self._kfree[k], self._kpmin[k], self._kpmax[k])
        F = self.principal_full
        self._silhouette = SilhouetteBuffers((max(F.height, Hk), max(F.width, Wk)))
        self._gaps = GapBuffers((max(F.height, Hk), max(F.width, Wk)))
        self._loaded_options_pending = None
        self.states_used = 0       # camera states copied in (set_frames(states=...))
        self.pyramids_used = 0     # ... and the other cameras' pyramids made with them
        self.shares_used = 0       # ... and their clearing made off the build (set_frames(shares=...))
        self.share_requests = False  # keep share_request's snapshots (the monitor's grids)
        self._requests: dict = {}
        self._cap_lo = np.zeros(P.shape + (depth_grid_capsules.MAX_CAPS_PER_PIXEL,))
        self._cap_hi = np.zeros(P.shape + (depth_grid_capsules.MAX_CAPS_PER_PIXEL,))
        self._cap_n = np.zeros(P.shape, dtype=np.int64)
        self._cap_written = np.array([0, P.height - 1, 0, P.width - 1], dtype=np.int64)   # capsule_intervals'
        # lazy per-frame work: memoised cell classes per principal pixel (bits), frame stamps
        nw = (self.n_d + 63) // 64
        self._obits = np.zeros(P.shape + (nw,), dtype=np.uint64)
        self._cbits = np.zeros(P.shape + (nw,), dtype=np.uint64)
        self._stamp = np.zeros(P.shape, dtype=np.int64)
        # what each other camera clears, kept while that camera's frame is (depth_grid_memo)
        self._kmemo = new_memo(nk, P.height, P.width, nw)
        self._clear = np.zeros(P.shape, dtype=np.int32)
        self._free_to = np.zeros(P.shape)
        self._span = np.zeros((2,) + P.shape, dtype=np.int32)   # merged slice range per pixel
        self._frame = 0
        self._queried = -1        # the frame of the last query (the first query of a frame prefills)
        self._tmin = np.zeros(self._tile_first.shape)
        self.lazy = True
        self._rays_arg = self.rays if nk else np.zeros((1, 1, 1, 3))
        self._orig_arg = self.origins if nk else np.zeros((1, 3))
        self._kint_arg = self._kint if nk else np.zeros((1, 8))
        self._lazy_model = lazy_model(self)      # the camera set's tables as the lazy kernels take them

    def touch(self) -> int:
        """Write every memory page of the lazy path's per-frame buffers once, now, leaving their
        content as it is; returns the bytes touched. The system maps a page of a new array on its
        first write, so without this the first frames pay for it: about 150 MB for two 640x480
        cameras, 30-270 ms (R29: the frames' path; the monitor calls it off that path,
        :meth:`~depthguard.runtime.fusion_worker.FusionWorker.prepare`)."""
        arrays = (self._pfree_own, self._pkind_own, self._kfree, self._kkind, self._band, self._cap_lo, self._cap_hi,
                  self._cap_n, self._obits, self._cbits, self._stamp, *self._kmemo, self._clear, self._free_to,
                  self._span, self._kpmin, self._kpmax)
        return sum(touch_pages(a) for a in arrays)

    def _alloc_points(self, n: int) -> None:
        self._cap = n
        self._dist = np.empty(n)
        self._dir = np.empty((n, 3))
        self._count = np.empty(n, dtype=np.int64)
        self._obs = np.empty(n, dtype=np.bool_)
        self._ws = np.empty((n, 10))
        self._axbuf = np.empty((n, self.principal.width))

    def set_frames(self, depths: dict, robot_depths: dict | None = None,
                   robot_offset: float = PRODUCT_ROBOT_OFFSET, robot_capsules=None, invalid: str = PRODUCT_INVALID,
                   robot_in_others: str = PRODUCT_ROBOT_IN_OTHERS, reach=None, lazy: bool = True,
                   changed=None, silhouette_px: int = 0, gap_px: int = 0, states=None, shares=None) -> None:
        """Load one frame per camera (R9, R28, R32); call once per camera frame.

        depths : dict camera id -> (H, W) float metres (0 / NaN / inf / below
            ``min_range`` = invalid: the ray is unknown from ``min_range`` on; a finite
            value beyond ``max_range`` is a return beyond the rated range: free up to
            ``max_range``, unknown behind it). The principal's frame is required; a
            missing other camera clears nothing (safe).
        robot_depths : optional dict camera id -> (H, W) the robot rendered into
            that camera at its current joints (0 = no robot). A pixel is the
            robot's where ``measured >= robot_depth - robot_offset``: free up
            to the robot, unknown behind it (R9, R12 case 4).
        robot_capsules : the robot's padded volume (list of ``Capsule`` or
            ``(segments (C, 2, 3), radii (C,))``, world); cells inside are never
            obstacles. Usually ``robot.collision_capsules(q, padding)``.
        invalid : R28 policy for invalid pixels (0, NaN, below ``min_range``):
            ``"unknown"`` (default, safe): the ray is unknown from ``min_range``
            on — an obstacle for the principal unless another camera clears
            it, and it clears nothing in another camera (a return beyond
            ``max_range``: free up to ``max_range``, unknown behind); ``"free"``:
            nothing on the ray, beyond-range returns included (for simulated
            cells without walls, where 0 means the ray left the scene).
        robot_in_others : what a robot pixel of a *non-principal* camera says.
            ``"unknown"`` (default, R9): free up to the robot, unknown behind
            it, so space hidden by the robot from that camera stays obstacle
            when the principal cannot see it either. ``"free"`` (the paper's
            removal): the pixel confirms nothing; this drops the robot's
            shadow in the other cameras (the shadow of fig. 12 disappears)
            but a hand hidden behind the robot from every camera is missed.
        reach : optional region holding every ball of radius ``rho`` around the
            points that will be queried with this frame: a world box
            ``(lo (3,), hi (3,))`` or capsules (list of ``Capsule`` or
            ``(segments, radii)``, e.g. :meth:`robot_reach`). Gray cells outside
            it are not examined and count as obstacles (safe); answers for
            points whose balls lie inside are the same as without ``reach``,
            at a fraction of the cost.
        lazy : True (default): the frame only stores the per-pixel states, the
            other cameras' pyramids and the capsule intervals; each principal
            column's cells are classified on first use by a query within this
            frame, only over the slices within ``rho`` of its points, and kept
            (per-pixel frame stamp, preallocated bits). False: every column's
            obstacle runs now (the eager form; same answers unless a column has
            more than ``RUNS_PER_COLUMN`` runs, which are then merged on the safe side).
        changed : optional ids of the cameras whose frame (or robot depth) is new since
            the previous call; the others keep the per-pixel states and pyramids computed
            then (cameras that are not synchronised deliver one at a time). ``None``
            (default): every camera is loaded again. A camera that was not loaded by the
            previous call with the same ``robot_offset``, ``invalid``,
            ``robot_in_others``, ``silhouette_px`` and ``gap_px`` is loaded regardless; the robot
            volume and the memo are always renewed.
        silhouette_px : int >= 0 pixels (default 0: off, today's answers). With
            ``invalid="unknown"``, an *invalid* pixel of a camera within
            ``silhouette_px`` pixels of the robot's silhouette in that camera's
            ``robot_depths`` image is a robot pixel free up to the smallest robot
            depth of its ``(2n+1)^2`` window, unknown behind it (R9, R32): the
            dropout at the robot's outline is no obstacle, the cells behind it must
            be cleared by the other cameras as for any robot pixel (R12). In a
            non-principal camera this holds with ``robot_in_others="free"`` too (the
            pixel is only presumed to be the robot, so it clears only the space in
            front of it). Invalid pixels farther away stay unknown from
            ``min_range`` (R28); valid pixels are unchanged. The product runs with 4.
        states : optional dict camera id -> :class:`~depthguard.fusion.depth_grid_state.CameraState`,
            the frame's per-pixel state made off the build (the camera's share, e.g. on its
            worker thread, :class:`~depthguard.fusion.depth_grid_state.StateMaker`) from the same
            ``depths`` / ``robot_depths``; copied in where it was made with these options and
            role, worked out here otherwise. ``states_used`` counts the states copied in.
        shares : optional dict camera id -> :class:`~depthguard.fusion.depth_grid_share.CameraShare`,
            another camera's clearing of some columns made off the build from its state in
            ``states`` (:mod:`~depthguard.fusion.depth_grid_share`): installed as that camera's
            memo where it was made with this grid's tables and that very state (the same bits
            the build would work out). ``shares_used`` counts them.
        gap_px : int >= 0 pixels (default 0: off, today's answers). With
            ``invalid="unknown"``, an invalid pixel (outside the silhouette rule) in a
            run of at most ``gap_px`` invalid pixels along its row or column, bounded
            by returns on both sides, is free up to the nearer end's depth and unknown
            behind it (not from ``min_range``): the fixed scene's edge dropout. The
            price: an all-invalid object at most ``gap_px`` pixels wide in front of
            both neighbours can be missed (:mod:`depthguard.distance.gaps`).
        """
        if not isinstance(depths, dict):
            raise ValueError("depths must be a dict camera id -> depth image")
        robot_depths = robot_depths or {}
        if not isinstance(robot_depths, dict):
            raise ValueError("robot_depths must be a dict camera id -> rendered robot depth")
        known = {self.principal.id, *(c.id for c in self.others)}
        for name, d in (("depths", depths), ("robot_depths", robot_depths)):
            extra = set(d) - known
            if extra:
                raise ValueError(f"{name} names unknown camera(s) {sorted(extra)}; cameras: {sorted(known)}")
        off = float(robot_offset)
        if not (math.isfinite(off) and off >= 0):
            raise ValueError(f"robot_offset must be finite and >= 0 metres (got {robot_offset!r})")
        if invalid not in ("unknown", "free"):
            raise ValueError(f"invalid must be 'unknown' or 'free' (got {invalid!r})")
        if robot_in_others not in ("unknown", "free"):
            raise ValueError(f"robot_in_others must be 'unknown' or 'free' (got {robot_in_others!r})")
        n_sil = check_silhouette_px(silhouette_px)
        n_gap = check_gap_px(gap_px)
        P = self.principal
        if P.id not in depths:
            raise ValueError(f"depths has no frame of the principal camera {P.id!r}")
        options = StateOptions(off, invalid, robot_in_others, n_sil, n_gap)
        if states is not None and not isinstance(states, dict):
            raise ValueError("states must be a dict camera id -> CameraState")
        if changed is None or options != self._loaded_options:
            fresh = set(known)
        else:
            fresh = set(changed)
            extra = fresh - known
            if extra:
                raise ValueError(f"changed names unknown camera(s) {sorted(extra)}; cameras: {sorted(known)}")
            # a camera loaded last time from nothing (no frame) must be loaded once its frame comes
            fresh |= {cid for cid in known if (cid in depths) != (cid in self._loaded_with_frame)}
        # a failure half-way leaves a mix of old and new states: no frames until the next call
        self.has_frames = False
        self._loaded_options = None
        self._loaded_options_pending = options
        self._load_frames(fresh, depths, robot_depths, off, robot_in_others, reach, lazy, robot_capsules,
                          states or {}, shares or {})
        self._loaded_options = options
        self._loaded_with_frame = {cid for cid in known if cid in depths}

    def _load_frames(self, fresh, depths, robot_depths, off, robot_in_others, reach, lazy, robot_capsules,
                     states, shares) -> None:
        """The loading part of :meth:`set_frames` (arguments checked there)."""
        P = self.principal
        if P.id in fresh:
            self._principal_state(depths[P.id], robot_depths.get(P.id), states.get(P.id))
            depth_grid_lazy.tile_min(self._pfree, self._tmin)     # what a new frame needs of the lazy memo
        for k, cam in enumerate(self.others):
            if cam.id not in fresh:
                continue
            if self.share_requests:               # what the builds asked of k during its old frame
                self._requests[k] = memo_request(self._kmemo[1], self._kmemo[2], k, self._kmemo[0][k], self._stamp,
                                                 self._frame, self._span)
            self._kmemo[0][k] += 1                # its memoised clearings belong to the old frame
            used = None
            if cam.id in depths:
                used = self._other_state(k, cam, depths[cam.id], robot_depths.get(cam.id),
                                         robot_in_others == "free", states.get(cam.id))
            else:
                self._kfree[k].fill(0.0)          # nothing seen: clears nothing
                self._views.point(k, self._kfree[k], self._kpmin[k], self._kpmax[k])
            if used is not None and self._pyramids_usable(used):
                self.pyramids_used += 1           # the camera's pyramids, made with its state, read in place
                share = shares.get(cam.id)
                if share is not None and share.state is used and share.key == (self.key, k, self._koff.shape[1]):
                    install_share(self._kmemo[1], self._kmemo[2], self._kmemo[3], k, self._kmemo[0][k],
                                  share.idx, share.done, share.clr, self.principal.width)
                    self.shares_used += 1
                continue
            # build_pyramids' arrays bit for bit, in vectorised row passes (0.5x its time, issue 29)
            free = self._views.arrays(k)[0]
            state_pyramids(free, cam.height, cam.width, self._kpmin[k], self._kpmax[k], self._koff[k], self._kdims[k],
                           1)
            self._views.point(k, free, self._kpmin[k], self._kpmax[k])
        self._set_band(reach)
        self.lazy = bool(lazy)
        self.set_robot_capsules(robot_capsules)
        if self.lazy:
            self.has_frames = True
            return
        depth_grid_eager.column_runs(self._pfree, self._pkind, self._pint, self.d_min, self.delta_d, self.n_d,
                      self._views.free, self._views.pmin, self._views.pmax, self._koff, self._kdims, self._rays_arg,
                      self._orig_arg, self._kint_arg, len(self.others), self._caps, self._ncaps,
                      self._cap_lo, self._cap_hi, self._cap_n, self._band, self._runs, self._nruns)
        depth_grid_lookup.tile_first_cells(self._runs, self._nruns, self._tile_first)
        self.has_frames = True

    def __repr__(self) -> str:
        H, W, nd = self.shape
        return (f"DepthGridMap(principal={self.principal.id!r}, others={[c.id for c in self.others]}, "
                f"{W}x{H}x{nd} cells, d=[{self.d_min:.4f}, {self.d_max:.4f}] m, "
                f"delta_d={self.delta_d} m, {self.nbytes / 1e6:.1f} MB)")
