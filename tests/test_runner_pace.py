"""The real-time runner's joint pump (issue 29): a source on the run's clock is polled when its next
state is due, not every 0.5 ms — and never later than one interval of its stream."""

import math

import pytest

from depthguard.runtime.runner import POLL_S, _Pace


def test_a_500_hz_stream_is_polled_when_its_next_state_is_due():
    p = _Pace()
    assert p.wait(0.0) == POLL_S                           # nothing seen yet: as before
    p.seen([(0.0, None)])
    assert p.wait(0.0) == POLL_S                           # one state: no interval yet
    p.seen([(0.002, None), (0.004, None)])
    assert p.gap == pytest.approx(0.002)
    assert p.wait(0.0041) == pytest.approx(0.0019)         # the next state is due at 0.006
    assert p.wait(0.0058) == POLL_S                        # due within POLL_S: not sooner than that
    assert p.wait(0.0075) == POLL_S                        # overdue: polled every POLL_S until it comes
    assert p.wait(-1.0) == pytest.approx(0.002)            # stamps ahead of the clock: once an interval
    p.seen([(0.0039, None)])                               # out of order (older): ignored
    assert p.last == 0.004 and p.gap == pytest.approx(0.002)


def test_polls_of_a_simulated_stream_drop_to_about_one_per_state():
    """A 500 Hz stream on an ideal clock: the pump's polls over one simulated second (the clock
    advances by each wait), against 2000 with the fixed 0.5 ms poll; none is late."""
    p, t, polls, late, last_taken = _Pace(), 0.0, 0, 0.0, -1
    while t < 1.0:
        polls += 1
        due = [k * 0.002 for k in range(last_taken + 1, int(math.floor(t / 0.002 + 1e-9)) + 1)]
        if due:
            late = max(late, t - due[0])
            last_taken += len(due)
            p.seen([(s, None) for s in due])
        t += p.wait(t)
    assert polls < 600 and late <= POLL_S + 1e-9, (polls, late)
