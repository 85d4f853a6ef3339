"""The depth grid at the principal's binned pixel (R10, ``principal_bin``): the binned camera
against projection geometry, the state's binning against its numpy twin, and the grid's
answers against the scenes' analytic distances (the safety bound of R25 at the block's size)."""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.fusion.depth_grid import DepthGridMap
from depthguard.fusion.depth_grid_kernels import KIND_ROBOT, KIND_SURFACE, KIND_UNKNOWN
from depthguard.fusion.depth_grid_state import StateMaker, StateOptions, bin_state, bin_state_numpy
from depthguard.geometry.primitives import Box, Sphere, sdf_union
from depthguard.render import render_depth
from tests.test_depth_grid import _T, _cam, _eps, _room, _scene


@pytest.mark.parametrize("b", [2, 3])
def test_binned_camera_projects_into_the_block(b):
    """A world point falls in binned pixel ``(u // b, v // b)`` of the pixel ``(u, v)`` it falls in."""
    rng = np.random.default_rng(b)
    cam = _cam("a", (2.5, 0.3, 1.0), w=161, h=121)
    binned = cam.binned(b)
    assert binned.shape == (-(-121 // b), -(-161 // b))
    P = rng.uniform(-0.8, 0.8, (4000, 3))
    full = cam.world_to_depth_space(P)
    coarse = binned.world_to_depth_space(P)
    u = np.floor(full[:, 0] + 0.5).astype(int)
    v = np.floor(full[:, 1] + 0.5).astype(int)
    inside = (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    # away from the pixel borders (rounding of the two projections)
    away = (np.abs(full[:, 0] + 0.5 - np.round(full[:, 0] + 0.5)) > 1e-6) & \
           (np.abs(full[:, 1] + 0.5 - np.round(full[:, 1] + 0.5)) > 1e-6)
    sel = inside & away
    assert sel.sum() > 1000
    assert np.array_equal(np.floor(coarse[sel, 0] + 0.5).astype(int), u[sel] // b)
    assert np.array_equal(np.floor(coarse[sel, 1] + 0.5).astype(int), v[sel] // b)
    np.testing.assert_allclose(coarse[:, 2], full[:, 2])
    assert cam.binned(1) is cam


@pytest.mark.parametrize("b,shape", [(2, (48, 64)), (2, (47, 63)), (3, (50, 31))])
def test_bin_state_equals_numpy_twin(b, shape):
    rng = np.random.default_rng(sum(shape) + b)
    free = np.round(rng.uniform(0.3, 3.0, shape), 1)          # many ties within a block
    free[rng.random(shape) < 0.1] = np.inf
    kind = rng.choice(np.array([KIND_SURFACE, KIND_ROBOT, KIND_UNKNOWN], np.int8), shape)
    hb, wb = -(-shape[0] // b), -(-shape[1] // b)
    f, k = np.empty((hb, wb)), np.empty((hb, wb), np.int8)
    bin_state(free, kind, b, f, k)
    tf, tk = bin_state_numpy(free, kind, b)
    np.testing.assert_array_equal(f, tf)
    np.testing.assert_array_equal(k, tk)
    # a block's free depth is its nearest pixel's, a surface wins a tie
    j, i = 3, 5
    block = free[j * b:j * b + b, i * b:i * b + b]
    assert f[j, i] == block.min()
    kinds = kind[j * b:j * b + b, i * b:i * b + b][block == block.min()]
    assert (k[j, i] == KIND_SURFACE) == bool((kinds == KIND_SURFACE).any())


def test_binned_state_made_on_the_worker_gives_the_grids_answers():
    """The principal's binned state made off the build (the camera worker's share) gives the
    same answers as the grid binning it itself."""
    rng = np.random.default_rng(5)
    prims, cams, depths = _scene(rng, 2)
    opts = StateOptions(0.03, "unknown", "unknown", 0, 0)
    P = rng.uniform(-0.6, 0.6, (40, 3))
    answers = []
    for made in (False, True):
        grid = DepthGridMap(cams, "c0", 0.6, 5.0, 0.02, cache=False, principal_bin=2)
        states = {"c0": StateMaker(cams[0]).make(depths["c0"], None, opts, bin=2)} if made else None
        grid.set_frames(depths, robot_offset=0.03, states=states)
        answers.append(grid.query(P, rho=0.4).distance.copy())
        assert grid.states_used == (1 if made else 0)
    np.testing.assert_array_equal(answers[0], answers[1])


@pytest.mark.slow
@pytest.mark.parametrize("b", [2, 3, 4, 8])     # 3, 4, 8: what the grid budget chooses (grid_budget.py)
def test_property_random_scenes_binned(b):
    """R25 with the binned grid: reported <= true + eps for every point, eps the discretisation
    bound at the binned pixel (its footprint, not the camera's)."""
    rho, dd = 0.4, 0.03
    n = 0
    for seed in range(8):
        rng = np.random.default_rng(300 + seed)
        prims, cams, depths = _scene(rng, int(rng.integers(2, 4)))
        binned = DepthGridMap(cams, "c0", 0.6, 5.0, dd, cache=False, principal_bin=b)
        P = rng.uniform(-0.9, 0.9, (80, 3))
        truth = sdf_union(prims, P)
        P, truth = P[truth > 0.02], truth[truth > 0.02]
        corners = (P[:, None, :] + rho * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1)
                                                    for z in (-1, 1)])[None]).reshape(-1, 3)
        in_p = cams[0].in_view(corners).reshape(-1, 8).all(1)
        P, truth = P[in_p], truth[in_p]
        res = binned.distance(depths, P, rho, "hybrid")
        eps = _eps(binned.principal, P, rho, dd)
        rep = np.where(np.isfinite(res.distance), res.distance, np.inf)
        tr = np.where(truth <= rho, truth, np.inf)
        assert np.all(rep <= tr + eps), (seed, rep, tr)
        n += len(P)
    assert n >= 100


@pytest.mark.parametrize("b", [2, 4])
def test_binned_shadow_cleared_and_hidden_object_found(b):
    """Two cameras at 90 degrees (as in test_depth_grid): the binned grid still clears the
    occluder's shadow by the other camera and still finds an object hidden behind it."""
    a = _cam("a", (2.6, 0, 0.3))
    c = _cam("b", (0, 2.6, 0.3))
    occluder = Box(size=(0.1, 0.4, 0.4), world_from_local=_T(1.2, 0, 0))
    hidden = Sphere(radius=0.1, world_from_local=_T(-0.5, 0, 0))
    P = np.array([[0.0, 0.0, 0.0]])
    for scene in (_room() + [occluder], _room() + [occluder, hidden]):
        meshes = [p.mesh() for p in scene]
        depths = {k.id: render_depth(k, meshes) for k in (a, c)}
        grid = DepthGridMap([a, c], "a", 1.0, 4.6, 0.02, cache=False, principal_bin=b)
        two = grid.distance(depths, P, 0.6, "min")
        truth = sdf_union(scene, P)
        eps = _eps(grid.principal, P, 0.6, 0.02)
        if truth[0] > 0.6:
            assert np.isinf(two.distance[0])
        else:
            assert truth[0] - eps[0] <= two.distance[0] <= truth[0] + eps[0]


def test_bad_principal_bin_is_refused():
    cams = [_cam("a", (2.6, 0, 0.3)), _cam("b", (0, 2.6, 0.3))]
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ValueError, match="principal_bin"):
            DepthGridMap(cams, "a", 1.0, 4.6, 0.02, cache=False, principal_bin=bad)


@pytest.mark.parametrize("b", [2, 3])
def test_binned_state_in_one_pass_equals_numpy_twins(b):
    """The binned state made in one pass (:func:`frame_state_binned`, on the worker) is the
    plain-numpy frame state (R9, R28, R32) binned by the plain-numpy block rule, on a noisy
    frame with the robot, its silhouette and small gaps."""
    from depthguard.fusion import depth_grid_ref as ref
    from tests.test_depth_grid import _with_robot
    from tests.test_depth_grid_state import _noisy

    rng = np.random.default_rng(40 + b)
    prims, cams, depths = _scene(rng, 2)
    _a, _b, _c, depths, rdepths, _caps = _with_robot(prims, cams)
    depths = _noisy(rng, depths)
    cam = cams[0]
    for invalid, sil, gap in (("unknown", 4, 3), ("unknown", 0, 0), ("free", 0, 0)):
        st = StateMaker(cam).make(depths[cam.id], rdepths[cam.id], StateOptions(0.03, invalid, "unknown", sil, gap),
                                  bin=b)
        free, kind = ref.frame_state_numpy(cam, depths[cam.id], rdepths[cam.id], 0.03, invalid, False, sil, gap)
        tf, tk = bin_state_numpy(free, kind, b)
        assert st.bin == b and st.free.shape == cam.binned(b).shape
        np.testing.assert_array_equal(st.free, tf)
        np.testing.assert_array_equal(st.kind, tk)
