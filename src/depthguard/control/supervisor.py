"""The speed override and the conditions that stop the robot (R26, R27).

:class:`SafetySupervisor` ramps the override ``k`` to 0 while any stop
reason holds and back to 1 once none does, and keeps each episode (first and
last time, message). :func:`stop_reasons` lists the reasons of one cycle.
Used by the runtime (:class:`depthguard.runtime.Monitor`) and the simulated
closed loop.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["SafetySupervisor", "stop_reasons", "stale_reason", "point_reasons", "points_hold_robot",
           "points_hold_robot_numpy"]


class SafetySupervisor:
    """Speed override ``k``: ramps to 0 while a stop reason holds, back to 1 after (R26, R27).

    ``update(t, reasons)`` with ``reasons`` a dict ``key -> message`` of the
    conditions that hold now; returns ``k``. ``episodes`` lists each
    condition's first/last time and message.

    ``k0`` is the override before the first cycle: 0 by default — before any cycle has
    found nothing to stop for, nothing is known (R26, R27), so the robot starts stopped and
    ramps up over ``resume_time`` once no reason holds, never down from full speed while
    blind. ``k0=1`` only where the start is known to be safe (a unit test of the ramps).
    """

    def __init__(self, dt: float, stop_time: float, resume_time: float, k0: float = 0.0):
        if not 0.0 <= k0 <= 1.0:
            raise ValueError(f"k0 must be in [0, 1], got {k0}")
        self.dt = dt
        self.stop_time, self.resume_time = stop_time, resume_time
        self.down = dt / stop_time
        self.up = dt / resume_time
        self.k = float(k0)
        self.episodes: list[dict] = []
        self._open: dict[str, dict] = {}

    def update(self, t: float, reasons: dict[str, str], dt: float | None = None) -> float:
        """The override after this cycle; ``dt`` (s) since the previous cycle when it is not the
        fixed ``dt`` given at construction (a monitor stepped at an irregular rate)."""
        if dt is not None:
            self.down = max(0.0, dt) / self.stop_time
            self.up = max(0.0, dt) / self.resume_time
        if not reasons and not self._open:       # the usual cycle: nothing holds, nothing to close
            self.k = min(1.0, self.k + self.up)
            return self.k
        for key, msg in reasons.items():
            ep = self._open.get(key)
            if ep is None:
                ep = {"reason": msg, "key": key, "t_start": round(t, 4), "t_end": None, "t_stopped": None}
                self._open[key] = ep
                self.episodes.append(ep)
        for key in [k for k in self._open if k not in reasons]:
            self._open.pop(key)["t_end"] = round(t, 4)
        if reasons:
            self.k = max(0.0, self.k - self.down)
            if self.k == 0.0:
                for ep in self._open.values():
                    if ep["t_stopped"] is None:
                        ep["t_stopped"] = round(t, 4)
        else:
            self.k = min(1.0, self.k + self.up)
        return self.k


_stale_said: dict = {}              # (camera, age limit, before its first frame) -> (key, message)


def stale_reason(cid: str, age_limit: float, first: bool) -> tuple[str, str]:
    """``(key, message)`` of camera ``cid``'s stale-data stop (R27): its newest frame older than
    ``age_limit`` s, or ``first`` — no frame yet. Made once per camera and limit (issue 29: every
    stale cycle asks)."""
    said = _stale_said.get((cid, age_limit, first))
    if said is None:
        if len(_stale_said) > 1024:
            _stale_said.clear()
        said = _stale_said[(cid, age_limit, first)] = (
            "stale:" + cid, f"camera {cid}: no frame yet - stale data (R27)" if first else
            f"camera {cid}: no frame for more than {age_limit * 1e3:.0f} ms - stale data (R27)")
    return said


def stop_reasons(ages, age_limit: float, camera_ids, observed, D, V, names) -> dict[str, str]:
    """The conditions that make the supervisor stop the robot, ``key -> message`` (R26, R27).

    ``ages`` (n_cam,) s since each camera's last frame (``inf`` before the
    first); ``observed`` (m,) bool; ``D`` (m,) m; ``V`` (m, 3). Rules:
    a frame older than ``age_limit`` (stale data, R27; before a camera's first frame the
    message says ``no frame yet``); a control point that
    no camera can judge (``observed = False``, R26: the worst case, not free);
    a control point inside an obstacle frustum (finite ``D`` that is 0 or has
    no direction: no way to flee, and R14 gives no limit without ``V``).
    ``D = inf`` (nothing within ρ) is never a reason.
    """
    reasons = {}
    for i, cid in enumerate(camera_ids):
        if ages[i] > age_limit + 1e-9:
            # the same stop before a camera's first frame, said as it is: nothing to judge yet
            key, msg = stale_reason(cid, age_limit, ages[i] == math.inf)
            reasons[key] = msg
    if (isinstance(observed, np.ndarray) and observed.dtype == np.bool_ and isinstance(D, np.ndarray)
            and D.dtype == np.float64 and isinstance(V, np.ndarray) and V.dtype == np.float64 and V.ndim == 2
            and not points_hold_robot(observed, D, V)):
        return reasons                  # the usual cycle: every point observed, none enclosed (R26)
    point_reasons(reasons, observed, D, V, names)
    return reasons


def point_reasons(reasons: dict[str, str], observed, D, V, names) -> None:
    """Add to ``reasons`` the control points' stops of :func:`stop_reasons` (R26): ``unobserved:<name>``
    for each point ``observed`` (m,) False, then ``inside:<name>`` for each finite ``D`` (m,) m that
    is <= 0 or whose direction ``V`` (m, 3) is 0. The monitor's cycle calls it only when
    :func:`points_hold_robot` says one holds."""
    for j in np.nonzero(~np.asarray(observed, dtype=bool))[0]:
        reasons[f"unobserved:{names[j]}"] = f"control point {names[j]} is not observed by any camera (R26)"
    D = np.asarray(D, dtype=np.float64)
    inside = np.isfinite(D) & ((D <= 0.0) | (np.linalg.norm(V, axis=1) == 0.0))
    for j in np.nonzero(inside)[0]:
        reasons[f"inside:{names[j]}"] = (f"control point {names[j]} lies inside an obstacle frustum "
                                         f"(D = 0, no direction)")


@numba.njit(cache=True)      # microseconds: keeps the GIL (a release costs the control thread a hand-over)
def points_hold_robot(observed, D, V) -> bool:
    """True when a control point gives :func:`stop_reasons` a reason (R26): one not observed, or
    one inside an obstacle frustum (finite ``D`` that is <= 0 or whose direction ``V`` (m, 3) has
    norm 0, as numpy computes it). ``observed`` (m,) bool, ``D`` (m,) m float64. One pass, no allocation: the control
    cycle asks this first and builds the sentences only when it holds."""
    for j in range(D.shape[0]):
        if not observed[j]:
            return True
        d = D[j]
        if math.isfinite(d) and (d <= 0.0 or V[j, 0] * V[j, 0] + V[j, 1] * V[j, 1] + V[j, 2] * V[j, 2] == 0.0):
            return True
    return False


def points_hold_robot_numpy(observed, D, V) -> bool:
    """Plain twin of :func:`points_hold_robot`."""
    D = np.asarray(D, dtype=np.float64)
    inside = np.isfinite(D) & ((D <= 0.0) | (np.linalg.norm(V, axis=1) == 0.0))
    return bool((~np.asarray(observed, dtype=bool)).any() or inside.any())
