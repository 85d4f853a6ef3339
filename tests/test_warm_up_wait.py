"""warm_up's wait counts only the time in which numba compiles nothing (R29, issue 33's
first-contact check): on a fresh clone (cold disk cache) at load 9 on 2 cores, ``depthguard run
--rig examples/own_cell/cell.yaml --scenario reach`` spent over 600 s in warm_up's compilation
and ended in a ``TimeoutError`` traceback. The truth here is numba itself: a real compilation
on another thread, seen through the dispatcher's own list of compiled signatures."""

import threading
import time

import numba
import numpy as np
import pytest

from depthguard.runtime.warm_up import CompileActivity, wait_idle


class _Compiled:
    """Idle once ``fn`` holds a compiled signature (numba adds it before its compile event ends)."""

    def __init__(self, fn):
        self.fn = fn

    def idle(self) -> bool:
        return len(self.fn.signatures) > 0


def _fresh_kernel():
    def kernel(a, b):                     # a new function object: never compiled, not cached
        s = 0.0
        for i in range(a.shape[0]):
            for j in range(b.shape[0]):
                d = np.sqrt((a[i] - b[j]) ** 2 + 1.0)
                if d > s:
                    s = d
        return np.sort(a)[0] + s

    return numba.njit(cache=False)(kernel)


def test_a_compilation_longer_than_the_timeout_is_waited_for_not_a_timeout():
    fn = _fresh_kernel()
    timeout = 0.02
    with CompileActivity() as act:
        th = threading.Thread(target=fn.compile, args=((numba.float64[:], numba.float32[:]),), daemon=True)
        t0 = time.perf_counter()
        th.start()
        while act.quiet_s() > 0.0 and not fn.signatures:         # until numba has started
            time.sleep(0.0005)
        wait_idle(_Compiled(fn), timeout, act)
        took = time.perf_counter() - t0
        th.join()
    # a wall-clock deadline of `timeout` (Monitor.flush, what warm_up used) would have raised
    assert took > 5 * timeout, took
    assert act.compiles >= 1 and len(fn.signatures) == 1


def test_a_target_that_stays_busy_with_nothing_compiling_times_out_after_the_timeout():
    class Never:
        def idle(self):
            return False

    with CompileActivity() as act:
        t0 = time.perf_counter()
        with pytest.raises(TimeoutError, match="0.3 s after the last kernel compilation"):
            wait_idle(Never(), 0.3, act)
        took = time.perf_counter() - t0
    assert 0.3 - 0.005 <= took < 5.0, took     # the 0.3 s run from the activity's start, just before t0 (0.2995 seen)
