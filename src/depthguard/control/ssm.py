"""Speed and separation monitoring, the equations in plain numpy (R33; ISO/TS 15066 formula 1).

Per control point ``i`` with the fused distance ``D_i`` (m) and unit direction
``V_i`` (3,) towards the obstacle, the robot's joint velocity ``q̇`` (n,) rad/s
and the point's Jacobian ``J_i`` (3, n):

    v_r  = V_iᵀ J_i q̇                     speed towards the obstacle (m/s; < 0 = moving away)
    T_r  = camera latency + frame age + control period + controller latency  (s)
    S_s, T_s = stopping model at v = max(v_r, 0)  (max deceleration or a table)
    S_h  = v_h (T_r + T_s)                 the person's approach meanwhile
    S_r  = max(v_r, 0) T_r                 the robot's approach during the reaction
    C    = ISO 13855 intrusion distance of the detection capability
    Z_d  = ½ √(2 w² + Δd²) + k σ(z) + ½ q(z)    the sensing's uncertainty at the obstacle's depth z:
           pixel footprint w = z / f, the grid's depth slice Δd, k times the
           sensor model's depth noise σ(z) = σ_a + σ_z2 z², the disparity step q(z)
    Z_r  = the robot's position uncertainty
    S_p  = S_h + S_r + S_s + C + Z_d + Z_r

Nothing within the range (``D = inf``): the obstacle may be anywhere at the
range, so ``D`` counts as the range and ``v_r`` as the point's whole speed
``|J_i q̇|`` (its direction is unknown).

The speed override scales the commanded motion by ``s`` in [0, 1]; ``v_r``
and the stopping terms scale with it, so ``S_p(s)`` rises with ``s`` and the
largest ``s`` with ``D ≥ S_p(s)`` has a closed form: the root of a quadratic
for the deceleration model, of a linear piece for a table. ``v_h`` is 2.0 m/s
where ``D < 0.5`` m, 1.6 m/s beyond (ISO 13855: with S > 500 mm, K = 1.6 m/s
and S ≥ 500 mm, which ``D ≥ 0.5`` m meets). A robot moving away (``v_r ≤ 0``)
is not slowed: only ``S_h``, ``C``, ``Z_d``, ``Z_r`` remain, and either they
fit (``s = 1``) or nothing does (protective stop).

:mod:`depthguard.control.ssm_kernel` is the numba twin used per control cycle;
the tests compare both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from depthguard.control.ssm_config import SSMConfig

__all__ = ["SSMCameras", "stopping", "z_d", "protective_distance", "largest_scale",
           "ssm_numpy", "derived_detection_capability", "TERMS"]

#: columns of the per-point term table (the kernel's ``out`` and ``Reaction.ssm``)
TERMS = ("D", "v_h", "v_r", "T_r", "T_s", "S_h", "S_r", "S_s", "C", "Z_d", "Z_r", "S_p", "limit")


@dataclass(frozen=True)
class SSMCameras:
    """What ``Z_d`` needs of each monitored camera: ``R`` (nc, 3, 3) and ``t`` (nc, 3) camera
    from world, ``f`` (nc,) px focal length (the smaller of fx, fy), the depth noise
    ``sigma_a`` (nc,) m and ``sigma_z2`` (nc,) 1/m, and ``q`` (nc,) 1/m: the disparity step
    is ``q z²`` m (structured light; 0 otherwise)."""
    R: np.ndarray
    t: np.ndarray
    f: np.ndarray
    sigma_a: np.ndarray
    sigma_z2: np.ndarray
    q: np.ndarray

    @classmethod
    def of(cls, cameras, cfg: SSMConfig, pixel_bin: int = 1) -> "SSMCameras":
        """From :class:`~depthguard.camera.Camera` objects: the noise of their ``sensor`` model
        (:mod:`depthguard.sensors`), ``cfg.default_sigma_*`` for a camera without one.
        ``pixel_bin``: the grid's cell is that many pixels wide (``principal_bin``), so ``f`` is
        the focal length over it (the disparity step stays the sensor's)."""
        from depthguard.sensors import SENSOR_MODELS

        R, t, f, sa, sz, q = [], [], [], [], [], []
        for cam in cameras:
            T = np.linalg.inv(np.asarray(cam.world_from_camera, dtype=np.float64))
            R.append(T[:3, :3])
            t.append(T[:3, 3])
            f.append(min(cam.fx, cam.fy) / max(int(pixel_bin), 1))
            model = SENSOR_MODELS.get(cam.sensor) if cam.sensor else None
            if model is None:
                sa.append(cfg.default_sigma_a)
                sz.append(cfg.default_sigma_z2)
                q.append(0.0)
            else:
                sa.append(model.sigma_a)
                sz.append(model.sigma_z2)
                quant = model.kind == "structured_light" and model.disparity_bits > 0 and model.baseline > 0
                q.append(1.0 / (min(cam.fx, cam.fy) * model.baseline * 2 ** model.disparity_bits) if quant else 0.0)
        arr = [np.ascontiguousarray(a, dtype=np.float64) for a in (R, t, f, sa, sz, q)]
        return cls(*arr)


def derived_detection_capability(cameras, gap_px: int) -> float:
    """Detection capability d (m) when none is set: an object must cover more than the
    ``gap_px`` pixels the filling closes, i.e. ``gap_px + 1`` pixels at the farthest camera's
    rated range (Kinect v1: 4 px of 4 m / 585 px = 27 mm)."""
    return max((gap_px + 1) * cam.max_range / min(cam.fx, cam.fy) for cam in cameras)


def stopping(v: float, cfg: SSMConfig) -> tuple[float, float]:
    """``(S_s m, T_s s)`` of a point moving at ``v ≥ 0`` m/s towards the obstacle."""
    v = max(float(v), 0.0)
    if cfg.stop_model == "deceleration":
        return v * cfg.brake_delay_s + v * v / (2.0 * cfg.deceleration), cfg.brake_delay_s + v / cfg.deceleration
    tab = cfg.stop_table
    sp, ds, ts = (np.asarray(a, dtype=np.float64) for a in (tab.speed, tab.distance, tab.time))
    if v <= sp[-1]:
        return float(np.interp(v, sp, ds)), float(np.interp(v, sp, ts))
    u = (v - sp[-2]) / (sp[-1] - sp[-2])           # the last segment, extended
    return float(ds[-2] + u * (ds[-1] - ds[-2])), float(ts[-2] + u * (ts[-1] - ts[-2]))


def z_d(z: float, f: float, sigma_a: float, sigma_z2: float, q: float, delta_d: float, n_sigma: float) -> float:
    """``Z_d`` (m) of one camera at depth ``z`` (m): ½ cell diagonal (pixel footprint ``z/f``
    twice, depth slice ``delta_d``) + ``n_sigma`` σ(z) + ½ disparity step ``q z²``."""
    z = max(float(z), 0.0)
    w = z / f
    return 0.5 * math.sqrt(2.0 * w * w + delta_d * delta_d) + n_sigma * (sigma_a + sigma_z2 * z * z) + 0.5 * q * z * z


def protective_distance(D: float, v_h: float, v_r: float, T_r: float, C: float, Z_d: float, Z_r: float,
                        cfg: SSMConfig) -> dict:
    """Every term of formula (1) for a point moving at ``v_r`` m/s towards the obstacle
    (negative: away) — a dict with the keys of :data:`TERMS` but ``limit``."""
    v = max(v_r, 0.0)
    S_s, T_s = stopping(v, cfg)
    S_h = v_h * (T_r + T_s)
    S_r = v * T_r
    return dict(D=D, v_h=v_h, v_r=v_r, T_r=T_r, T_s=T_s, S_h=S_h, S_r=S_r, S_s=S_s, C=C, Z_d=Z_d, Z_r=Z_r,
                S_p=S_h + S_r + S_s + C + Z_d + Z_r)


def largest_scale(D: float, v_r0: float, v_h: float, T_r: float, C: float, Z_d: float, Z_r: float,
                  cfg: SSMConfig) -> float:
    """The largest ``s`` in [0, 1] with ``D ≥ S_p`` at ``v_r = s v_r0`` (closed form); 0 when
    even a standing robot is too close (protective stop)."""
    K = C + Z_d + Z_r

    def g(v):
        S_s, T_s = stopping(v, cfg)
        return v_h * (T_r + T_s) + v * T_r + S_s + K

    if g(0.0) > D:
        return 0.0
    if v_r0 <= 0.0 or g(v_r0) <= D:
        return 1.0
    if cfg.stop_model == "deceleration":
        a, tb = cfg.deceleration, cfg.brake_delay_s
        A = 1.0 / (2.0 * a)                              # in v: A v² + B v + (g(0) − D) = 0
        B = T_r + tb + v_h / a
        x = D - g(0.0)
        return float(2.0 * x / (B + math.sqrt(B * B + 4.0 * A * x)) / v_r0)
    sp = list(cfg.stop_table.speed)
    knots = [v for v in sp if v < v_r0] + [v_r0]     # g is linear between these speeds
    for va, vb in zip(knots, knots[1:]):
        ga, gb = g(va), g(vb)
        if gb > D:
            return float((va + (D - ga) / (gb - ga) * (vb - va)) / v_r0)
    return 1.0


def ssm_numpy(D, V, P, J, qd, cams: SSMCameras, cfg: SSMConfig, T_r: float, C: float, delta_d: float,
              v_h_measured=None) -> np.ndarray:
    """The per-point table (m, len(TERMS)) at ``s = 1`` with ``limit`` = each point's largest
    scale (:func:`largest_scale`); the reference the numba kernel is tested against.

    ``D`` (m,) m (inf = nothing within ``cfg.range``), ``V`` (m, 3), ``P`` (m, 3) the points,
    ``J`` (m, 3, n), ``qd`` (n,) the commanded joint velocity; ``v_h_measured`` (m,) m/s or None.
    """
    m = len(D)
    out = np.zeros((m, len(TERMS)))
    for i in range(m):
        xdot = J[i] @ qd
        if math.isfinite(D[i]) and D[i] < cfg.range:
            d, v_r0 = float(D[i]), float(V[i] @ xdot)
            O = P[i] + d * V[i]
            z = cams.R @ O + cams.t                     # (nc, 3)
            depth = z[:, 2]
        else:                                            # anywhere at the range, in any direction
            d, v_r0 = cfg.range, float(np.linalg.norm(xdot))
            depth = (cams.R @ P[i] + cams.t)[:, 2] + cfg.range
        zd = max(z_d(depth[c], cams.f[c], cams.sigma_a[c], cams.sigma_z2[c], cams.q[c], delta_d, cfg.noise_sigmas)
                 for c in range(len(cams.f)))
        if v_h_measured is not None:
            v_h = max(cfg.v_h_floor, float(v_h_measured[i]))
        else:
            v_h = cfg.v_h_near if d < cfg.near_limit else cfg.v_h
        s = largest_scale(d, v_r0, v_h, T_r, C, zd, cfg.z_r, cfg)
        t = protective_distance(d, v_h, v_r0, T_r, C, zd, cfg.z_r, cfg)
        t["limit"] = s
        out[i] = [t[k] for k in TERMS]
    return out
