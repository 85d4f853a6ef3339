"""The cameras' workers make their clearing of the depth grid's cells and the fusion installs it
(issue 29, :mod:`depthguard.runtime.camera_shares`).

Truth: the same monitor with the shares off (``monitor: camera_shares``, the default), fed the
same simulated frames and joints, cycle by cycle: the distances, directions and observed flags of
every control point are the same bit for bit; and the shares are made and installed when on (not
vacuous): every build after another camera's frame installs one; when off none is made, asked
for or installed.
"""

from __future__ import annotations

import numpy as np
from sim_feed import fed_frames


def _run(cell: str, shares_on: bool):
    from depthguard.runtime.monitor import Monitor
    from depthguard.sources.sim_source import SimFrames, SimWorld

    world = SimWorld(cell, seed=0)
    frames = SimFrames(world).frames_until(0.8)
    rig = world.rig
    assert rig.monitor.camera_shares is False                   # the default
    cfg = rig.monitor.with_changes(camera_shares=True) if shares_on else rig.monitor
    out = []
    with Monitor(rig, cfg) as mon, mon.replay():
        for f in fed_frames(mon, world, frames):
            r = mon.step(f.stamp + 0.004)
            out.append((r.distance.copy(), r.direction.copy(), r.observed.copy()))
        grid = mon.fusion.front.grid
        used, made = grid.shares_used, mon._shares.made
        assert grid.share_requests is shares_on
        principal = mon.camera_ids[0]
        # each camera's frames but its first two (its request is what the builds asked of its
        # frame before the last: none before its second frame is loaded)
        others = sum(1 for f in frames if f.camera_id != principal) - 2 * (len(mon.camera_ids) - 1)
        assert mon.fusion.errors == 0, mon.fusion.last_error
    return out, used, made, others


def test_the_workers_shares_give_the_same_reactions():
    """ur3-cell: three cameras other than the principal, a share each (one other camera:
    ``tests/test_depth_grid_share.py`` on flacco-cell)."""
    on, used, made, others = _run("ur3-cell", True)
    off, used_off, made_off, _ = _run("ur3-cell", False)
    assert used_off == 0 and made_off == 0
    assert made >= others and used >= others, (made, used, others)
    assert len(on) == len(off) >= 20
    for (d1, v1, o1), (d2, v2, o2) in zip(on, off):
        np.testing.assert_array_equal(d1, d2)
        np.testing.assert_array_equal(v1, v2)
        np.testing.assert_array_equal(o1, o2)
    assert any(np.isfinite(d).any() for d, _, _ in on)          # obstacles within reach: distances compared
