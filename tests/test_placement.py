"""Sensor placement criterion (R23) on hand-built camera sets: truth by hand-computed angles."""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.camera import Camera
from depthguard.evaluation.placement import (azimuths, candidate_cameras, greedy_placement,
                                             passes_criterion, passes_criterion_numpy,
                                             share_vs_cameras, visibility)
from depthguard.geometry import Box
from depthguard.transforms import look_at


def ring(angles_deg, r=2.5, z=2.2, target=(0.0, 0.0, 0.5)):
    cams = []
    for k, a in enumerate(np.deg2rad(angles_deg)):
        eye = np.array([r * np.cos(a), r * np.sin(a), z])
        cams.append(Camera(f"c{k}", 160, 120, 100.0, 100.0, 79.5, 59.5, look_at(eye, target),
                           min_range=0.3, max_range=8.0))
    return cams


P = np.array([[0.0, 0.0, 0.5]])


@pytest.mark.parametrize("angles, expected", [
    ([0, 120, 240], True),
    ([0, 110, 230], True),        # gaps 110, 120, 130
    ([0, 100, 200], True),        # gaps 100, 100, 160: exactly 100 passes
    ([0, 90, 200], False),        # 0-90 too close, 90-200 ok, 200-0 ok: no triple
    ([0, 90, 180, 270], False),   # four cameras, but any three include a 90 deg pair
    ([0, 60, 130, 250], True),    # the triple 0/130/250 (gaps 130, 120, 110)
    ([0, 120], False),            # two cameras are not enough
])
def test_criterion_on_a_ring(angles, expected):
    cams = ring(angles)
    seen = visibility(cams, P)
    assert seen.all()
    az = azimuths(cams, P)
    assert np.allclose(np.rad2deg(az[:, 0]) % 360, np.asarray(angles) % 360)
    assert passes_criterion(seen, az)[0] == expected
    assert passes_criterion_numpy(seen, az)[0] == expected


def test_static_occluder_removes_a_view():
    cams = ring([0, 120, 240])
    wall = Box.from_bounds([1.0, -0.3, 0.0], [1.1, 0.3, 2.0]).mesh()  # between cam c0 and P
    seen = visibility(cams, P, [wall])
    assert seen[:, 0].tolist() == [False, True, True]
    assert not passes_criterion(seen, azimuths(cams, P))[0]


def test_out_of_view_and_range():
    cams = ring([0, 120, 240])
    far = np.array([[30.0, 0.0, 0.5]])   # beyond max_range / outside the images
    assert not visibility(cams, far).any()


def test_kernel_matches_numpy_twin_random():
    rng = np.random.default_rng(0)
    C, N = 9, 3000
    seen = rng.random((C, N)) < 0.6
    az = rng.uniform(-np.pi, np.pi, (C, N))
    for sep in (100.0, 115.0):
        assert np.array_equal(passes_criterion(seen, az, min_separation_deg=sep),
                              passes_criterion_numpy(seen, az, min_separation_deg=sep))


def test_greedy_reaches_target_on_a_small_room():
    template = Camera("t", 160, 120, 100.0, 100.0, 79.5, 59.5, np.eye(4), 0.3, 8.0)
    cands = candidate_cameras([-2, -2, 0], [2, 2, 2.8], target=(0, 0, 0.8), template=template,
                              spacing=1.0)
    g = np.stack(np.meshgrid(*[np.linspace(-0.8, 0.8, 5)] * 2, [0.5, 1.2], indexing="ij"), -1).reshape(-1, 3)
    seen = visibility(cands, g)
    az = azimuths(cands, g)
    res = greedy_placement(seen, az, cands, target_share=1.0)
    assert res.final_share == 1.0
    assert 3 <= len(res.chosen) <= 8
    # independent check with the twin, and pruning leaves no redundant camera
    assert passes_criterion_numpy(seen[res.chosen], az[res.chosen]).all()
    for c in res.chosen:
        rest = [x for x in res.chosen if x != c]
        assert not passes_criterion_numpy(seen[rest], az[rest]).all()
    curve = share_vs_cameras(seen, az, res.chosen)
    assert curve[-1] == 1.0 and curve[0] == 0.0
