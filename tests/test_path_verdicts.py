"""Issue 30's "done when": 0 truly colliding motions judged safe on every built-in cell and
situation, with the product's defaults (R22, R37).

``depthguard.evaluation.path_verdicts`` (the table of ``python -m
depthguard.evaluation.path_verdicts``): per built-in cell with a robot and each of its
situations, the runtime's free-space map from the simulator's noisy frames (robot removed at the
frames' joints, the rig's ``monitor:`` defaults) and random joint paths from the robot's pose,
judged per segment. Truth: the scene's own geometry (``true_distance`` of the static objects,
people and props) at dense points along the robot's unpadded capsules at 10 poses per segment.
"""

from __future__ import annotations

import pytest

from depthguard.evaluation.path_verdicts import run
from depthguard.sim import list_cells, load_cell


@pytest.fixture(scope="module")
def rows():
    return run(paths=8, seed=3, log=lambda _m: None)


def test_every_cell_with_a_robot_and_every_situation_is_judged(rows):
    want = {(c, s) for c in list_cells() if load_cell(c).rig.robot is not None for s in load_cell(c).situations}
    assert {(r["cell"], r["situation"]) for r in rows} == want
    assert {"flacco-cell", "ur3-cell"} <= {c for c, _ in want}


def test_no_truly_colliding_segment_is_judged_safe(rows):
    assert sum(r["truly_colliding"] for r in rows) >= 20          # the paths do meet obstacles
    bad = {(r["cell"], r["situation"]): r["colliding_judged_safe"] for r in rows if r["colliding_judged_safe"]}
    assert not bad, bad
    # and the map is not merely all unknown: somewhere truly free segments are judged safe
    assert sum(r["free_judged_safe"] for r in rows) > 0
