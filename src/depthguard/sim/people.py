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
from depthguard.transforms import pose, rot_z

__all__ = ["BodyShape", "Key", "Carry", "Person", "PersonPose"]


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


#: the elbow's pole in the body frame per arm (down, out and back), read-only
_POLE = {side: np.array([-0.2, 0.5 * s, -1.0]) for side, s in (("left", 1.0), ("right", -1.0))}
for _a in _POLE.values():
    _a.setflags(write=False)


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
        o = np.asarray(self.offset, dtype=np.float64)
        return o if o.shape == (4, 4) else pose(t=o)


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
        return pose(rot_z(heading), [xy[0], xy[1], self.floor_z])

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
            memo = self._pose_memo = (t, self._resolve(*self._between(t)), {})
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

    def _resolve(self, a: Key, b: Key, s: float) -> PersonPose:
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
        return PersonPose(xy, heading, hands["left"], hands["right"])

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
        return pose(rot_z(p.heading), hand)

    def primitives(self, t: float) -> list[Primitive]:
        """The body at time ``t`` as exact primitives (empty when not present)."""
        if not self.is_present(t):
            return []
        p = self.pose_at(t)
        swing = self.leg_swing(t, p)
        key = (p.xy.tobytes(), p.heading, None if p.left is None else p.left.tobytes(),
               None if p.right is None else p.right.tobytes(), swing)
        memo = self._memo                                # one read: safe if another thread asks too
        if memo is None or memo[0] != key:               # a person who stands still: the same solids
            memo = self._memo = (key, self.primitives_at(p, swing))
        return list(memo[1])

    def leg_swing(self, t: float, p: PersonPose | None = None) -> float:
        """Swing angle (rad) of the left leg at time ``t`` (the right leg swings opposite): grows
        with the forward walking speed (full ±25° from 1 m/s); 0 when standing or stepping back.
        ``p``: the pose at ``t`` if the caller has it."""
        if not self.gait or not self.shape.legs or self.interp == "step":
            return 0.0
        dt = 0.05
        if p is None:
            p = self.pose_at(t)
        vel = (self._xy_at(t + dt) - self._xy_at(t - dt)) / (2 * dt)
        v = max(float(vel @ [math.cos(p.heading), math.sin(p.heading)]), 0.0)
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
