"""The joint history of the runtime (R30): interpolation at a stamp, never extrapolation."""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.runtime.joints import JointHistory, OutsideHistory


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
    assert e.value.kind == "empty"
    for t in (0.0, 0.01, 0.02, 0.2, 0.21):                      # a 0.18 s hole in the stream
        h.push(t, [t])
    for stamp, kind in ((0.215, "future"), (0.05, "too_old"), (0.15, "gap")):
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
