"""A person's body posed as arrays, in one compiled pass (R16, issue 29).

:meth:`depthguard.sim.people.Person.primitives_at` builds the body of a frame as a solid per
part (``Capsule.between``, ``Box``, ``Sphere``: a few numpy calls and a dataclass each, the
arms' two-link IK in numpy) — a simulated camera frame asks for it at every capture time.
:meth:`~depthguard.sim.people.Person.part_poses` makes the same parts as arrays
(:class:`PartPoses`): the body-frame points of :func:`_body_locals` moved to the world by one
stacked ``R @ v`` (per point numpy's gemv, the call ``R @ v`` makes: the same bits), then
:func:`_pose_parts` — the arms' IK, each capsule's frame (``_frame_along``), the box and the
spheres — in plain float arithmetic in the order of the numpy code (a 3-vector's dot product
is the left-to-right sum: what numpy's ``ddot`` gives for 3 terms). The tests compare every part
over the built-in cells' scripts: the same bits on the machines before 2026-11-27; to the
rounding (1.4e-15 at most) on an AVX-512 Xeon, whose BLAS fuses multiply-adds where this
arithmetic does not.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numba
import numpy as np

__all__ = ["PartPoses"]

#: the elbow's pole in the body frame per arm (down, out and back), read-only
_POLE = {side: np.array([-0.2, 0.5 * s, -1.0]) for side, s in (("left", 1.0), ("right", -1.0))}
for _a in _POLE.values():
    _a.setflags(write=False)


class PartPoses(NamedTuple):
    """The parts of ``Person.primitives_at`` as arrays (R16, issue 29): ``kinds`` the
    parts' shapes, a tuple of ``("capsule", radius, segments)`` (spheres too, ``length`` 0) and
    ``("box", size)``; ``T`` (K, 4, 4) float64 their ``world_from_local``; ``length`` (K,)
    float64 m a capsule's length (0 otherwise). The primitives' own, to the rounding (module
    docstring; read-only)."""
    kinds: tuple
    T: np.ndarray
    length: np.ndarray


@functools.lru_cache(maxsize=64)
def _body_locals(shape) -> tuple[np.ndarray, tuple, float]:
    """The body-frame vectors of ``Person.primitives_at`` (``shape``: its ``BodyShape``), (16, 3)
    float64 m — points: 0 / 2 the left / right hip, 1 / 3 the feet (written per swing), 4 the
    torso's centre, 5 the neck's base, 6 the head's centre, 7 / 9 the shoulders, 8 / 10 the
    relaxed hands; directions: 11 / 12 the elbows' poles, 13 down, 14 / 15 left / right — the
    parts' ``kinds`` (:class:`PartPoses`) and the leg length ``L`` (m)."""
    sh = shape
    loc = np.zeros((16, 3))
    for side, s, hip in (("left", 1.0, 0), ("right", -1.0, 2)):
        loc[hip] = [0.0, s * sh.hip_width / 2, sh.hip_z]
    torso_h = sh.shoulder_z - sh.hip_z + 0.05
    loc[4] = [0.0, 0.0, sh.hip_z - 0.05 + torso_h / 2]
    loc[5] = [0.0, 0.0, sh.shoulder_z - 0.02]
    loc[6] = [0.0, 0.0, sh.height - sh.head_radius]
    loc[7], loc[8] = sh.shoulder("left"), sh.rest_hand("left")
    loc[9], loc[10] = sh.shoulder("right"), sh.rest_hand("right")
    loc[11], loc[12] = _POLE["left"], _POLE["right"]
    loc[13] = [0.0, 0.0, -1.0]
    loc[14] = [0.0, 1.0, 0.0]
    loc[15] = [0.0, -1.0, 0.0]
    cap = lambda r: ("capsule", float(r), 16)          # noqa: E731  (Capsule.between's segments)
    sph = lambda r: ("capsule", float(r), 24)          # noqa: E731  (a Sphere's segments, length 0)
    kinds = ((cap(sh.leg_radius), cap(sh.leg_radius)) if sh.legs else ()) + (
        ("box", (float(sh.torso_depth), float(sh.torso_width), float(torso_h))), cap(sh.neck_radius),
        sph(sh.head_radius), cap(sh.arm_radius), cap(sh.forearm_radius), sph(sh.hand_radius),
        cap(sh.arm_radius), cap(sh.forearm_radius), sph(sh.hand_radius))
    return loc, kinds, sh.hip_z - sh.leg_radius


