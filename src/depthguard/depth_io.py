"""Depth images on disk (SPEC §1).

- ``.png``: 16-bit single channel, millimetres, 0 = no measurement.
- ``.npy``: float32 metres, 0 or NaN = no measurement.

In memory a depth image is ``(H, W) float32`` metres with 0 = no measurement.

:func:`depth_units_problem` is the one check that a depth image is in metres at all
(used by ``depthguard distance`` and by the monitor, which refuses such a frame as
``bad_units``): no sensor returns nearer than its ``min_range`` or much beyond its
``max_range``, so an image whose measured pixels mostly lie there is in the wrong units.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numba import njit

__all__ = ["read_depth", "write_depth", "DepthFileError", "depth_units_problem", "UnitsCheck", "UNITS_SHARE", "NEAR_LIMIT_M"]

_MAX_MM = 65535

#: share of the measured pixels outside the returns a sensor can give above which an image
#: is taken to be in the wrong units
UNITS_SHARE = 0.5

#: no depth camera measures nearer than this (m); metres written into a millimetre PNG
#: read back as at most 0.0655 m. A hand right in front of a lens that returns a little
#: nearer than its rated ``min_range`` stays above it.
NEAR_LIMIT_M = 0.1

#: the units check samples every this-th pixel in each direction: 4800 of a 640x480 frame, run
#: on every frame of every camera (issue 29: every 4th took 0.11 ms of a worker's CPU a frame in
#: a real-time run, every 8th 0.07)
UNITS_STEP = 8


class DepthFileError(ValueError):
    """A depth file is missing, of an unknown kind, or does not hold a depth image."""


def read_depth(path: str | Path, png_units_m: float = 0.001) -> np.ndarray:
    """Read a depth image as ``(H, W) float32`` metres, 0 where there is no measurement.

    ``png_units_m``: metres per unit of a 16-bit PNG (default millimetres; a TUM RGB-D
    PNG counts 1/5000 m: 0.0002)."""
    p = Path(path)
    if not p.is_file():
        raise DepthFileError(f"{p}: no such depth file")
    suffix = p.suffix.lower()
    if suffix == ".png":
        from PIL import Image

        try:
            with Image.open(p) as im:
                mode = im.mode
                arr = np.asarray(im)
        except Exception as exc:
            raise DepthFileError(f"{p}: not a readable PNG ({exc})") from None
        if arr.ndim != 2 or arr.dtype not in (np.uint16, np.int32, np.uint8) or mode not in ("I;16", "I;16B", "I", "L"):
            raise DepthFileError(
                f"{p}: a depth PNG must be 16-bit single-channel millimetres (got mode {mode}, shape {arr.shape})"
            )
        if mode == "L":
            raise DepthFileError(f"{p}: 8-bit PNG is not a depth image; expected 16-bit millimetres")
        if arr.dtype == np.int32 and (arr.min() < 0 or arr.max() > _MAX_MM):
            raise DepthFileError(f"{p}: values outside the 16-bit range")
        if arr.size == 0:
            raise DepthFileError(f"{p}: an empty image (shape {arr.shape})")
        if png_units_m != 0.001:
            return (arr.astype(np.float64) * float(png_units_m)).astype(np.float32)
        return (arr.astype(np.float32) / np.float32(1000.0)).astype(np.float32)
    if suffix == ".npy":
        try:
            arr = np.load(p, allow_pickle=False)
        except Exception as exc:
            raise DepthFileError(f"{p}: not a readable .npy array ({exc})") from None
        if arr.ndim != 2:
            raise DepthFileError(f"{p}: a depth image must be 2-D (got shape {arr.shape})")
        if arr.size == 0:
            raise DepthFileError(f"{p}: an empty image (shape {arr.shape})")
        if not np.issubdtype(arr.dtype, np.floating):
            raise DepthFileError(f"{p}: a .npy depth image must be float metres (got dtype {arr.dtype})")
        with np.errstate(invalid="ignore", over="ignore"):
            negative = int((arr < 0).sum())            # before float32 rounds -1e39 to -inf
            if negative:
                raise DepthFileError(f"{p}: negative depths ({negative} pixels)")
            out = arr.astype(np.float32)
        out[~np.isfinite(out)] = 0.0                   # NaN, inf and beyond float32: no measurement
        return out
    raise DepthFileError(f"{p}: unknown depth file type {suffix!r} (use .png or .npy)")


def depth_units_problem(depth: np.ndarray, cam) -> str | None:
    """A sentence when most measured pixels of ``depth`` lie outside what ``cam`` can return, else None.

    depth : (H, W) float metres, 0 or NaN = no measurement; cam : a
    :class:`~depthguard.camera.Camera` (``id``, ``min_range``, ``max_range``).

    More than :data:`UNITS_SHARE` of the measured pixels (every :data:`UNITS_STEP`-th pixel in
    each direction is enough to tell) beyond ``RETURN_LIMIT_FACTOR x max_range``: an image in
    millimetres read as metres. More than that share nearer than ``min_range`` and than
    :data:`NEAR_LIMIT_M`: metres written into a millimetre PNG. A real sensor gives 0, not
    a value, where it has no return, so neither happens with depth in the right units (R28).
    """
    from depthguard.camera import RETURN_LIMIT_FACTOR

    full = np.asarray(depth)
    d = full[::UNITS_STEP, ::UNITS_STEP]
    far_limit = RETURN_LIMIT_FACTOR * float(cam.max_range)
    near_limit = min(float(cam.min_range), NEAR_LIMIT_M)
    if full.ndim == 2 and full.dtype in (np.float32, np.float64):
        # one compiled loop over the sample (the limits in the image's dtype, as numpy compares)
        n, far, near = _units_counts(full, UNITS_STEP, full.dtype.type(far_limit), full.dtype.type(near_limit))
    else:
        n, far, near = _units_counts_numpy(d, far_limit, near_limit)
    if n == 0:
        return None
    if far <= UNITS_SHARE * n and near <= UNITS_SHARE * n:
        return None                                    # every frame of a live camera: no median
    with np.errstate(invalid="ignore"):
        measured = np.isfinite(d) & (d > 0)
    median = float(np.median(d[measured]))
    if far > UNITS_SHARE * n:
        return (f"camera {cam.id}: {100 * far / n:.0f} % of the measured pixels lie beyond {far_limit:g} m "
                f"(median {median:g}): depth must be metres - is this image in millimetres?")
    if near > UNITS_SHARE * n:
        return (f"camera {cam.id}: {100 * near / n:.0f} % of the measured pixels lie nearer than "
                f"{near_limit:g} m (median {median:g} m): a depth PNG holds millimetres - does this image "
                f"hold metres?")
    return None


class UnitsCheck:
    """:func:`depth_units_problem` for the frames of one camera ``cam``, its limits worked out
    once: ``check(depth)`` is the same sentence or None. A float32 / float64 (H, W) frame goes
    straight to the compiled count (a camera worker's every frame, issue 29: the function's
    conversions, import and limits cost more thread CPU than its count); another frame, or one
    whose counts call for a sentence, goes through :func:`depth_units_problem` itself."""

    def __init__(self, cam):
        from depthguard.camera import RETURN_LIMIT_FACTOR

        self.camera = cam
        far = RETURN_LIMIT_FACTOR * float(cam.max_range)
        near = min(float(cam.min_range), NEAR_LIMIT_M)
        # the limits in the image's dtype, as depth_units_problem passes them
        self._limits = {np.dtype(np.float32): (np.float32(far), np.float32(near)),
                        np.dtype(np.float64): (np.float64(far), np.float64(near))}

    def __call__(self, depth) -> str | None:
        limits = self._limits.get(depth.dtype) if type(depth) is np.ndarray and depth.ndim == 2 else None
        if limits is None:
            return depth_units_problem(depth, self.camera)
        n, far, near = _units_counts(depth, UNITS_STEP, limits[0], limits[1])
        if n == 0 or (far <= UNITS_SHARE * n and near <= UNITS_SHARE * n):
            return None
        return depth_units_problem(depth, self.camera)


@njit(cache=True)      # ~35 us a 640x480 frame: keeps the GIL (a release costs a retake behind the other threads)
def _units_counts(depth, step, far_limit, near_limit):
    """``(measured, far, near)`` pixel counts of :func:`depth_units_problem` over every
    ``step``-th pixel of ``depth`` (H, W) in both directions; the limits (m) of the image's dtype.
    Branch-free per row in 32-bit counts (a NaN fails ``x > 0``): about a third of the CPU of
    the branching loop on a 640x480 frame with dropouts (70 -> 21 us, one thread)."""
    H, W = depth.shape
    n = 0
    far = 0
    near = 0
    ws = (W + step - 1) // step
    for v in range(0, H, step):
        row = depth[v]
        a = np.int32(0)
        b = np.int32(0)
        c = np.int32(0)
        for i in range(ws):
            x = row[i * step]
            ok = (x > 0) & (x != np.inf)
            a += np.int32(ok)
            b += np.int32(ok & (x > far_limit))
            c += np.int32(ok & (x < near_limit))
        n += a
        far += b
        near += c
    return n, far, near


def _units_counts_numpy(d: np.ndarray, far_limit: float, near_limit: float) -> tuple[int, int, int]:
    """The plain-numpy twin of :func:`_units_counts` on the sampled image ``d``."""
    with np.errstate(invalid="ignore"):
        measured = np.isfinite(d) & (d > 0)
        return (int(measured.sum()), int((measured & (d > far_limit)).sum()),
                int((measured & (d < near_limit)).sum()))


def write_depth(path: str | Path, depth: np.ndarray) -> Path:
    """Write ``(H, W)`` metres as 16-bit millimetre PNG or float32 ``.npy``.

    PNG rounds to the nearest millimetre; depths beyond 65.535 m cannot be
    stored and raise ``ValueError`` rather than being clipped silently.
    """
    p = Path(path)
    d = np.asarray(depth)
    if d.ndim != 2:
        raise ValueError(f"depth must be a 2-D image (got shape {d.shape})")
    d = d.astype(np.float64)
    d[~np.isfinite(d)] = 0.0
    if (d < 0).any():
        raise ValueError("depth has negative values")
    suffix = p.suffix.lower()
    p.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".png":
        from PIL import Image

        mm = np.rint(d * 1000.0)
        if mm.max(initial=0) > _MAX_MM:
            raise ValueError(f"depth up to {d.max():.3f} m does not fit a 16-bit millimetre PNG")
        Image.fromarray(mm.astype(np.uint16)).save(p)
    elif suffix == ".npy":
        np.save(p, d.astype(np.float32))
    else:
        raise ValueError(f"unknown depth file type {suffix!r} (use .png or .npy)")
    return p
