"""Solid primitives packed into arrays for one numba signed-distance pass (ground truth, R24, R25).

:func:`~depthguard.geometry.primitives.sdf_union` asks each primitive for its
distance with a few numpy calls; over a run of the closed loop (a few hundred
points on the robot's capsule axes against a dozen primitives, 500 times per
simulated second) that Python overhead is most of the ground truth's cost.
:class:`PackedSolids` holds the same primitives as flat arrays and
:func:`packed_sdf_min` evaluates the union in one compiled pass:

- ``kind`` (K,) int8: :data:`BOX`, :data:`SPHERE`, :data:`CAPSULE`, :data:`CYLINDER`;
- ``local_from_world`` (K, 3, 4) float64: ``[R^T | -R^T t]`` of each pose
  ``world_from_local = [R | t]`` (rigid);
- ``size`` (K, 3) float64, metres: box half extents; sphere ``(r, 0, 0)``;
  capsule and cylinder ``(r, half length, 0)`` along local z.

The formulas are those of the primitives' own ``sdf`` methods (negative
inside), which the tests use as the independent twin. Primitives of other
types (a :class:`~depthguard.sim.ground_truth.MeshSolid`) are not packed:
:meth:`PackedSolids.split` hands them back for their own ``sdf``.
"""

from __future__ import annotations

import math
from typing import Sequence

import numba
import numpy as np

from depthguard.geometry.primitives import Box, Capsule, Cylinder, Primitive, Sphere

__all__ = ["BOX", "SPHERE", "CAPSULE", "CYLINDER", "PackedSolids", "packed_sdf_min"]

BOX, SPHERE, CAPSULE, CYLINDER = 0, 1, 2, 3


class PackedSolids:
    """Boxes, spheres, capsules and cylinders as arrays (module docstring); immutable once built."""

    def __init__(self, kind: np.ndarray, local_from_world: np.ndarray, size: np.ndarray):
        self.kind = np.ascontiguousarray(kind, dtype=np.int8)
        self.local_from_world = np.ascontiguousarray(local_from_world, dtype=np.float64)
        self.size = np.ascontiguousarray(size, dtype=np.float64)
        k = len(self.kind)
        if self.local_from_world.shape != (k, 3, 4) or self.size.shape != (k, 3):
            raise ValueError(f"packed solids: kind ({k},), local_from_world {self.local_from_world.shape} "
                             f"and size {self.size.shape} do not match")
        for a in (self.kind, self.local_from_world, self.size):
            a.setflags(write=False)

    def __len__(self) -> int:
        return len(self.kind)

    @staticmethod
    def split(primitives: Sequence[Primitive]) -> tuple["PackedSolids", list[Primitive]]:
        """``(packed, rest)``: the boxes, spheres, capsules and cylinders of ``primitives``
        packed, and every other primitive as it is."""
        kinds, mats, sizes, rest = [], [], [], []
        for p in primitives:
            if isinstance(p, Box):
                kinds.append(BOX)
                sizes.append(tuple(0.5 * float(s) for s in p.size))
            elif isinstance(p, Sphere):
                kinds.append(SPHERE)
                sizes.append((float(p.radius), 0.0, 0.0))
            elif isinstance(p, Capsule):
                kinds.append(CAPSULE)
                sizes.append((float(p.radius), 0.5 * float(p.length), 0.0))
            elif isinstance(p, Cylinder):
                kinds.append(CYLINDER)
                sizes.append((float(p.radius), 0.5 * float(p.length), 0.0))
            else:
                rest.append(p)
                continue
            T = p.world_from_local
            Rt = T[:3, :3].T
            m = np.empty((3, 4))
            m[:, :3] = Rt
            m[:, 3] = -(Rt @ T[:3, 3])
            mats.append(m)
        k = len(kinds)
        packed = PackedSolids(np.asarray(kinds, dtype=np.int8).reshape(k),
                              np.asarray(mats, dtype=np.float64).reshape(k, 3, 4),
                              np.asarray(sizes, dtype=np.float64).reshape(k, 3))
        return packed, rest

    def sdf_min(self, points: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(N,) signed distance (m, negative inside) from ``points`` (N, 3) to the union; ``+inf``
        when empty. ``out`` (N,) float64 is filled and returned if given."""
        p = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        if out is None:
            out = np.empty(len(p))
        elif out.shape != (len(p),) or out.dtype != np.float64:
            raise ValueError(f"out must be float64 of shape ({len(p)},), got {out.dtype} {out.shape}")
        return packed_sdf_min(self.kind, self.local_from_world, self.size, p, out)


@numba.njit(cache=True, nogil=True)
def packed_sdf_min(kind, local_from_world, size, points, out):
    """Kernel of :meth:`PackedSolids.sdf_min`: ``out[i] = min_k sdf_k(points[i])`` (inf if K = 0)."""
    n = points.shape[0]
    for i in range(n):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        best = np.inf
        for k in range(kind.shape[0]):
            A = local_from_world[k]
            x = A[0, 0] * px + A[0, 1] * py + A[0, 2] * pz + A[0, 3]
            y = A[1, 0] * px + A[1, 1] * py + A[1, 2] * pz + A[1, 3]
            z = A[2, 0] * px + A[2, 1] * py + A[2, 2] * pz + A[2, 3]
            c = kind[k]
            if c == 0:                                   # box
                qx = abs(x) - size[k, 0]
                qy = abs(y) - size[k, 1]
                qz = abs(z) - size[k, 2]
                ox, oy, oz = max(qx, 0.0), max(qy, 0.0), max(qz, 0.0)
                d = math.sqrt(ox * ox + oy * oy + oz * oz) + min(max(qx, max(qy, qz)), 0.0)
            elif c == 1:                                 # sphere
                d = math.sqrt(x * x + y * y + z * z) - size[k, 0]
            elif c == 2:                                 # capsule along z
                h = size[k, 1]
                zz = z - min(max(z, -h), h)
                d = math.sqrt(x * x + y * y + zz * zz) - size[k, 0]
            else:                                        # cylinder along z
                dr = math.hypot(x, y) - size[k, 0]
                dz = abs(z) - size[k, 1]
                d = math.hypot(max(dr, 0.0), max(dz, 0.0)) + min(max(dr, dz), 0.0)
            if d < best:
                best = d
        out[i] = best
    return out
