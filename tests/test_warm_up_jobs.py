"""``depthguard warm-up``'s grid job (R29): the flat frames' per-pixel states it hands to
``set_frames`` are the ones the grid works out itself, so the job compiles the grid's lookup and
not the frame classification (the other process's job compiles that one, side by side).

Truth: the same grid loaded from the same frames with ``set_frames`` working the states out
(its own classification kernels): equal per-pixel states, pyramids and query answers.
"""

from __future__ import annotations

import numpy as np

from depthguard.cli.warm_up import _flat_grid


def test_grid_job_states_are_the_grids_own_and_skip_the_classification():
    given, points, cfg = _flat_grid("flacco-cell")
    own, _, _ = _flat_grid("flacco-cell", states=False)
    n_cams = 1 + len(given.others)
    assert given.states_used == n_cams, "a state was worked out by set_frames: the classification compiles here"
    assert own.states_used == 0
    for name in ("_pfree", "_pkind", "_kfree", "_kpmin", "_kpmax"):
        assert np.array_equal(getattr(given, name), getattr(own, name)), name
    rng = np.random.default_rng(7)
    q = np.concatenate([points, points[:1] + rng.normal(0.0, 0.25, (300, 3))])
    a = given.query(q, rho=cfg.query_rho, method=cfg.method, threads=1)
    b = own.query(q, rho=cfg.query_rho, method=cfg.method, threads=1)
    assert np.isfinite(b.distance).any() and b.observed.any()      # the flat wall is within reach
    assert np.array_equal(a.distance, b.distance)
    assert np.array_equal(a.observed, b.observed)
    assert np.array_equal(a.direction, b.direction)

