"""Ground truth of simulated scenes: exact distances and voxel occupancy (R24, R25).

Every obstacle of a scene is a :class:`~depthguard.geometry.primitives.Primitive`
with an exact signed distance (negative inside). Mesh objects (CAD files)
become a :class:`MeshSolid`, whose distance is trimesh's closest point on the
surface and whose inside is trimesh's containment test (the mesh must be
watertight for the sign to mean anything).

Distance (R25's "true distance"): ``max(0, min_k sdf_k(p))`` — the exact
Euclidean distance from ``p`` to the nearest obstacle surface, 0 inside.

Occupancy of the grid ``lo + [i, i+1)·s`` (voxel (i, j, k); likewise j, k):

- ``mode="centre"``: occupied iff the voxel centre lies in an obstacle
  (``sdf(centre) <= 0``). Unbiased: the count of occupied voxels times ``s³``
  estimates the obstacles' volume.
- ``mode="any"``: occupied iff the obstacle *may* touch the voxel — a
  conservative superset of the voxels that intersect an obstacle. A voxel is
  a candidate when ``sdf(centre) <= s·√3/2`` (the distance is 1-Lipschitz,
  so every voxel that meets an obstacle passes); candidates are split into
  ``2**refine`` sub-cells per axis and kept when some sub-cell passes the
  same test at its own size. The superset adds only voxels within
  ``s·√3/2 / 2**refine`` of an obstacle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from depthguard.geometry.mesh import Mesh, as_mesh
from depthguard.geometry.packed import PackedSolids
from depthguard.geometry.primitives import Primitive

__all__ = ["MeshSolid", "true_distance", "occupancy", "grid_shape", "voxel_centres"]


@dataclass(frozen=True, eq=False)
class MeshSolid(Primitive):
    """A closed triangle mesh as a solid: ``local`` mesh (metres) posed by ``world_from_local``."""
    local: Mesh = None  # type: ignore[assignment]
    _tm: object = field(default=None, init=False, repr=False)

    def __post_init__(self):
        if self.local is None:
            raise ValueError(f"MeshSolid {self.name!r}: needs a mesh")
        m = as_mesh(self.local, name=f"mesh solid {self.name!r}")
        object.__setattr__(self, "local", m)
        import trimesh
        # process=True merges the duplicated vertices of STL files, so that closed meshes are watertight
        object.__setattr__(self, "_tm", trimesh.Trimesh(m.vertices, m.faces, process=True))

    def local_mesh(self) -> Mesh:
        return self.local

    @property
    def watertight(self) -> bool:
        return bool(self._tm.is_watertight)

    def sdf(self, points: np.ndarray) -> np.ndarray:
        """(N,) signed distance, metres, negative inside (inside only for watertight meshes)."""
        p = self._local(points)
        out = np.empty(len(p))
        if len(p) == 0:
            return out
        _, dist, _ = self._tm.nearest.on_surface(p)
        out[:] = dist
        if self.watertight:
            inside = self._tm.contains(p)
            out[inside] *= -1.0
        return out


def true_distance(obstacles: Sequence[Primitive], points: np.ndarray) -> np.ndarray:
    """(N,) exact distance (m) from each point (N, 3) to the nearest obstacle surface, 0 inside;
    ``inf`` when there are no obstacles."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim == 1 and p.shape == (3,):
        p = p[None]
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {np.shape(points)}")
    packed, rest = PackedSolids.split(obstacles)
    out = packed.sdf_min(p)                       # boxes, spheres, capsules, cylinders: one numba pass
    for prim in rest:                             # mesh solids: their own sdf
        np.minimum(out, prim.sdf(p), out=out)
    return np.maximum(out, 0.0)


def grid_shape(lo, hi, voxel_size: float) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int]]:
    """Checked ``(lo, hi, (nx, ny, nz))`` with ``n = ceil((hi - lo) / s)`` (a voxel may stick out of hi)."""
    lo = np.asarray(lo, dtype=np.float64).reshape(-1)
    hi = np.asarray(hi, dtype=np.float64).reshape(-1)
    if lo.shape != (3,) or hi.shape != (3,):
        raise ValueError(f"lo and hi must be 3-vectors (got {lo.shape}, {hi.shape})")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
        raise ValueError(f"need finite lo < hi on every axis (got lo={lo.tolist()}, hi={hi.tolist()})")
    s = float(voxel_size)
    if not (s > 0 and math.isfinite(s)):
        raise ValueError(f"voxel_size must be > 0 (got {voxel_size!r})")
    n = np.ceil((hi - lo) / s - 1e-9).astype(int)
    return lo, hi, (int(n[0]), int(n[1]), int(n[2]))


def voxel_centres(lo, voxel_size: float, i0, i1) -> np.ndarray:
    """(M, 3) centres of the voxels with index ``i0 <= (i, j, k) < i1``, C order over (i, j, k)."""
    axes = [lo[a] + (np.arange(i0[a], i1[a]) + 0.5) * voxel_size for a in range(3)]
    g = np.meshgrid(*axes, indexing="ij")
    return np.stack([x.ravel() for x in g], axis=1)


def occupancy(obstacles: Sequence[Primitive], lo, hi, voxel_size: float, mode: str = "centre",
              refine: int = 2) -> np.ndarray:
    """(nx, ny, nz) bool occupancy of the voxel grid over ``[lo, hi]`` (module docstring for the rule).

    Each obstacle is evaluated only on the voxels of its bounding box.
    """
    if mode not in ("centre", "any"):
        raise ValueError(f"mode must be 'centre' or 'any' (got {mode!r})")
    lo, hi, n = grid_shape(lo, hi, voxel_size)
    s = float(voxel_size)
    occ = np.zeros(n, dtype=bool)
    half_diag = s * math.sqrt(3) / 2
    for prim in obstacles:
        b = prim.bounds()
        pad = half_diag + 0.02 * float(np.max(b[1] - b[0])) + 1e-6
        i0 = np.clip(np.floor((b[0] - pad - lo) / s).astype(int), 0, n)
        i1 = np.clip(np.ceil((b[1] + pad - lo) / s).astype(int), 0, n)
        if np.any(i1 <= i0):
            continue
        c = voxel_centres(lo, s, i0, i1)
        d = prim.sdf(c)
        if mode == "centre":
            hit = d <= 0.0
        else:
            hit = d <= half_diag
            cand = np.nonzero(hit & (d > 0.0))[0]  # centre outside: refine
            if refine > 0 and cand.size:
                hit[cand] = _refine_any(prim, c[cand], s, refine)
        sub = occ[i0[0]:i1[0], i0[1]:i1[1], i0[2]:i1[2]]
        sub |= hit.reshape(sub.shape)
    return occ


def _refine_any(prim: Primitive, centres: np.ndarray, s: float, levels: int) -> np.ndarray:
    """For voxels (centres (M, 3), size s) that passed the coarse test: does some sub-cell
    ``levels`` halvings down still pass ``sdf(sub-centre) <= half its diagonal``? (superset test)"""
    offs = np.array([[dx, dy, dz] for dx in (-1, 1) for dy in (-1, 1) for dz in (-1, 1)], float)
    owner = np.arange(len(centres))
    cur = centres
    size = s
    for _ in range(levels):
        size /= 2
        cur = (cur[:, None, :] + offs[None] * (size / 2)).reshape(-1, 3)
        owner = np.repeat(owner, 8)
        d = prim.sdf(cur)
        ok = d <= size * math.sqrt(3) / 2
        cur, owner = cur[ok], owner[ok]
        if not len(owner):
            break
    keep = np.zeros(len(centres), dtype=bool)
    keep[owner] = True
    return keep
