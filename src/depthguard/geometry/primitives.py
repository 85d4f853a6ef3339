"""Solid primitives with a triangle mesh and an exact signed distance.

Each primitive has a pose ``world_from_local`` (4x4) and offers
``mesh()`` (outward-wound :class:`~depthguard.geometry.mesh.Mesh` in the
world), ``sdf(points)`` ((N, 3) -> (N,) signed distance in metres, negative
inside) and ``bounds()`` ((2, 3) world AABB). Scenes are built from them so
that ground truth (distance, occupancy) is analytic, not sampled.
"""

from __future__ import annotations

import functools
import math

from dataclasses import dataclass, field

import numpy as np

from depthguard.geometry.mesh import Mesh
from depthguard.transforms import invert_rigid, transform_points

__all__ = ["Primitive", "Box", "Sphere", "Capsule", "Cylinder", "sdf_union"]


@dataclass(frozen=True, eq=False)
class Primitive:
    world_from_local: np.ndarray = field(default_factory=lambda: np.eye(4), kw_only=True)
    name: str = field(default="", kw_only=True)

    def _local(self, points: np.ndarray) -> np.ndarray:
        return transform_points(invert_rigid(self.world_from_local), np.asarray(points, dtype=np.float64).reshape(-1, 3))

    def mesh(self) -> Mesh:
        return self.local_mesh().transformed(self.world_from_local)

    def bounds(self) -> np.ndarray:
        v = self.mesh().vertices
        pad = self._bounds_pad()
        return np.stack([v.min(0) - pad, v.max(0) + pad])

    def _bounds_pad(self) -> float:
        return 0.0

    def moved(self, T: np.ndarray) -> "Primitive":
        """A copy posed at ``T @ world_from_local``."""
        import dataclasses
        return dataclasses.replace(self, world_from_local=np.asarray(T) @ self.world_from_local)

    def at(self, world_from_local: np.ndarray) -> "Primitive":
        """A copy with the given pose."""
        import dataclasses
        return dataclasses.replace(self, world_from_local=np.asarray(world_from_local, dtype=np.float64))

    # subclasses
    def local_mesh(self) -> Mesh:  # pragma: no cover - abstract
        raise NotImplementedError

    def sdf(self, points: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError


@dataclass(frozen=True, eq=False)
class Box(Primitive):
    """Box of full ``size`` (3,) centred on its local origin."""
    size: tuple[float, float, float] = (1.0, 1.0, 1.0)

    @staticmethod
    def from_bounds(lo, hi, name: str = "") -> "Box":
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        T = np.eye(4)
        T[:3, 3] = (lo + hi) / 2
        return Box(size=tuple(hi - lo), world_from_local=T, name=name)

    def local_mesh(self) -> Mesh:
        h = np.asarray(self.size, dtype=np.float64) / 2
        v = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float) * h
        # vertex index = 4*ix + 2*iy + iz ; faces wound outward
        f = np.array([
            [0, 1, 3], [0, 3, 2],  # -x
            [4, 6, 7], [4, 7, 5],  # +x
            [0, 4, 5], [0, 5, 1],  # -y
            [2, 3, 7], [2, 7, 6],  # +y
            [0, 2, 6], [0, 6, 4],  # -z
            [1, 5, 7], [1, 7, 3],  # +z
        ], dtype=np.int32)
        return Mesh(v, f)

    def sdf(self, points: np.ndarray) -> np.ndarray:
        p = self._local(points)
        q = np.abs(p) - np.asarray(self.size, dtype=np.float64) / 2
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
        inside = np.minimum(q.max(axis=1), 0.0)
        return outside + inside


@dataclass(frozen=True, eq=False)
class Sphere(Primitive):
    radius: float = 0.1
    segments: int = 24

    def local_mesh(self) -> Mesh:
        return _uv_sphere(self.radius, self.segments)

    def sdf(self, points: np.ndarray) -> np.ndarray:
        return np.linalg.norm(self._local(points), axis=1) - self.radius


@dataclass(frozen=True, eq=False)
class Capsule(Primitive):
    """Capsule whose axis runs along local z from ``-length/2`` to ``+length/2``."""
    radius: float = 0.05
    length: float = 0.2
    segments: int = 16

    @staticmethod
    def between(a, b, radius: float, name: str = "", segments: int = 16) -> "Capsule":
        """Capsule whose segment runs from world point ``a`` to ``b``."""
        a, b = np.asarray(a, float), np.asarray(b, float)
        return Capsule(radius=radius, length=float(np.linalg.norm(b - a)), segments=segments,
                       world_from_local=_frame_along(a, b), name=name)

    def local_mesh(self) -> Mesh:
        return _capsule_mesh(self.radius, self.length, self.segments)

    def sdf(self, points: np.ndarray) -> np.ndarray:
        p = self._local(points)
        h = self.length / 2
        z = np.clip(p[:, 2], -h, h)
        d = p.copy()
        d[:, 2] -= z
        return np.linalg.norm(d, axis=1) - self.radius

    def segment(self) -> tuple[np.ndarray, np.ndarray]:
        """World end points of the axis."""
        h = self.length / 2
        return tuple(transform_points(self.world_from_local, np.array([[0, 0, -h], [0, 0, h]], float)))


