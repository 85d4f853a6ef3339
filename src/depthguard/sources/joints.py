"""Joint-state sources: ``csv:FILE`` (a recording) and ``zenoh:KEY`` (live) (R27, R31).

Both serve ``states_until(t) -> [(stamp s, q (dof,) float64 rad or m), ...]`` in
strictly increasing stamp order, checked against the rig robot's dof and
joint limits ``rig.robot.q_min / q_max``.

``csv:FILE``: header ``stamp,<name 1>,...,<name dof>`` (the joint names are free,
their count must be the robot's dof), one state a line; the whole file is
checked when it opens and every problem names the file and line.

``zenoh:KEY``: a subscriber on the key expression ``KEY``; each sample is UTF-8
JSON ``{"stamp": <float s>, "q": [<dof floats>]}`` (other fields are ignored).
A bad payload is never used: it is counted in ``rejected`` and described in
``last_error``; a state whose stamp is not after the previous one is dropped and
counted in ``out_of_order``. The session is a zenoh peer on loopback
(:func:`depthguard.transport.settings.zenoh_config`); the run's ``context``
may hold ``zenoh_session`` (a shared session), or ``zenoh_listen`` /
``zenoh_connect`` (lists of endpoints, default listen ``tcp/127.0.0.1:0``).
"""

from __future__ import annotations

import csv
import json
import math
import threading
from pathlib import Path
from typing import Sequence

import numpy as np

from depthguard.sources.base import register_joints
from depthguard.sources.stamped_queue import StampedQueue

__all__ = ["CsvJointSource", "ZenohJointSource", "JointSourceError", "check_joint_state"]

_MAX_PENDING = 8192   # states received but not yet taken (a monitor polls at 500 Hz)


class JointSourceError(ValueError):
    """A joint recording or joint state is not usable (the message says where and why)."""


def _robot(rig):
    if getattr(rig, "robot", None) is None:
        raise JointSourceError(f"rig {getattr(rig, 'name', '?')!r} has no robot: joint states cannot be checked")
    return rig.robot


def check_joint_state(robot, stamp, q) -> tuple[float, np.ndarray]:
    """``(stamp, q)`` as ``(float, (dof,) float64)``; :class:`JointSourceError` for a non-number,
    a non-finite value, a wrong length or a joint outside ``[q_min, q_max]``."""
    if not _is_number(stamp) or not math.isfinite(float(stamp)):
        raise JointSourceError(f"stamp {stamp!r} is not a finite number")
    if isinstance(q, np.ndarray):
        q = q.tolist()
    if not isinstance(q, (list, tuple)) or not all(_is_number(v) for v in q):
        raise JointSourceError(f"q must be a list of {robot.dof} numbers (got {q!r:.200})")
    arr = np.array([float(v) for v in q], dtype=np.float64)
    if arr.shape != (robot.dof,):
        raise JointSourceError(f"q has {arr.size} values, the robot {robot.name} has {robot.dof} joints")
    if not np.isfinite(arr).all():
        raise JointSourceError(f"q has non-finite values: {arr.tolist()}")
    bad = np.nonzero((arr < robot.q_min - 1e-9) | (arr > robot.q_max + 1e-9))[0]
    if bad.size:
        j = int(bad[0])
        raise JointSourceError(f"joint {j + 1} = {arr[j]:.6g} is outside its limits "
                               f"[{robot.q_min[j]:.6g}, {robot.q_max[j]:.6g}]")
    return float(stamp), arr


def _is_number(v) -> bool:
    """A real number that converts to a float (not a bool, a string, or an int beyond float range)."""
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        return False
    try:
        float(v)
    except OverflowError:
        return False
    return True


class _Served:
    """Shared ``states_until`` over a list of states in stamp order."""

    first_stamp: float | None

    def _init_served(self, states: list[tuple[float, np.ndarray]]) -> None:
        self._states = states
        self._next = 0
        self._closed = False

    def states_until(self, t: float) -> list[tuple[float, np.ndarray]]:
        """The states with stamp <= ``t`` (s) not given yet, in stamp order (copies)."""
        out = []
        while not self._closed and self._next < len(self._states) and self._states[self._next][0] <= t:
            s, q = self._states[self._next]
            out.append((s, q.copy()))
            self._next += 1
        return out


