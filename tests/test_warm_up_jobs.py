"""``depthguard warm-up``'s grid job (R29): the flat frames' per-pixel states it hands to
``set_frames`` are the ones the grid works out itself, so the job compiles the grid's lookup and
not the frame classification (the other process's job compiles that one, side by side).

Truth: the same grid loaded from the same frames with ``set_frames`` working the states out
(its own classification kernels): equal per-pixel states, pyramids and query answers.
"""

from __future__ import annotations

import numpy as np

from depthguard.cli.warm_up import _flat_grid
from depthguard.fusion.depth_grid_state import pyramid_layout


def test_grid_job_states_are_the_grids_own_and_skip_the_classification():
    given, points, cfg = _flat_grid("flacco-cell")
    own, _, _ = _flat_grid("flacco-cell", states=False)
    n_cams = 1 + len(given.others)
    assert given.states_used == n_cams, "a state was worked out by set_frames: the classification compiles here"
    assert own.states_used == 0
    for name in ("_pfree", "_pkind"):
        assert np.array_equal(getattr(given, name), getattr(own, name)), name
    for k, cam in enumerate(given.others):          # what the kernels read of each other camera
        (fa, mina, maxa), (fb, minb, maxb) = given._views.arrays(k), own._views.arrays(k)
        assert fa.base is not given._kfree and fb.base is own._kfree     # the state's own, the grid's own
        H, W = cam.shape
        assert np.array_equal(fa[:H, :W], fb[:H, :W]), cam.id
        offs, _dims, n = pyramid_layout(H, W, given._koff.shape[1])
        lo = offs[1] if len(offs) > 1 else 0          # level 0 is never read
        assert np.array_equal(mina[lo:n], minb[lo:n]) and np.array_equal(maxa[lo:n], maxb[lo:n]), cam.id
    rng = np.random.default_rng(7)
    q = np.concatenate([points, points[:1] + rng.normal(0.0, 0.25, (300, 3))])
    a = given.query(q, rho=cfg.query_rho, method=cfg.method, threads=1)
    b = own.query(q, rho=cfg.query_rho, method=cfg.method, threads=1)
    assert np.isfinite(b.distance).any() and b.observed.any()      # the flat wall is within reach
    assert np.array_equal(a.distance, b.distance)
    assert np.array_equal(a.observed, b.observed)
    assert np.array_equal(a.direction, b.direction)

