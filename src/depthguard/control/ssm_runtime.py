"""The speed override of speed and separation monitoring, one call per control cycle (R33).

:class:`SpeedSeparation` holds the preallocated buffers and the protective
stop's state; :meth:`SpeedSeparation.update` runs the numba kernels
(:mod:`depthguard.control.ssm_kernel`) and returns the scale ``s`` in [0, 1] for
the commanded motion and the stop flag. Protective stop: entered at once when
the largest scale that keeps ``D ≥ S_p`` at every observed control point is
``≤ stop_scale``; released after it stayed ``≥ resume_scale`` for
``resume_hold_s`` (hysteresis and debounce); the scale then rises at most by
``dt / ramp_up_s`` per cycle and falls at once. Points that no camera can
judge are the supervisor's (R26: it stops the robot), not this module's.
"""

from __future__ import annotations

import math

import numpy as np

from depthguard.control import ssm_kernel
from depthguard.control.ssm import TERMS, SSMCameras, derived_detection_capability
from depthguard.control.ssm_config import SSMConfig, intrusion_distance

__all__ = ["SpeedSeparation"]

_LIM = TERMS.index("limit")
_D = TERMS.index("D")
_VR = TERMS.index("v_r")


class SpeedSeparation:
    """Speed and separation monitoring of ``n_points`` control points (module docstring).

    cfg : :class:`~depthguard.control.ssm_config.SSMConfig`.
    cameras : the monitored :class:`~depthguard.camera.Camera` objects (``Z_d``).
    dof : joints; delta_d : m, the grid's depth slice; gap_px : the monitor's gap filling
    (for the derived detection capability); control_dt : s, one control period (part of T_r);
    pixel_bin : the depth grid's principal pixels per column side (``principal_bin``: its cell
    is that many pixels wide, part of ``Z_d``).
    """

    def __init__(self, cfg: SSMConfig, cameras, n_points: int, dof: int, delta_d: float, gap_px: int,
                 control_dt: float, pixel_bin: int = 1):
        self.cfg = cfg
        self.cams = SSMCameras.of(cameras, cfg, pixel_bin)
        self.detection_capability = (float(cfg.detection_capability) if cfg.detection_capability is not None
                                     else derived_detection_capability(cameras, gap_px))
        self.C = intrusion_distance(self.detection_capability)
        self.delta_d = float(delta_d)
        self.control_dt = float(control_dt)
        self.table = np.zeros((n_points, len(TERMS)))
        if cfg.stop_model == "table":
            tab = cfg.stop_table
            self._kind = 1
            self._tab = tuple(np.ascontiguousarray(a, dtype=np.float64) for a in (tab.speed, tab.distance, tab.time))
        else:
            self._kind = 0
            self._tab = (np.zeros(2), np.zeros(2), np.zeros(2))
        self._measured = cfg.v_h_mode == "measured"
        self._vh_est = np.zeros(n_points)
        self._d_prev = np.full(n_points, np.inf)
        self._rate = np.zeros(n_points)
        self._qd0 = np.zeros(dof)
        self.stopped = False
        self.scale = 1.0
        self.requested = 1.0
        self.T_r = 0.0
        self._ok_since: float | None = None
        self.stops = 0

    def reaction_time(self, frame_age: float) -> float:
        """T_r (s): camera latency + the age of the oldest frame in use + one control period +
        the controller's latency."""
        age = frame_age if math.isfinite(frame_age) and frame_age > 0.0 else 0.0
        return self.cfg.camera_latency_s + age + self.control_dt + self.cfg.controller_latency_s

    def update(self, t: float, dt: float, D, V, P, J, qd, observed, frame_age: float) -> tuple[float, bool]:
        """``(scale, stopped)`` of this cycle. ``D`` (m,) m, ``V`` (m, 3), ``P`` (m, 3), ``J``
        (m, 3, n) of the control points; ``qd`` (n,) rad/s the commanded joint velocity at scale 1
        (``None``: not moving); ``observed`` (m,) bool; ``frame_age`` s of the oldest frame in use.
        ``self.table`` holds every term per point at the returned scale."""
        cfg = self.cfg
        qd = self._qd0 if qd is None else qd
        T_r = self.T_r = self.reaction_time(frame_age)
        if self._measured:
            self._measure(D, dt)
        tab_v, tab_s, tab_t = self._tab
        s_req = ssm_kernel.limits(D, V, P, J, qd, observed, cfg.range, self.cams.R, self.cams.t, self.cams.f,
                                  self.cams.sigma_a, self.cams.sigma_z2, self.cams.q, self.delta_d,
                                  cfg.noise_sigmas, T_r, self.C, cfg.z_r, cfg.v_h, cfg.v_h_near, cfg.near_limit,
                                  self._measured, cfg.v_h_floor, self._vh_est, self._kind, cfg.deceleration,
                                  cfg.brake_delay_s, tab_v, tab_s, tab_t, self.table)
        self.requested = s_req
        if self.stopped:
            if s_req >= cfg.resume_scale:
                if self._ok_since is None:
                    self._ok_since = t
                if t - self._ok_since >= cfg.resume_hold_s - 1e-12:
                    self.stopped = False
            else:
                self._ok_since = None
            if self.stopped:
                self.scale = 0.0
            else:
                self.scale = min(s_req, dt / cfg.ramp_up_s)
        elif s_req <= cfg.stop_scale:
            self.stopped = True
            self.stops += 1
            self._ok_since = None
            self.scale = 0.0
        else:
            self.scale = min(s_req, self.scale + dt / cfg.ramp_up_s)
        if self._measured:
            self._rate[:] = self.table[:, _VR] * self.scale     # the robot's own approach, for the next cycle
        ssm_kernel.terms_at(self.scale, self._kind, cfg.deceleration, cfg.brake_delay_s, tab_v, tab_s, tab_t,
                            self.table)
        return self.scale, self.stopped

    def _measure(self, D, dt: float) -> None:
        """v_h measured: the rate at which each point's distance shrinks beyond the robot's own
        approach (previous cycle), smoothed over ~0.1 s; reset where nothing is within range."""
        if dt <= 0.0:
            return
        near = np.isfinite(D) & np.isfinite(self._d_prev)
        alpha = min(1.0, dt / 0.1)
        rate = np.where(near, (np.where(near, self._d_prev, 0.0) - np.where(near, D, 0.0)) / dt - self._rate, 0.0)
        self._vh_est += alpha * (rate - self._vh_est)
        self._vh_est[~np.isfinite(D)] = 0.0
        self._d_prev[:] = D

    def reason(self, names) -> dict[str, str]:
        """The stop reason of the nearest limiting point while stopped (``{}`` otherwise)."""
        if not self.stopped:
            return {}
        i = int(np.argmin(self.table[:, _LIM] + self.table[:, _D] * 1e-6))
        row = dict(zip(TERMS, self.table[i]))
        return {f"ssm:{names[i]}": (f"protective stop (R33): control point {names[i]} at {row['D']:.3f} m, "
                                    f"S_p of a standing robot {row['S_p']:.3f} m (S_h {row['S_h']:.3f} + "
                                    f"C {row['C']:.3f} + Z_d {row['Z_d']:.3f} + Z_r {row['Z_r']:.3f}); released "
                                    f"after the scale stays >= {self.cfg.resume_scale:g} for "
                                    f"{self.cfg.resume_hold_s:g} s")}
