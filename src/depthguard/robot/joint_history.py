"""A short history of timestamped joint states, for capture-time self removal (R30).

Used wherever a frame meets the joints it was captured at: the monitor's camera
workers (:mod:`depthguard.runtime.ingest`), the camera units
(:mod:`depthguard.distributed.node`), the simulator as a source and the bag index of
the replay view; it sits with the robot, below all of them.

A camera frame shows the robot where it was when the frame was exposed, not
where it is when the frame reaches the computer. :class:`JointHistory` keeps
the last ``span_s`` seconds of joint states and answers ``at(stamp)``: the
joints linearly interpolated at ``stamp``, or the reason why it cannot —
before the oldest state kept ("too old") or after the newest ("in the
future"). Nothing is ever extrapolated: a frame outside the history is
refused by the monitor and counted, never used with the wrong joints.
:meth:`JointHistory.wait_at` waits a bounded time for states that lag the frame, woken by
the ``push`` of each new state (a condition, not a poll: issue 29).

The reasons (``OutsideHistory.kind``) are the names under which the monitor and the
camera units count refused frames: ``"too_old"``, ``"future"``, ``"joint_gap"``,
``"no_joints"``.

Thread-safe: ``push`` from the joint thread, ``at`` / ``latest`` from any
other. Storage is a preallocated ring (no allocation per state).
"""

from __future__ import annotations

import math
import threading
import time
from typing import Callable

import numba
import numpy as np

__all__ = ["JointHistory", "OutsideHistory", "state_check", "state_check_numpy"]


@numba.njit(cache=True)      # microseconds: keeps the GIL
def state_check(q, lo, hi) -> int:
    """-1 when every joint of ``q`` (dof,) is finite and within ``[lo, hi]`` (dof,) rad, -2 when one is
    not finite, else the index of the first joint outside (R27: refused states). No allocation;
    ``push`` asks it for every state (issue 29: 500 a second)."""
    for j in range(q.shape[0]):
        if not math.isfinite(q[j]):
            return -2
    for j in range(q.shape[0]):
        if q[j] < lo[j] or q[j] > hi[j]:
            return j
    return -1


def state_check_numpy(q, lo, hi) -> int:
    """Plain twin of :func:`state_check`."""
    if not np.all(np.isfinite(q)):
        return -2
    out = (q < lo) | (q > hi)
    return int(np.argmax(out)) if out.any() else -1


class OutsideHistory(LookupError):
    """A stamp outside the joint history; ``kind`` (the refusal's name) is ``"too_old"``, ``"future"``,
    ``"joint_gap"`` or ``"no_joints"``."""

    def __init__(self, kind: str, message: str):
        super().__init__(message)
        self.kind = kind


