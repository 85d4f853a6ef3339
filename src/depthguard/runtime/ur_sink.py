"""The reaction to a Universal Robots arm: its speed slider through RTDE (``--sink ur-rtde:HOST``) (R27, R31).

:class:`UrSpeedSlider` is a sink (``sink(reaction)``, ``close()``) that sets the robot's speed
slider (RTDE input ``speed_slider_fraction``, the teach pendant's speed slider: it scales every
motion of the running program) from the reaction's ``speed_scale`` — the override, times the
SSM scale in ``ssm``/``both`` modes, equal to the override in repulsion mode
(``docs/MONITOR.md``) — through ``rtde_io.RTDEIOInterface.setSpeedSlider`` of the ``ur-rtde``
package (run in a child process, :mod:`depthguard.transport.ur_rtde_worker`).

Rate: the monitor reacts at 500 Hz; the sink keeps only the newest reaction and a thread of its
own sends a value when it differs from the last one sent (by more than 0.001), at most
``rate_hz`` (125) times a second, and again every ``keepalive_s`` (0.5 s). A call never blocks
the monitor.

A stop, and the slider of exactly 0: the UR ROS 2 driver (``ur_controllers`` GPIO controller)
accepts slider values in [0.01, 1] only, since a slider of 0 followed by another value was
reported to protective-stop the robot (Universal_Robots_Client_Library issue 58; ROS 2 driver
issue 90); the ROS 1 driver accepts 0 again since 2025 (its PR 738) to pause a motion without
pausing the program. A floor of 0.01 alone would leave the robot moving at 1 % of its speed
while the monitor says stop, so this sink does:

- ``speed_scale`` < ``floor`` (0.01), a stop included: the slider is set to exactly 0 — the
  program's motion halts on its path, the program keeps running; a value below the floor is
  rounded down to 0, never up;
- ``speed_scale`` >= ``floor``: the slider is set to it (at most 1);
- resuming from 0: the first value sent is the floor, held ``resume_hold_s`` (0.1 s), then the
  slider follows the reaction (whose override ramps up with ``resume_time``) — the robot never
  jumps from 0 to a large fraction.

Stale data and lost connections stop the robot (R27): stale joint states or cameras stop it
through the reaction itself (``reasons``, override 0). When no reaction reaches the sink for
more than ``stale_s`` (0.1 s: the monitor hung or ended), the sink sets 0 and says so. When the
RTDE connection is lost, nothing can be sent: the sink says so (``lost``, the log), tries to
reconnect every ``retry_s`` (1 s), and once connected sends 0 first, then resumes as above. At
:meth:`close` it sets the slider to 0: the robot does not go on at speed unwatched; restore the
slider on the teach pendant (or by restarting the monitor) to go on.
"""

from __future__ import annotations

import math
import threading
import time

from depthguard.progress import log
from depthguard.transport.ur_rtde_worker import UrError, Worker, check_reachable, missing_package, parse_address

__all__ = ["UrSpeedSlider", "open_ur_sink"]


