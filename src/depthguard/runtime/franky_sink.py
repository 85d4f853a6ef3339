"""The reaction to a Franka FR3 through franky: ``--sink franky:HOST,path=FILE`` (R27, R31).

libfranka has no global speed override. franky runs *motions* that a new motion replaces
while they run (``robot.move(motion, asynchronous=True)``), each with a *relative dynamics
factor* in (0, 1] that scales the robot's velocity, acceleration and jerk limits. This sink
is the program that moves the robot: it runs a joint path (``path``: waypoints, (n, 7) rad,
a CSV file of 7 numbers a line in the spec, or the name of a built-in cell that ships one:
``path=fr3-cell``) waypoint after waypoint, in a loop, each leg a
``franky.JointMotion`` to the next waypoint, and applies the reaction's ``speed_scale``
(the override, times the SSM scale in ``ssm``/``both`` modes) to it:

- ``speed_scale`` >= ``floor`` (0.05): the leg runs with that factor on the velocity limits;
  when the factor wanted differs from the running leg's by more than ``step`` (0.1), the leg
  is replaced by one to the same waypoint with the new factor (slow down, speed up). Only
  the velocity is scaled: acceleration and jerk keep the robot's full limits, so that a leg
  slowed down brakes to its new speed as fast as the robot can. franky's single factor scales
  all three, and a leg at 0.1 then braked from 2.1 to 0.27 rad/s in 1.38 s of franky-sim's
  time, against 0.43 s with the velocity alone (0.74 s to a full stop);
- ``speed_scale`` < ``floor``, a stop included: the leg is replaced by a
  ``franky.JointStopMotion`` (the robot decelerates on its path within its limits and holds);
- back above the floor: the leg to the same waypoint starts again (resume).

The sink is the program, so it tells the monitor what speed scale 1 means (:meth:`attach`,
R33): :meth:`commanded_qd` is the joint velocity of the running leg at its full speed, a
straight line in joint space towards its waypoint with the joint that has the farthest to go
at its velocity limit (``qd_max``, the rig's). Without it SSM would scale the joints'
measured rate — the motion already slowed by the reaction — and this sink would apply that
relative scale to the full speed: faster than SSM allowed, and rising again as soon as the
robot had slowed (measured 1.2-1.7 rad/s of joint 1 where SSM allowed 0.1-0.5 of it).

Stale data and lost connections stop the robot (R27): stale joints or cameras through the
reaction itself (override 0); no reaction for more than ``stale_s`` (0.1 s: the monitor hung
or ended) stops it here; an error of franky or libfranka (a reflex, a lost connection) is
said (``lost``, the log) and the sink tries ``recover_from_errors`` every second, the robot
standing meanwhile. :meth:`close` stops the robot and waits for it to stand (5 s at most).

``events``: what happened (``(time.monotonic() s, sentence)``); ``legs``: the motions
started, ``(time.monotonic() s, "leg"|"stop", waypoint index, factor)``.
"""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path

import numpy as np

from depthguard.progress import log
from depthguard.transport.franky_link import FRANKA_DOF, FrankyError, link_for, parse_host

__all__ = ["FrankySink", "open_franky_sink", "read_path"]


