"""The ``robot`` bench group runs in quick mode and reports its rows (figures are not asserted)."""

import math

import depthguard.evaluation.bench.robot  # noqa: F401  (registers the group)
from depthguard.evaluation.bench import GROUPS, BenchContext


def test_robot_bench_quick_rows():
    rows = GROUPS["robot"](BenchContext(quick=True))
    names = [r.name for r in rows]
    assert names == ["robot.lwr4.fk_jac9_us", "robot.ur3.fk_jac8_us", "robot.lwr4.fk_jac9_alloc_us"]
    for r in rows:
        assert r.unit == "us" and math.isfinite(r.value) and r.value > 0
        assert r.peer and math.isfinite(r.peer_value) and r.peer_value > 0
