"""Kinematic chains: joint tables, forward kinematics and point Jacobians (R9, R14, R16).

Every robot — from a Denavit–Hartenberg table or a URDF — becomes the same
model: a list of *links* in topological order (a link's parent comes
before it). Link ``k`` hangs from its parent through one joint::

    T_k = T_parent(k) · pre_k · M_k(q) · post_k

* ``pre_k`` (4x4) is the fixed parent→joint origin (URDF ``<origin>``),
* ``M_k(q)`` is the joint motion: a rotation by ``q[qidx_k]`` about the unit
  ``axis_k`` (revolute), a translation by ``q[qidx_k] · axis_k`` (prismatic)
  or the identity (fixed),
* ``post_k`` (4x4) is a fixed transform after the motion (identity for
  URDF; ``Rz(θ0) Tz(d) Tx(a) Rx(α)`` for a standard DH row, whose motion
  comes first).

The root link (index 0) is placed at the robot's ``base`` pose.

Position Jacobian of a point ``p`` (world) fixed to link ``k``, column ``j``
(for each actuated joint ``j`` between the root and ``k``, with world axis
``z_j`` through the world point ``o_j`` = origin of ``T_parent · pre``)::

    revolute:   J[:, j] = z_j × (p − o_j)
    prismatic:  J[:, j] = z_j
    otherwise:  J[:, j] = 0

:func:`forward_kernel` (numba, no allocation) computes link poses, joint
frames, the world positions of ``m`` control points and their (3, dof)
Jacobians in one call; :func:`forward_numpy` and :func:`point_jacobian_numpy`
are the plain-numpy twins that read like the equations above (tests only).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np

__all__ = ["FIXED", "REVOLUTE", "PRISMATIC", "LinkSpec", "Chain", "forward_kernel",
           "forward_numpy", "point_jacobian_numpy", "joint_motion"]

FIXED, REVOLUTE, PRISMATIC = 0, 1, 2
_TYPE_NAMES = {FIXED: "fixed", REVOLUTE: "revolute", PRISMATIC: "prismatic"}


@dataclass(frozen=True, eq=False)
class LinkSpec:
    """One link and the joint that carries it (see the module docstring).

    ``parent`` is the parent link's name (``None`` for the root); ``lower`` /
    ``upper`` are position limits (rad or m, ``±inf`` for none) and ``vmax``
    the velocity limit (rad/s or m/s, ``inf`` for none) of an actuated joint.
    """
    name: str
    parent: str | None = None
    joint: str = ""
    jtype: int = FIXED
    pre: np.ndarray = field(default_factory=lambda: np.eye(4))
    axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    post: np.ndarray = field(default_factory=lambda: np.eye(4))
    lower: float = -np.inf
    upper: float = np.inf
    vmax: float = np.inf


def _ro(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


class Chain:
    """Immutable joint tables of a robot built from :class:`LinkSpec` rows.

    Arrays (``L`` links, ``n`` actuated joints, in the order the links are given):
    ``parent`` (L,) int64 (−1 for the root), ``jtype`` (L,) int64, ``qidx`` (L,)
    int64 (−1 for fixed), ``pre`` / ``post`` (L, 4, 4), ``axis`` (L, 3) unit,
    ``support`` (L, n) uint8 — 1 where actuated joint ``j`` moves link ``k``.
    ``q_min``, ``q_max``, ``qd_max`` (n,), ``joint_names`` (n), ``link_names`` (L).
    """

    def __init__(self, links: list[LinkSpec]):
        if not links:
            raise ValueError("a chain needs at least one link")
        names = [l.name for l in links]
        if len(set(names)) != len(names):
            dup = sorted({n for n in names if names.count(n) > 1})
            raise ValueError(f"duplicate link names: {dup}")
        index = {n: i for i, n in enumerate(names)}
        L = len(links)
        parent = np.full(L, -1, dtype=np.int64)
        jtype = np.zeros(L, dtype=np.int64)
        qidx = np.full(L, -1, dtype=np.int64)
        pre = np.zeros((L, 4, 4))
        post = np.zeros((L, 4, 4))
        axis = np.zeros((L, 3))
        joint_names, lo, hi, vmax = [], [], [], []
        for k, l in enumerate(links):
            if k == 0:
                if l.parent is not None:
                    raise ValueError(f"the first link {l.name!r} must be the root (parent None)")
            else:
                if l.parent is None:
                    raise ValueError(f"link {l.name!r}: only the first link may be a root")
                if l.parent not in index or index[l.parent] >= k:
                    raise ValueError(f"link {l.name!r}: parent {l.parent!r} must be listed before it")
                parent[k] = index[l.parent]
            if l.jtype not in _TYPE_NAMES:
                raise ValueError(f"link {l.name!r}: unknown joint type {l.jtype!r}")
            for nm, M in (("pre", l.pre), ("post", l.post)):
                M = np.asarray(M, dtype=np.float64)
                if M.shape != (4, 4) or not np.all(np.isfinite(M)):
                    raise ValueError(f"link {l.name!r}: {nm} must be a finite 4x4 matrix")
                R = M[:3, :3]
                if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
                    raise ValueError(f"link {l.name!r}: {nm} rotation is not a proper rotation")
            pre[k], post[k] = l.pre, l.post
            a = np.asarray(l.axis, dtype=np.float64).reshape(-1)
            if l.jtype != FIXED:
                if a.shape != (3,) or not np.all(np.isfinite(a)) or np.linalg.norm(a) < 1e-12:
                    raise ValueError(f"joint {l.joint or l.name!r}: axis must be a non-zero 3-vector, got {l.axis!r}")
                a = a / np.linalg.norm(a)
                if not l.lower <= l.upper:
                    raise ValueError(f"joint {l.joint!r}: lower limit {l.lower} > upper limit {l.upper}")
                if not l.vmax > 0:
                    raise ValueError(f"joint {l.joint!r}: velocity limit must be > 0, got {l.vmax}")
                qidx[k] = len(joint_names)
                joint_names.append(l.joint or l.name)
                lo.append(l.lower)
                hi.append(l.upper)
                vmax.append(l.vmax)
            else:
                a = np.array([0.0, 0.0, 1.0])
            axis[k] = a
            jtype[k] = l.jtype
        n = len(joint_names)
        support = np.zeros((L, n), dtype=np.uint8)
        for k in range(L):
            i = k
            while i >= 0:
                if qidx[i] >= 0:
                    support[k, qidx[i]] = 1
                i = parent[i]
        self.links = tuple(links)
        self.link_names = tuple(names)
        self.joint_names = tuple(joint_names)
        self.parent, self.jtype, self.qidx = _ro(parent), _ro(jtype), _ro(qidx)
        self.pre, self.post, self.axis, self.support = _ro(pre), _ro(post), _ro(axis), _ro(support)
        self.q_min = _ro(np.array(lo, dtype=np.float64))
        self.q_max = _ro(np.array(hi, dtype=np.float64))
        self.qd_max = _ro(np.array(vmax, dtype=np.float64))
        # pre/post packed for the kernel: (L, 2, 4, 4)
        self.xf = _ro(np.stack([pre, post], axis=1))
        self.ints = _ro(np.stack([parent, jtype, qidx], axis=1))

    @property
    def n_links(self) -> int:
        return len(self.link_names)

    @property
    def dof(self) -> int:
        return len(self.joint_names)

    def link_index(self, link: int | str) -> int:
        """Index of a link given by index or name (``ValueError`` naming the known links)."""
        if isinstance(link, (int, np.integer)) and not isinstance(link, bool):
            if not 0 <= int(link) < self.n_links:
                raise ValueError(f"link index {link} out of range [0, {self.n_links})")
            return int(link)
        try:
            return self.link_names.index(link)
        except ValueError:
            raise ValueError(f"unknown link {link!r}; links are {list(self.link_names)}") from None


# ----------------------------------------------------------------- numba kernel
@numba.njit(cache=True, inline="always")
def _motion(jt, a, q, M):
    """M (4x4, preallocated) <- joint motion of type ``jt`` about unit axis ``a`` by ``q``."""
    for r in range(4):
        for c in range(4):
            M[r, c] = 1.0 if r == c else 0.0
    if jt == 1:
        x, y, z = a[0], a[1], a[2]
        c = np.cos(q)
        s = np.sin(q)
        t = 1.0 - c
        M[0, 0] = c + t * x * x
        M[0, 1] = t * x * y - s * z
        M[0, 2] = t * x * z + s * y
        M[1, 0] = t * x * y + s * z
        M[1, 1] = c + t * y * y
        M[1, 2] = t * y * z - s * x
        M[2, 0] = t * x * z - s * y
        M[2, 1] = t * y * z + s * x
        M[2, 2] = c + t * z * z
    elif jt == 2:
        M[0, 3] = a[0] * q
        M[1, 3] = a[1] * q
        M[2, 3] = a[2] * q


@numba.njit(cache=True, inline="always")
def _rigid_mul(A, B, out):
    """out <- A @ B for rigid 4x4 transforms (bottom row [0 0 0 1])."""
    for r in range(3):
        a0, a1, a2 = A[r, 0], A[r, 1], A[r, 2]
        for c in range(3):
            out[r, c] = a0 * B[0, c] + a1 * B[1, c] + a2 * B[2, c]
        out[r, 3] = a0 * B[0, 3] + a1 * B[1, 3] + a2 * B[2, 3] + A[r, 3]
    out[3, 0] = 0.0
    out[3, 1] = 0.0
    out[3, 2] = 0.0
    out[3, 3] = 1.0


@numba.njit(cache=True)
def forward_kernel(q, base, xf, ints, axis, support, cp_link, cp_off,
                   poses, jframe, scratch, cp_pos, cp_jac):
    """Link poses, joint frames, control-point positions and Jacobians (R14).

    Inputs: ``q`` (n,), ``base`` (4, 4), ``xf`` (L, 2, 4, 4) pre/post,
    ``ints`` (L, 3) parent/jtype/qidx, ``axis`` (L, 3), ``support`` (L, n),
    ``cp_link`` (m,) int64, ``cp_off`` (m, 3) link-frame offsets (m).
    Outputs (overwritten): ``poses`` (L, 4, 4) world, ``jframe`` (L, 2, 3)
    world joint origin / unit axis, ``scratch`` (3, 4, 4), ``cp_pos`` (m, 3),
    ``cp_jac`` (m, 3, n). No allocation. Returns ``False`` (outputs untouched)
    when ``q`` holds a non-finite value, ``True`` otherwise.
    """
    for i in range(q.shape[0]):
        if not np.isfinite(q[i]):
            return False
    L = ints.shape[0]
    A = scratch[0]
    M = scratch[1]
    B = scratch[2]
    for k in range(L):
        p = ints[k, 0]
        if p < 0:
            _rigid_mul(base, xf[k, 0], A)
        else:
            _rigid_mul(poses[p], xf[k, 0], A)
        jt = ints[k, 1]
        for r in range(3):
            jframe[k, 0, r] = A[r, 3]
            jframe[k, 1, r] = A[r, 0] * axis[k, 0] + A[r, 1] * axis[k, 1] + A[r, 2] * axis[k, 2]
        if jt == 0:
            _rigid_mul(A, xf[k, 1], poses[k])
        else:
            _motion(jt, axis[k], q[ints[k, 2]], M)
            _rigid_mul(A, M, B)
            _rigid_mul(B, xf[k, 1], poses[k])
    m = cp_link.shape[0]
    n = cp_jac.shape[2]
    for c in range(m):
        k = cp_link[c]
        T = poses[k]
        ox, oy, oz = cp_off[c, 0], cp_off[c, 1], cp_off[c, 2]
        px = T[0, 0] * ox + T[0, 1] * oy + T[0, 2] * oz + T[0, 3]
        py = T[1, 0] * ox + T[1, 1] * oy + T[1, 2] * oz + T[1, 3]
        pz = T[2, 0] * ox + T[2, 1] * oy + T[2, 2] * oz + T[2, 3]
        cp_pos[c, 0] = px
        cp_pos[c, 1] = py
        cp_pos[c, 2] = pz
        for j in range(n):
            cp_jac[c, 0, j] = 0.0
            cp_jac[c, 1, j] = 0.0
            cp_jac[c, 2, j] = 0.0
        for l in range(L):
            j = ints[l, 2]
            if j < 0 or support[k, j] == 0:
                continue
            zx, zy, zz = jframe[l, 1, 0], jframe[l, 1, 1], jframe[l, 1, 2]
            if ints[l, 1] == 1:
                dx = px - jframe[l, 0, 0]
                dy = py - jframe[l, 0, 1]
                dz = pz - jframe[l, 0, 2]
                cp_jac[c, 0, j] = zy * dz - zz * dy
                cp_jac[c, 1, j] = zz * dx - zx * dz
                cp_jac[c, 2, j] = zx * dy - zy * dx
            else:
                cp_jac[c, 0, j] = zx
                cp_jac[c, 1, j] = zy
                cp_jac[c, 2, j] = zz
    return True


# ----------------------------------------------------------------- numpy twins
def joint_motion(jtype: int, axis: np.ndarray, q: float) -> np.ndarray:
    """4x4 joint motion: Rodrigues rotation ``exp(q [a]x)`` or translation ``q a``."""
    M = np.eye(4)
    a = np.asarray(axis, dtype=np.float64)
    if jtype == REVOLUTE:
        K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
        M[:3, :3] = np.eye(3) + np.sin(q) * K + (1 - np.cos(q)) * (K @ K)
    elif jtype == PRISMATIC:
        M[:3, 3] = q * a
    return M


def forward_numpy(chain: Chain, q: np.ndarray, base: np.ndarray = np.eye(4)):
    """Twin of :func:`forward_kernel`'s FK: ``(poses (L,4,4), joint_origins (L,3), joint_axes (L,3))``."""
    L = chain.n_links
    poses = np.zeros((L, 4, 4))
    origins = np.zeros((L, 3))
    axes = np.zeros((L, 3))
    for k in range(L):
        parent_pose = base if chain.parent[k] < 0 else poses[chain.parent[k]]
        joint_frame = parent_pose @ chain.pre[k]
        origins[k] = joint_frame[:3, 3]
        axes[k] = joint_frame[:3, :3] @ chain.axis[k]
        qk = q[chain.qidx[k]] if chain.qidx[k] >= 0 else 0.0
        poses[k] = joint_frame @ joint_motion(chain.jtype[k], chain.axis[k], qk) @ chain.post[k]
    return poses, origins, axes


def point_jacobian_numpy(chain: Chain, q: np.ndarray, link: int, p_local: np.ndarray,
                         base: np.ndarray = np.eye(4)) -> np.ndarray:
    """Twin of the Jacobian part of :func:`forward_kernel`: (3, n) for one point."""
    poses, origins, axes = forward_numpy(chain, q, base)
    p = poses[link, :3, :3] @ p_local + poses[link, :3, 3]
    J = np.zeros((3, chain.dof))
    for l in range(chain.n_links):
        j = chain.qidx[l]
        if j < 0 or not chain.support[link, j]:
            continue
        if chain.jtype[l] == REVOLUTE:
            J[:, j] = np.cross(axes[l], p - origins[l])
        else:
            J[:, j] = axes[l]
    return J
