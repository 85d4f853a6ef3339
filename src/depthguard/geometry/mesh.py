"""Triangle meshes as plain arrays (R16).

A :class:`Mesh` is a ``NamedTuple`` of ``vertices`` (V, 3) float64 metres and
``faces`` (F, 3) int32 vertex indices, counter-clockwise seen from outside
(so the outward normal is ``(b - a) x (c - a)``). Being a tuple, it unpacks
as ``vertices, faces`` wherever the public API takes ``(vertices, faces)``.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple, Sequence

import numpy as np

from depthguard.transforms import transform_points

__all__ = ["Mesh", "as_mesh", "merge_meshes", "load_mesh"]


class Mesh(NamedTuple):
    vertices: np.ndarray  # (V, 3) float64, metres
    faces: np.ndarray     # (F, 3) int32

    def transformed(self, T: np.ndarray) -> "Mesh":
        """The mesh moved by the 4x4 rigid transform ``T``."""
        return Mesh(transform_points(T, self.vertices), self.faces)

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) axis-aligned bounds ``[lo, hi]``."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])


def as_mesh(m, name: str = "mesh") -> Mesh:
    """Accept a :class:`Mesh`, a ``(vertices, faces)`` pair or a ``trimesh.Trimesh``."""
    if hasattr(m, "vertices") and hasattr(m, "faces") and not isinstance(m, Mesh):
        m = (m.vertices, m.faces)
    try:
        v, f = m
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a (vertices, faces) pair") from None
    v = np.ascontiguousarray(v, dtype=np.float64)
    f = np.asarray(f)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"{name}: vertices must have shape (V, 3), got {v.shape}")
    if f.size == 0:
        f = f.reshape(0, 3)
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"{name}: faces must be an integer array of shape (F, 3), got {f.dtype} {f.shape}")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(f"{name}: face indices must lie in [0, {len(v)})")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name}: vertices must be finite")
    return Mesh(v, np.ascontiguousarray(f, dtype=np.int32))


def merge_meshes(meshes: Sequence[Mesh]) -> Mesh:
    """One mesh holding all triangles of ``meshes``."""
    meshes = [as_mesh(m) for m in meshes]
    if not meshes:
        return Mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int32))
    offs = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
    return Mesh(np.concatenate([m.vertices for m in meshes]),
                np.concatenate([m.faces + o for m, o in zip(meshes, offs)]).astype(np.int32))


def load_mesh(path: str | Path, scale: float | Sequence[float] = 1.0) -> Mesh:
    """Load an STL / OBJ / PLY / DAE file with trimesh, all parts merged, scaled."""
    import trimesh

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"mesh file not found: {p}")
    try:
        loaded = trimesh.load(p, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many kinds
        raise ValueError(f"cannot read mesh {p}: {exc}") from None
    if len(loaded.faces) == 0:
        raise ValueError(f"mesh {p} has no triangles")
    v = np.asarray(loaded.vertices, dtype=np.float64) * np.asarray(scale, dtype=np.float64)
    return as_mesh((v, loaded.faces), name=str(p))
