"""Real-time scheduling of the control thread (runtime/realtime.py), checked with the kernel's own view."""

from __future__ import annotations

import os
import threading

import pytest

from depthguard.runtime.ingest import background_thread
from depthguard.runtime.realtime import realtime_control

pytestmark = pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="no POSIX scheduling API here")


def _policy(tid: int) -> tuple[int, int]:
    return os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority


def _may_fifo() -> bool:
    try:
        tid = threading.get_native_id()
        old = _policy(tid)
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(1))
        os.sched_setscheduler(tid, old[0], os.sched_param(old[1]))
        return True
    except OSError:
        return False


def test_priority_range_is_checked():
    with pytest.raises(ValueError, match="control_priority"):
        realtime_control(100)
    with pytest.raises(ValueError, match="control_priority"):
        realtime_control(-1)


def test_zero_leaves_the_thread_alone():
    tid = threading.get_native_id()
    before = _policy(tid)
    with realtime_control(0) as rt:
        assert not rt.active and _policy(tid) == before
        assert "normal" in rt.status


def test_fifo_for_the_calling_thread_only_and_restored():
    if not _may_fifo():
        pytest.skip("this process may not use SCHED_FIFO (not root, no rtprio limit)")
    tid = threading.get_native_id()
    before = _policy(tid)
    seen = {}

    def worker():
        seen["inherited"] = _policy(threading.get_native_id())
        background_thread()                      # what every monitor worker does first
        seen["worker"] = _policy(threading.get_native_id())

    with realtime_control(50) as rt:
        assert rt.active and rt.status == "SCHED_FIFO 50"
        assert _policy(tid) == (os.SCHED_FIFO, 50)
        th = threading.Thread(target=worker)
        th.start()
        th.join()
    assert _policy(tid) == before
    assert seen["inherited"] == (os.SCHED_FIFO, 50)      # Linux: a new thread inherits the policy...
    assert seen["worker"][0] == os.SCHED_OTHER           # ...and a worker gives it back


def test_not_permitted_says_why(monkeypatch):
    def refuse(*_a):
        raise PermissionError(1, "Operation not permitted")
    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with realtime_control(50) as rt:
        assert not rt.active
        assert "not permitted" in rt.status and "rtprio" in rt.status


def test_background_priority_gives_another_thread_the_workers_niceness():
    """The kernel's own view: after the call, the other thread's niceness is the workers'
    (the live view does this to its web server's thread); the caller's is unchanged."""
    from depthguard.runtime.ingest import WORKER_NICENESS
    from depthguard.runtime.realtime import background_priority

    if not hasattr(os, "setpriority"):
        pytest.skip("no per-thread priority here")
    mine = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    if mine > WORKER_NICENESS:
        pytest.skip(f"this process already runs at niceness {mine}: it may not lower it to {WORKER_NICENESS}")
    release = threading.Event()
    t = threading.Thread(target=release.wait, args=(30,))
    t.start()
    try:
        assert background_priority(t.native_id)
        assert os.getpriority(os.PRIO_PROCESS, t.native_id) == WORKER_NICENESS
        assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == mine
    finally:
        release.set()
        t.join()
    assert not background_priority(None)
