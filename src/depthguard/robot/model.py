"""The robot model: immutable kinematics + geometry, and a small workspace (R9, R14, R16).

Pinocchio-style: :class:`RobotModel` never changes (``with_base`` /
``with_control_points`` return new models); :class:`RobotData` holds the
preallocated buffers of the 500 Hz loop::

    data = robot.create_data()
    robot.forward(q, data)      # data.link_poses (L,4,4), data.cp_positions (m,3),
                                # data.cp_jacobians (m,3,n): views, overwritten per call

The other methods are conveniences that allocate and return fresh arrays.
Units: metres, radians; poses are 4x4 ``world_from_link``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Mapping, Sequence

import numpy as np
from numba import njit

from depthguard.geometry import Capsule, Mesh
from depthguard.robot.capsules import LinkCapsule
from depthguard.robot.chain import Chain, forward_kernel
from depthguard.transforms import as_rigid, transform_points

__all__ = ["ControlPoint", "RobotData", "RobotModel"]


@dataclass(frozen=True, eq=False)
class ControlPoint:
    """A point fixed to ``link`` (name) at ``offset`` (3,) in the link frame (m), with a ``radius`` (m)
    — the robot's extent around it, for distances (R13, R14)."""
    name: str
    link: str
    offset: np.ndarray
    radius: float = 0.0

    def __repr__(self) -> str:
        return (f"ControlPoint({self.name!r}, link={self.link!r}, "
                f"offset={np.round(self.offset, 4).tolist()}, radius={self.radius})")


class RobotData:
    """Preallocated buffers for :meth:`RobotModel.forward` (one per thread / loop)."""

    def __init__(self, n_links: int, dof: int, n_cp: int):
        self.link_poses = np.zeros((n_links, 4, 4))
        self.joint_frames = np.zeros((n_links, 2, 3))     # world joint origin, world unit axis
        self.scratch = np.zeros((3, 4, 4))
        self.cp_positions = np.zeros((n_cp, 3))
        self.cp_jacobians = np.zeros((n_cp, 3, dof))


def _ro(a) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.setflags(write=False)
    return a


def _ro_faces(f) -> np.ndarray:
    f = np.array(f, dtype=np.int32)
    f.setflags(write=False)
    return f


