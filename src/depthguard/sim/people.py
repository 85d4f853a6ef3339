"""People for simulated scenes: articulated capsule bodies following scripted keyframes.

A :class:`Person` is built from exact primitives (so ground truth stays
analytic): legs (capsules), torso (box), neck (capsule), head (sphere),
upper arms, forearms (capsules) and hands (spheres). Its pose at time ``t``
comes from keyframes (:class:`Key`): where it stands on the floor, where it
faces, and optionally a world point each hand reaches for (two-link
inverse kinematics of the arm, elbow down and out). Between keys the pose is
interpolated (``"linear"`` with smooth-step easing) or held (``"step"``).

A person can carry props: :class:`Carry` attaches a scene prop to a hand for
a time window; after the window the prop stays where it was released.

Body frame: x forward (the heading), y to the person's left, z up; the
origin is on the floor under the pelvis.
"""

from __future__ import annotations

import bisect
import functools
import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from depthguard.geometry.primitives import Box, Capsule, Primitive, Sphere
from depthguard.sim.body_pose import _POLE, PartPoses, _body_locals, _pose_parts
from depthguard.transforms import pose

__all__ = ["BodyShape", "Key", "Carry", "Person", "PersonPose", "PartPoses"]


@dataclass(frozen=True)
class BodyShape:
    """Body dimensions in metres (an adult of about 1.75 m by default)."""
    height: float = 1.75
    torso_depth: float = 0.22
    torso_width: float = 0.36
    head_radius: float = 0.11
    neck_radius: float = 0.05
    upper_arm: float = 0.30        # shoulder to elbow
    forearm: float = 0.30          # elbow to hand centre
    arm_radius: float = 0.045
    forearm_radius: float = 0.04
    hand_radius: float = 0.05
    leg_radius: float = 0.075
    hip_width: float = 0.20        # between the leg axes
    legs: bool = True

    @property
    def hip_z(self) -> float:
        return 0.50 * self.height

    @property
    def shoulder_z(self) -> float:
        return 0.82 * self.height

    def shoulder(self, side: str) -> np.ndarray:
        """Shoulder joint in the body frame (a read-only (3,) array, made once per shape and side)."""
        return _body_points(self, side)[0]

    def rest_hand(self, side: str) -> np.ndarray:
        """Hand centre of a relaxed, hanging arm in the body frame (read-only, as :meth:`shoulder`)."""
        return _body_points(self, side)[1]


@functools.lru_cache(maxsize=64)
def _body_points(shape: BodyShape, side: str) -> tuple[np.ndarray, np.ndarray]:
    """``(shoulder, rest hand)`` of :class:`BodyShape` in the body frame: fixed by the shape,
    so made once (a person is posed at every simulated frame)."""
    s = 1.0 if side == "left" else -1.0
    sh = np.array([0.0, s * (shape.torso_width / 2 + shape.arm_radius), shape.shoulder_z - 0.04])
    reach = 0.97 * (shape.upper_arm + shape.forearm)
    rest = sh + np.array([0.06, 0.02 * np.sign(sh[1]), -math.sqrt(reach ** 2 - 0.06 ** 2 - 0.02 ** 2)])
    for a in (sh, rest):
        a.setflags(write=False)
    return sh, rest




@dataclass(frozen=True)
class Key:
    """A keyframe: at time ``t`` the person stands at ``xy`` (floor position, m) facing
    ``heading`` (rad, 0 = +x, counter-clockwise); ``left`` / ``right`` are world points
    (3,) the hands reach for, or ``None`` for a relaxed arm."""
    t: float
    xy: tuple[float, float]
    heading: float = 0.0
    left: tuple[float, float, float] | None = None
    right: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class Carry:
    """The scene prop ``prop`` is held by the ``hand`` (``"left"``/``"right"``) for ``t0 <= t < t1``;
    its pose is the hand frame (hand centre, body heading) times ``offset`` (4x4 or (3,) translation)."""
    prop: str
    hand: str
    t0: float
    t1: float
    offset: tuple = (0.0, 0.0, 0.0)

    def offset_matrix(self) -> np.ndarray:
        """The offset as a 4x4 pose (read-only, made once: a carried prop is posed per frame)."""
        T = self.__dict__.get("_offset_T")
        if T is None:
            o = np.asarray(self.offset, dtype=np.float64)
            T = np.array(o if o.shape == (4, 4) else pose(t=o), dtype=np.float64)
            T.setflags(write=False)
            object.__setattr__(self, "_offset_T", T)      # frozen: a cache beside the fields
        return T


@dataclass(frozen=True)
class PersonPose:
    """The resolved pose at one time: floor position, heading, and hand targets in the world."""
    xy: np.ndarray
    heading: float
    left: np.ndarray | None
    right: np.ndarray | None


