"""The depth grid's off-line map (Flacco & De Luca 2015; SPEC §3, R11), and its cache.

The map is kept compact: for every other camera ``k``, the rays through the
corners of the principal camera's pixels in ``k``'s frame, ``rays (nk, H+1,
W+1, 3)`` float64 (7.4 MB per camera for 640x480), and the principal's optical
centre in ``k``'s frame, ``origins (nk, 3)`` metres. Each cell's pixels in
``k`` and its depth range there follow on the fly
(:mod:`~depthguard.fusion.depth_grid_kernels` states the rule).

The map depends only on the cameras and the grid's slices, so it is built once
per rig and cached on disk under a key of every camera's
:meth:`~depthguard.camera.Camera.key` and the grid parameters: a changed rig
builds a new map; a file that cannot be read or does not match is rebuilt,
never trusted; a cache that cannot be written only costs a rebuild next time.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np

from depthguard.camera import Camera

__all__ = ["default_cache_dir", "map_key", "corner_rays", "load_map", "save_map"]

_FORMAT = 1


def default_cache_dir() -> Path:
    """``$DEPTHGUARD_CACHE`` or ``~/.cache/depthguard``."""
    return Path(os.environ.get("DEPTHGUARD_CACHE", Path.home() / ".cache" / "depthguard"))


def map_key(principal: Camera, others: list[Camera], d_min: float, delta_d: float, n_d: int) -> str:
    """24 hex digits naming the off-line map of these cameras and slices."""
    h = hashlib.sha256()
    h.update(repr((_FORMAT, principal.key(), [c.key() for c in others], d_min, delta_d, n_d)).encode())
    return h.hexdigest()[:24]


def corner_rays(principal: Camera, others: list[Camera], quiet: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """``(rays (nk, H+1, W+1, 3), origins (nk, 3))``: the corner rays of the principal's
    pixels, ``M_k ((u - 1/2 - cx)/fx, (v - 1/2 - cy)/fy, 1)``, and its optical centre, in
    each other camera's frame (R11); a progress bar unless ``quiet``."""
    from depthguard.progress import track

    P = principal
    H, W = P.height, P.width
    nk = len(others)
    rays = np.empty((max(nk, 1), H + 1, W + 1, 3))
    origins = np.zeros((max(nk, 1), 3))
    uc = (np.arange(W + 1) - 0.5 - P.cx) / P.fx
    vc = (np.arange(H + 1) - 0.5 - P.cy) / P.fy
    chunk = max(1, (H + 1) // 8)
    steps = [(k, r0) for k in range(nk) for r0 in range(0, H + 1, chunk)]
    Rpw = P.world_from_camera[:3, :3]
    tpw = P.world_from_camera[:3, 3]
    for k, r0 in track(steps, "depth grid map", quiet=quiet or not steps):
        cam = others[k]
        M = cam.R @ Rpw                        # principal frame -> k frame
        origins[k] = cam.R @ tpw + cam.t       # principal optical centre in k
        r1 = min(r0 + chunk, H + 1)
        c = np.empty((r1 - r0, W + 1, 3))
        c[..., 0] = uc[None, :]
        c[..., 1] = vc[r0:r1, None]
        c[..., 2] = 1.0
        rays[k, r0:r1] = c @ M.T
    if nk == 0:
        rays = rays[:0]
        origins = origins[:0]
    return np.ascontiguousarray(rays), np.ascontiguousarray(origins)


def save_map(path: Path, key: str, rays: np.ndarray, origins: np.ndarray) -> None:
    """Write the map to ``path`` (atomically: a temporary file renamed); nothing on an OSError."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + f".{os.getpid()}.tmp.npz")
        np.savez(tmp, key=np.array(key), rays=rays, origins=origins)
        os.replace(tmp, path)
    except OSError:
        pass  # a cache that cannot be written only costs a rebuild next time


def load_map(path: Path | None, key: str, shape: tuple[int, int], nk: int):
    """``(rays, origins)`` read from ``path`` when it holds the map named ``key`` for a principal
    image of ``shape`` ``(H, W)`` and ``nk`` other cameras, with finite values; else None."""
    if path is None or not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            stored = str(z["key"])
            rays = np.ascontiguousarray(z["rays"], dtype=np.float64)
            origins = np.ascontiguousarray(z["origins"], dtype=np.float64)
    except Exception:
        return None
    H, W = shape
    if (stored != key or rays.shape != (nk, H + 1, W + 1, 3) or origins.shape != (nk, 3)
            or not np.all(np.isfinite(rays)) or not np.all(np.isfinite(origins))):
        return None
    return rays, origins
