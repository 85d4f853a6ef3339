"""The ``voxels`` bench group runs (quick mode) and its distributed harness works; figures are not asserted."""

import math

import pytest

from depthguard.evaluation.bench import BenchContext


@pytest.mark.slow
def test_voxels_bench_quick_rows():
    from depthguard.evaluation.bench.voxels import bench_voxels

    rows = {r.name: r for r in bench_voxels(BenchContext(quick=True, repeats=3))}
    for tag in ("424x240", "640x480", "1280x720"):
        assert rows[f"voxels.filter.{tag}_ms"].value > 0
        assert rows[f"voxels.kernel.{tag}_ms"].peer_value > 0          # OctoMap measured in the same run
        assert rows[f"voxels.bytes.{tag}"].value < rows[f"voxels.bytes.{tag}"].peer_value
    assert rows["voxels.refresh.3cam.1280x720_ms"].paper == 287.0
    assert rows["voxels.refresh.3cam.1280x720_ms"].peer_value > 0      # centralised measured
    assert rows["voxels.vote.blobs_t0.1.false_removed"].peer_value > 0


@pytest.mark.slow
@pytest.mark.multiprocess
@pytest.mark.timeout(300)
def test_distributed_refresh_harness():
    """Trigger → every node's update arrives, for two node processes at 424x240."""
    from depthguard.evaluation.bench.voxels import distributed_refresh
    from depthguard.sim import load_cell

    cell = load_cell("ur3-cell")
    t = cell.time_of("arm_reaching")
    q = cell.scene.robot_q(t)
    cpu = {}
    dt = distributed_refresh(["camA", "camB"], 424, 240, t, repeats=3, qs=(q, q + 1e-4), cpu=cpu)
    assert len(dt) == 3 and all(0 < x < 5 and math.isfinite(x) for x in dt)
    assert cpu["per_node_ms"].shape == (2,) and (cpu["per_node_ms"] >= 0).all()
