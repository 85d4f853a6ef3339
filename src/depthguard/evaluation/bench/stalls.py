"""Bench group ``stalls``: what the monitor's process spends outside its own work (R29; issue 29).

- ``stalls.gc_full_ms`` — the CPU of one full garbage collection (``gc.collect()``) once a
  ``flacco-cell`` monitor is built, inside a real-time run's :func:`~depthguard.runtime.realtime.frozen_heap`
  (the objects made before the run frozen: the collection walks what the run made); the peer is
  the same collection with nothing frozen, as before issue 29 (it walked every module, numba
  dispatcher and array of the process, holding the GIL), alternated, median of the repeats.
- ``stalls.joint_wait_cpu_us`` — the CPU of :meth:`~depthguard.robot.joint_history.JointHistory.wait_at`
  per frame whose joints lag it by 5 ms, a thread pushing states at 500 Hz (the camera worker's
  case); the peer is the poll it replaced (a look-up every 0.5 ms until the state comes), on
  the same history, alternated, median.
"""

from __future__ import annotations

import gc
import threading
import time

import numpy as np

from depthguard.evaluation.bench import BenchContext, BenchRow, group


def _poll_wait(h, stamp: float, timeout: float, poll_s: float = 0.0005):
    """The wait before issue 29: look again every ``poll_s`` s (the peer)."""
    from depthguard.robot.joint_history import OutsideHistory

    deadline = time.perf_counter() + timeout
    while True:
        try:
            return h.at(stamp)
        except OutsideHistory as exc:
            if exc.kind not in ("future", "no_joints") or time.perf_counter() >= deadline:
                raise
        time.sleep(poll_s)


def _gc_rows(ctx: BenchContext) -> BenchRow:
    from depthguard.runtime.monitor import Monitor, warm_up
    from depthguard.runtime.realtime import frozen_heap
    from depthguard.sim import load_cell

    rig = load_cell("flacco-cell").rig
    warm_up(rig, rig.monitor)
    ours, peer = [], []
    with Monitor(rig, rig.monitor):
        for _ in range(3 if ctx.quick else 10):
            t0 = time.thread_time()
            gc.collect()
            peer.append(time.thread_time() - t0)
            with frozen_heap():
                t0 = time.thread_time()
                gc.collect()
                ours.append(time.thread_time() - t0)
        tracked = len(gc.get_objects())
    return BenchRow("stalls.gc_full_ms", float(np.median(ours)) * 1e3, "ms", None, "nothing frozen (before issue 29)",
                    float(np.median(peer)) * 1e3, f"{tracked} objects tracked unfrozen; a full collection holds the GIL")


def _wait_rows(ctx: BenchContext) -> BenchRow:
    from depthguard.robot.joint_history import JointHistory

    h = JointHistory(6, span_s=1.0)
    q = np.full(6, 0.1)
    t0 = time.perf_counter()
    stop = threading.Event()

    def joints():
        k = 0
        while not stop.is_set():
            h.push(k * 0.002, q)
            k += 1
            time.sleep(max(0.0, t0 + k * 0.002 - time.perf_counter()))

    th = threading.Thread(target=joints, daemon=True, name="bench-joints")
    th.start()
    ours, peer = [], []
    try:
        while h.newest_stamp < 0.01:
            time.sleep(0.005)
        for i in range(40 if ctx.quick else 200):
            for fn, out in ((h.wait_at, ours), (lambda s, t: _poll_wait(h, s, t), peer))[:: 1 if i % 2 else -1]:
                stamp = h.newest_stamp + 0.005           # a frame 5 ms after the newest joint state
                c0 = time.thread_time()
                fn(stamp, 1.0)
                out.append(time.thread_time() - c0)
                time.sleep(0.01)
    finally:
        stop.set()
        th.join(1.0)
    return BenchRow("stalls.joint_wait_cpu_us", float(np.median(ours)) * 1e6, "us", None,
                    "poll every 0.5 ms (before issue 29)", float(np.median(peer)) * 1e6,
                    "joints 5 ms behind the frame, 500 Hz")


@group("stalls")
def bench_stalls(ctx: BenchContext) -> list[BenchRow]:
    return [_gc_rows(ctx), _wait_rows(ctx)]
