"""The joint history (R30): interpolation at a stamp, never extrapolation; the bounded wait for
states that lag a frame, used by the monitor's camera workers and the camera units."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from depthguard.robot.joint_history import JointHistory, OutsideHistory


def test_interpolation_is_exact_for_a_linear_motion_and_survives_the_ring_wrapping():
    h = JointHistory(2, span_s=0.5, capacity=64)
    v = np.array([0.3, -1.2])                                   # rad/s
    for k in range(300):                                        # wraps the 64-slot ring several times
        assert h.push(k * 0.002, v * k * 0.002)
    newest = 299 * 0.002
    for s in np.linspace(newest - 0.12, newest, 37):           # within what the ring still holds
        np.testing.assert_allclose(h.at(s), v * s, atol=1e-12)
    assert h.latest()[0] == pytest.approx(newest)


def test_stamps_outside_the_history_are_refused_with_their_kind():
    h = JointHistory(1, span_s=0.1, max_gap_s=0.05)
    with pytest.raises(OutsideHistory) as e:
        h.at(0.0)
    assert e.value.kind == "no_joints"
    for t in (0.0, 0.01, 0.02, 0.2, 0.21):                      # a 0.18 s hole in the stream
        h.push(t, [t])
    for stamp, kind in ((0.215, "future"), (0.05, "too_old"), (0.15, "joint_gap")):
        with pytest.raises(OutsideHistory) as e:
            h.at(stamp)
        assert e.value.kind == kind, (stamp, e.value)
    assert h.at(0.205)[0] == pytest.approx(0.205)


def test_bad_states_are_refused_and_counted():
    h = JointHistory(2, q_min=[-1, -1], q_max=[1, 1])
    assert h.push(1.0, [0, 0])
    assert not h.push(1.0, [0, 0])                              # not after the newest
    assert not h.push(0.5, [0, 0])
    assert not h.push(2.0, [0, np.nan])
    assert not h.push(2.0, [0, 0, 0])
    assert not h.push(2.0, [0, 1.5])
    assert h.refused == 5 and "outside its limits" in h.last_refusal
    np.testing.assert_array_equal(h.at(1.0), [0, 0])


# ------------------------------------------------------------------ wait_at
def test_wait_at_returns_the_joints_once_the_lagging_state_arrives():
    """States pushed by another thread after the call: the answer is the interpolation between
    them (the same as ``at`` once they are in), not a refusal and not an extrapolation."""
    h = JointHistory(1, span_s=1.0)
    h.push(0.0, [0.0])
    asked = threading.Event()
    calls = []

    def stop():
        calls.append(1)
        if len(calls) == 3:                 # the caller has waited a little: the state comes now
            asked.set()
        return False

    def joint_thread():
        asked.wait(30)
        h.push(0.1, [1.0])

    t = threading.Thread(target=joint_thread)
    t.start()
    q = h.wait_at(0.025, timeout=30.0, stop=stop)
    t.join()
    assert q[0] == pytest.approx(0.25)
    assert len(calls) >= 3


def test_wait_at_feeds_the_history_before_each_look_up():
    """A caller that drains its joint stream on its own thread (the camera unit) passes ``feed``:
    the stream's second state makes the stamp answerable."""
    h = JointHistory(2, span_s=1.0)
    stream = [(0.0, [0.0, 0.0]), (0.2, [2.0, -2.0])]
    fed = []

    def feed():
        fed.append(1)
        if stream:
            h.push(*stream.pop(0))

    np.testing.assert_allclose(h.wait_at(0.05, timeout=30.0, feed=feed), [0.5, -0.5])
    assert len(fed) == 2


def test_wait_at_stops_when_asked_and_refuses_with_the_reason():
    h = JointHistory(1, span_s=1.0)
    calls = []

    def stop():
        calls.append(1)
        return len(calls) >= 4              # a newer frame came: give this one up

    with pytest.raises(OutsideHistory) as e:
        h.wait_at(1.0, timeout=60.0, stop=stop)
    assert e.value.kind == "no_joints" and len(calls) == 4
    h.push(0.0, [0.0])
    calls.clear()
    with pytest.raises(OutsideHistory) as e:
        h.wait_at(1.0, timeout=60.0, stop=stop)
    assert e.value.kind == "future" and len(calls) == 4


@pytest.mark.parametrize("stamp, kind", [(0.05, "too_old"), (0.15, "joint_gap")])
def test_wait_at_does_not_wait_for_what_no_later_state_can_fix(stamp, kind):
    """A stamp before the history or in a gap stays so: refused at the first look-up."""
    h = JointHistory(1, span_s=0.1, max_gap_s=0.05)
    for t in (0.0, 0.01, 0.02, 0.2, 0.21):
        h.push(t, [t])
    looks = []
    with pytest.raises(OutsideHistory) as e:
        h.wait_at(stamp, timeout=60.0, stop=lambda: looks.append(1) or False, feed=lambda: looks.append(0))
    assert e.value.kind == kind and looks == [0]


