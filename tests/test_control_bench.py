"""The ``control`` bench group (issue 29) runs in quick mode and reports its rows (figures are not asserted)."""

import math

import pytest

import depthguard.evaluation.bench.control  # noqa: F401  (registers the group)
from depthguard.evaluation.bench import GROUPS, BenchContext


@pytest.mark.slow
def test_control_bench_quick_rows():
    rows = GROUPS["control"](BenchContext(quick=True))
    assert [r.name for r in rows] == ["control.cycle_cpu_us", "control.log_line_us", "control.sinks_cpu_us"]
    for r in rows:
        assert r.unit == "us" and math.isfinite(r.value) and r.value > 0
    assert all(math.isfinite(r.peer_value) and r.peer_value > 0 for r in rows[1:])