class JointHistory:
    """Ring of ``(stamp, q)`` with stamps strictly increasing (R30).

    dof : joints per state. span_s : seconds kept behind the newest state.
    max_gap_s : two states further apart than this are not interpolated between
        (the joint stream was interrupted: where the robot was then is not known).
    capacity : states kept at most (default: enough for 2 kHz over ``span_s``).
    q_min, q_max : optional (dof,) limits; a state outside them is refused.
    """

    def __init__(self, dof: int, span_s: float = 1.0, capacity: int | None = None,
                 q_min=None, q_max=None, max_gap_s: float = math.inf):
        if int(dof) < 1:
            raise ValueError(f"dof must be >= 1 (got {dof!r})")
        if not (math.isfinite(span_s) and span_s > 0):
            raise ValueError(f"span_s must be > 0 s (got {span_s!r})")
        self.dof = int(dof)
        self.span_s = float(span_s)
        self.max_gap_s = float(max_gap_s)     # no interpolation across a longer gap between states
        cap = int(capacity) if capacity is not None else int(math.ceil(span_s * 2000)) + 16
        self._t = np.full(cap, -np.inf)
        self._q = np.zeros((cap, self.dof))
        self._n = 0            # states stored (<= cap)
        self._head = 0         # index of the next write
        self._lock = threading.Lock()
        self._pushed = threading.Condition(self._lock)   # wait_at's waiters, notified by push and wake
        self._pushes = 0         # states accepted so far (a waiter's check for one it missed)
        self._waiters = 0        # threads in wait_at's wait
        self._wake_at = math.inf  # the earliest stamp a waiter waits for: a push at or after it wakes them
        self.q_min = None if q_min is None else np.asarray(q_min, dtype=np.float64)
        self.q_max = None if q_max is None else np.asarray(q_max, dtype=np.float64)
        # the limits as push compares them (1e-6 rad of slack), or unbounded
        self._lo = np.full(self.dof, -np.inf) if q_min is None else np.ascontiguousarray(self.q_min - 1e-6)
        self._hi = np.full(self.dof, np.inf) if q_max is None else np.ascontiguousarray(self.q_max + 1e-6)
        self.refused = 0
        self.last_refusal: str | None = None

    # ------------------------------------------------------------ writing
    def push(self, stamp: float, q) -> bool:
        """Add a state; returns False (and counts it) when it is refused: a stamp not after the
        newest, non-finite values, a wrong length, or joints outside the limits."""
        qa = q if (type(q) is np.ndarray and q.dtype == np.float64 and q.ndim == 1 and q.flags.c_contiguous) else \
            np.asarray(q, dtype=np.float64).reshape(-1)
        reason = None
        if qa.shape[0] != self.dof:
            reason = f"joint state has {qa.shape[0]} values, the robot has {self.dof} joints"
        elif not math.isfinite(stamp):
            reason = "joint state with a non-finite stamp or value"
        else:
            j = state_check(qa, self._lo, self._hi)
            if j == -2:
                reason = "joint state with a non-finite stamp or value"
            elif j >= 0:
                reason = (f"joint {j} = {qa[j]:.4f} rad is outside its limits "
                          f"[{self.q_min[j]:.4f}, {self.q_max[j]:.4f}]")
        with self._lock:
            if reason is None and self._n and stamp <= self._t[(self._head - 1) % len(self._t)]:
                reason = (f"joint state stamped {stamp:.6f} s is not after the newest "
                          f"({self._t[(self._head - 1) % len(self._t)]:.6f} s)")
            if reason is not None:
                self.refused += 1
                self.last_refusal = reason
                return False
            self._t[self._head] = stamp
            self._q[self._head] = qa
            self._head = (self._head + 1) % len(self._t)
            self._n = min(self._n + 1, len(self._t))
            self._pushes += 1
            if stamp >= self._wake_at:
                self._wake_at = math.inf        # each waiter woken says again what it waits for
                self._pushed.notify_all()
        return True

    def wake(self) -> None:
        """Wake every thread in :meth:`wait_at` now, to ask its ``stop()`` again (a newer frame
        came, or its worker closes)."""
        with self._lock:
            if self._waiters:
                self._wake_at = math.inf
                self._pushed.notify_all()

    def clear(self) -> None:
        with self._lock:
            self._n = 0
            self._head = 0
            self._t.fill(-np.inf)

    # ------------------------------------------------------------ reading
    def _newest(self) -> float:
        return self._t[(self._head - 1) % len(self._t)] if self._n else -math.inf

    def _window(self) -> tuple[float, float]:
        cap = len(self._t)
        newest = self._t[(self._head - 1) % cap]
        oldest = self._t[(self._head - self._n) % cap]
        return max(oldest, newest - self.span_s), newest

    def latest(self) -> tuple[float, np.ndarray] | None:
        """``(stamp, q copy)`` of the newest state, or None before the first."""
        with self._lock:
            if not self._n:
                return None
            i = (self._head - 1) % len(self._t)
            return float(self._t[i]), self._q[i].copy()

    @property
    def newest_stamp(self) -> float:
        with self._lock:
            return float(self._t[(self._head - 1) % len(self._t)]) if self._n else -math.inf

    def at(self, stamp: float, out: np.ndarray | None = None) -> np.ndarray:
        """(dof,) joints linearly interpolated at ``stamp`` (R30); raises :class:`OutsideHistory`
        when ``stamp`` lies before the oldest kept state (older than ``span_s`` behind the
        newest) or after the newest."""
        with self._lock:
            if not self._n:
                raise OutsideHistory("no_joints", "no joint state received yet")
            lo, hi = self._window()
            if stamp > hi:
                raise OutsideHistory("future", f"stamp {stamp:.6f} s is after the newest joint state "
                                                f"({hi:.6f} s)")
            if stamp < lo:
                raise OutsideHistory("too_old", f"stamp {stamp:.6f} s is before the oldest joint state kept "
                                                 f"({lo:.6f} s)")
            cap = len(self._t)
            # binary search over the ring in logical order (0 = oldest)
            a, b = 0, self._n - 1
            base = (self._head - self._n) % cap
            while b - a > 1:
                mid = (a + b) // 2
                if self._t[(base + mid) % cap] <= stamp:
                    a = mid
                else:
                    b = mid
            ia, ib = (base + a) % cap, (base + b) % cap
            ta, tb = self._t[ia], self._t[ib]
            if ta < stamp < tb and tb - ta > self.max_gap_s:
                raise OutsideHistory("joint_gap", f"stamp {stamp:.6f} s falls in a gap of {tb - ta:.3f} s between joint "
                                            f"states (more than {self.max_gap_s:.3f} s)")
            res = out if out is not None else np.empty(self.dof)
            if self._n == 1 or tb <= ta or stamp <= ta:
                res[:] = self._q[ia]
            elif stamp >= tb:
                res[:] = self._q[ib]
            else:
                w = (stamp - ta) / (tb - ta)
                np.multiply(self._q[ia], 1.0 - w, out=res)
                res += w * self._q[ib]
            return res

    def wait_at(self, stamp: float, timeout: float, stop: Callable[[], bool] | None = None, *,
                feed: Callable[[], None] | None = None, poll_s: float = 0.0005,
                stop_poll_s: float = 0.005, arrived: Callable[[float], object] | None = None) -> np.ndarray:
        """(dof,) joints at capture ``stamp`` (R30), waiting up to ``timeout`` s for states that
        lag the frame: while the stamp is after the newest state (``"future"``) or no state came
        yet (``"no_joints"``), look again when :meth:`push` adds a state at or after ``stamp``
        (issue 29: a condition, where a poll every 0.5 ms looked ten times per frame 5 ms ahead
        of its joints). Never extrapolates.

        ``stop()`` (optional) is asked before each wait; True ends the wait (the caller has a
        newer frame, or is closing): it is asked again at each state pushed, at :meth:`wake`, and
        at least every ``stop_poll_s`` s. ``feed()`` (optional) is called before each look-up,
        for a caller that pulls its joint stream on the same thread: no other thread pushes
        then, so it looks again when ``arrived(seconds)`` returns (the stream's wait for its next
        state, at most ``seconds``: e.g. ``ZenohJointSource.wait_for_states``), or without it
        every ``poll_s`` s. Raises :class:`OutsideHistory` (its ``kind``
        the refusal's name) when the stamp is too old, in a gap, or still outside the history
        when the wait ends.
        """
        deadline = time.perf_counter() + float(timeout)
        while True:
            if feed is not None:
                feed()
            seen = self._pushes
            try:
                return self.at(stamp)
            except OutsideHistory as exc:
                lagging = exc.kind in ("future", "no_joints")
                wanted = stamp if exc.kind == "future" else -math.inf
                left = deadline - time.perf_counter()
                if not lagging or left <= 0.0 or (stop is not None and stop()):
                    raise
            if feed is not None:
                if arrived is not None:
                    arrived(left if stop is None else min(left, stop_poll_s))
                else:
                    time.sleep(poll_s)
                continue
            with self._pushed:
                if self._pushes == seen or self._newest() < wanted:   # nothing that answers came yet
                    self._wake_at = min(self._wake_at, wanted)
                    self._waiters += 1
                    try:
                        self._pushed.wait(left if stop is None else min(left, stop_poll_s))
                    finally:
                        self._waiters -= 1