def test_wait_at_with_no_time_left_refuses_a_lagging_stamp():
    h = JointHistory(1, span_s=1.0)
    h.push(0.0, [0.0])
    with pytest.raises(OutsideHistory) as e:
        h.wait_at(0.5, timeout=0.0)
    assert e.value.kind == "future"


def test_a_waiter_sleeps_until_a_push_wakes_it():
    """issue 29: the wait is a condition notified by ``push``, not a poll. Over a 0.3 s wait the
    waiter looks the stamp up once before and once after the push (a poll every 0.5 ms looked
    ~600 times: 14-18 ms of CPU against 0.14-0.25 ms now, measured), and it answers with the
    pushed state's interpolation — the push itself is the wake-up (without ``stop`` there is no
    backstop wake-up at all)."""

    class Counted(JointHistory):
        looks = 0

        def at(self, stamp, out=None):
            self.looks += 1
            return super().at(stamp, out)

    h = Counted(1, span_s=1.0)
    h.push(0.0, [0.0])
    out = {}

    def waiter():
        out["q"] = h.wait_at(0.025, timeout=30.0)
        out["woke"] = time.perf_counter()

    t = threading.Thread(target=waiter)
    t.start()
    time.sleep(0.3)
    assert t.is_alive() and "q" not in out               # still waiting for a state at or after 0.025
    pushed = time.perf_counter()
    h.push(0.1, [1.0])
    t.join(30.0)
    assert out["q"][0] == pytest.approx(0.25)
    assert out["woke"] >= pushed
    assert h.looks == 2, h.looks


def test_wake_makes_a_waiter_ask_stop_again():
    """A newer frame (``wake``) ends the wait of the older one at once, not at its timeout."""
    h = JointHistory(1, span_s=1.0)
    h.push(0.0, [0.0])
    newer = threading.Event()
    res = {}

    def waiter():
        try:
            h.wait_at(0.5, timeout=60.0, stop=newer.is_set, stop_poll_s=60.0)
        except OutsideHistory as exc:
            res["kind"] = exc.kind

    t = threading.Thread(target=waiter)
    t.start()
    time.sleep(0.1)
    assert t.is_alive()
    newer.set()
    h.wake()
    t.join(5.0)                                           # the backstop is 60 s: only wake() ends it
    assert not t.is_alive() and res["kind"] == "future"


def test_a_unit_feeding_its_own_history_sleeps_until_its_stream_receives():
    """The camera unit drains its joint stream on its own thread (``feed``); with ``arrived`` (the
    stream's wait, here a :class:`StampedQueue` filled by a receiving thread as ``zenoh:`` is)
    it looks again when a state is received, not every ``poll_s``: over a 0.3 s wait, two
    look-ups and two feeds, not ~300."""
    from depthguard.sources.stamped_queue import StampedQueue

    h = JointHistory(1, span_s=1.0)
    stream = StampedQueue(64)
    stream.offer(0.0, (0.0, [0.0]))
    fed = []

    def feed():
        fed.append(1)
        for st, q in stream.until(float("inf")):
            h.push(st, q)

    def receiver():
        time.sleep(0.3)
        stream.offer(0.1, (0.1, [1.0]))

    t = threading.Thread(target=receiver)
    t.start()
    q = h.wait_at(0.025, timeout=30.0, feed=feed, poll_s=0.001, arrived=stream.wait)
    t.join()
    assert q[0] == pytest.approx(0.25)
    assert len(fed) == 2, len(fed)


def test_state_check_kernel_equals_its_twin_and_refuses_as_before():
    """issue 29: ``push`` checks a state with one numba pass (``state_check``); it answers as its
    numpy twin, and a refused state gets the sentence of the checks it replaced: the first joint
    outside its limits, with 1e-6 rad of slack."""
    from depthguard.robot.joint_history import state_check, state_check_numpy

    rng = np.random.default_rng(2)
    lo, hi = np.full(6, -1.0), np.full(6, 1.0)
    for k in range(500):
        q = rng.uniform(-1.2, 1.2, 6) * (k % 3 == 0) + rng.uniform(-0.99, 0.99, 6) * (k % 3 != 0)
        if k % 11 == 0:
            q[rng.integers(0, 6)] = rng.choice([np.nan, np.inf, -np.inf])
        assert state_check(q, lo, hi) == state_check_numpy(q, lo, hi), q
    h = JointHistory(3, q_min=[-1, -1, -1], q_max=[1, 1, 1])
    assert h.push(0.0, np.array([1.0 + 0.9e-6, -1.0 - 0.9e-6, 0.0]))        # within the slack
    assert not h.push(0.1, np.array([0.0, 1.0 + 2e-6, -2.0]))
    assert h.last_refusal == "joint 1 = 1.0000 rad is outside its limits [-1.0000, 1.0000]"
    assert not h.push(0.1, np.array([0.0, np.nan, -2.0]))
    assert h.last_refusal == "joint state with a non-finite stamp or value"
    assert not h.push(np.inf, np.zeros(3)) and h.refused == 3
    view = np.zeros((3, 2))[:, 0]                                            # not contiguous: copied
    assert h.push(0.2, view) and np.array_equal(h.latest()[1], view)
