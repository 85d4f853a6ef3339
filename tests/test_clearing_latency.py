"""Clearing latency of the runtime's free-space map (R21, R37; issue 30 "done when": <= 0.2 s).

Truth: the simulator's person (``Person.primitives``, centre rule) on the map's voxels every 20 ms;
the map rebuilt at the product's 10 Hz from 30 Hz frames of ur3-cell's four cameras while the
person walks out of the workspace (``depthguard.evaluation.clearing_latency``, simulation time plus
each build's measured wall time). A sticky map, or one that waited for more than one update
after the cameras see the space free, fails.
"""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.evaluation.clearing_latency import clearing_latency, vacated_truth
from depthguard.geometry.voxel_grid import VoxelGrid
from depthguard.sim import load_cell


@pytest.mark.slow
@pytest.mark.realtime
def test_the_persons_last_voxel_is_free_in_the_published_map_within_0_2_s():
    r = clearing_latency(t0=10.4, t1=11.6, step=0.02, every_voxel=False)
    assert r["judged"] > 500 and r["judged"] >= 0.9 * r["vacated"]       # the person really leaves
    assert 10.4 < r["t_last_free_s"] < 11.6
    assert 0.0 < r["last_s"] <= 0.2, r


def test_vacated_truth_is_the_persons_own_geometry():
    cell = load_cell("ur3-cell")
    g = VoxelGrid(cell.rig.workspace.lo, cell.rig.workspace.hi, 0.05)
    vac, tf = vacated_truth(cell, g, "operator", 10.4, 11.6, step=0.1)
    p = next(q for q in cell.scene.people if q.name == "operator")
    c = g.centres().reshape(*g.shape, 3)
    idx = np.argwhere(vac)[::50]
    for i, j, k in idx:                      # inside the person just before, outside from t_free on
        t = tf[i, j, k]
        assert min(float(s.sdf(c[i, j, k][None])[0]) for s in p.primitives(t - 0.1)) <= 0.0
        assert all(float(s.sdf(c[i, j, k][None])[0]) > 0.0 for s in p.primitives(11.6))
    with pytest.raises(ValueError, match="no person"):
        vacated_truth(cell, g, "nobody", 10.4, 11.6)
