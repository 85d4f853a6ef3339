"""The ``stalls`` bench group (issue 29) runs in quick mode and reports its rows (figures are not asserted)."""

import math

import pytest

import depthguard.evaluation.bench.stalls  # noqa: F401  (registers the group)
from depthguard.evaluation.bench import GROUPS, BenchContext


@pytest.mark.slow                 # ~2 min on the loaded 2-core machine: a flacco-cell monitor built
def test_stalls_bench_quick_rows():
    rows = GROUPS["stalls"](BenchContext(quick=True))
    assert [r.name for r in rows] == ["stalls.gc_full_ms", "stalls.joint_wait_cpu_us"]
    for r in rows:
        assert math.isfinite(r.value) and r.value > 0 and math.isfinite(r.peer_value) and r.peer_value > 0
