"""Camera frames from capture to delivery (evaluation/closed_loop/camera_pipeline.py, R15, R27)."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from depthguard.evaluation.closed_loop.camera_pipeline import CameraPipeline


def _fake(log):
    def simulate(i, t, q):
        log.append((i, t, threading.current_thread().name))
        d = np.full((2, 3), 10.0 * i + t, np.float32)
        return d, d * 0, 0.001, 0.002
    return simulate


def test_without_latency_a_frame_is_delivered_at_once_in_the_callers_thread():
    log, timing = [], {"self_removal": 0.0, "camera_sim": 0.0}
    p = CameraPipeline(_fake(log), ["a", "b"], 0.0, timing)
    p.start(np.zeros(2))                          # nothing in flight: the first cycle captures
    assert list(p.deliver(0.0)) == []
    p.capture(1, 0.5, np.ones(2))
    out = list(p.deliver(0.5))
    assert [(i, c, t) for i, c, t, *_ in out] == [(1, "b", 0.5)]
    assert np.all(out[0][4] == np.float32(10.5)) and log[0][2] == threading.current_thread().name
    assert timing["self_removal"] == pytest.approx(0.001) and timing["camera_sim"] == pytest.approx(0.002)
    p.close()


def test_with_latency_frames_arrive_latency_after_capture_in_order_from_another_thread():
    log, timing = [], {"self_removal": 0.0, "camera_sim": 0.0}
    L = 0.03
    p = CameraPipeline(_fake(log), ["a", "b"], L, timing)
    p.start(np.zeros(2))                          # captured at -L, delivered at 0
    first = list(p.deliver(0.0))
    assert [(i, t) for i, _, t, *_ in first] == [(0, -L), (1, -L)]
    q = np.array([1.0, 2.0])
    p.capture(0, 0.01, q)
    q[:] = 9.0                                    # the caller's joints move on: the frame keeps its own
    p.capture(1, 0.02, np.ones(2))
    assert list(p.deliver(0.01 + L - 0.005)) == []            # not yet due
    got = list(p.deliver(0.01 + L))
    assert [(i, t) for i, _, t, *_ in got] == [(0, 0.01)]
    assert np.array_equal(got[0][3], [1.0, 2.0])
    got = list(p.deliver(1.0))
    assert [(i, t) for i, _, t, *_ in got] == [(1, 0.02)]
    assert np.all(got[0][4] == np.float32(10.02))
    names = {name for i, t, name in log if t > 0}          # the frames captured by the loop
    assert names and all(name.startswith("depthguard-cameras") for name in names)
    p.capture(0, 2.0, q)                          # in flight when the run ends: dropped
    p.close()
    assert list(p.deliver(10.0)) == []


def test_bad_latency_is_refused():
    for bad in (-0.01, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="latency"):
            CameraPipeline(_fake([]), ["a"], bad, {})


def test_not_threaded_frames_still_arrive_after_the_latency_from_the_callers_thread():
    """Without a thread-safe numba threading layer the loop simulates each frame at capture in
    its own thread; the latency still applies."""
    from depthguard.evaluation.closed_loop.camera_pipeline import threadsafe_numba
    assert isinstance(threadsafe_numba(), bool)
    log = []
    p = CameraPipeline(_fake(log), ["a"], 0.05, {"self_removal": 0.0, "camera_sim": 0.0}, threaded=False)
    assert not p.threaded
    p.capture(0, 1.0, np.zeros(2))
    assert list(p.deliver(1.04)) == [] and log[0][2] == threading.current_thread().name
    assert [t for _, _, t, *_ in p.deliver(1.05)] == [1.0]
    p.close()
