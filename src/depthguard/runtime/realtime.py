"""Real-time scheduling of the control thread (R29: the control path never waits).

A robot controller runs its control loop under a real-time policy (ros2_control's
``thread_priority``, 50 by default, SCHED_FIFO): the loop then preempts the
camera and fusion workers as soon as its sleep ends, instead of waiting for
the kernel's fair scheduler to give it a turn (2–10 ms late on a loaded
2-core machine). :func:`realtime_control` puts the *calling thread* (only that
thread: threads it starts afterwards get normal scheduling back) under
``SCHED_FIFO`` at ``priority`` for the length of a ``with`` block, and
restores the previous policy after it. Where the process may not (no root, no
``CAP_SYS_NICE`` / ``rtprio`` limit, not Linux) it runs on normally and says why
in :attr:`RealtimeControl.status` — the reaction is the same, only its timing
is less regular; the run's summary records which.

Linux keeps 5 % of each second for normal threads (``sched_rt_runtime_us``),
so a control thread that never sleeps cannot lock the machine up.

The other way round, :func:`background_priority` gives a thread that is not the
monitor's own (the live view's web server) the workers' lower priority.

:func:`frozen_heap` leaves what exists before a real-time run out of Python's cyclic garbage
collector for the run's length, so that no full collection holds every thread for tens of
milliseconds in it (:func:`~depthguard.runtime.runner.run` and ``Monitor.real_time()`` enter it).
"""

from __future__ import annotations

import gc
import os
import threading
from contextlib import contextmanager

__all__ = ["RealtimeControl", "realtime_control", "normal_scheduling", "background_priority", "frozen_heap",
           "TIMING_KEEP"]

#: timing samples a long run keeps per list (the monitor's step and frame-to-reaction times, the
#: runner's frame ages at hand-over): past it the oldest half goes, so the percentiles are of the
#: newest; a day at 30 Hz or 500 Hz would otherwise hold millions of floats
TIMING_KEEP = 100_000


class RealtimeControl:
    """Context manager: the calling thread under SCHED_FIFO ``priority`` (1–99); 0 = leave it.

    ``status``: a sentence saying what was set, or why not (after ``__enter__``).
    ``active``: True while the real-time policy is in force.
    """

    def __init__(self, priority: int):
        p = int(priority)
        if not 0 <= p <= 99:
            raise ValueError(f"control_priority must be 0 (normal scheduling) to 99 (got {priority!r})")
        self.priority = p
        self.active = False
        self.status = "normal scheduling (control_priority 0)"
        self._tid: int | None = None
        self._old: tuple[int, int] | None = None

    def __enter__(self) -> "RealtimeControl":
        if self.priority == 0:
            return self
        if not hasattr(os, "sched_setscheduler"):
            self.status = "normal scheduling: this system has no SCHED_FIFO"
            return self
        tid = threading.get_native_id()
        try:
            old = (os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority)
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(self.priority))
        except OSError as exc:
            self.status = (f"normal scheduling: SCHED_FIFO {self.priority} not permitted ({exc.strerror}); "
                           f"run as root or give the user an rtprio limit (/etc/security/limits.conf)")
            return self
        self._tid, self._old, self.active = tid, old, True
        self.status = f"SCHED_FIFO {self.priority}"
        return self

    def __exit__(self, *exc) -> None:
        if self.active and self._tid is not None and self._old is not None:
            try:
                os.sched_setscheduler(self._tid, self._old[0], os.sched_param(self._old[1]))
            except OSError:
                pass
            self.active = False


def realtime_control(priority: int) -> RealtimeControl:
    """``with realtime_control(50) as rt: ...`` (see :class:`RealtimeControl`)."""
    return RealtimeControl(priority)


def normal_scheduling() -> None:
    """Put the calling thread back under normal scheduling (a thread started by a
    real-time thread inherits its policy; workers call this first)."""
    if not hasattr(os, "sched_setscheduler"):
        return
    tid = threading.get_native_id()
    try:
        if os.sched_getscheduler(tid) != os.SCHED_OTHER:
            os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
    except OSError:
        pass


def background_priority(native_id: int | None) -> bool:
    """Give the thread ``native_id`` (``threading.Thread.native_id``) the lower scheduling priority
    of the monitor's workers (Linux, :data:`depthguard.runtime.ingest.WORKER_NICENESS`), so that
    the control thread runs first when the cores are short (R29). For threads the caller does
    not run code in (a library's event loop); a worker of its own calls
    :func:`depthguard.runtime.ingest.background_thread`. True when set; False where that is not
    possible (no native id, not Linux, not permitted)."""
    from depthguard.runtime.ingest import WORKER_NICENESS

    if not native_id:
        return False
    try:
        os.setpriority(os.PRIO_PROCESS, int(native_id), WORKER_NICENESS)
    except (AttributeError, OSError):
        return False
    return True


_frozen_lock = threading.Lock()
_frozen_runs = 0


@contextmanager
def frozen_heap():
    """The objects made before a real-time run (modules, numba's dispatchers, the rig, the monitor's
    state: ~155k on flacco-cell) left out of the cyclic garbage collector for the run's length
    (``gc.collect()`` then ``gc.freeze()``; ``gc.unfreeze()`` when the last such run ends), R29.

    Issue 29: without it, a full (generation 2) collection during the run walked all of them —
    40-115 ms of CPU holding the GIL, on whichever thread allocated (often the joints pump at
    the workers' low priority), collecting under 200 objects — and every thread, the control
    thread too, waited: the joints went stale (``stale:joints``, > 50 ms). Frozen, a full
    collection walks only what the run itself keeps. Garbage made of frozen objects is still
    freed by reference counting; only frozen reference cycles wait for the unfreeze."""
    global _frozen_runs
    with _frozen_lock:
        if _frozen_runs == 0:
            gc.collect()
            gc.freeze()
        _frozen_runs += 1
    try:
        yield
    finally:
        with _frozen_lock:
            _frozen_runs -= 1
            if _frozen_runs == 0:
                gc.unfreeze()
