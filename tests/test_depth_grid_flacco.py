"""Flacco & De Luca 2015 situations on the flacco-cell (figs. 8/12, 9/13) on the numbers,
against the exact ground truth ``scene.true_distance``, and the CLI from a fresh output dir."""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.evaluation.flacco2015 import run_flacco2015

PADDING = 0.05


@pytest.fixture(scope="module")
def res(tmp_path_factory):
    return run_flacco2015(rho=0.4, padding=PADDING, cache_dir=tmp_path_factory.mktemp("cache"))


@pytest.mark.slow
def test_shadow_one_camera_phantom_two_cameras_clear(res):
    s = res["shadow"]
    # one camera: the person's gray area reads as an obstacle far nearer than anything real
    assert np.sum(s.one < s.truth - 0.1) >= 3, (s.one, s.truth)
    # two cameras, the paper's removal in cam1: no phantom, every reading >= truth - eps
    two = np.where(np.isfinite(s.two_paper), s.two_paper, np.inf)
    assert np.all(two >= np.minimum(s.truth, 0.4) - s.eps), (two, s.truth)
    # R9 (robot pixels of cam1 unknown behind): never less safe than the paper's mode
    assert np.all(np.nan_to_num(s.two, posinf=9) <= np.nan_to_num(s.two_paper, posinf=9) + 1e-12)


@pytest.mark.slow
def test_hidden_hand_missed_by_one_found_by_two(res):
    h = res["hidden_hand"]
    near = h.truth < 0.2                      # the control points next to the hand
    assert near.sum() >= 3
    one = np.where(np.isfinite(h.one), h.one, np.inf)
    # missed: one camera sees the arm holding it at best, well beyond the discretisation
    assert np.all(one[near] > h.truth[near] + 2 * h.eps[near]), (one, h.truth)
    # found: within the discretisation, or within the padded self volume that hides the hand's
    # part touching the robot (cells inside it are never obstacles, R12)
    assert np.all(h.two[near] <= h.truth[near] + PADDING + h.eps[near]), (h.two, h.truth)
    i = int(np.argmin(np.abs(h.two - h.truth) + 10 * ~near))
    assert abs(h.two[i] - h.truth[i]) <= h.eps[i]


@pytest.mark.slow
def test_robot_alone_no_self_distance(res):
    a = res["robot_alone"]
    for two in (a.two, a.two_paper):
        rep = np.where(np.isfinite(two), two, np.inf)
        assert np.all(rep >= np.minimum(a.truth, 0.4) - a.eps), (rep, a.truth)


@pytest.mark.slow
def test_robot_alone_sees_the_room_within_a_wider_rho(tmp_path):
    """The other side of the robot-alone test: nothing lies within 0.4 m of its control points
    (the test above holds for a grid that answers inf everywhere), so with rho = 0.65 m the room
    around the robot (floor, walls) is within reach of most points and must be found within the
    discretisation, while the robot still never reads itself nearer than what is there."""
    a = run_flacco2015(rho=0.65, padding=PADDING, cache_dir=tmp_path)["robot_alone"]
    near = a.truth + a.eps < 0.65
    assert near.sum() >= 5, a.truth
    for two in (a.two, a.two_paper):
        rep = np.where(np.isfinite(two), two, np.inf)
        assert np.all(rep >= np.minimum(a.truth, 0.65) - a.eps), (rep, a.truth)
        assert np.all(rep[near] <= a.truth[near] + a.eps[near]), (rep, a.truth)


@pytest.mark.slow
def test_reproduce_cli_writes_plots_and_table(tmp_path):
    from typer.testing import CliRunner

    from depthguard.cli import app

    r = CliRunner().invoke(app, ["reproduce", "flacco2015", "--out", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    for n in ("flacco2015_shadow.png", "flacco2015_hidden_hand.png", "flacco2015_robot_alone.png",
              "table.md"):
        assert (tmp_path / "o" / n).stat().st_size > 1000 or n == "table.md"
    assert "hidden_hand" in (tmp_path / "o" / "table.md").read_text()
    bad = CliRunner().invoke(app, ["reproduce", "flacco2015", "--rho", "-1"])
    assert bad.exit_code != 0


@pytest.mark.slow
def test_bench_group_quick_rows():
    from depthguard.evaluation.bench import BenchContext, run

    pytest.importorskip("scipy")
    rows = {r.name: r for r in run(["depthgrid"], BenchContext(quick=True, repeats=3))}
    for n in ("depthgrid.cycle_ms", "depthgrid.cycle_p99_ms", "depthgrid.build_s", "depthgrid.bytes",
              "depthgrid.cycle_ms.1cam", "depthgrid.cycle_ms.4cam"):
        assert n in rows and np.isfinite(rows[n].value) and rows[n].value > 0
    assert rows["depthgrid.cycle_ms"].paper == 3.3 and rows["depthgrid.cycle_ms"].peer_value > 0
    # the rows are measured, not judged here (speed lives in the bench, issue 33); memory is a bound
    assert rows["depthgrid.bytes"].value <= 1e9