@dataclass
class Person:
    """A scripted person (module docstring).

    Parameters
    ----------
    name : prefix of the primitive names (``"<name>/torso"`` …).
    keys : keyframes, sorted by time; before the first / after the last the end keys hold.
    shape : body dimensions.
    floor_z : height of the floor the person stands on, m.
    present : ``(t_enter, t_leave)``: outside this window the person is not in the scene.
    carries : props held in a hand over time windows.
    interp : ``"linear"`` (eased) or ``"step"`` (hold each key until the next).
    """
    name: str
    keys: Sequence[Key]
    shape: BodyShape = field(default_factory=BodyShape)
    floor_z: float = 0.0
    present: tuple[float, float] = (-math.inf, math.inf)
    carries: Sequence[Carry] = ()
    interp: str = "linear"
    gait: bool = True   # swing the legs while walking (1.8 steps/s, up to ±25°)
    _memo: tuple | None = field(default=None, init=False, repr=False, compare=False)
    _pose_memo: tuple | None = field(default=None, init=False, repr=False, compare=False)
    _key_times: tuple | None = field(default=None, init=False, repr=False, compare=False)
    _parts_memo: tuple | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        if not self.keys:
            raise ValueError(f"person {self.name!r}: needs at least one keyframe")
        self.keys = sorted(self.keys, key=lambda k: k.t)
        if self.interp not in ("linear", "step"):
            raise ValueError(f"person {self.name!r}: interp must be 'linear' or 'step' (got {self.interp!r})")
        for c in self.carries:
            if c.hand not in ("left", "right"):
                raise ValueError(f"person {self.name!r}: carry hand must be 'left' or 'right' (got {c.hand!r})")

    # ---------------------------------------------------------------- pose
    def is_present(self, t: float) -> bool:
        return self.present[0] <= t < self.present[1]

    def body_frame(self, xy, heading) -> np.ndarray:
        """4x4 world pose of the body frame at floor position ``xy`` facing ``heading`` rad:
        ``pose(rot_z(heading), [x, y, floor_z])``, its numbers made in one array."""
        c, s = np.cos(heading), np.sin(heading)
        return np.array([[c, -s, 0.0, xy[0]], [s, c, 0.0, xy[1]], [0.0, 0.0, 1.0, self.floor_z],
                         [0.0, 0.0, 0.0, 1.0]], dtype=np.float64)

    def _frame(self, p: PersonPose) -> np.ndarray:
        """:meth:`body_frame` of the pose ``p``, made once for the pose :meth:`pose_at` last
        returned (read-only then: the body and both arms of a frame share it)."""
        memo = self._pose_memo
        if memo is not None and memo[1] is p:
            T = memo[2].get("T")
            if T is None:
                T = memo[2]["T"] = self.body_frame(p.xy, p.heading)
                T.setflags(write=False)
            return T
        return self.body_frame(p.xy, p.heading)

    def pose_at(self, t: float) -> PersonPose:
        """Floor position, heading and world hand targets at time ``t`` (the last time's answer is
        kept: a frame asks for the body and for the hand that carries a prop at the same time)."""
        memo = self._pose_memo                           # one read: safe if another thread asks too
        if memo is None or memo[0] != t:
            p, T = self._resolve(*self._between(t))
            T.setflags(write=False)                      # the body frame of this pose (_frame)
            memo = self._pose_memo = (t, p, {"T": T})
        return memo[1]

    def _between(self, t: float) -> tuple[Key, Key, float]:
        """The keys around ``t`` and the eased blend ``s`` from the first to the second."""
        ks = self.keys
        if t <= ks[0].t or len(ks) == 1:
            return ks[0], ks[0], 0.0
        if t >= ks[-1].t:
            return ks[-1], ks[-1], 0.0
        kt = self._key_times
        if kt is None or kt[0] is not ks:                # the keys' times, listed once per key list
            kt = self._key_times = (ks, [k.t for k in ks])
        i = bisect.bisect_right(kt[1], t) - 1
        a, b = ks[i], ks[i + 1]
        if self.interp == "step":
            return a, a, 0.0
        s = (t - a.t) / (b.t - a.t)
        s = s * s * (3 - 2 * s)  # smooth step: start and stop gently
        return a, b, s

    def _xy_at(self, t: float) -> np.ndarray:
        """The floor position of :meth:`pose_at` alone (the same arithmetic, without the hands)."""
        a, b, s = self._between(t)
        return (1 - s) * np.asarray(a.xy, float) + s * np.asarray(b.xy, float)

    def _xy_floats(self, t: float) -> tuple[float, float]:
        """:meth:`_xy_at` as two floats (the same arithmetic per coordinate)."""
        a, b, s = self._between(t)
        return (1 - s) * float(a.xy[0]) + s * float(b.xy[0]), (1 - s) * float(a.xy[1]) + s * float(b.xy[1])

    def _resolve(self, a: Key, b: Key, s: float) -> tuple[PersonPose, np.ndarray]:
        """The pose between keys ``a`` and ``b`` at blend ``s``, and its body frame (4x4)."""
        xy = (1 - s) * np.asarray(a.xy, float) + s * np.asarray(b.xy, float)
        dh = (b.heading - a.heading + math.pi) % (2 * math.pi) - math.pi
        heading = a.heading + s * dh
        T = self.body_frame(xy, heading)
        hands = {}
        for side in ("left", "right"):
            ta, tb = getattr(a, side), getattr(b, side)
            if ta is None and tb is None:
                hands[side] = None
                continue
            rest = T[:3, :3] @ self.shape.rest_hand(side) + T[:3, 3]
            pa = rest if ta is None else np.asarray(ta, float)
            pb = rest if tb is None else np.asarray(tb, float)
            hands[side] = (1 - s) * pa + s * pb
        return PersonPose(xy, heading, hands["left"], hands["right"]), T

    def arm_points(self, p: PersonPose, side: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World shoulder, elbow and hand centre of one arm (two-link IK towards the target);
        kept for the pose :meth:`pose_at` last returned (read-only arrays then)."""
        memo = self._pose_memo
        if memo is not None and memo[1] is p:
            arm = memo[2].get(side)
            if arm is None:
                arm = memo[2][side] = self._arm_points(p, side)
                for a in arm:
                    a.setflags(write=False)
            return arm
        return self._arm_points(p, side)

    def _arm_points(self, p: PersonPose, side: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        sh = self.shape
        T = self._frame(p)
        R, o = T[:3, :3], T[:3, 3]
        S = R @ sh.shoulder(side) + o
        target = getattr(p, side)
        if target is None:
            target = R @ sh.rest_hand(side) + o
        L1, L2 = sh.upper_arm, sh.forearm
        d_vec = np.asarray(target, float) - S
        d = math.sqrt(d_vec.dot(d_vec))              # np.linalg.norm's arithmetic (sqrt of the dot)
        u = d_vec / d if d > 1e-9 else R @ np.array([0.0, 0.0, -1.0])
        d = min(max(d, abs(L1 - L2) + 0.05), 0.999 * (L1 + L2))
        hand = S + d * u
        a = (L1 * L1 - L2 * L2 + d * d) / (2 * d)
        h = math.sqrt(max(L1 * L1 - a * a, 0.0))
        s = 1.0 if side == "left" else -1.0
        pole = R @ _POLE[side]                              # elbow goes down, out and back
        w = pole - (pole @ u) * u
        nw = math.sqrt(w.dot(w))
        w = w / nw if nw > 1e-9 else R @ np.array([0.0, s, 0.0])
        elbow = S + a * u + h * w
        return S, elbow, hand

    def hand_frame(self, t: float, side: str) -> np.ndarray:
        """4x4 world pose of a hand: origin at the hand centre, axes of the body heading."""
        p = self.pose_at(t)
        _, _, hand = self.arm_points(p, side)
        c, s = np.cos(p.heading), np.sin(p.heading)          # pose(rot_z(heading), hand), in one array
        return np.array([[c, -s, 0.0, hand[0]], [s, c, 0.0, hand[1]], [0.0, 0.0, 1.0, hand[2]],
                         [0.0, 0.0, 0.0, 1.0]], dtype=np.float64)

    def primitives(self, t: float) -> list[Primitive]:
        """The body at time ``t`` as exact primitives (empty when not present)."""
        if not self.is_present(t):
            return []
        p = self.pose_at(t)
        swing = self.leg_swing(t, p)
        key = _pose_key(p, swing)
        memo = self._memo                                # one read: safe if another thread asks too
        if memo is None or memo[0] != key:               # a person who stands still: the same solids
            memo = self._memo = (key, self.primitives_at(p, swing))
        return list(memo[1])

    def part_poses(self, t: float) -> PartPoses | None:
        """The body at time ``t`` as arrays (:class:`PartPoses`: the parts of :meth:`primitives`,
        in order, their poses and lengths, to the rounding), None when not present; the last pose's
        answer is kept (a person who stands still: the same object). The posing of a frame in
        one pass (:func:`_pose_parts`) instead of a solid per part (issue 29)."""
        if not self.is_present(t):
            return None
        p = self.pose_at(t)
        swing = self.leg_swing(t, p)
        key = _pose_key(p, swing)
        memo = self._parts_memo                          # one read: safe if another thread asks too
        if memo is not None and memo[0] == key:
            return memo[1]
        sh = self.shape
        loc, kinds, L = _body_locals(sh)
        if sh.legs:                                      # the feet: primitives_at's arithmetic
            loc = loc.copy()
            for s, row in ((1.0, 1), (-1.0, 3)):
                a = swing * s
                loc[row] = [L * math.sin(a), s * sh.hip_width / 2, sh.hip_z - L * math.cos(a)]
        T = self._frame(p)
        R, o = T[:3, :3], T[:3, 3]
        W = np.ascontiguousarray((R @ loc[:, :, None])[:, :, 0])   # R @ v per row: the same gemv
        W[:11] += o                                      # points; rows 11-15 are directions
        L1, L2 = sh.upper_arm, sh.forearm
        K = len(kinds)
        Ts, lengths, arms = np.empty((K, 4, 4)), np.empty(K), np.empty((2, 2, 3))
        _pose_parts(W, np.ascontiguousarray(R), W[8] if p.left is None else np.asarray(p.left, float),
                    W[10] if p.right is None else np.asarray(p.right, float), p.left is not None,
                    p.right is not None, bool(sh.legs), float(L1), float(L2), abs(L1 - L2) + 0.05,
                    0.999 * (L1 + L2), arms, Ts, lengths)
        Ts.setflags(write=False)
        lengths.setflags(write=False)
        memo = self._pose_memo
        if memo is not None and memo[1] is p:            # the arms of this pose, for arm_points
            for side, k, sh_row in (("left", 0, 7), ("right", 1, 9)):
                if side not in memo[2]:
                    arm = (W[sh_row].copy(), arms[k, 0].copy(), arms[k, 1].copy())
                    for a in arm:
                        a.setflags(write=False)
                    memo[2][side] = arm
        out = PartPoses(kinds, Ts, lengths)
        self._parts_memo = (key, out)
        return out

    def leg_swing(self, t: float, p: PersonPose | None = None) -> float:
        """Swing angle (rad) of the left leg at time ``t`` (the right leg swings opposite): grows
        with the forward walking speed (full ±25° from 1 m/s); 0 when standing or stepping back.
        ``p``: the pose at ``t`` if the caller has it."""
        if not self.gait or not self.shape.legs or self.interp == "step":
            return 0.0
        dt = 0.05
        if p is None:
            p = self.pose_at(t)
        (x1, y1), (x0, y0) = self._xy_floats(t + dt), self._xy_floats(t - dt)
        vx, vy = (x1 - x0) / (2 * dt), (y1 - y0) / (2 * dt)      # (_xy_at(t + dt) - _xy_at(t - dt)) / (2 dt)
        v = max(vx * math.cos(p.heading) + vy * math.sin(p.heading), 0.0)   # its dot product, in order
        return math.radians(25.0) * min(v, 1.0) * math.sin(2 * math.pi * 0.9 * t)

    def primitives_at(self, p: PersonPose, swing: float = 0.0) -> list[Primitive]:
        sh, n = self.shape, self.name
        T = self._frame(p)
        R, o = T[:3, :3], T[:3, 3]

        def w(v):
            return R @ np.asarray(v, float) + o

        out: list[Primitive] = []
        if sh.legs:
            for side, s in (("left", 1.0), ("right", -1.0)):
                a = swing * s  # the legs swing in opposite phase, forward-backward
                hip = w([0.0, s * sh.hip_width / 2, sh.hip_z])
                L = sh.hip_z - sh.leg_radius
                foot = w([L * math.sin(a), s * sh.hip_width / 2, sh.hip_z - L * math.cos(a)])
                out.append(Capsule.between(foot, hip, sh.leg_radius, name=f"{n}/{side}_leg"))
        torso_h = sh.shoulder_z - sh.hip_z + 0.05
        out.append(Box(size=(sh.torso_depth, sh.torso_width, torso_h),
                       world_from_local=pose(R, w([0.0, 0.0, sh.hip_z - 0.05 + torso_h / 2])),
                       name=f"{n}/torso"))
        head_c = w([0.0, 0.0, sh.height - sh.head_radius])
        out.append(Capsule.between(w([0.0, 0.0, sh.shoulder_z - 0.02]), head_c, sh.neck_radius, name=f"{n}/neck"))
        out.append(Sphere(radius=sh.head_radius, world_from_local=pose(t=head_c), name=f"{n}/head"))
        for side in ("left", "right"):
            S, E, Hd = self.arm_points(p, side)
            out.append(Capsule.between(S, E, sh.arm_radius, name=f"{n}/{side}_upper_arm"))
            out.append(Capsule.between(E, Hd, sh.forearm_radius, name=f"{n}/{side}_forearm"))
            out.append(Sphere(radius=sh.hand_radius, world_from_local=pose(t=Hd), name=f"{n}/{side}_hand"))
        return out


def _pose_key(p: PersonPose, swing: float) -> tuple:
    """The key of a posed body: equal keys, equal solids (:meth:`Person.primitives`)."""
    return (p.xy.tobytes(), p.heading, None if p.left is None else p.left.tobytes(),
            None if p.right is None else p.right.tobytes(), swing)
