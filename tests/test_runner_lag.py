"""A real-time run notes each frame's age when its source hands it over (``frame_lag_at_push_ms``,
issue 29), and a long run keeps only the newest ages (``TIMING_KEEP``), not one float per frame
for ever. Truth: the frames' own capture stamps and the run's clock."""

from __future__ import annotations

import math

from depthguard.runtime import runner
from depthguard.runtime.monitor import Monitor, warm_up
from depthguard.runtime.runner import run, summarise
from depthguard.sim import load_cell
from depthguard.sources.base import open_joints, open_source


def test_the_ages_at_hand_over_are_kept_within_bounds(monkeypatch):
    rig = load_cell("flacco-cell").rig
    cfg = rig.monitor
    warm_up(rig, cfg)
    monkeypatch.setattr(runner, "TIMING_KEEP", 6)            # a long run, in a short one
    context: dict = {}
    frames = open_source("sim:flacco-cell:alone:noiseless", rig, context)
    joints = open_joints("sim", rig, context)
    with Monitor(rig, cfg) as mon:
        stats, wall = run(mon, [frames], joints, duration=0.8)
        summary = summarise(mon, stats, wall, {})
    lags = stats.lag_at_push
    assert set(lags) == set(rig.camera_ids)
    for cid, ages in lags.items():
        # 0.8 s at 30 Hz is ~24 frames a camera: trimmed to the newest half whenever above 6
        assert 1 <= len(ages) <= 6, (cid, ages)
        assert all(math.isfinite(a) and 0.0 <= a < wall for a in ages), ages     # after capture, within the run
        assert summary["frame_lag_at_push_ms"][cid]["frames"] == len(ages)
        assert summary["stats"]["cameras"][cid]["frames"] > 6                    # more were pushed than kept