class UrSpeedSlider:
    """Sets a UR robot's speed slider from the reactions (module docstring).

    ``host``: the robot's address (RTDE port 30004). ``sent``: values sent and acknowledged;
    ``lost``: a sentence while the connection is lost, else ``None``; ``events``: what happened
    (stops, resumes, losses), each ``(time.monotonic() s, sentence)``.
    """

    name = "ur-rtde"
    direct = True                  # keeps the newest reaction; its own thread sends (sink_specs)
    live = True                    # drives a robot: never a run as fast as possible

    def __init__(self, host: str, *, floor: float = 0.01, rate_hz: float = 125.0, keepalive_s: float = 0.5,
                 stale_s: float = 0.1, resume_hold_s: float = 0.1, retry_s: float = 1.0,
                 connect_timeout_s: float = 2.0):
        if not 0.0 < floor < 1.0:
            raise UrError(f"ur-rtde: the slider floor must be in (0, 1) (got {floor})")
        if not rate_hz > 0 or not stale_s > 0 or not keepalive_s > 0:
            raise UrError("ur-rtde: rate_hz, stale_s and keepalive_s must be > 0")
        missing = missing_package()
        if missing:
            raise UrError(missing)
        self.host = host
        self.floor, self.period, self.keepalive_s = float(floor), 1.0 / float(rate_hz), float(keepalive_s)
        self.stale_s, self.resume_hold_s, self.retry_s = float(stale_s), float(resume_hold_s), float(retry_s)
        self.connect_timeout_s = float(connect_timeout_s)
        self.sent = 0
        self.lost: str | None = None
        self.events: list[tuple[float, str]] = []
        self._cond = threading.Condition()
        self._newest: tuple[float, float] | None = None       # (speed_scale, monotonic time it came)
        self._closing = False
        self._last_sent: float | None = None                  # None: unknown (a new connection)
        self._last_sent_at = -math.inf
        self._floor_since: float | None = None
        self._stale_said = False
        check_reachable(host, f"ur-rtde sink {host}", connect_timeout_s)
        self._worker = self._connect()
        self._thread = threading.Thread(target=self._run, name="ur-rtde-slider", daemon=True)
        self._thread.start()

    # --- connection ---------------------------------------------------------------------------
    def _connect(self) -> Worker:
        return Worker("io", self.host, on_line=self._on_line, on_end=self._on_end,
                      timeout_s=max(15.0, self.connect_timeout_s))

    def _on_line(self, line: str) -> None:
        if line.startswith("ok"):
            self.sent += 1

    def _on_end(self, reason: str) -> None:
        with self._cond:
            if self._closing:
                return
            self.lost = (f"ur-rtde {self.host}: connection lost ({reason}): the speed slider cannot be set; "
                         f"the robot keeps its last slider value until the connection is back (R27)")
            self._cond.notify_all()
        self._event(self.lost)

    def _event(self, sentence: str) -> None:
        self.events.append((time.monotonic(), sentence))
        log(sentence)

    def _reconnect(self) -> bool:
        try:
            check_reachable(self.host, f"ur-rtde sink {self.host}", min(0.5, self.connect_timeout_s))
            worker = self._connect()
        except UrError:
            return False
        old, self._worker = self._worker, worker
        old.close()
        with self._cond:
            self.lost = None
        self._last_sent, self._floor_since = None, None
        self._event(f"ur-rtde {self.host}: connected again; the slider is set to 0 first, then follows the monitor")
        return True

    # --- the sink -------------------------------------------------------------------------------
    def __call__(self, reaction) -> None:
        with self._cond:                     # the sender wakes every 1 / rate_hz s by itself
            self._newest = (float(reaction.speed_scale), time.monotonic())

    def target(self, scale: float) -> float:
        """The slider for a speed scale: 0 below the floor (rounded down, never up), else min(scale, 1)."""
        if not math.isfinite(scale) or scale < self.floor:
            return 0.0
        return min(float(scale), 1.0)

    def _next_value(self, now: float) -> float | None:
        """What to send now (``None``: nothing yet)."""
        if self._newest is None:
            return None
        scale, at = self._newest
        if now - at > self.stale_s:
            self._floor_since = None
            if not self._stale_said:
                self._stale_said = True
                self._event(f"ur-rtde {self.host}: no reaction from the monitor for more than "
                            f"{self.stale_s * 1e3:.0f} ms: speed slider 0 (R27)")
            return 0.0
        self._stale_said = False
        want = self.target(scale)
        if want > 0.0 and (self._last_sent is None or self._last_sent == 0.0 or self._floor_since is not None):
            if self._floor_since is None:
                if self._last_sent is None:
                    return 0.0                       # a new connection: 0 first
                self._floor_since = now              # resuming from 0: the floor first
                return self.floor
            if now - self._floor_since < self.resume_hold_s:
                return self.floor
            self._floor_since = None
        elif want == 0.0:
            self._floor_since = None
        return want

    def _run(self) -> None:
        next_retry = 0.0
        while True:
            with self._cond:
                if self._closing:
                    return
                self._cond.wait(self.period)
                if self._closing:
                    return
                lost = self.lost is not None
            now = time.monotonic()
            if lost:
                if now >= next_retry:
                    next_retry = now + self.retry_s
                    self._reconnect()
                continue
            if now - self._last_sent_at < self.period:
                continue
            value = self._next_value(now)
            if value is None:
                continue
            changed = self._last_sent is None or abs(value - self._last_sent) > 1e-3 or \
                (value == 0.0) != (self._last_sent == 0.0)
            if changed or now - self._last_sent_at >= self.keepalive_s:
                self._send(value, now)

    def _send(self, value: float, now: float) -> None:
        if self._worker.send(repr(float(value))):
            if value == 0.0 and self._last_sent not in (None, 0.0):
                self.events.append((now, f"ur-rtde {self.host}: speed slider 0 (stop)"))
            elif value > 0.0 and self._last_sent == 0.0:
                self.events.append((now, f"ur-rtde {self.host}: resuming at the slider floor {self.floor:g}"))
            self._last_sent, self._last_sent_at = value, now

    def close(self) -> None:
        """Set the slider to 0 (nobody watches any more), stop the thread, end the connection."""
        with self._cond:
            if self._closing:
                return
            self._closing = True
            self._cond.notify_all()
        self._thread.join(2.0)
        if self.lost is None and self._worker.send("0.0"):
            deadline = time.monotonic() + 1.0
            target = self.sent + 1
            while self.sent < target and time.monotonic() < deadline and self._worker.alive:
                time.sleep(0.005)
        self._worker.close()


def open_ur_sink(argument: str, rig=None, context: dict | None = None) -> UrSpeedSlider:
    """The sink of ``ur-rtde:HOST[:30004]`` (:mod:`depthguard.runtime.sink_specs`): live, direct."""
    return UrSpeedSlider(parse_address(argument, "--sink ur-rtde"))