class CsvJointSource(_Served):
    """Joint states of a CSV recording (module docstring); ``first_stamp``, ``last_stamp`` = its first
    and last stamps (``None`` when it has no state); ``lost`` is always ``None`` (the file is checked
    at open)."""

    def __init__(self, path: str | Path, rig):
        robot = _robot(rig)
        self.path = Path(path)
        if not self.path.is_file():
            raise JointSourceError(f"joint recording {self.path} does not exist")
        states: list[tuple[float, np.ndarray]] = []
        with open(self.path, newline="", encoding="utf-8") as fh:
            rows = csv.reader(fh)
            header = [h.strip() for h in next(rows, [])]
            if not header or header[0] != "stamp" or len(header) != robot.dof + 1:
                raise JointSourceError(f"{self.path}:1: the header must be stamp and {robot.dof} joint names "
                                       f"for {robot.name} (got {header})")
            for row in rows:
                where = f"{self.path}:{rows.line_num}"
                if not row or all(not c.strip() for c in row):
                    continue
                if len(row) != robot.dof + 1:
                    raise JointSourceError(f"{where}: expected {robot.dof + 1} columns, got {len(row)}")
                try:
                    values = [float(c) for c in row]
                except ValueError:
                    raise JointSourceError(f"{where}: not a number in {row}") from None
                try:
                    stamp, q = check_joint_state(robot, values[0], values[1:])
                except JointSourceError as exc:
                    raise JointSourceError(f"{where}: {exc}") from None
                if states and stamp <= states[-1][0]:
                    raise JointSourceError(f"{where}: stamp {stamp!r} is not after the previous stamp "
                                           f"{states[-1][0]!r} (stamps must strictly increase)")
                states.append((stamp, q))
        self._init_served(states)
        self.first_stamp = states[0][0] if states else None
        self.last_stamp = states[-1][0] if states else None

    @property
    def done(self) -> bool:
        return self._closed or self._next >= len(self._states)

    @property
    def lost(self) -> str | None:
        return None

    def close(self) -> None:
        self._closed = True


class ZenohJointSource:
    """Live joint states from a zenoh key expression (module docstring).

    ``rejected`` / ``last_error``: bad payloads; ``out_of_order``: states dropped
    because their stamp was not after the previous accepted one; ``overflow``:
    the oldest untaken states dropped when more than 8192 were waiting.
    ``first_stamp`` is ``None`` (a live source has no recorded start); ``done``
    turns True only when closed.
    """

    live = True     # stamps on the wall clock (time.time()): the runner's clock is then too

    first_stamp = None

    def __init__(self, key: str, rig, session=None, listen: Sequence[str] = ("tcp/127.0.0.1:0",),
                 connect: Sequence[str] = ()):
        import zenoh

        from depthguard.transport.settings import zenoh_config

        self._robot = _robot(rig)
        try:
            self.key = str(zenoh.KeyExpr(key))
        except Exception as exc:  # noqa: BLE001 - zenoh raises its own error type
            raise JointSourceError(f"zenoh joint source: {key!r} is not a key expression ({exc})") from None
        self.rejected = 0
        self.out_of_order = 0
        self.overflow = 0
        self.last_error: str | None = None
        self._lock = threading.Lock()
        self._queue = StampedQueue(_MAX_PENDING)
        self._closed = False
        self._own = session is None
        self.session = session if session is not None else zenoh.open(zenoh_config(listen, connect))
        self._sub = self.session.declare_subscriber(self.key, self._on_sample)

    def _on_sample(self, sample) -> None:
        try:
            msg = json.loads(sample.payload.to_bytes().decode("utf-8"))
            if not isinstance(msg, dict) or "stamp" not in msg or "q" not in msg:
                raise JointSourceError('the payload must be a JSON object {"stamp": s, "q": [...]}')
            stamp, q = check_joint_state(self._robot, msg["stamp"], msg["q"])
        except (ValueError, UnicodeDecodeError) as exc:   # JSONDecodeError and JointSourceError are ValueErrors
            with self._lock:
                self.rejected += 1
                self.last_error = f"{sample.key_expr}: {exc}"
            return
        what = self._queue.offer(stamp, (stamp, q))
        if what is not None:
            with self._lock:
                if what == "out_of_order":
                    self.out_of_order += 1
                else:
                    self.overflow += 1

    def states_until(self, t: float) -> list[tuple[float, np.ndarray]]:
        """The received states with stamp <= ``t`` (s) not given yet, in stamp order."""
        return self._queue.until(t)

    def wait_for_states(self, timeout: float) -> bool:
        """Sleep until a received state is waiting to be taken, at most ``timeout`` s (issue 29:
        a camera unit waits for its frame's joints without polling); True when one is."""
        return self._queue.wait(timeout)

    @property
    def done(self) -> bool:
        return self._closed

    @property
    def lost(self) -> str | None:
        return None

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._sub.undeclare()
        except Exception:  # noqa: BLE001 - closing anyway
            pass
        if self._own:
            self.session.close()


@register_joints("csv")
def open_csv_joints(argument: str, rig, context: dict) -> CsvJointSource:
    """Factory of ``csv:FILE``."""
    if not argument:
        raise JointSourceError("the csv joint source needs a file: csv:FILE")
    return CsvJointSource(argument, rig)


@register_joints("zenoh")
def open_zenoh_joints(argument: str, rig, context: dict) -> ZenohJointSource:
    """Factory of ``zenoh:KEY`` (``context``: ``zenoh_session``, ``zenoh_listen``, ``zenoh_connect``)."""
    if not argument:
        raise JointSourceError("the zenoh joint source needs a key expression: zenoh:KEY")
    return ZenohJointSource(argument, rig, session=context.get("zenoh_session"),
                            listen=context.get("zenoh_listen", ("tcp/127.0.0.1:0",)),
                            connect=context.get("zenoh_connect", ()))
