"""Is my next motion free? A planned joint path against the free-space map, per segment (R22, R37).

A path is waypoints ``(stamp_i, q_i)`` (s, rad), times strictly increasing; segment ``i`` runs from
waypoint ``i`` to ``i + 1`` by linear interpolation in joint space (what a joint trajectory
controller does between close waypoints). The robot's capsules padded by ``padding`` m are
swept along each segment against a map whose voxels are each :data:`FREE`, :data:`UNKNOWN`
(no camera judged it: hidden, out of view, invalid depth — R25) or :data:`OCCUPIED` (a camera
saw a surface in it, or the known scene)::

    safe    every voxel the swept padded robot touches is free
    maybe   it touches unknown voxels (or leaves the mapped box), no occupied one
    unsafe  it touches an occupied voxel

Conservative sweep: a voxel is touched when its centre lies within ``r + padding + pad_k +
s*sqrt(3)/2`` of a capsule's axis at a sample ``k`` (``s`` the voxel size; half the voxel's
diagonal, so every voxel the padded capsule meets counts). Samples are spaced so that no point
of the robot moves more than ``max_move`` (default a quarter voxel) between two of them; the
bound is ``sum_j |dq_j| * 2 E`` with ``E`` the robot's largest reach from its base over the
samples (every joint axis and every point lie within ``E`` of the base), and ``pad_k`` = half
that move (x 1.05), so every pose between two samples is covered by one of them.

The known scene (the rig's CAD: the table the robot stands on, fixtures) is exact and does not
move: its voxels (``known``, centre inside a CAD object) are touched with ``scene_padding``
(default 2 cm, ``monitor.free_space_scene_padding``) in place of the robot's padding. The sweep's
half voxel diagonal still covers every point of such a voxel, so a voxel with anything in it is
still met by the unpadded robot that reaches it (issue 30: with 7 cm, a UR3 turning its shoulder
capsule 4 mm off its axis "met" the table it is mounted on in every path of ur3-cell).

A capsule whose axis stays put along the whole path (:data:`STILL`: the base on its mount, a
column turning about its own axis) sweeps nothing it does not already cover and is left out: what
touches it now (the mount) is not the motion's. Only the robot's body when the map was taken (``exclude``: the voxels whose centre lies inside
its unpadded capsules, :func:`body_mask`) is left out: nothing else can be there. The padded
shell around the robot is not: a hand on the robot, or behind it, is in voxels no camera can
judge (the robot is in the way), and they stay unknown — a path through them is ``maybe``,
never ``safe`` (issue 30: leaving out the padded start volume judged 18 colliding segments safe
on flacco-cell).

The sweep is :mod:`depthguard.control.path_sweep` (:func:`sweep_states`, the numba kernel, and
:func:`sweep_states_numpy`, its plain numpy twin; the tests hold them equal).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np

from depthguard.control.path_sweep import sweep_states, sweep_states_numpy
from depthguard.robot.chain import forward_kernel

__all__ = ["FREE", "UNKNOWN", "OCCUPIED", "VERDICTS", "SegmentVerdict", "PathVerdict", "check_path_states",
           "validate_path", "sweep_states", "sweep_states_numpy", "sample_path", "sample_path_numpy", "capsule_ends", "touched_mask", "body_mask"]

FREE, UNKNOWN, OCCUPIED = 0, 1, 2
VERDICTS = ("safe", "maybe", "unsafe")      # index = the worst state touched
_HALF_DIAG = math.sqrt(3.0) / 2.0
STILL = 1e-6        # m: a capsule whose axis ends move less than this along a path stays put


@dataclass(frozen=True)
class SegmentVerdict:
    """Segment ``index`` (waypoint ``index`` to ``index + 1``, stamps ``t0``..``t1`` s): ``verdict``
    one of :data:`VERDICTS`; ``voxel`` (i, j, k) the first voxel of the worst state met (None if
    safe, or only outside the box); ``outside`` True when the swept robot leaves the mapped box."""
    index: int
    t0: float
    t1: float
    verdict: str
    voxel: tuple | None = None
    outside: bool = False
    why: str = ""

    @property
    def reason(self) -> str:
        if self.why:
            return self.why
        if self.verdict == "safe":
            return "every voxel swept is free"
        if self.verdict == "unsafe":
            return f"the swept robot meets an occupied voxel {self.voxel}"
        if self.voxel is not None:
            return f"the swept robot meets unknown space (voxel {self.voxel}: no camera judged it)"
        return "the swept robot leaves the mapped workspace (unknown space)"


@dataclass(frozen=True)
class PathVerdict:
    """The verdict of a whole path: per segment, the worst overall, the first segment that is not
    safe (None when all are) and the map's stamp (s) it was judged in."""
    segments: tuple
    map_stamp: float = float("nan")
    samples: int = 0
    verdict: str = field(init=False)
    first_not_safe: int | None = field(init=False)

    def __post_init__(self):
        worst = max((VERDICTS.index(s.verdict) for s in self.segments), default=0)
        object.__setattr__(self, "verdict", VERDICTS[worst])
        first = next((s.index for s in self.segments if s.verdict != "safe"), None)
        object.__setattr__(self, "first_not_safe", first)

    def reasons(self) -> list[str]:
        """One line per segment that is not safe."""
        return [f"segment {s.index} ({s.t0:.3f}-{s.t1:.3f} s): {s.verdict}: {s.reason}"
                for s in self.segments if s.verdict != "safe"]

    def as_dict(self) -> dict:
        return {"verdict": self.verdict, "first_not_safe": self.first_not_safe, "map_stamp": self.map_stamp,
                "samples": self.samples, "reasons": self.reasons(),
                "segments": [{"index": s.index, "t0": s.t0, "t1": s.t1, "verdict": s.verdict,
                              "voxel": list(s.voxel) if s.voxel is not None else None, "outside": s.outside}
                             for s in self.segments]}


