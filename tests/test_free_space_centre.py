"""The free-space map's centre-pixel update from the cameras' own images (R21, R9, R30; issue 30).

The update reads each camera's pairs in pixel order straight from the caller's image and tests the
robot pixels per pair from the robot's rendered depth. Two independent truths for its counts and
verdicts: the flat-buffer kernel (``free_space_update``: every image copied into one buffer, a robot
pixel's depth negated there, pairs in voxel order, parallel over voxel chunks) and the plain-numpy
twin, both fed with buffers built here from the robot pixels' definition. Scenes are Embree
renders (``tests/test_free_space.py``) with noise, holes, NaN, negative depths and returns beyond
the rated range; one camera gives a float64 image, one gives none, one has no robot depth.
"""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.camera import RETURN_LIMIT_FACTOR, Camera
from depthguard.fusion.free_space import FreeSpaceMap
from depthguard.fusion.free_space_kernels import (free_space_update, free_space_update_numpy, robot_pixels_numpy,
                                                  voxel_counts_numpy, voxel_states, voxel_states_numpy)
from test_free_space import BOX, FLOOR, HI, LO, S, embree_depth, floor_background, four_cams

OFFSET = 0.05


def _scene(rng, cams):
    """Per camera: depth (float32; camera c1's as float64) and the robot (the box) rendered alone."""
    depths, robots = {}, {}
    for c in cams:
        d = embree_depth(c, [BOX, ((0.4, -0.8, 0.0), (0.7, -0.5, 1.1)), FLOOR])
        d += rng.normal(0, 0.01, d.shape).astype(np.float32) * (d > 0)
        d[rng.random(d.shape) < 0.04] = 0.0
        d[rng.random(d.shape) < 0.01] = np.nan
        d[rng.random(d.shape) < 0.01] *= -1.0                                   # negative: invalid
        far = rng.random(d.shape) < 0.02
        d[far] = rng.uniform(0.9, 1.2 * RETURN_LIMIT_FACTOR, far.sum()) * c.max_range   # beyond the rated range
        depths[c.id] = d.astype(np.float64) if c.id == "c1" else d
        robots[c.id] = embree_depth(c, [BOX])
    return depths, robots


def _signed(cams, depths, masks):
    """The flat buffer's images: negatives 0 (NaN kept), a robot pixel's depth negated; zeros for
    a camera without an image."""
    out = []
    for c in cams:
        if c.id not in depths:
            out.append(np.zeros(c.shape, np.float32))
            continue
        y = np.maximum(depths[c.id], 0.0).astype(np.float32)
        m = masks.get(c.id)
        out.append(y if m is None else np.where(m, -y, y))
    return out


@pytest.mark.parametrize("background", [False, True])
def test_centre_update_equals_the_flat_buffer_kernel_and_the_twin(background):
    rng = np.random.default_rng(11)
    cams = four_cams()
    c3 = cams[3]                                    # min_range 0: its missing image is read as zeros
    cams[3] = Camera(c3.id, c3.width, c3.height, c3.fx, c3.fy, c3.cx, c3.cy,
                     world_from_camera=c3.world_from_camera, min_range=0.0, max_range=c3.max_range)
    lo = LO - np.array([0.0, 0.0, 0.2]) if background else LO
    fs = FreeSpaceMap(cams, bounds=(lo, HI), voxel_size=S / 2, margin=0.02,
                      margin_growth={"c0": 0.004, "c2": 0.002})
    if background:
        fs.set_background({c.id: floor_background(c) for c in cams[:3]}, tolerance=0.05)
    kw = fs.background_twin_args()
    depths, robots = _scene(rng, cams)
    robots.pop("c2")                                # no robot depth for c2
    for missing in (None, "c0", "c3"):
        given = {k: v for k, v in depths.items() if k != missing}
        occ = fs.update_robot_depth(given, robots, OFFSET).ravel().copy()
        nf, ns = (a.ravel().copy() for a in fs.counts())
        masks = {k: robot_pixels_numpy(given[k], robots[k], OFFSET) for k in robots if k in given}
        signed = _signed(cams, given, masks)
        # truth 1: the flat-buffer kernel on the buffer built here
        kf, ks = np.zeros_like(nf), np.zeros_like(ns)
        kfree, kocc = np.zeros(len(nf), bool), np.ones(len(nf), bool)
        free_space_update(np.concatenate([s.ravel() for s in signed]), fs.offs, fs.widths, fs.heights, fs.rmin,
                          fs.rmax, fs.vstart, fs.chunk, fs.vox, fs.pix, fs.zc, fs.ru, fs.rv, fs.half, fs.far,
                          fs._bg, fs.background_tolerance, fs._use_bg, fs.margin, fs.grow, fs.min_free_views,
                          False, False, kf, ks, kfree, kocc)
        assert np.array_equal(nf, kf) and np.array_equal(ns, ks) and np.array_equal(occ, kocc)
        # truth 2: the numpy twin
        tf, ts = voxel_counts_numpy(signed, fs.grid.size, *fs.twin_args(), fs.margin, False, **kw)
        assert np.array_equal(nf, tf) and np.array_equal(ns, ts)
        assert np.array_equal(occ, free_space_update_numpy(signed, fs.grid.size, *fs.twin_args(), fs.margin,
                                                           fs.min_free_views, **kw))
        # the same robot pixels given as masks: the same map
        assert np.array_equal(fs.update(given, robot=masks).ravel(), occ)
        assert np.array_equal(fs.counts()[1].ravel(), ns)
        # not a vacuous case: the robot's pixels dropped surfaces, both rules are exercised
        plain = voxel_counts_numpy(_signed(cams, given, {}), fs.grid.size, *fs.twin_args(), fs.margin, False, **kw)[1]
        assert (ns < plain).sum() > 20 and (nf >= 3).any() and ((nf >= 1) & (ns >= 1)).any()


def test_pairs_in_pixel_order_are_the_maps_pairs():
    fs = FreeSpaceMap(four_cams(), bounds=(LO, HI), voxel_size=S)
    cp = fs._centre
    for ci in range(len(fs.cameras)):
        a, b = fs.start[ci], fs.start[ci + 1]
        assert np.all(np.diff(cp.spix[a:b]) >= 0)                      # the image read front to back
        mine = np.rec.fromarrays([cp.spix[a:b], cp.svox[a:b], cp.szc[a:b]])
        model = np.rec.fromarrays([fs.pix[a:b] - fs.offs[ci], fs.vox[a:b], fs.zc[a:b]])
        assert np.array_equal(np.sort(mine), np.sort(model))


def test_voxel_states_kernel_equals_twin():
    rng = np.random.default_rng(2)
    occ = rng.random(5000) < 0.6
    ns = rng.integers(0, 3, 5000).astype(np.uint8)
    out = voxel_states(occ, ns, 0, 1, 2, np.empty(5000, np.uint8))
    assert np.array_equal(out, voxel_states_numpy(occ, ns, 0, 1, 2))
    assert set(np.unique(out)) == {0, 1, 2}


def test_robot_depth_bad_input():
    cams = four_cams()
    fs = FreeSpaceMap(cams, bounds=(LO, HI), voxel_size=S)
    d = {c.id: np.ones(c.shape, np.float32) for c in cams}
    with pytest.raises(ValueError, match="robot depth for camera 'c0' has shape"):
        fs.update_robot_depth(d, {"c0": np.ones((3, 3), np.float32)}, OFFSET)
    with pytest.raises(ValueError, match="unknown camera ids"):
        fs.update_robot_depth(d, {"nope": np.ones((3, 3), np.float32)}, OFFSET)