class RobotModel:
    """Kinematic chain, limits, control points and link geometry of one robot.

    Attributes: ``name``, ``dof``, ``joint_names``, ``q_min`` / ``q_max`` (n,)
    rad or m (±inf for continuous joints), ``qd_max`` (n,) rad/s or m/s,
    ``q_home`` (n,), ``base`` (4, 4) world pose of the root link,
    ``link_names`` (L), ``control_points`` (index 0 = end effector),
    ``link_mesh_names`` (links with geometry), ``capsules`` (link-frame
    :class:`~depthguard.robot.capsules.LinkCapsule` s), ``chain``.
    """

    def __init__(self, name: str, chain: Chain, *, base: np.ndarray | None = None,
                 q_home: Sequence[float] | None = None,
                 control_points: Iterable[ControlPoint | Mapping] = (),
                 link_meshes: Mapping[str, Mesh] | None = None,
                 capsules: Iterable[LinkCapsule] = (), source: str = ""):
        self.name = str(name)
        self.chain = chain
        self.source = source
        self.base = _ro(np.eye(4) if base is None else self._check_base(base))
        n = chain.dof
        qh = np.zeros(n) if q_home is None else np.asarray(q_home, dtype=np.float64)
        if qh.shape != (n,):
            raise ValueError(f"{name}: q_home must have {n} values, got shape {qh.shape}")
        if np.any(qh < chain.q_min) or np.any(qh > chain.q_max):
            raise ValueError(f"{name}: q_home {qh.tolist()} violates the joint limits")
        self.q_home = _ro(qh)
        meshes = dict(link_meshes or {})
        for ln in meshes:
            chain.link_index(ln)
        order = [ln for ln in chain.link_names if ln in meshes]
        self.link_mesh_names = tuple(order)
        self._mesh_link = np.array([chain.link_index(ln) for ln in order], dtype=np.int64)
        self._meshes = tuple(Mesh(_ro(meshes[ln].vertices), _ro_faces(meshes[ln].faces)) for ln in order)
        self._render_meshes = {}         # render_link_meshes per cell, clustered on first use
        self._render_local = {}          # their link-frame vertices one after the other, per cell
        self._render_counts = {}         # their vertex counts per cell (render_link_vertices)
        caps = tuple(capsules)
        for c in caps:
            chain.link_index(c.link)
            if not c.radius > 0:
                raise ValueError(f"{name}: capsule {c.name or c.link!r} needs a radius > 0")
        self.capsules = caps
        self._cap_link = np.array([chain.link_index(c.link) for c in caps], dtype=np.int64)
        self._cap_ab = np.array([[c.a, c.b] for c in caps], dtype=np.float64).reshape(-1, 2, 3)
        self._cap_r = _ro(np.array([c.radius for c in caps], dtype=np.float64))
        self._set_control_points(control_points)
        self._frozen = True

    def __setattr__(self, key, value):
        if getattr(self, "_frozen", False):
            raise AttributeError(f"RobotModel is immutable (use with_base / with_control_points), "
                                 f"cannot set {key!r}")
        object.__setattr__(self, key, value)

    # ------------------------------------------------------------ properties
    @property
    def dof(self) -> int:
        return self.chain.dof

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.chain.joint_names

    @property
    def link_names(self) -> tuple[str, ...]:
        return self.chain.link_names

    @property
    def q_min(self) -> np.ndarray:
        return self.chain.q_min

    @property
    def q_max(self) -> np.ndarray:
        return self.chain.q_max

    @property
    def qd_max(self) -> np.ndarray:
        return self.chain.qd_max

    @property
    def control_points(self) -> tuple[ControlPoint, ...]:
        return self._cps

    def __repr__(self) -> str:
        return (f"RobotModel({self.name!r}, dof={self.dof}, links={len(self.link_names)}, "
                f"control_points={len(self._cps)})")

    # ------------------------------------------------------------ validation
    def _check_base(self, T) -> np.ndarray:
        try:
            return as_rigid(T)
        except ValueError as exc:
            raise ValueError(f"robot base pose {exc}") from None

    def check_q(self, q) -> np.ndarray:
        """``q`` as a float64 (dof,) array; ``ValueError`` naming the expected length otherwise."""
        qa = np.asarray(q, dtype=np.float64)
        if qa.shape != (self.dof,):
            raise ValueError(f"q must have {self.dof} joint values for robot {self.name!r} "
                             f"({', '.join(self.joint_names)}), got shape {qa.shape}")
        if not np.all(np.isfinite(qa)):
            raise ValueError(f"q must be finite, got {qa.tolist()}")
        return qa

    def _set_control_points(self, cps) -> None:
        out = []
        for i, c in enumerate(cps):
            if isinstance(c, Mapping):
                unknown = set(c) - {"name", "link", "offset", "radius"}
                if unknown or "link" not in c:
                    raise ValueError(f"control point {i}: needs 'link' (and optional name, offset, radius); "
                                     f"unknown keys {sorted(unknown)}" if unknown else
                                     f"control point {i}: missing 'link'")
                c = ControlPoint(c.get("name", f"cp{i}"), c["link"], c.get("offset", (0.0, 0.0, 0.0)),
                                 c.get("radius", 0.0))
            if not isinstance(c, ControlPoint):
                raise ValueError(f"control point {i}: expected a ControlPoint or a mapping, got {type(c).__name__}")
            k = self.chain.link_index(c.link)
            off = np.asarray(c.offset, dtype=np.float64).reshape(-1)
            if off.shape != (3,) or not np.all(np.isfinite(off)):
                raise ValueError(f"control point {c.name!r}: offset must be 3 finite numbers, got {c.offset!r}")
            r = float(c.radius)
            if not (np.isfinite(r) and r >= 0):
                raise ValueError(f"control point {c.name!r}: radius must be >= 0, got {c.radius!r}")
            out.append(ControlPoint(str(c.name), self.chain.link_names[k], _ro(off), r))
        if not out:
            raise ValueError(f"robot {self.name!r} needs at least one control point (index 0 = end effector)")
        names = [c.name for c in out]
        if len(set(names)) != len(names):
            raise ValueError(f"control point names must be unique, got {names}")
        self._cps = tuple(out)
        self._cp_link = np.array([self.chain.link_index(c.link) for c in out], dtype=np.int64)
        self._cp_off = np.ascontiguousarray([c.offset for c in out], dtype=np.float64)

    # ------------------------------------------------------------ copies
    def _copy(self) -> "RobotModel":
        new = object.__new__(RobotModel)
        new.__dict__.update(self.__dict__)
        new.__dict__["_frozen"] = False
        return new

    def with_base(self, T: np.ndarray) -> "RobotModel":
        """The same robot with its root link at the world pose ``T`` (4, 4)."""
        new = self._copy()
        new.base = _ro(self._check_base(T))
        new._frozen = True
        return new

    def with_control_points(self, control_points: Iterable[ControlPoint | Mapping]) -> "RobotModel":
        """The same robot with another control-point set (index 0 = end effector)."""
        new = self._copy()
        new._set_control_points(control_points)
        new._frozen = True
        return new

    # ------------------------------------------------------------ hot path
    def create_data(self) -> RobotData:
        """Buffers for :meth:`forward`, sized for this model's control points."""
        return RobotData(self.chain.n_links, self.dof, len(self._cps))

    def forward(self, q: np.ndarray, data: RobotData) -> RobotData:
        """FK of every link + positions and (3, dof) Jacobians of all control points into ``data`` (R14).

        ``q`` (dof,) float64; a wrong length or a non-finite value raises ``ValueError``.
        No allocation for a float64 ``q`` of the right length.
        """
        if not (isinstance(q, np.ndarray) and q.dtype == np.float64 and q.shape == (self.dof,)):
            q = self.check_q(q)
        c = self.chain
        if not forward_kernel(q, self.base, c.xf, c.ints, c.axis, c.support, self._cp_link, self._cp_off,
                              data.link_poses, data.joint_frames, data.scratch, data.cp_positions,
                              data.cp_jacobians):
            self.check_q(q)  # raises, naming the bad value
        return data

    def forward_into(self, data: RobotData):
        """``fk(q) -> bool``: :meth:`forward` into ``data`` with the model's arrays bound once (the
        control cycle's, issue 29: no attribute look-ups nor checks per call). ``q`` must be a
        float64 (dof,) array — the caller checks it (a wrong length reads out of bounds); False when
        a value of ``q`` is not finite (``data`` untouched)."""
        c = self.chain
        args = (self.base, c.xf, c.ints, c.axis, c.support, self._cp_link, self._cp_off, data.link_poses,
                data.joint_frames, data.scratch, data.cp_positions, data.cp_jacobians)

        def fk(q, _kernel=forward_kernel, _args=args):
            return _kernel(q, *_args)
        return fk

    # ------------------------------------------------------------ conveniences
    def _run(self, q, cp_link: np.ndarray, cp_off: np.ndarray):
        q = self.check_q(q)
        c = self.chain
        poses = np.empty((c.n_links, 4, 4))
        jf = np.empty((c.n_links, 2, 3))
        pos = np.empty((len(cp_link), 3))
        jac = np.empty((len(cp_link), 3, self.dof))
        forward_kernel(q, self.base, c.xf, c.ints, c.axis, c.support, cp_link, cp_off,
                       poses, jf, np.empty((3, 4, 4)), pos, jac)
        return poses, pos, jac

    def link_poses(self, q) -> np.ndarray:
        """(L, 4, 4) world poses of all links, ordered as :attr:`link_names`."""
        return self._run(q, self._cp_link[:0], self._cp_off[:0])[0]

    def link_pose(self, q, link: int | str) -> np.ndarray:
        """(4, 4) world pose of one link."""
        return self.link_poses(q)[self.chain.link_index(link)]

    def point_jacobian(self, q, link: int | str, p_local) -> np.ndarray:
        """(3, dof) position Jacobian of the point ``p_local`` (3,) fixed to ``link`` (R14)."""
        k = self.chain.link_index(link)
        p = np.asarray(p_local, dtype=np.float64).reshape(-1)
        if p.shape != (3,):
            raise ValueError(f"p_local must be 3 numbers, got shape {np.shape(p_local)}")
        return self._run(q, np.array([k], dtype=np.int64), p.reshape(1, 3))[2][0]

    def point_position(self, q, link: int | str, p_local) -> np.ndarray:
        """(3,) world position of ``p_local`` fixed to ``link``."""
        T = self.link_pose(q, link)
        return T[:3, :3] @ np.asarray(p_local, dtype=np.float64) + T[:3, 3]

    def control_point_positions(self, q) -> np.ndarray:
        """(m, 3) world positions of the control points."""
        return self._run(q, self._cp_link, self._cp_off)[1]

    def control_point_jacobians(self, q) -> np.ndarray:
        """(m, 3, dof) position Jacobians of the control points."""
        return self._run(q, self._cp_link, self._cp_off)[2]

    def link_meshes(self, q) -> list[Mesh]:
        """World meshes of the links with geometry (order :attr:`link_mesh_names`), for rendering (R16)."""
        poses = self.link_poses(q)
        return [Mesh(transform_points(poses[k], m.vertices), m.faces)
                for k, m in zip(self._mesh_link, self._meshes)]

    def render_link_meshes(self, q, cell: float | None = None) -> list[Mesh]:
        """:meth:`link_meshes` from the meshes clustered to ``cell`` m (default
        :data:`~depthguard.geometry.decimate.RENDER_CELL`; made once per cell,
        :func:`~depthguard.geometry.decimate.cluster_decimate`): what a camera's robot depth is
        rendered from at every frame (R9; within ``sqrt(3) cell`` of the model's surface)."""
        meshes = self._clustered(cell)
        poses = self.link_poses(q)
        out = []
        for k, m in zip(self._mesh_link, meshes):      # posed as render_link_vertices poses them: the same bits
            v = np.empty((len(m.vertices), 3))
            _pose_vertices(v, poses, np.array([k], dtype=np.int64), np.array([len(v)], dtype=np.int64), _local(m))
            out.append(Mesh(v, m.faces))
        return out

    def _clustered(self, cell: float | None) -> tuple[Mesh, ...]:
        from depthguard.geometry.decimate import RENDER_CELL, cluster_decimate

        cell = RENDER_CELL if cell is None else float(cell)
        meshes = self._render_meshes.get(cell)
        if meshes is None:
            meshes = tuple(cluster_decimate(m, cell) for m in self._meshes)
            self._render_meshes[cell] = meshes          # a cache of what the model holds
        return meshes

    def render_link_topology(self, cell: float | None = None) -> list[Mesh]:
        """The link-frame meshes of :meth:`render_link_meshes` (order :attr:`link_mesh_names`):
        their faces and vertex counts are what :meth:`render_link_vertices` fills vertices for."""
        return list(self._clustered(cell))

    def render_link_vertices(self, q, cell: float | None, out: np.ndarray) -> np.ndarray:
        """The world vertices of :meth:`render_link_meshes` ``(q, cell)``, all links one after the
        other, written into ``out`` (V, 3) float64 C-contiguous (the same bits: both posed by
        :func:`_pose_vertices`, into ``out`` instead of new arrays); returns ``out[:V]`` (R16)."""
        return self.render_vertices_at(self.link_poses(q), cell, out)

    def render_vertices_at(self, poses: np.ndarray, cell: float | None, out: np.ndarray) -> np.ndarray:
        """:meth:`render_link_vertices` from the links' world ``poses`` (L, 4, 4) float64 at the
        joints (:meth:`forward`'s ``data.link_poses``): a camera worker poses the links once a
        frame for its render and its capsules (issue 29; :meth:`segments_at`)."""
        _check_poses(poses, self.chain.n_links)
        local = self._render_local.get(cell)
        if local is None:                            # the links' vertices one after the other, once per cell
            local = self._render_local[cell] = np.ascontiguousarray(
                np.concatenate([m.vertices for m in self._clustered(cell)]), dtype=np.float64)
        if not (type(out) is np.ndarray and out.dtype == np.float64 and out.ndim == 2 and out.shape[1] == 3
                and out.shape[0] >= len(local) and out.flags.c_contiguous):
            raise ValueError(f"out must be a C-contiguous float64 ({len(local)}, 3) array or longer, got "
                             f"{getattr(out, 'dtype', type(out).__name__)} {getattr(out, 'shape', '')}")
        counts = self._render_counts.get(cell)
        if counts is None:
            counts = self._vertex_counts(cell, self._clustered(cell))
        _pose_vertices(out, poses, self._mesh_link, counts, local)
        return out[:len(local)]

    def _vertex_counts(self, cell: float | None, meshes) -> np.ndarray:
        """(links with geometry,) int64: the vertex count of each clustered mesh, made once per cell."""
        counts = self._render_counts.get(cell)
        if counts is None:
            counts = np.array([len(m.vertices) for m in meshes], dtype=np.int64)
            self._render_counts[cell] = counts
        return counts

    def local_link_meshes(self) -> dict[str, Mesh]:
        """Link-frame meshes by link name."""
        return dict(zip(self.link_mesh_names, self._meshes))

    def collision_segments(self, q, padding: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """World capsule end points (K, 2, 3) and radii (K,) (+ ``padding``, m), new arrays.
        (Per camera frame on its worker, issue 29: one compiled posing, :func:`_capsule_ends`,
        instead of numpy's fancy index and einsum: 0.11 ms of thread CPU a frame in a real-time
        run, where each numpy call is taxed by the other threads.)"""
        return self.segments_at(self.link_poses(q), padding)

    def segments_at(self, poses: np.ndarray, padding: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`collision_segments` from the links' world ``poses`` (L, 4, 4) float64 at the
        joints (:meth:`render_vertices_at`'s)."""
        _check_poses(poses, self.chain.n_links)
        ab = np.empty(self._cap_ab.shape)
        _capsule_ends(poses, self._cap_link, self._cap_ab, ab)
        return ab, self._cap_r + float(padding)

    def collision_capsules(self, q, padding: float = 0.0) -> list[Capsule]:
        """World :class:`~depthguard.geometry.Capsule` s covering the links, radii + ``padding`` (m).

        The robot's own (padded) volume: self-distance, ground truth, free space (R9, R12, R21).
        """
        if not (np.isfinite(padding) and padding >= 0):
            raise ValueError(f"padding must be >= 0 (m), got {padding!r}")
        ab, r = self.collision_segments(q, padding)
        return [Capsule.between(ab[i, 0], ab[i, 1], float(r[i]), name=c.name or c.link)
                for i, c in enumerate(self.capsules)]


def _check_poses(poses, n_links: int) -> None:
    """``poses`` must be the (L, 4, 4) float64 C-contiguous link poses a kernel reads in place."""
    if not (type(poses) is np.ndarray and poses.dtype == np.float64 and poses.shape == (n_links, 4, 4)
            and poses.flags.c_contiguous):
        raise ValueError(f"poses must be a C-contiguous float64 ({n_links}, 4, 4) array of the links' world "
                         f"poses, got {getattr(poses, 'dtype', type(poses).__name__)} {getattr(poses, 'shape', '')}")


@njit(cache=True)      # microseconds: keeps the GIL
def _capsule_ends(poses, cap_link, cap_ab, out):
    """``out[k, n] = R @ cap_ab[k, n] + t`` with ``R``, ``t`` of link ``cap_link[k]``'s pose
    (``poses`` (L, 4, 4)): the capsules' end points (K, 2, 3) float64 m in the world (R12)."""
    for k in range(cap_link.shape[0]):
        T = poses[cap_link[k]]
        for n in range(2):
            x = cap_ab[k, n, 0]
            y = cap_ab[k, n, 1]
            z = cap_ab[k, n, 2]
            for i in range(3):
                out[k, n, i] = T[i, 0] * x + T[i, 1] * y + T[i, 2] * z + T[i, 3]


@njit(cache=True)      # ~0.1 ms a frame: keeps the GIL (a release costs a retake behind the other threads)
def _pose_vertices(out, poses, mesh_link, counts, local):
    """``out[rows of mesh i] = local[rows] @ R.T + t`` with ``R``, ``t`` the rotation and
    translation of link ``mesh_link[i]``'s pose (``poses`` (L, 4, 4)): the links' world vertices
    (``local`` and ``out`` (V, 3) float64 m, the meshes one after the other with ``counts`` (M,)
    vertices each), R16. One compiled call per posing: a numpy ``matmul`` per link gave the GIL
    away and waited to take it back, each, in a real-time run (issue 29)."""
    o = 0
    for i in range(counts.shape[0]):
        k = mesh_link[i]
        r00 = poses[k, 0, 0]
        r01 = poses[k, 0, 1]
        r02 = poses[k, 0, 2]
        r10 = poses[k, 1, 0]
        r11 = poses[k, 1, 1]
        r12 = poses[k, 1, 2]
        r20 = poses[k, 2, 0]
        r21 = poses[k, 2, 1]
        r22 = poses[k, 2, 2]
        tx = poses[k, 0, 3]
        ty = poses[k, 1, 3]
        tz = poses[k, 2, 3]
        for j in range(o, o + counts[i]):
            x = local[j, 0]
            y = local[j, 1]
            z = local[j, 2]
            out[j, 0] = (x * r00 + y * r01 + z * r02) + tx
            out[j, 1] = (x * r10 + y * r11 + z * r12) + ty
            out[j, 2] = (x * r20 + y * r21 + z * r22) + tz
        o += counts[i]


def _local(mesh) -> np.ndarray:
    """A mesh's vertices as :func:`_pose_vertices` reads them ((V, 3) float64 C-contiguous)."""
    return np.ascontiguousarray(mesh.vertices, dtype=np.float64)