def validate_path(stamps, q, robot) -> tuple[np.ndarray, np.ndarray]:
    """Check a path: ``stamps`` (n,) s strictly increasing, ``q`` (n, dof) rad within the robot's
    limits, everything finite, n >= 2. Returns float64 copies; ``ValueError`` naming the first
    bad waypoint (0-based) otherwise."""
    t = np.asarray(stamps, dtype=np.float64).reshape(-1)
    Q = np.asarray(q, dtype=np.float64)
    if Q.ndim != 2 or Q.shape[0] != t.shape[0]:
        raise ValueError(f"a path is n stamps and n joint vectors; got {t.shape[0]} stamps and joints of shape {Q.shape}")
    if len(t) < 2:
        raise ValueError(f"a path needs at least 2 waypoints, got {len(t)}")
    if Q.shape[1] != robot.dof:
        raise ValueError(f"waypoint 0: {Q.shape[1]} joints, the robot {robot.name!r} has {robot.dof}")
    lo, hi = np.asarray(robot.q_min, float), np.asarray(robot.q_max, float)
    with np.errstate(invalid="ignore"):
        bad_t = ~np.isfinite(t)
        bad_q = ~np.all(np.isfinite(Q), axis=1)
        bad_order = np.concatenate([[False], ~(t[1:] > t[:-1])])
        bad_lim = np.any((Q < lo - 1e-9) | (Q > hi + 1e-9), axis=1)
    bad = bad_t | bad_q | bad_order | bad_lim
    if bad.any():
        i = int(np.argmax(bad))
        if bad_t[i]:
            raise ValueError(f"waypoint {i}: stamp {float(t[i])} is not finite")
        if bad_q[i]:
            raise ValueError(f"waypoint {i}: joints {Q[i].tolist()} are not all finite")
        if bad_order[i]:
            raise ValueError(f"waypoint {i}: stamp {t[i]:.6f} s does not increase (previous {t[i - 1]:.6f} s)")
        j = int(np.argmax((Q[i] < lo - 1e-9) | (Q[i] > hi + 1e-9)))
        raise ValueError(f"waypoint {i}: joint {j} = {Q[i, j]:.4f} rad is outside its limits "
                         f"[{lo[j]:.4f}, {hi[j]:.4f}]")
    return t, Q


