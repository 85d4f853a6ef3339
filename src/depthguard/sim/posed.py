"""The people and props of a scene as one packed mesh, posed in place (R16, issue 29).

A simulated camera frame renders what moves besides the robot — the scene's people and props
(:meth:`~depthguard.sim.scene.Scene.dynamic_at`) — at the frame's capture time. Building a
:class:`~depthguard.geometry.mesh.Mesh` per body part per frame (``Primitive.mesh()``: a local
mesh made again, moved into a new array) cost 0.2-0.4 ms of a frame; :class:`PosedMeshes`
instead keeps, per scene:

- the faces of all moving parts packed once (:class:`PackedMeshes`: ``faces`` (F, 3) int32 local
  to each part, ``mesh_off`` (M + 1, 2) int64 the first vertex and face of each part and the
  totals, and ``topology``, a number that changes only when the parts do — a person enters or
  leaves — so a renderer packs its faces once per topology);
- the world vertices (V, 3) float64 m of every part, written in place into one preallocated
  buffer from each part's template (a capsule's or sphere's vertices from
  :func:`~depthguard.geometry.primitives._capsule_template`, a box's corners made once per size)
  by the same ``p @ R.T + t`` as ``Primitive.mesh()``: the same bits;
- the answer of the last time asked: the cameras of one time step (a closed loop's, or
  :class:`~depthguard.sources.simulated.SimSource`'s) pose the scene once, not once per camera.

``PosedMeshes.at(t)`` returns the :class:`PackedMeshes` of time ``t`` (its arrays are the
object's buffers: overwritten by the next call with another time), or None when nothing moves.
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import numpy as np

from depthguard.geometry.mesh import Mesh
from depthguard.geometry.primitives import Box, Capsule, Sphere, _capsule_template

__all__ = ["PackedMeshes", "PosedMeshes", "pack_primitives"]

_TOPOLOGY = itertools.count(1)      # topology numbers, unique in the process


class PackedMeshes(NamedTuple):
    """Meshes one after the other (module docstring): ``vertices`` (V, 3) float64 m world,
    ``faces`` (F, 3) int32 local to their mesh, ``mesh_off`` (M + 1, 2) int64, ``topology``."""
    vertices: np.ndarray
    faces: np.ndarray
    mesh_off: np.ndarray
    topology: int

    def meshes(self) -> list[Mesh]:
        """The packed meshes as :class:`~depthguard.geometry.mesh.Mesh` views (in order)."""
        o = self.mesh_off
        return [Mesh(self.vertices[o[k, 0]:o[k + 1, 0]], self.faces[o[k, 1]:o[k + 1, 1]])
                for k in range(len(o) - 1)]


class _Part(NamedTuple):
    kind: str                # "capsule" (spheres too: length 0), "fixed" (a template), "mesh" (any other)
    base: np.ndarray         # (n, 3) float64: the template's vertices (length 0 for a capsule)
    zsign: np.ndarray | None  # (n,) float64: a capsule's cap of each vertex (-1 / +1)
    faces: np.ndarray        # (f, 3) int32


_BOXES: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}


def _part(prim) -> tuple[tuple, _Part]:
    """``(topology key, template)`` of one primitive (module docstring)."""
    if type(prim) is Capsule or type(prim) is Sphere:
        r, n = float(prim.radius), int(prim.segments)
        v0, zs, faces = _capsule_template(r, n)
        return ("capsule", id(faces)), _Part("capsule", v0, zs, faces)
    if type(prim) is Box:
        key = tuple(float(s) for s in prim.size)
        tpl = _BOXES.get(key)
        if tpl is None:
            m = prim.local_mesh()             # the same numbers every time: made once per size
            tpl = _BOXES[key] = (m.vertices, m.faces)
            for a in tpl:
                a.setflags(write=False)
        return ("box", key), _Part("fixed", tpl[0], None, tpl[1])
    m = prim.local_mesh()
    v = np.ascontiguousarray(m.vertices, dtype=np.float64)
    f = np.ascontiguousarray(m.faces, dtype=np.int32)
    return ("mesh", len(v), f.tobytes()), _Part("mesh", v, None, f)


class _Packer:
    """The buffers of :func:`pack_primitives` (grown when a topology needs more). Per topology each
    part's views are made once (``slots``: the part's rows of the vertices, and a capsule's local
    vertices with the template's x, y already in place and its cap offsets): a posing is then
    per part one or two numpy calls for a capsule's caps and the ``p @ R.T + t`` of
    ``Mesh.transformed`` (issue 29: 22 to ~10 µs a part)."""

    def __init__(self):
        self.key: tuple | None = None
        self.packed: PackedMeshes | None = None
        self.vertices = np.zeros((0, 3))
        self.slots: list[tuple] = []

    def topology(self, key: tuple, parts: list[_Part]) -> None:
        nv = [len(p.base) for p in parts]
        nf = [len(p.faces) for p in parts]
        off = np.zeros((len(parts) + 1, 2), np.int64)
        np.cumsum(nv, out=off[1:, 0])
        np.cumsum(nf, out=off[1:, 1])
        n_v = int(off[-1, 0])
        if n_v > len(self.vertices):
            self.vertices = np.zeros((n_v, 3))
        faces = (np.concatenate([p.faces for p in parts]) if parts else np.zeros((0, 3), np.int32)).astype(np.int32)
        self.key = key
        self.packed = PackedMeshes(self.vertices[:n_v], np.ascontiguousarray(faces), off, next(_TOPOLOGY))
        slots = []
        for k, part in enumerate(parts):
            dst = self.packed.vertices[int(off[k, 0]):int(off[k + 1, 0])]
            if part.kind == "capsule":         # _capsule_mesh: v = v0.copy(); v[:, 2] += zsign * (length / 2)
                local = part.base.copy()       # x, y: the template's, once; z: written per posing
                slots.append((dst, local, local[:, 2], part.base[:, 2], part.zsign, np.zeros(len(local))))
            else:
                slots.append((dst, part.base, None, None, None, None))
        self.slots = slots


def pack_primitives(prims, packer: _Packer | None = None) -> PackedMeshes:
    """The world meshes of ``prims`` (``[p.mesh() for p in prims]``, the same bits) packed
    (module docstring), written into ``packer``'s buffers (a new packer when None)."""
    packer = _Packer() if packer is None else packer
    keyed = [_part(p) for p in prims]
    key = tuple(k for k, _ in keyed)
    if key != packer.key:
        packer.topology(key, [p for _, p in keyed])
    for prim, (dst, src, z, base_z, zsign, lift) in zip(prims, packer.slots):
        if z is not None:                   # a capsule (a sphere: length 0): the caps apart
            length = float(prim.length) if type(prim) is Capsule else 0.0
            np.multiply(zsign, length / 2, out=lift)
            np.add(base_z, lift, out=z)
        T = prim.world_from_local           # Mesh.transformed: p @ T[:3, :3].T + T[:3, 3]
        np.matmul(src, T[:3, :3].T, out=dst)
        dst += T[:3, 3]
    return packer.packed


class PosedMeshes:
    """The moving meshes of ``scene`` at a time (module docstring); ``alone``: nothing moves.
    One object per thread (its buffers are reused)."""

    def __init__(self, scene, alone: bool = False):
        self.scene = scene
        self.alone = bool(alone)
        self._packer = _Packer()
        self._last: tuple[float, PackedMeshes | None] | None = None

    def at(self, t: float) -> PackedMeshes | None:
        """The :class:`PackedMeshes` of the people and props at scene time ``t`` s (None: none)."""
        last = self._last
        if last is not None and last[0] == t:
            return last[1]
        prims = [] if self.alone else self.scene.dynamic_at(t)
        packed = pack_primitives(prims, self._packer) if prims else None
        self._last = (t, packed)
        return packed