@dataclass(frozen=True, eq=False)
class Cylinder(Primitive):
    """Closed cylinder along local z, centred on the origin."""
    radius: float = 0.05
    length: float = 0.2
    segments: int = 24

    @staticmethod
    def between(a, b, radius: float, name: str = "", segments: int = 24) -> "Cylinder":
        a, b = np.asarray(a, float), np.asarray(b, float)
        return Cylinder(radius=radius, length=float(np.linalg.norm(b - a)), segments=segments,
                        world_from_local=_frame_along(a, b), name=name)

    def local_mesh(self) -> Mesh:
        n = self.segments
        a = np.linspace(0, 2 * np.pi, n, endpoint=False)
        h = self.length / 2
        ring = np.stack([self.radius * np.cos(a), self.radius * np.sin(a)], axis=1)
        v = np.concatenate([np.c_[ring, np.full(n, -h)], np.c_[ring, np.full(n, h)],
                            [[0, 0, -h], [0, 0, h]]])
        f = []
        for i in range(n):
            j = (i + 1) % n
            f += [[i, j, n + j], [i, n + j, n + i]]          # side
            f += [[2 * n, j, i], [2 * n + 1, n + i, n + j]]  # bottom, top
        return Mesh(v, np.asarray(f, dtype=np.int32))

    def sdf(self, points: np.ndarray) -> np.ndarray:
        p = self._local(points)
        dr = np.hypot(p[:, 0], p[:, 1]) - self.radius
        dz = np.abs(p[:, 2]) - self.length / 2
        outside = np.hypot(np.maximum(dr, 0), np.maximum(dz, 0))
        return outside + np.minimum(np.maximum(dr, dz), 0.0)


def sdf_union(primitives, points: np.ndarray) -> np.ndarray:
    """(N,) signed distance to the union of ``primitives`` (+inf if there are none)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.full(len(p), np.inf)
    for prim in primitives:
        np.minimum(out, prim.sdf(p), out=out)
    return out


# ---------------------------------------------------------------- helpers
def _frame_along(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pose whose origin is the midpoint of ``a b`` and whose z axis points along it."""
    z = b - a
    n = math.sqrt(float(z @ z))
    z = z / n if n > 0 else np.array([0.0, 0.0, 1.0])
    z0, z1, z2 = (float(c) for c in z)
    # x = z x e_z (or z x e_x near the vertical), normalised; y = z x x (plain floats: this
    # runs for every capsule of every person at every control cycle)
    x0, x1, x2 = (z1, -z0, 0.0) if abs(z2) < 0.9 else (0.0, z2, -z1)
    nx = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
    x0, x1, x2 = x0 / nx, x1 / nx, x2 / nx
    T = np.eye(4)
    T[:3, 0] = (x0, x1, x2)
    T[:3, 1] = (z1 * x2 - z2 * x1, z2 * x0 - z0 * x2, z0 * x1 - z1 * x0)
    T[:3, 2] = (z0, z1, z2)
    T[:3, 3] = (a + b) / 2
    return T


def _uv_sphere(r: float, n: int) -> Mesh:
    return _capsule_mesh(r, 0.0, n)


def _capsule_mesh(r: float, length: float, n: int) -> Mesh:
    """Capsule (sphere when ``length == 0``) as a UV mesh: ``n`` around, ``n//2`` rings per cap."""
    v0, zsign, faces = _capsule_template(float(r), int(n))
    v = v0.copy()
    v[:, 2] += zsign * (length / 2)
    return Mesh(v, faces)


@functools.lru_cache(maxsize=128)
def _capsule_template(r: float, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The capsule mesh of :func:`_capsule_mesh` at length 0 (read-only, memoised: people and
    robot links ask for the same few radii at every frame), the side (-1 bottom cap, +1 top
    cap) of each vertex, and the faces."""
    m = max(n // 4, 2)  # rings per hemisphere (excluding the pole)
    az = np.linspace(0, 2 * np.pi, n, endpoint=False)
    rings = []  # (z, radius, side)
    for i in range(1, m + 1):  # bottom hemisphere from the pole upward
        t = -np.pi / 2 + np.pi / 2 * i / m
        rings.append((r * np.sin(t), r * np.cos(t), -1.0))
    for i in range(0, m):  # top hemisphere
        t = np.pi / 2 * i / m
        rings.append((r * np.sin(t), r * np.cos(t), 1.0))
    verts = [[0.0, 0.0, -r]]
    side = [-1.0]
    for z, rr, sd in rings:
        verts += [[rr * np.cos(a), rr * np.sin(a), z] for a in az]
        side += [sd] * n
    verts.append([0.0, 0.0, r])
    side.append(1.0)
    v = np.asarray(verts)
    top = len(v) - 1
    f = []
    for j in range(n):  # bottom fan
        k = (j + 1) % n
        f.append([0, 1 + k, 1 + j])
    for i in range(len(rings) - 1):
        b0, b1 = 1 + i * n, 1 + (i + 1) * n
        for j in range(n):
            k = (j + 1) % n
            f += [[b0 + j, b0 + k, b1 + k], [b0 + j, b1 + k, b1 + j]]
    last = 1 + (len(rings) - 1) * n
    for j in range(n):  # top fan
        k = (j + 1) % n
        f.append([top, last + j, last + k])
    faces = np.asarray(f, dtype=np.int32)
    zs = np.asarray(side)
    for a in (v, zs, faces):
        a.setflags(write=False)
    return v, zs, faces