def _base(robot) -> np.ndarray:
    b = getattr(robot, "base", None)
    return np.asarray(b, dtype=np.float64)[:3, 3] if b is not None else np.zeros(3)


def _axis_reach(A: np.ndarray, B: np.ndarray, base: np.ndarray) -> float:
    """Largest distance (m) from ``base`` of a capsule axis end (axes are convex: of any axis point)."""
    return float(max(np.max(np.linalg.norm(A - base, axis=-1)), np.max(np.linalg.norm(B - base, axis=-1))))


def capsule_ends(robot, Qs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World capsule axis ends ``A``, ``B`` (S, K, 3) m of the robot at each row of ``Qs`` (S, dof)
    rad, forward kinematics in one numba call (the rows must be finite)."""
    Qs = np.ascontiguousarray(Qs, dtype=np.float64)
    c = robot.chain
    A = np.empty((len(Qs), len(robot._cap_link), 3))
    B = np.empty_like(A)
    _ends_kernel(Qs, np.ascontiguousarray(robot.base, dtype=np.float64), c.xf, c.ints, c.axis, c.support,
                 robot._cap_link, robot._cap_ab, A, B)
    return A, B


@numba.njit(cache=True, nogil=True)
def _ends_kernel(Qs, base, xf, ints, axis, support, cap_link, cap_ab, A, B):
    _poses_ends(Qs, base, xf, ints, axis, support, cap_link, cap_ab, A, B, np.zeros(3))


def sample_path(robot, Q: np.ndarray, max_move: float, padding: float):
    """Samples of the path ``Q`` (n, dof): capsule axis ends ``A``, ``B`` (S, K, 3) m, radii ``R``
    (S, K) m (the capsule's + ``padding`` + the sample's own pad), the segment of each sample (S,)
    int64. Each segment's samples include both its ends.

    Speed bound: a point ``p`` moves at most ``sum_j |dq_j| |p - o_j|`` for revolute joint origins
    ``o_j`` (``|dq_j|`` for a prismatic one); every axis point lies within ``E`` of the base and
    every joint origin within ``E + r_max`` (it is inside a capsule), so the lever is at most
    ``max(2 E + r_max, 1 m)``. ``E`` is taken over the waypoints first, then over the samples,
    resampling while a sample reaches farther."""
    A, B, R, seg, _ = _samples(robot, Q, max_move, padding)
    return A, B, R, seg


def _samples(robot, Q: np.ndarray, max_move: float, padding: float):
    """:func:`sample_path` in one numba call, and per capsule whether its axis moves along the
    path (K,) bool (more than :data:`STILL`)."""
    c = robot.chain
    r0 = np.array([cap.radius for cap in robot.capsules], dtype=np.float64)
    return _samples_kernel(np.ascontiguousarray(Q, dtype=np.float64), np.ascontiguousarray(robot.base, dtype=np.float64),
                           c.xf, c.ints, c.axis, c.support, robot._cap_link, robot._cap_ab, r0, float(padding),
                           float(max_move), STILL)


@numba.njit(cache=True, nogil=True)
def _poses_ends(Qs, base, xf, ints, axis, support, cap_link, cap_ab, A, B, bpos):
    """Capsule axis ends of each row of ``Qs`` into ``A``, ``B`` (rows, K, 3); returns the largest
    distance (m) of an end from ``bpos`` (3,) (:func:`_axis_reach`)."""
    L = ints.shape[0]
    n = Qs.shape[1]
    poses = np.empty((L, 4, 4))
    jf = np.empty((L, 2, 3))
    scratch = np.empty((3, 4, 4))
    cp_link = np.empty(0, np.int64)
    cp_off = np.empty((0, 3))
    cp_pos = np.empty((0, 3))
    cp_jac = np.empty((0, 3, n))
    e = 0.0
    for s in range(Qs.shape[0]):
        forward_kernel(Qs[s], base, xf, ints, axis, support, cp_link, cp_off, poses, jf, scratch, cp_pos, cp_jac)
        for k in range(cap_link.shape[0]):
            T = poses[cap_link[k]]
            for r in range(3):
                A[s, k, r] = T[r, 0] * cap_ab[k, 0, 0] + T[r, 1] * cap_ab[k, 0, 1] + T[r, 2] * cap_ab[k, 0, 2] + T[r, 3]
                B[s, k, r] = T[r, 0] * cap_ab[k, 1, 0] + T[r, 1] * cap_ab[k, 1, 1] + T[r, 2] * cap_ab[k, 1, 2] + T[r, 3]
            da = math.sqrt((A[s, k, 0] - bpos[0]) ** 2 + (A[s, k, 1] - bpos[1]) ** 2 + (A[s, k, 2] - bpos[2]) ** 2)
            db = math.sqrt((B[s, k, 0] - bpos[0]) ** 2 + (B[s, k, 1] - bpos[1]) ** 2 + (B[s, k, 2] - bpos[2]) ** 2)
            e = max(e, da, db)
    return e


@numba.njit(cache=True, nogil=True)
def _samples_kernel(Q, base, xf, ints, axis, support, cap_link, cap_ab, r0, padding, max_move, still):
    """Numba form of :func:`sample_path_numpy` (the same expressions, so the same samples), plus
    the capsules whose axis moves (module docstring)."""
    nw = Q.shape[0]
    dof = Q.shape[1]
    K = cap_link.shape[0]
    bpos = np.empty(3)
    for r in range(3):
        bpos[r] = base[r, 3]
    r_max = 0.0
    for k in range(K):
        r_max = max(r_max, r0[k])
    Aw = np.empty((nw, K, 3))
    Bw = np.empty((nw, K, 3))
    e = _poses_ends(Q, base, xf, ints, axis, support, cap_link, cap_ab, Aw, Bw, bpos)
    l1 = np.zeros(nw - 1)
    for i in range(nw - 1):
        for j in range(dof):
            l1[i] += abs(Q[i + 1, j] - Q[i, j])
    n = np.empty(nw - 1, np.int64)
    move = np.empty(nw - 1)
    A = Aw
    B = Bw
    seg = np.empty(0, np.int64)
    for _ in range(6):
        lever = max(2.0 * e + r_max, 1.0)
        total = 0
        for i in range(nw - 1):
            move[i] = l1[i] * lever
            n[i] = max(1, int(math.ceil(move[i] / max_move)))
            total += n[i] + 1
        Qs = np.empty((total, dof))
        seg = np.empty(total, np.int64)
        m = 0
        for i in range(nw - 1):
            for j in range(n[i] + 1):
                frac = j / n[i]
                for d in range(dof):
                    Qs[m, d] = Q[i, d] + frac * (Q[i + 1, d] - Q[i, d])
                seg[m] = i
                m += 1
        A = np.empty((total, K, 3))
        B = np.empty((total, K, 3))
        e_seen = _poses_ends(Qs, base, xf, ints, axis, support, cap_link, cap_ab, A, B, bpos)
        if e_seen <= e + 0.5 * max_move:
            break
        e = e_seen
    S = A.shape[0]
    R = np.empty((S, K))
    moving = np.zeros(K, np.bool_)
    for m in range(S):
        pad = 0.5 * 1.05 * move[seg[m]] / n[seg[m]]
        for k in range(K):
            R[m, k] = r0[k] + padding + pad
            for r in range(3):
                if abs(A[m, k, r] - A[0, k, r]) > still or abs(B[m, k, r] - B[0, k, r]) > still:
                    moving[k] = True
    return A, B, R, seg, moving


def sample_path_numpy(robot, Q: np.ndarray, max_move: float, padding: float):
    """Plain numpy twin of :func:`sample_path` (the tests hold them equal)."""
    base = _base(robot)
    r0 = np.array([c.radius for c in robot.capsules], dtype=np.float64)
    r_max = float(np.max(r0))
    A, B = capsule_ends(robot, Q)
    e = _axis_reach(A, B, base)
    dq = np.diff(Q, axis=0)
    l1 = np.sum(np.abs(dq), axis=1)
    for _ in range(6):
        lever = max(2.0 * e + r_max, 1.0)
        move = l1 * lever
        n = np.maximum(1, np.ceil(move / max_move).astype(np.int64))
        seg = np.repeat(np.arange(len(dq), dtype=np.int64), n + 1)
        starts = np.concatenate([[0], np.cumsum(n + 1)[:-1]])
        frac = (np.arange(len(seg)) - starts[seg]) / n[seg]        # 0, 1/m, ..., 1 per segment
        Qs = Q[seg] + frac[:, None] * dq[seg]
        A, B = capsule_ends(robot, Qs)
        e_seen = _axis_reach(A, B, base)
        if e_seen <= e + 0.5 * max_move:        # the rest is covered by the 5 % on the pad
            break
        e = e_seen                              # a pose between waypoints reaches farther: resample
    pad = 0.5 * 1.05 * move / n
    R = r0[None, :] + float(padding) + pad[seg][:, None]
    return A, B, R, seg


def check_path_states(state, lo, voxel_size: float, robot, stamps, q, padding: float = 0.0,
                      exclude=None, max_move: float | None = None, map_stamp: float = float("nan"),
                      twin: bool = False, known=None, scene_padding: float | None = None) -> PathVerdict:
    """R22/R37: the verdict per segment of the path ``(stamps (n,) s, q (n, dof) rad)`` in the map
    ``state`` (nx, ny, nz) uint8 (:data:`FREE`/:data:`UNKNOWN`/:data:`OCCUPIED`) whose voxel
    ``(0, 0, 0)`` starts at ``lo`` (3,) m, cubes of ``voxel_size`` m.

    ``padding`` m is added to the robot's capsules; ``exclude`` (nx, ny, nz) bool voxels never
    count (default: the robot's body at the first waypoint, :func:`body_mask` — the map taken
    there);
    ``known`` (nx, ny, nz) bool: the known scene's voxels (centre inside the rig's CAD,
    :func:`~depthguard.runtime.free_space_map.known_scene_mask`), touched with ``scene_padding`` m
    (default ``padding``) instead of ``padding``: the CAD is exact and static, the padding covers
    what the cameras may have misjudged (module docstring);
    ``max_move`` m between samples (default a quarter voxel); ``twin`` uses the numpy twin.
    A bad path raises ``ValueError`` naming the waypoint (:func:`validate_path`)."""
    t, Q = validate_path(stamps, q, robot)
    st = np.ascontiguousarray(state, dtype=np.uint8)
    lo = np.ascontiguousarray(lo, dtype=np.float64)
    s = float(voxel_size)
    if exclude is None:
        exclude = body_mask(st.shape, lo, s, robot, Q[0])
    ex = np.ascontiguousarray(exclude, dtype=np.bool_)
    if ex.shape != st.shape:
        raise ValueError(f"exclude has shape {ex.shape}, the map {st.shape}")
    kn = np.zeros(st.shape, np.bool_) if known is None else np.ascontiguousarray(known, dtype=np.bool_)
    if kn.shape != st.shape:
        raise ValueError(f"known has shape {kn.shape}, the map {st.shape}")
    dpad = 0.0 if scene_padding is None else max(float(padding) - float(scene_padding), 0.0)
    mm = 0.25 * s if max_move is None else float(max_move)
    if twin:
        A, B, R, seg = sample_path_numpy(robot, Q, mm, float(padding))
        moving = np.max(np.abs(np.concatenate([A - A[:1], B - B[:1]], axis=0)), axis=(0, 2)) > STILL
    else:
        A, B, R, seg, moving = _samples(robot, Q, mm, float(padding))
    # a capsule whose axis stays put along the whole path (the base on its mount, a column turning
    # about its own axis) sweeps nothing it does not cover now: it is left out
    if not moving.all():
        A, B, R = A[:, moving], B[:, moving], R[:, moving]
    n = len(Q) - 1
    if twin:
        worst, first, outside = sweep_states_numpy(st, ex, kn, dpad, lo, s, A, B, R, seg, n)
    else:
        worst, first, outside = np.zeros(n, np.uint8), np.zeros(n, np.int64), np.zeros(n, np.bool_)
        sweep_states(st, ex, kn, dpad, lo, s, np.ascontiguousarray(A), np.ascontiguousarray(B), np.ascontiguousarray(R),
                     seg, n, worst, first, outside)
    w = np.where(outside, np.maximum(worst, UNKNOWN), worst).tolist()
    ijk = np.stack(np.unravel_index(np.maximum(first, 0), st.shape), axis=1).tolist()
    has, out, tl = (first >= 0).tolist(), outside.tolist(), t.tolist()
    segs = tuple(SegmentVerdict(i, tl[i], tl[i + 1], VERDICTS[w[i]], tuple(ijk[i]) if has[i] else None, out[i])
                 for i in range(n))
    return PathVerdict(segs, float(map_stamp), len(A))


def body_mask(shape, lo, s, robot, q) -> np.ndarray:
    """(nx, ny, nz) bool voxels whose centre lies inside the robot's own capsules (no padding) at
    ``q`` (dof,) rad: the robot's body, where nothing else can be (the map's centre convention,
    R21). The only voxels a path check may leave out; the padded shell around them is not."""
    return touched_mask(shape, lo, s, robot, q, -float(s) * _HALF_DIAG)


def touched_mask(shape, lo, s, robot, q, padding) -> np.ndarray:
    """(nx, ny, nz) bool voxels the robot's capsules (+ ``padding`` m) at ``q`` touch (the sweep's
    rule: centre within ``r + padding + s*sqrt(3)/2`` of the axis)."""
    A, B = capsule_ends(robot, np.asarray(q, dtype=np.float64)[None, :])
    R = np.array([c.radius for c in robot.capsules], dtype=np.float64)[None, :] + float(padding)
    out = np.zeros(shape, np.bool_)
    _mark_kernel(out, np.ascontiguousarray(lo, dtype=np.float64), float(s), A, B, R)
    return out


@numba.njit(cache=True, nogil=True)
def _mark_kernel(out, lo, s, A, B, R):
    reach0 = s * 0.8660254037844386
    for k in range(A.shape[0]):
        for c in range(A.shape[1]):
            reach = R[k, c] + reach0
            d = B[k, c] - A[k, c]
            L2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
            i0 = np.empty(3, np.int64)
            i1 = np.empty(3, np.int64)
            for e in range(3):
                mn = min(A[k, c, e], B[k, c, e])
                mx = max(A[k, c, e], B[k, c, e])
                i0[e] = min(max(int(math.floor((mn - reach - lo[e]) / s)), 0), out.shape[e])
                i1[e] = min(max(int(math.floor((mx + reach - lo[e]) / s)) + 1, 0), out.shape[e])
            for ii in range(i0[0], i1[0]):
                for jj in range(i0[1], i1[1]):
                    for kk in range(i0[2], i1[2]):
                        px = lo[0] + (ii + 0.5) * s - A[k, c, 0]
                        py = lo[1] + (jj + 0.5) * s - A[k, c, 1]
                        pz = lo[2] + (kk + 0.5) * s - A[k, c, 2]
                        u = 0.0
                        if L2 > 0.0:
                            u = min(max((px * d[0] + py * d[1] + pz * d[2]) / L2, 0.0), 1.0)
                        ex, ey, ez = px - u * d[0], py - u * d[1], pz - u * d[2]
                        if ex * ex + ey * ey + ez * ez <= reach * reach:
                            out[ii, jj, kk] = True
