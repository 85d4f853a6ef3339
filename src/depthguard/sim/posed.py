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
  by the same ``p @ R.T + t`` as ``Primitive.mesh()``: the same bits, or the same to the
  rounding where the CPU's BLAS fuses multiply-adds in one product and not the other (last
  bits of some coordinates on an AVX-512 Xeon, 2026-11-27);
- the answer of the last time asked: the cameras of one time step (a closed loop's, or
  :class:`~depthguard.sources.simulated.SimSource`'s) pose the scene once, not once per camera.

``PosedMeshes.at(t)`` returns the :class:`PackedMeshes` of time ``t`` (its arrays are the
object's buffers: overwritten by the next call with another time), or None when nothing moves.
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import numba
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
        off.setflags(write=False)            # fixed per topology: a renderer checks it once
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


def _kind_part(kind: tuple) -> tuple[tuple, _Part]:
    """``_part`` of a part named by its kind (:class:`~depthguard.sim.people.PartPoses`)."""
    if kind[0] == "capsule":
        return _part(Capsule(radius=kind[1], segments=kind[2]))
    return _part(Box(size=kind[1]))


class _GroupPacker(_Packer):
    """:class:`_Packer` for parts given as poses (:class:`~depthguard.sim.people.PartPoses` and
    props). Per topology the parts are grouped by kind and vertex count and laid out one group
    after the other (``local``, ``out`` (N, 3) float64: each part's local / posed vertices;
    ``gT`` (P, 4, 4) their poses); a posing is :func:`_lift` (the poses gathered, the capsules'
    caps apart), per group one stacked ``np.matmul`` (per part the same BLAS call as
    ``Mesh.transformed``: the same arithmetic) and :func:`_place` (``+ t``, into the packed vertices):
    a handful of calls, not a few per part (issue 29)."""

    def topology(self, key: tuple, parts: list[_Part]) -> None:
        super().topology(key, parts)
        off = self.packed.mesh_off
        by: dict[tuple, list[int]] = {}
        for k, part in enumerate(parts):
            by.setdefault((part.kind == "capsule", len(part.base)), []).append(k)
        order = [k for ks in by.values() for k in ks]                 # the parts, group after group
        n_v = sum(len(parts[k].base) for k in order)
        self.src = np.asarray(order, np.int64)                       # slot -> part
        self.is_cap = np.asarray([parts[k].kind == "capsule" for k in order])
        self.local = np.concatenate([parts[k].base for k in order]) if order else np.zeros((0, 3))
        self.base_z = self.local[:, 2].copy()
        self.zsign = np.concatenate([parts[k].zsign if parts[k].zsign is not None else np.zeros(len(parts[k].base))
                                     for k in order]) if order else np.zeros(0)
        self.vslot = np.repeat(np.arange(len(order), dtype=np.int64), [len(parts[k].base) for k in order])
        self.vdst = (np.concatenate([np.arange(off[k, 0], off[k + 1, 0]) for k in order]) if order
                     else np.zeros(0, np.int64)).astype(np.int64)
        self.out = np.zeros((n_v, 3))
        self.gT = np.zeros((len(order), 4, 4))
        groups, s0, v0 = [], 0, 0
        for (_, n), ks in by.items():                                # views of one group's parts
            k = len(ks)
            groups.append((self.local[v0:v0 + k * n].reshape(k, n, 3),
                           self.gT[s0:s0 + k, :3, :3].transpose(0, 2, 1),      # T[:3, :3].T per part
                           self.out[v0:v0 + k * n].reshape(k, n, 3)))
            s0, v0 = s0 + k, v0 + k * n
        self.groups = groups
        self.sources: tuple = ()

    def pose(self, T: np.ndarray, length: np.ndarray) -> None:
        """Write the packed vertices of the parts posed at ``T`` (P, 4, 4) with ``length`` (P,) m:
        per part ``_capsule_mesh``'s lift of the caps and ``p @ R.T + t`` (``pack_primitives``'
        arithmetic)."""
        _lift(T, length, self.src, self.is_cap, self.gT, self.vslot, self.base_z, self.zsign, self.local)
        matmul = np.matmul
        for local, RT, out in self.groups:
            matmul(local, RT, out=out)                   # Mesh.transformed: p @ R.T (+ t: _place)
        _place(self.out, self.gT, self.vslot, self.vdst, self.packed.vertices)


@numba.njit(cache=True)      # microseconds: keeps the GIL (a release costs a retake behind the other threads)
def _lift(T, length, src, is_cap, gT, vslot, base_z, zsign, local):
    """The poses ``T`` (P, 4, 4) gathered in slot order (``gT[j] = T[src[j]]``), and each
    capsule's local z: ``base_z + zsign * (length / 2)`` (``_capsule_mesh``, the same order)."""
    for j in range(src.shape[0]):
        gT[j] = T[src[j]]
    for v in range(vslot.shape[0]):
        j = vslot[v]
        if is_cap[j]:
            local[v, 2] = base_z[v] + zsign[v] * (length[src[j]] / 2)


@numba.njit(cache=True)      # microseconds: keeps the GIL (a release costs a retake behind the other threads)
def _place(out, gT, vslot, vdst, vertices):
    """``vertices[vdst[v]] = out[v] + t`` of its part's pose (``dst += T[:3, 3]``)."""
    for v in range(vslot.shape[0]):
        j = vslot[v]
        d = vdst[v]
        for c in range(3):
            vertices[d, c] = out[v, c] + gT[j, c, 3]


class PosedMeshes:
    """The moving meshes of ``scene`` at a time (module docstring); ``alone``: nothing moves.
    One object per thread (its buffers are reused).

    A :class:`~depthguard.sim.scene.Scene` whose people are :class:`~depthguard.sim.people.Person` s
    (not subclassed) is posed from arrays: each person's parts in one pass
    (``Person.part_poses``), the parts' vertices a few stacked numpy calls
    (:class:`_GroupPacker`), and nothing again while no part moves (issue 29); the vertices of
    :func:`pack_primitives` of ``scene.dynamic_at(t)`` (to the rounding: module docstring), which
    any other scene takes."""

    def __init__(self, scene, alone: bool = False):
        from depthguard.sim.people import Person
        from depthguard.sim.scene import Scene

        self.scene = scene
        self.alone = bool(alone)
        self._packer = _Packer()
        self._fast = _GroupPacker()
        self.posed_as_arrays = (getattr(type(scene), "dynamic_at", None) is Scene.dynamic_at
                                and getattr(type(scene), "props_at", None) is Scene.props_at
                                and all(type(p) is Person for p in getattr(scene, "people", ())))
        self._last: tuple[float, PackedMeshes | None] | None = None

    def at(self, t: float) -> PackedMeshes | None:
        """The :class:`PackedMeshes` of the people and props at scene time ``t`` s (None: none)."""
        last = self._last
        if last is not None and last[0] == t:
            return last[1]
        if self.alone:
            packed = None
        elif self.posed_as_arrays:
            packed = self._at_arrays(t)
        else:
            prims = self.scene.dynamic_at(t)
            packed = pack_primitives(prims, self._packer) if prims else None
        self._last = (t, packed)
        return packed

    def _at_arrays(self, t: float) -> PackedMeshes | None:
        """:meth:`at` of a scene of :class:`~depthguard.sim.people.Person` s (class docstring)."""
        blocks = [b for b in (p.part_poses(t) for p in self.scene.people) if b is not None]
        props = self.scene.props_at(t)
        if not blocks and not props:
            return None
        if any(type(p) is not Box and type(p) is not Capsule and type(p) is not Sphere for p in props):
            return pack_primitives(self.scene.dynamic_at(t), self._packer)   # another solid: its own mesh
        packer = self._fast
        key = tuple(b.kinds for b in blocks) + tuple(_part(p)[0] for p in props)
        if key != packer.key:
            parts = [_kind_part(k)[1] for b in blocks for k in b.kinds] + [_part(p)[1] for p in props]
            packer.topology(key, parts)
        sources = tuple(blocks) + tuple(props)
        old = packer.sources
        if len(old) == len(sources) and all(a is b for a, b in zip(old, sources)):
            return packer.packed                         # nothing moved since the last posing
        T = np.concatenate([b.T for b in blocks] + [p.world_from_local[None] for p in props])
        length = np.concatenate([b.length for b in blocks]
                                + [np.array([float(p.length) if type(p) is Capsule else 0.0]) for p in props])
        packer.pose(T, length)
        packer.sources = sources
        return packer.packed
