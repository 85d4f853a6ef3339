"""The availability bench's parts (R27, R36): its stale-time count against a log whose answer is
known by construction, and its rig file against the rig loader."""

from __future__ import annotations

import json

import pytest

from depthguard.evaluation.bench.availability import _rig_file, stale_seconds


def test_stale_seconds_counts_the_time_from_each_stale_cycle_to_the_next(tmp_path):
    # cycles every 2 ms; a camera stale from 0.010 to 0.020 s (cycles 5..9), the joints from
    # 0.030 s on (cycles 15..19); a person near (not stale) in between: 10 + 10 cycles of 2 ms,
    # the last cycle having no successor
    lines = []
    for k in range(20):
        reasons = {}
        if 5 <= k <= 9:
            reasons["stale:cam0"] = "camera cam0: no frame for more than 100 ms - stale data (R27)"
        if 11 <= k <= 13:
            reasons["near:ee"] = "a person"
        if k >= 15:
            reasons["stale:joints"] = "joint states: none for more than 50 ms - stale data (R27)"
        lines.append(json.dumps({"t": 0.002 * k, "reasons": reasons}))
    (tmp_path / "log.jsonl").write_text("\n".join(lines) + "\n")
    assert stale_seconds(tmp_path / "log.jsonl") == pytest.approx(0.002 * (5 + 4))


def test_stale_seconds_leaves_out_the_wait_for_the_first_frames_but_not_a_camera_that_never_came(tmp_path):
    # cycles every 2 ms: cam0 and cam1 have no frame yet in cycles 0..3, cam1 none in 4..6, then
    # cam0 goes stale (a late frame) in cycles 10..12
    def run(n_wait, never=False):
        lines = []
        for k in range(20):
            reasons = {}
            if k < n_wait or never:
                reasons["stale:cam1"] = "camera cam1: no frame yet - stale data (R27)"
            if k < 4:
                reasons["stale:cam0"] = "camera cam0: no frame yet - stale data (R27)"
            if 10 <= k <= 12:
                reasons["stale:cam0"] = "camera cam0: no frame for more than 100 ms - stale data (R27)"
            lines.append(json.dumps({"t": 0.002 * k, "reasons": reasons}))
        path = tmp_path / f"log{n_wait}{never}.jsonl"
        path.write_text("\n".join(lines) + "\n")
        return stale_seconds(path)

    assert run(7) == pytest.approx(0.002 * 3)            # from cycle 7 on: only the late frame
    assert run(7, never=True) == pytest.approx(0.002 * 19)  # cam1 never came: every cycle counts


def test_the_rig_file_of_a_run_is_the_cells_with_the_setting_changed(tmp_path):
    from depthguard.rig import Rig
    from depthguard.sim import load_cell

    path = _rig_file("ur3-cell", tmp_path, fusion_duty=0.3)
    rig = Rig.load(path)
    shipped = load_cell("ur3-cell").rig
    assert rig.monitor.fusion_duty == 0.3
    assert rig.monitor.with_changes(fusion_duty=shipped.monitor.fusion_duty) == shipped.monitor
    assert [c.id for c in rig.cameras] == [c.id for c in shipped.cameras]
    assert len(rig.static_meshes()) == len(shipped.static_meshes())      # the STL found through the link


def test_the_runs_text_gives_every_run_and_how_many_met_the_goal():
    from depthguard.evaluation.bench.availability import GOAL_S, _runs_text

    assert GOAL_S == 0.3
    assert _runs_text([0.0, 2.786, 0.3, 0.301]) == "runs 0.00, 2.79, 0.30, 0.30 s (2 of 4 <= 0.3 s)"
