"""Where a run's CPU went (runtime.thread_cpu, issue 29): the kernel's per-thread counters.

Truth: threads that burn a known amount of CPU (a busy loop timed by ``time.thread_time``, the
interpreter's own per-thread clock) and one that sleeps.
"""

from __future__ import annotations

import sys
import threading
import time

import pytest

from depthguard.runtime.thread_cpu import cpu_by_part, thread_cpu_seconds, top_parts

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the counters are Linux's /proc")


def _burn(seconds: float, done: threading.Event, used: dict, key: str) -> None:
    t0 = time.thread_time()
    while time.thread_time() - t0 < seconds:
        sum(range(1000))
    used[key] = time.thread_time() - t0
    done.wait()


def test_each_part_gets_its_threads_cpu():
    since, p0 = thread_cpu_seconds(), time.process_time()
    done, used = threading.Event(), {}
    threads = [threading.Thread(target=_burn, args=(s, done, used, n), name=n, daemon=True)
               for n, s in (("depthguard-camera-left", 0.3), ("depthguard-camera-right", 0.2),
                            ("depthguard-fusion", 0.4))]
    threads.append(threading.Thread(target=done.wait, name="depthguard-sinks", daemon=True))
    for th in threads:
        th.start()
    while len(used) < 3:
        time.sleep(0.01)
    try:
        parts = cpu_by_part(since, p0)
    finally:
        done.set()
        for th in threads:
            th.join()
    tick = 0.02                                          # the counters' resolution (10 ms ticks) and rounding
    cams = used["depthguard-camera-left"] + used["depthguard-camera-right"]
    assert parts["depthguard-camera"] == pytest.approx(cams, abs=2 * tick)     # one line for both cameras
    assert parts["depthguard-fusion"] == pytest.approx(used["depthguard-fusion"], abs=tick)
    assert parts["depthguard-sinks"] <= tick                                   # it only waited
    assert parts["process"] >= cams + used["depthguard-fusion"] - 3 * tick
    assert "other" in parts and parts["other"] >= 0.0
    line = top_parts(parts, 1.0, n=2)                   # the largest first, in cores over 1 s
    (n1, c1), (n2, c2) = [(x.rsplit(" ", 1)[0], float(x.rsplit(" ", 1)[1])) for x in line.split(", ")]
    assert (n1, n2) == ("depthguard-camera", "depthguard-fusion"), line
    assert c1 == pytest.approx(cams, abs=0.03) and c2 == pytest.approx(used["depthguard-fusion"], abs=0.03), line