@numba.njit(cache=True, nogil=True)
def _capsule_between(a, b, T, k, length):
    """``T[k]``, ``length[k]`` of ``Capsule.between(a, b)`` (``_frame_along``'s arithmetic, the
    length its ``sqrt`` of the dot product: ``np.linalg.norm``'s)."""
    z0, z1, z2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    n = math.sqrt(z0 * z0 + z1 * z1 + z2 * z2)
    if n > 0:
        z0, z1, z2 = z0 / n, z1 / n, z2 / n
    else:
        z0, z1, z2 = 0.0, 0.0, 1.0
    if abs(z2) < 0.9:
        x0, x1, x2 = z1, -z0, 0.0
    else:
        x0, x1, x2 = 0.0, z2, -z1
    nx = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
    x0, x1, x2 = x0 / nx, x1 / nx, x2 / nx
    y0, y1, y2 = z1 * x2 - z2 * x1, z2 * x0 - z0 * x2, z0 * x1 - z1 * x0
    for i, (x, y, z) in enumerate(((x0, y0, z0), (x1, y1, z1), (x2, y2, z2))):
        T[k, i, 0] = x
        T[k, i, 1] = y
        T[k, i, 2] = z
        T[k, i, 3] = (a[i] + b[i]) / 2
    T[k, 3, 0] = 0.0
    T[k, 3, 1] = 0.0
    T[k, 3, 2] = 0.0
    T[k, 3, 3] = 1.0
    length[k] = n


@numba.njit(cache=True, nogil=True)
def _arm(S, tgt, down, pole, side_dir, L1, L2, lo, hi, out):
    """``out`` (2, 3): elbow and hand of ``Person._arm_points`` (its arithmetic, in order)
    from the world shoulder ``S``, target ``tgt``, the body's down, pole and side directions."""
    d0, d1, d2 = tgt[0] - S[0], tgt[1] - S[1], tgt[2] - S[2]
    d = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    if d > 1e-9:
        u0, u1, u2 = d0 / d, d1 / d, d2 / d
    else:
        u0, u1, u2 = down[0], down[1], down[2]
    d = min(max(d, lo), hi)
    a = (L1 * L1 - L2 * L2 + d * d) / (2 * d)
    h = math.sqrt(max(L1 * L1 - a * a, 0.0))
    pu = pole[0] * u0 + pole[1] * u1 + pole[2] * u2
    w0, w1, w2 = pole[0] - pu * u0, pole[1] - pu * u1, pole[2] - pu * u2
    nw = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    if nw > 1e-9:
        w0, w1, w2 = w0 / nw, w1 / nw, w2 / nw
    else:
        w0, w1, w2 = side_dir[0], side_dir[1], side_dir[2]
    out[0, 0] = S[0] + a * u0 + h * w0
    out[0, 1] = S[1] + a * u1 + h * w1
    out[0, 2] = S[2] + a * u2 + h * w2
    out[1, 0] = S[0] + d * u0
    out[1, 1] = S[1] + d * u1
    out[1, 2] = S[2] + d * u2


@numba.njit(cache=True)      # microseconds: keeps the GIL (a release costs a retake behind the other threads)
def _pose_parts(W, R, left, right, has_left, has_right, legs, L1, L2, lo, hi, arms, T, length):
    """The parts of ``Person.primitives_at`` into ``T`` (K, 4, 4), ``length`` (K,) from the
    world points ``W`` (16, 3) (rows of :func:`_body_locals`, posed), the body's rotation ``R``
    and the hand targets; ``arms`` (2, 2, 3) scratch (elbow, hand per arm)."""
    _arm(W[7], left if has_left else W[8], W[13], W[11], W[14], L1, L2, lo, hi, arms[0])
    _arm(W[9], right if has_right else W[10], W[13], W[12], W[15], L1, L2, lo, hi, arms[1])
    k = 0
    if legs:
        _capsule_between(W[1], W[0], T, 0, length)
        _capsule_between(W[3], W[2], T, 1, length)
        k = 2
    T[k] = 0.0                                            # torso: pose(R, centre)
    for i in range(3):
        for j in range(3):
            T[k, i, j] = R[i, j]
        T[k, i, 3] = W[4, i]
    T[k, 3, 3] = 1.0
    length[k] = 0.0
    _capsule_between(W[5], W[6], T, k + 1, length)        # neck
    _sphere(W[6], T, k + 2, length)                       # head
    for s in range(2):
        j = k + 3 + 3 * s
        _capsule_between(W[7 + 2 * s], arms[s, 0], T, j, length)      # upper arm
        _capsule_between(arms[s, 0], arms[s, 1], T, j + 1, length)     # forearm
        _sphere(arms[s, 1], T, j + 2, length)                          # hand


@numba.njit(cache=True, nogil=True)
def _sphere(c, T, k, length):
    """``T[k]`` = ``pose(t=c)``, ``length[k]`` = 0."""
    T[k] = 0.0
    for i in range(4):
        T[k, i, i] = 1.0
    for i in range(3):
        T[k, i, 3] = c[i]
    length[k] = 0.0
