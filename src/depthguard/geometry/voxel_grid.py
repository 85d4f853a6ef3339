"""``VoxelGrid``: a box cut into cubic voxels (R21, R22).

The lattice of the free-space map (:mod:`depthguard.fusion.free_space`) and of the
motion checks that read it (:mod:`depthguard.control.motion_check`); pure geometry,
so it sits in ``geometry``, below both.
"""

from __future__ import annotations

import math
from typing import Iterable

import numpy as np

__all__ = ["VoxelGrid"]


class VoxelGrid:
    """Geometry of a box cut into cubic voxels.

    ``lo``, ``hi`` (3,) metres; the box is rounded *up* to whole voxels:
    ``shape = ceil((hi - lo) / voxel_size)``; voxel ``(i, j, k)`` spans
    ``lo + [i, i+1) * voxel_size``.
    """

    def __init__(self, lo, hi, voxel_size: float):
        lo = np.asarray(lo, dtype=np.float64).reshape(-1)
        hi = np.asarray(hi, dtype=np.float64).reshape(-1)
        if lo.shape != (3,) or hi.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError(f"bounds must be two finite 3-vectors (lo, hi), got {lo!r}, {hi!r}")
        if np.any(hi <= lo):
            raise ValueError(f"bounds: hi must exceed lo on every axis (lo={lo.tolist()}, hi={hi.tolist()})")
        s = float(voxel_size)
        if not (math.isfinite(s) and s > 0):
            raise ValueError(f"voxel_size must be a positive number of metres (got {voxel_size!r})")
        shape = np.ceil((hi - lo) / s - 1e-9).astype(np.int64)
        self.lo = lo
        self.voxel_size = s
        self.shape = tuple(int(n) for n in shape)
        self.hi = lo + shape * s

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    def centres(self) -> np.ndarray:
        """(nx*ny*nz, 3) voxel centres, C order over ``(i, j, k)``."""
        axes = [self.lo[a] + (np.arange(self.shape[a]) + 0.5) * self.voxel_size for a in range(3)]
        g = np.meshgrid(*axes, indexing="ij")
        return np.stack([x.ravel() for x in g], axis=1)

    def corners(self) -> np.ndarray:
        """((nx+1)*(ny+1)*(nz+1), 3) lattice of voxel corners, C order."""
        axes = [self.lo[a] + np.arange(self.shape[a] + 1) * self.voxel_size for a in range(3)]
        g = np.meshgrid(*axes, indexing="ij")
        return np.stack([x.ravel() for x in g], axis=1)

    def index_box(self, box_lo, box_hi) -> tuple[slice, slice, slice]:
        """Slices of the voxels whose extent meets the world box ``[box_lo, box_hi]``."""
        a = np.floor((np.asarray(box_lo) - self.lo) / self.voxel_size).astype(np.int64)
        b = np.floor((np.asarray(box_hi) - self.lo) / self.voxel_size).astype(np.int64) + 1
        a = np.clip(a, 0, self.shape)
        b = np.clip(b, 0, self.shape)
        return tuple(slice(int(a[k]), int(b[k])) for k in range(3))

    def block_centres(self, sl: tuple[slice, slice, slice]) -> np.ndarray:
        """(n, 3) centres of the voxels of a block given by :meth:`index_box`, C order."""
        axes = [self.lo[a] + (np.arange(sl[a].start, sl[a].stop) + 0.5) * self.voxel_size for a in range(3)]
        g = np.meshgrid(*axes, indexing="ij")
        return np.stack([x.ravel() for x in g], axis=1)

    def touched_by(self, primitives: Iterable, padding: float = 0.0) -> np.ndarray:
        """(nx, ny, nz) bool: voxels within ``padding`` of any primitive, *conservatively*.

        A voxel counts when the signed distance from its centre to a primitive is
        ``<= padding + s*sqrt(3)/2`` (half its diagonal): every voxel the padded
        primitive meets is included, plus a few it only nearly meets. Primitives
        need ``sdf(points)`` and ``bounds()`` (see :mod:`depthguard.geometry`).
        """
        out = np.zeros(self.shape, dtype=bool)
        reach = float(padding) + self.voxel_size * math.sqrt(3.0) / 2.0
        for prim in primitives:
            if not (hasattr(prim, "sdf") and hasattr(prim, "bounds")):
                raise ValueError(f"free volume entries must be geometry primitives with sdf() and bounds(), got {type(prim).__name__}")
            b = np.asarray(prim.bounds(), dtype=np.float64)
            sl = self.index_box(b[0] - reach, b[1] + reach)
            if any(s.stop <= s.start for s in sl):
                continue
            c = self.block_centres(sl)
            hit = np.asarray(prim.sdf(c)) <= reach
            out[sl] |= hit.reshape(tuple(s.stop - s.start for s in sl))
        return out
