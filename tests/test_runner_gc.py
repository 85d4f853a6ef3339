"""A real-time run leaves the objects made before it out of the cyclic garbage collector (issue 29):
a full collection during the run walked all ~155k of them (modules, numba's dispatchers, the rig,
the monitor) for ~100 ms of CPU holding the GIL, and every thread — the control thread too —
waited. Truth: the collector's own accounting (``gc.get_freeze_count``, ``gc.get_objects``)."""

from __future__ import annotations

import gc
import threading

import numpy as np

from depthguard.runtime.monitor import Monitor, warm_up
from depthguard.runtime.realtime import frozen_heap
from depthguard.runtime.runner import run
from depthguard.sim import load_cell


def _tracked(obj) -> bool:
    """``obj`` (a container the collector tracks: ``gc.is_tracked``) is among the objects the collector walks (not frozen)."""
    return any(o is obj for o in gc.get_objects())


def test_objects_made_before_are_frozen_inside_and_back_after():
    made_before = [[i] for i in range(5000)]       # lists: always tracked
    marker = made_before[1234]
    frozen0 = gc.get_freeze_count()
    with frozen_heap():
        assert gc.get_freeze_count() >= frozen0 + len(made_before)
        assert not _tracked(marker)
        made_inside = ["inside"]
        assert _tracked(made_inside)                   # what the run makes is collected as usual
        gc.collect()
        assert marker == [1234]                         # frozen objects stay alive and intact
    assert gc.get_freeze_count() == frozen0
    assert _tracked(marker)


def test_overlapping_runs_unfreeze_when_the_last_one_ends():
    marker = ["m"]
    first_in, first_out = threading.Event(), threading.Event()

    def first():
        with frozen_heap():
            first_in.set()
            first_out.wait(5.0)

    th = threading.Thread(target=first)
    th.start()
    assert first_in.wait(5.0)
    with frozen_heap():
        assert not _tracked(marker)
        first_out.set()
        th.join(5.0)
        assert not th.is_alive()
        assert not _tracked(marker)                   # the first run ended, this one still runs
    assert _tracked(marker)


class _Joints:
    """A joint stream on the run's clock: the robot still at ``q`` every 2 ms."""

    done = False

    def __init__(self, q):
        self.q = np.asarray(q, dtype=np.float64)
        self.next = 0.0

    def states_until(self, t):
        out = []
        while self.next <= t:
            out.append((self.next, self.q))
            self.next += 0.002
        return out


def test_a_real_time_run_is_frozen_while_it_runs():
    rig = load_cell("flacco-cell").rig
    cfg = rig.monitor.with_changes(invalid="free")
    warm_up(rig, cfg)
    marker = ["made before the run"]
    seen = []

    def sink(r):
        if not seen:
            seen.append((gc.get_freeze_count(), _tracked(marker)))

    frozen0 = gc.get_freeze_count()
    with Monitor(rig, cfg, sinks=[sink]) as mon:
        stats, _ = run(mon, [], _Joints(rig.robot_q0), duration=0.1)
    assert stats.cycles > 0 and seen
    frozen_during, marker_walked = seen[0]
    assert frozen_during > frozen0 + 10_000 and not marker_walked
    assert gc.get_freeze_count() == frozen0 and _tracked(marker)


def test_a_program_that_drives_the_monitor_itself_is_frozen_in_real_time():
    """``Monitor.real_time()`` (a program's own control loop, the monitor bench) freezes the heap as
    :func:`run` does; nested in a run, only the outermost freezes and unfreezes."""
    rig = load_cell("flacco-cell").rig
    cfg = rig.monitor.with_changes(invalid="free")
    marker = ["made before the loop"]
    frozen0 = gc.get_freeze_count()
    with Monitor(rig, cfg) as mon:
        with mon.real_time():
            assert gc.get_freeze_count() > frozen0 + 10_000 and not _tracked(marker)
            inner = gc.get_freeze_count()
            with frozen_heap():                      # a run around it would nest the same way
                assert gc.get_freeze_count() == inner
            assert gc.get_freeze_count() == inner and not _tracked(marker)
        assert gc.get_freeze_count() == frozen0 and _tracked(marker)
        with frozen_heap():
            outer = gc.get_freeze_count()
            with mon.real_time():
                assert gc.get_freeze_count() == outer
            assert gc.get_freeze_count() == outer        # the run's freeze holds until its end
        assert gc.get_freeze_count() == frozen0
