"""Flacco 2014 §4 on the flacco-walls cell: the paper's three claims, checked on the numbers
(scene ground truth and geometry of the walls), and ``depthguard reproduce flacco2014``."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from depthguard.evaluation.flacco2014 import TABLE_GAP, WALL_GAP, X_SWITCH, run_flacco2014


def _angles_deg(V):
    ok = np.linalg.norm(V, axis=1) > 0.5
    both = ok[:-1] & ok[1:]
    c = np.clip(np.einsum("ij,ij->i", V[:-1][both], V[1:][both]), -1, 1)
    return np.degrees(np.arccos(c))


def check_claims(res):
    x = res.x
    from depthguard.sim import load_cell

    cam = load_cell("flacco-walls").rig.cameras[0]
    dp = cam.world_to_depth_space(res.points)[:, 2]
    pixel = dp / cam.fx                                  # one pixel's width at the point's depth
    D = res.distance["min"]
    # ground truth of the cell: 0.03 to the wall's hidden face for x <= 0, then the wall's
    # edge, then the table 0.16 below
    np.testing.assert_allclose(res.truth[x <= 0], WALL_GAP, atol=1e-9)
    np.testing.assert_allclose(res.truth[x > X_SWITCH + 1e-3], TABLE_GAP, atol=1e-9)

    # 1. depth space, min: the wall nearest up to x = 0.1572, at <= 0.03 (gray area: smaller,
    #    up to one pixel of discretisation larger), then the table at about 0.16
    before = x <= 0
    assert np.all(D[before] <= WALL_GAP + pixel[before])
    assert D[before].min() < WALL_GAP - 0.003             # the gray area appears nearer
    assert np.all(res.nearest["min"][x < X_SWITCH - 0.02] == "wall")
    assert np.all(res.nearest["min"][x > X_SWITCH + 0.02] == "table")
    np.testing.assert_allclose(D[x > X_SWITCH + 0.02], TABLE_GAP, atol=0.015)
    # the wall's edge between 0 and the switch: sqrt(x^2 + 0.03^2), nearer by at most the
    # Kinect's error on the wall's x = 0 face (3 sigma + half a disparity step, at the face's
    # depth, about the point's) plus a pixel, farther by at most a pixel + 5 mm
    from depthguard.sensors import sensor_model

    km = sensor_model("kinect_v1")
    mid = (x > 0.01) & (x < X_SWITCH - 0.01)
    z = dp[mid]
    noise = 3 * km.sigma_z2 * z ** 2 + 0.5 * z ** 2 / (cam.fx * km.baseline * 2 ** km.disparity_bits)
    edge = np.hypot(x[mid], WALL_GAP)
    assert np.all(D[mid] >= edge - noise - pixel[mid]), (D[mid] - edge).min()
    assert np.all(D[mid] <= edge + pixel[mid] + 0.005), (D[mid] - edge).max()
    # conservative (R25): never above the truth by more than the discretisation (+ noise)
    assert np.all(D <= res.truth + 2 * pixel + 0.005)

    # 2. the Cartesian baseline takes the table (about 0.16 away, straight down) over much
    #    of x in [-0.5, -0.1572], where the wall's hidden face is in fact 0.03 away
    band = x <= -X_SWITCH
    C = res.distance["cartesian"]
    table_like = (np.abs(C[band] - TABLE_GAP) < 0.01) & (res.direction["cartesian"][band, 2] < -0.95)
    assert table_like.mean() > 0.5
    assert np.mean(res.nearest["cartesian"][band] == "table") > 0.5
    assert np.all(C[band] > 3 * WALL_GAP)

    # 3. mean and hybrid directions change continuously, min jumps (wall -> table at the switch)
    jumps = {m: _angles_deg(res.direction[m]).max() for m in ("min", "mean", "hybrid")}
    assert jumps["min"] > 45
    assert jumps["mean"] < 20 and jumps["hybrid"] < 20
    for m in jumps:
        assert res.summary["jump_deg"][m] == pytest.approx(jumps[m], abs=1e-9)
    assert res.summary["claim_min"] and res.summary["claim_cartesian"] and res.summary["claim_continuity"]


@pytest.mark.slow
def test_flacco2014_claims_noiseless():
    res = run_flacco2014(steps=201, noiseless=True)
    check_claims(res)
    # the switch from wall to table where the paper puts it (within two steps of 5 mm)
    assert abs(res.summary["min_wall_nearest_until"] - X_SWITCH) <= 0.011


@pytest.mark.slow
def test_flacco2014_claims_with_kinect_noise():
    res = run_flacco2014(steps=201, noiseless=False, seed=0)
    check_claims(res)


@pytest.mark.slow
def test_reproduce_command_writes_figures_and_table(tmp_path):
    from depthguard.cli import app

    out = tmp_path / "fl"
    r = CliRunner().invoke(app, ["reproduce", "flacco2014", "--out", str(out), "--steps", "21", "--noiseless"])
    assert r.exit_code == 0, r.output
    for f in ("fig7_cartesian.png", "fig8_min.png", "fig9_mean.png", "fig10_hybrid.png", "fig11_times.png",
              "table.csv", "summary.json", "summary.md"):
        assert (out / f).stat().st_size > 100, f
    S = json.loads((out / "summary.json").read_text())
    assert S["steps"] == 21 and S["claim_cartesian"]
    lines = (out / "table.csv").read_text().splitlines()
    assert len(lines) == 22 and lines[0].startswith("x,truth,cartesian_D")
    assert "min" in r.output and "Cartesian" in r.output


@pytest.mark.slow
def test_bench_group_quick_rows():
    from depthguard.evaluation.bench import BenchContext
    from depthguard.evaluation.bench.distance import bench_distance

    rows = {r.name: r for r in bench_distance(BenchContext(quick=True, repeats=3))}
    for name, paper in (("distance.min.worst_ms", 1.46), ("distance.mean.worst_ms", 3.335),
                        ("distance.hybrid.worst_ms", 3.335), ("distance.cartesian_kdtree.worst_ms", 70.6),
                        ("distance.cartesian_brute.worst_ms", 70.6)):
        assert rows[name].paper == paper and rows[name].peer_value is not None
    for name in ("distance.hybrid.9pts_ms", "distance.hybrid.32pts_ms", "distance.prepare_ms",
                 "distance.hybrid_vs_kdtree.speedup"):
        assert name in rows
    assert all(np.isfinite(r.value) and r.value > 0 for r in rows.values())
    assert "build" in rows["distance.cartesian_kdtree.worst_ms"].note