def read_path(path, what: str = "franky path") -> np.ndarray:
    """(n, 7) float64 rad from a CSV file (7 numbers a line; ``#`` comments) or an array; at least 2 waypoints."""
    if isinstance(path, (str, Path)):
        p = Path(path)
        try:
            lines = [x.split("#", 1)[0].strip() for x in p.read_text(encoding="utf-8").splitlines()]
        except OSError as exc:
            raise FrankyError(f"{what} {p}: cannot be read ({exc.strerror or exc})") from None
        rows = []
        for i, line in enumerate(lines, 1):
            if not line:
                continue
            try:
                rows.append([float(v) for v in line.replace(";", ",").split(",") if v.strip()])
            except ValueError:
                raise FrankyError(f"{what} {p}, line {i}: {line!r} is not {FRANKA_DOF} numbers") from None
            if len(rows[-1]) != FRANKA_DOF:
                raise FrankyError(f"{what} {p}, line {i}: {len(rows[-1])} values, a Franka has {FRANKA_DOF} joints")
        arr = np.asarray(rows, dtype=np.float64).reshape(-1, FRANKA_DOF)
    else:
        arr = np.asarray(path, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[1] != FRANKA_DOF:
            raise FrankyError(f"{what}: waypoints must be (n, {FRANKA_DOF}) rad (got shape {arr.shape})")
    if len(arr) < 2 or not np.isfinite(arr).all():
        raise FrankyError(f"{what}: needs at least 2 finite waypoints (got {len(arr)})")
    return arr


class FrankySink:
    """Runs ``path`` on the FR3 at ``host`` and applies the reactions to it (module docstring).

    ``q_min``/``q_max``: (7,) rad, the rig's limits; a waypoint outside them is refused at
    construction. ``qd_max``: (7,) rad/s, the joints' velocity limits (default: the FR3's data
    sheet), for :meth:`commanded_qd`. ``tolerance``: rad, a waypoint counts as reached when every
    joint is within it.
    """

    name = "franky"
    direct = True                  # keeps the newest reaction (runtime.sink_specs)
    live = True                    # drives a robot: never a run as fast as possible

    #: rad/s, the FR3's joint velocity limits (Franka's data sheet), where no rig gives them
    FR3_QD_MAX = (2.62, 2.62, 2.62, 2.62, 5.26, 4.18, 5.26)

    def __init__(self, host: str, path, *, q_min=None, q_max=None, qd_max=None, floor: float = 0.05, step: float = 0.1,
                 stale_s: float = 0.1, rate_hz: float = 100.0, tolerance: float = 2e-3, retry_s: float = 1.0):
        if not 0.0 < floor < 1.0 or not 0.0 < step < 1.0 or not stale_s > 0 or not rate_hz > 0:
            raise FrankyError("franky sink: floor and step must be in (0, 1), stale_s and rate_hz > 0")
        self.path = read_path(path)
        if q_min is not None and q_max is not None:
            lo, hi = np.asarray(q_min, float), np.asarray(q_max, float)
            bad = np.argwhere((self.path < lo - 1e-9) | (self.path > hi + 1e-9))
            if bad.size:
                i, j = (int(x) for x in bad[0])
                raise FrankyError(f"franky sink: waypoint {i + 1}, joint {j + 1} = {self.path[i, j]:.6g} is outside the "
                                  f"rig's limits [{lo[j]:.6g}, {hi[j]:.6g}]")
        self.qd_max = np.array(self.FR3_QD_MAX if qd_max is None else qd_max, dtype=np.float64).reshape(-1)
        if self.qd_max.shape != (FRANKA_DOF,) or not np.all(np.isfinite(self.qd_max) & (self.qd_max > 0)):
            raise FrankyError(f"franky sink: qd_max must be {FRANKA_DOF} velocity limits > 0 rad/s (got {qd_max!r})")
        self._qd = np.zeros(FRANKA_DOF)                  # commanded_qd's answer, the control thread's
        self._reach = np.zeros(FRANKA_DOF)               # its scratch: nothing allocated per cycle
        self.host, self.floor, self.step, self.stale_s = host, float(floor), float(step), float(stale_s)
        self.period, self.tolerance, self.retry_s = 1.0 / float(rate_hz), float(tolerance), float(retry_s)
        self.link = link_for(host)
        self.events: list[tuple[float, str]] = []
        self.legs: list[tuple[float, str, int, float]] = []
        self.lost: str | None = None
        self.index = 0                                   # the waypoint the robot goes to
        self._factor: float | None = None                # the running leg's factor, None: standing
        self._leg_at = -math.inf
        self._newest: tuple[float, float] | None = None  # (speed_scale, monotonic time)
        self._stale_said = False
        self._cond = threading.Condition()
        self._closing = False
        self._thread = threading.Thread(target=self._run, name="franky-sink", daemon=True)
        self._thread.start()

    def __call__(self, reaction) -> None:
        with self._cond:
            self._newest = (float(reaction.speed_scale), time.monotonic())

    def attach(self, monitor) -> None:
        """The monitor's SSM takes this program's speed at scale 1 (:meth:`commanded_qd`, R33)."""
        monitor.commanded_qd = self.commanded_qd

    def commanded_qd(self, q) -> np.ndarray:
        """(7,) rad/s: the joint velocity at speed scale 1 at ``q`` (7,) rad — towards the waypoint
        the robot goes to (the next one where it stands at it), along the straight line in joint
        space, the joint with the farthest to go relative to its limit at ``qd_max``. A franky leg
        keeps every joint within these limits and, started from rest, on that line; one that
        replaced a moving leg bends towards it. The same array each call, overwritten by the next."""
        qd, tmp = self._qd, self._reach
        np.subtract(self.path[self.index], q, out=qd)
        if np.abs(qd, out=tmp).max() <= self.tolerance:
            np.subtract(self.path[(self.index + 1) % len(self.path)], q, out=qd)
        np.abs(qd, out=tmp)
        reach = np.divide(tmp, self.qd_max, out=tmp).max()   # seconds of the slowest joint at its limit
        if reach > 0.0:
            qd /= reach
        return qd

    def _event(self, sentence: str) -> None:
        self.events.append((time.monotonic(), sentence))
        log(sentence)

    def _want(self, now: float) -> float:
        """The factor wanted now: 0 (stand) or in [floor, 1]."""
        if self._newest is None:
            return 0.0
        scale, at = self._newest
        if now - at > self.stale_s:
            if not self._stale_said:
                self._stale_said = True
                self._event(f"franky {self.host}: no reaction from the monitor for more than "
                            f"{self.stale_s * 1e3:.0f} ms: the robot stops (R27)")
            return 0.0
        self._stale_said = False
        if not math.isfinite(scale) or scale < self.floor:
            return 0.0
        return min(scale, 1.0)

    def _move(self, motion) -> None:
        with self.link.lock:
            self.link.robot.move(motion, asynchronous=True)

    def _leg(self, factor: float) -> None:
        fr = self.link.franky
        dynamics = fr.RelativeDynamicsFactor(float(factor), 1.0, 1.0)       # velocity; acceleration, jerk in full
        self._move(fr.JointMotion(self.path[self.index].tolist(), relative_dynamics_factor=dynamics))
        self._factor, self._leg_at = factor, time.monotonic()
        self.legs.append((self._leg_at, "leg", self.index, factor))

    def _stop(self) -> None:
        self._move(self.link.franky.JointStopMotion())
        self._factor = None
        self.legs.append((time.monotonic(), "stop", self.index, 0.0))

    def _tick(self, now: float) -> None:
        want = self._want(now)
        running = self._factor is not None
        if want == 0.0:
            if running:
                self._stop()
            return
        if running:
            st = self.link.robot.state
            q = np.asarray(st.q, dtype=np.float64).reshape(-1)
            dq = np.asarray(st.dq, dtype=np.float64).reshape(-1)
            if np.max(np.abs(q - self.path[self.index])) <= self.tolerance and np.max(np.abs(dq)) < 1e-2:
                self.index = (self.index + 1) % len(self.path)       # at the waypoint: the next leg
                self._leg(want)
                return
            self.link.robot.poll_motion()          # raises what went wrong in the motion (a reflex, the network)
        if not running or abs(want - self._factor) > self.step:
            self._leg(want)

    def _run(self) -> None:
        next_retry = 0.0
        while True:
            with self._cond:
                self._cond.wait(self.period)
                if self._closing:
                    return
            now = time.monotonic()
            if self.lost is not None:
                if now >= next_retry:
                    next_retry = now + self.retry_s
                    self._recover()
                continue
            try:
                self._tick(now)
            except Exception as exc:  # noqa: BLE001 - franky raises control, reflex and network errors
                self._factor = None
                self.lost = (f"franky {self.host}: the motion failed ({type(exc).__name__}: {exc}); the robot stands "
                             "until it recovers (R27)")
                self._event(self.lost)

    def _recover(self) -> None:
        try:
            with self.link.lock:
                ok = self.link.robot.recover_from_errors()
        except Exception:  # noqa: BLE001 - still unreachable
            return
        if ok:
            self.lost = None
            self._event(f"franky {self.host}: recovered; the path goes on when the monitor allows it")

    def close(self) -> None:
        """Stop the robot (it stands when this returns, 5 s at most), end the thread, release the link."""
        with self._cond:
            if self._closing:
                return
            self._closing = True
            self._cond.notify_all()
        self._thread.join(2.0)
        try:
            if self._factor is not None:
                self._stop()
            self.link.robot.join_motion(5.0)
        except Exception as exc:  # noqa: BLE001 - closing anyway
            self._event(f"franky {self.host}: stopping at close failed ({type(exc).__name__}: {exc})")
        self.link.release()


def open_franky_sink(argument: str, rig=None, context: dict | None = None) -> FrankySink:
    """The sink of ``franky:HOST,path=FILE`` (the rig's robot limits checked when a rig is given)."""
    host_part, _, rest = (argument or "").partition(",")
    opts = dict(x.split("=", 1) for x in rest.split(",") if "=" in x)
    unknown = [x for x in rest.split(",") if x and (x.partition("=")[0] != "path")]
    if unknown:
        raise FrankyError(f"--sink franky:{argument}: unknown option {unknown[0]!r} (franky:HOST,path=FILE)")
    if "path" not in opts:
        raise FrankyError(f"--sink franky:{argument}: give the path the robot runs: franky:HOST,path=FILE "
                          f"(a CSV of {FRANKA_DOF} joint values in rad a line)")
    host = parse_host(host_part, "--sink franky")
    path = opts["path"]
    if not Path(path).exists():
        from depthguard.sim.cells import cell_path_file

        try:
            path = cell_path_file(path)                  # path=fr3-cell: the cell's shipped path
        except (FileNotFoundError, ValueError):
            pass                                         # read_path says the file cannot be read
    robot = getattr(rig, "robot", None)
    if robot is not None and robot.dof != FRANKA_DOF:
        raise FrankyError(f"--sink franky:{host}: a Franka has {FRANKA_DOF} joints, the rig's robot {robot.name} has "
                          f"{robot.dof}: use the rig of this robot")
    return FrankySink(host, path, q_min=None if robot is None else robot.q_min,
                      q_max=None if robot is None else robot.q_max,
                      qd_max=None if robot is None else robot.qd_max)
