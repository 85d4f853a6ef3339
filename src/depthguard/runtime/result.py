"""What one control cycle of the monitor returns: :class:`Reaction` (R13, R14, R26, R27, R29).

Every array is a fresh copy: a reaction may be kept, queued to a sink or
sent to another thread. "No obstacle within rho" and "cannot judge" are
different values everywhere (SPEC §7): ``distance`` is ``inf`` for the first,
``observed`` is False for the second (and then the distance says nothing).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Reaction", "CameraStatus"]

#: the SSM table's columns (:data:`depthguard.control.ssm.TERMS`, repeated to keep this module light)
_SSM_TERMS = ("D", "v_h", "v_r", "T_r", "T_s", "S_h", "S_r", "S_s", "C", "Z_d", "Z_r", "S_p", "limit")


@dataclass(frozen=True)
class CameraStatus:
    """One camera as the monitor saw it in a cycle.

    ``age_s``: seconds since the capture of its newest frame in use (``inf``
    before the first); ``state``: ``"fresh"``, ``"stale"`` (older than its
    limit, R27), ``"waiting"`` (no frame yet), ``"untrusted"`` (the drift watch found it
    moved against the static scene, R34: a stop reason until recalibrated or accepted,
    :meth:`depthguard.runtime.Monitor.accept_camera`); ``frames``: frames used so
    far; ``refused``: frames refused so far (bad image, stamp outside the
    joint history, R30); ``stamp``: capture stamp of the frame in use.
    """
    age_s: float
    state: str
    frames: int = 0
    refused: int = 0
    stamp: float = -math.inf

    @classmethod
    def made(cls, age_s: float, state: str, frames: int, refused: int, stamp: float) -> "CameraStatus":
        """``CameraStatus(age_s, state, frames, refused, stamp)`` without the frozen dataclass's
        ``__init__`` (:meth:`Reaction.made`)."""
        c = object.__new__(cls)
        c.__dict__.update(age_s=age_s, state=state, frames=frames, refused=refused, stamp=stamp)
        return c


@dataclass(frozen=True)
class Reaction:
    """The monitor's answer for one control cycle at time ``t`` (s, the monitor's clock).

    override : speed override ``k`` in [0, 1] for the robot's commanded motion
        (0 = stop); ramps with the configured stop and resume times.
    repulsion : (3,) m/s, world, repulsive velocity of the end effector (R13),
        to be added to the commanded end-effector velocity.
    qd_min, qd_max : (dof,) rad/s joint-velocity limits from the other control
        points (R14) and the joint position limits, already times ``override``.
    names : the control points, then the watch points.
    distance : (m,) m, ``inf`` = nothing within ``rho``; meaningful only where observed.
    direction : (m, 3) world unit vectors towards the nearest obstacle (0 where none).
    observed : (m,) bool, False = no camera can judge the point (R26).
    is_watch : (m,) bool, True for the watch points.
    reasons : ``key -> sentence``, the conditions that hold now and stop the robot
        (stale camera or joints, unobserved or enclosed control point).
    cameras : camera id -> :class:`CameraStatus`.
    joints_age_s : seconds since the newest joint state (``inf`` before the first).
    q : (dof,) the joints the distances were computed at.
    frame_stamps : camera id -> capture stamp of the frame this cycle used.
    step_s : wall seconds the cycle took inside ``step``.
    reaction_mode : the monitor's mode (:attr:`MonitorConfig.reaction_mode
        <depthguard.config.MonitorConfig.reaction_mode>`), ``"repulsion"``, ``"ssm"`` or
        ``"both"`` (R33), or the reaction policies' names joined by ``+``.
    speed_scale : in [0, 1], the factor for the commanded motion (what ros2_control's speed
        scaling or a UR speed slider takes): ``override`` times the SSM scale (``override``
        alone in repulsion mode).
    protective_stop : True while speed and separation monitoring holds a protective stop.
    ssm_scale : in [0, 1], the SSM's scale alone (1 in repulsion mode).
    ssm : (m_cp, 13) float64 or None, one row per control point (not the watch points), the
        columns :data:`depthguard.control.ssm.TERMS` (``D v_h v_r T_r T_s S_h S_r S_s C Z_d Z_r
        S_p limit``) at the SSM scale commanded: ``S_p = S_h + S_r + S_s + C + Z_d + Z_r``.
    parts : policy name -> its :class:`~depthguard.control.policy.Part` this cycle (the
        reaction policies that ran, :mod:`depthguard.control.policy`); ``ssm``, ``ssm_scale``,
        ``repulsion`` and the box above are composed from them. A part's ``record`` is logged
        under ``policies.<name>``, its ``terms`` per point under ``points[i].<name>`` (the
        built-in repulsion and ssm parts have their own fields above).
    """
    t: float
    override: float
    repulsion: np.ndarray
    qd_min: np.ndarray
    qd_max: np.ndarray
    names: tuple[str, ...]
    distance: np.ndarray
    direction: np.ndarray
    observed: np.ndarray
    is_watch: np.ndarray
    reasons: dict[str, str]
    cameras: dict[str, CameraStatus]
    joints_age_s: float
    q: np.ndarray
    frame_stamps: dict[str, float] = field(default_factory=dict)
    step_s: float = 0.0
    reaction_mode: str = "repulsion"
    speed_scale: float = 1.0
    protective_stop: bool = False
    ssm: np.ndarray | None = None
    ssm_scale: float = 1.0
    parts: dict = field(default_factory=dict)

    @classmethod
    def made(cls, fields: dict) -> "Reaction":
        """The reaction of ``fields`` (every field by name, none left to its default), the same
        object as ``Reaction(**fields)`` without the frozen dataclass's ``__init__`` (one
        ``object.__setattr__`` per field: a few microseconds of the 500 Hz control cycle,
        issue 29); ``tests/test_monitor.py`` compares the two."""
        r = object.__new__(cls)
        r.__dict__.update(fields)
        return r

    @property
    def stopped(self) -> bool:
        return self.override <= 0.0

    def nearest(self) -> tuple[str | None, float]:
        """``(name, distance)`` of the nearest observed control point with an obstacle within
        rho, ``(None, inf)`` when there is none."""
        try:                                # a loop over the few points (issue 29: the runner asks every cycle)
            dist, obs, watch = self.distance.tolist(), self.observed.tolist(), self.is_watch.tolist()
        except AttributeError:
            return self._nearest_numpy()
        best, at = math.inf, -1
        for i, x in enumerate(dist):
            if obs[i] and not watch[i]:
                if x != x or x == -math.inf:
                    return self._nearest_numpy()
                if x < best:
                    best, at = x, i
        return (None, math.inf) if at < 0 else (self.names[at], float(best))

    def _nearest_numpy(self) -> tuple[str | None, float]:
        """:meth:`nearest` with numpy (its twin, and the answer wherever a distance is NaN or -inf)."""
        d = np.where(np.asarray(self.observed) & ~np.asarray(self.is_watch), self.distance, np.inf)
        if not np.any(np.isfinite(d)):
            return None, math.inf
        i = int(np.argmin(d))
        return self.names[i], float(d[i])

    def to_dict(self) -> dict:
        """The JSON-lines record of this cycle (schema in ``docs/MONITOR.md``): ``distance`` is
        ``null`` when nothing is within rho, and ``observed`` says whether it could be judged."""
        pts = []
        for i, n in enumerate(self.names):
            d = float(self.distance[i])
            if math.isnan(d):
                raise ValueError(f"reaction at t={self.t}: distance of {n} is NaN (a bug: never written as 'none')")
            pts.append({"name": n, "watch": bool(self.is_watch[i]),
                        "distance": round(d, 6) if math.isfinite(d) else None,
                        "direction": [round(float(x), 6) for x in self.direction[i]] if math.isfinite(d) else None,
                        "observed": bool(self.observed[i])})
            if self.ssm is not None and i < len(self.ssm):
                pts[-1]["ssm"] = {k: round(float(v), 6) for k, v in zip(_SSM_TERMS, self.ssm[i])}
            for name, part in self.parts.items():
                if name != "ssm" and part.terms is not None and i < len(part.terms):
                    pts[-1][name] = {k: round(float(v), 6) for k, v in zip(part.term_names, part.terms[i])}
        rec = {"t": round(float(self.t), 6), "override": round(float(self.override), 6),
                "repulsion": [round(float(x), 6) for x in self.repulsion],
                "points": pts, "reasons": dict(self.reasons),
                "cameras": {c: {"age_s": (round(s.age_s, 6) if math.isfinite(s.age_s) else None),
                                "state": s.state, "frames": s.frames, "refused": s.refused}
                            for c, s in self.cameras.items()},
                "joints_age_s": round(self.joints_age_s, 6) if math.isfinite(self.joints_age_s) else None,
                "q": [round(float(x), 6) for x in self.q],
                "reaction_mode": self.reaction_mode, "speed_scale": round(float(self.speed_scale), 6),
                "protective_stop": bool(self.protective_stop), "ssm_scale": round(float(self.ssm_scale), 6)}
        own = {n: dict(p.record, scale=round(float(p.scale), 6), stop=bool(p.stop))
               for n, p in self.parts.items() if p.record}
        if own:
            rec["policies"] = own
        return rec
