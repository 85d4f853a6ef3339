"""FreeSpaceMap (R21) on hand-built scenes.

Depth images come from Embree ray casting (trimesh + embreex) through the
pixel centres — an independent truth for what a perfect camera measures.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector

import depthguard as dg
from depthguard.camera import Camera
from depthguard.fusion.free_space import FreeSpaceMap
from depthguard.fusion.free_space_kernels import (free_space_update_numpy, robot_pixels, robot_pixels_numpy,
                                                  voxel_counts_numpy)
from depthguard.geometry import Box, Capsule
from depthguard.geometry.voxel_grid import VoxelGrid
from depthguard.transforms import look_at

LO = np.array([-1.0, -1.0, 0.0])
HI = np.array([1.0, 1.0, 1.2])
S = 0.1


def cam_at(name, eye, target=(0.0, 0.0, 0.4), w=160, h=120, f=110.0):
    return Camera(name, w, h, f, f, (w - 1) / 2, (h - 1) / 2,
                  world_from_camera=look_at(np.asarray(eye, float), np.asarray(target, float)),
                  min_range=0.2, max_range=8.0)


def embree_depth(cam: Camera, boxes: list[tuple]) -> np.ndarray:
    """Depth (z along the optical axis) of the nearest hit through each pixel centre; 0 = none."""
    meshes = [trimesh.creation.box(bounds=np.array([lo, hi], float)) for lo, hi in boxes]
    mesh = trimesh.util.concatenate(meshes)
    d_c = cam.ray_directions().reshape(-1, 3)
    d_w = d_c @ cam.world_from_camera[:3, :3].T
    o = np.repeat(cam.position[None], len(d_w), axis=0)
    locs, ray_idx, _ = RayMeshIntersector(mesh).intersects_location(o, d_w, multiple_hits=False)
    depth = np.zeros(len(d_w))
    z = (locs - cam.position) @ cam.world_from_camera[:3, 2]
    depth[ray_idx] = z
    return depth.reshape(cam.shape).astype(np.float32)


# a floor slab below the box (its top at z = 0) so every ray ends on a surface
FLOOR = ((-3.0, -3.0, -0.2), (3.0, 3.0, 0.0))
BOX = ((-0.25, -0.2, 0.0), (0.25, 0.2, 0.5))  # on the floor, voxel-aligned at 5 cm and 10 cm


def four_cams():
    return [cam_at(f"c{k}", (2.4 * np.cos(a), 2.4 * np.sin(a), 2.0))
            for k, a in enumerate(np.deg2rad([0.0, 95.0, 190.0, 280.0]))]


def truth_occupied(grid: VoxelGrid, boxes) -> np.ndarray:
    c = grid.centres()
    inside = np.zeros(len(c), bool)
    for lo, hi in boxes:
        inside |= np.all((c > np.asarray(lo)) & (c < np.asarray(hi)), axis=1)
    return inside.reshape(grid.shape)


def test_public_name_and_voxel_convention():
    fs = dg.FreeSpaceMap(four_cams(), bounds=(LO, HI), voxel_size=S)
    assert fs.shape == (20, 20, 12)
    c = fs.grid.centres().reshape(20, 20, 12, 3)
    # voxel (i, j, k) spans lo + [i, i+1) * s: its centre is lo + (i + 1/2) s
    assert np.allclose(c[3, 7, 5], LO + (np.array([3, 7, 5]) + 0.5) * S)
    assert fs.occupied.all()  # starts all occupied


def test_box_seen_by_four_cameras_interior_occupied_open_space_free():
    cams = four_cams()
    fs = FreeSpaceMap(cams, bounds=(LO, HI), voxel_size=S, margin=0.0)
    depths = {c.id: embree_depth(c, [BOX, FLOOR]) for c in cams}
    occ = fs.update(depths).copy()
    truth = truth_occupied(fs.grid, [BOX])
    # every voxel whose centre is inside the box stays occupied (no object seen as free)
    assert occ[truth].all()
    # open space well away from the box and above the floor is free, judged voxel by voxel:
    # a free voxel must be free if some camera sees its whole depth extent in front of the
    # surface; check the bulk: voxels farther than 2 voxels from the box and not in the
    # bottom layer (the floor's surface layer is seen as a surface) and seen by >= 1 camera
    c = fs.grid.centres()
    gap = np.maximum(np.abs(c[:, :2]) - np.array([0.25, 0.2]), 0).max(axis=1).reshape(fs.shape)
    far = (gap > 2 * S) & (np.arange(fs.shape[2])[None, None, :] >= 1)
    seen = fs.view_counts() >= 1
    assert (far & seen).sum() > 2000
    assert not occ[far & seen].any()
    # voxels never seen by any camera stay occupied (unknown is obstacle)
    assert occ[~seen].all()


def test_surface_needs_three_free_views_to_overrule():
    # one camera sees a surface in a voxel; n other cameras see it free
    cams = four_cams()
    fs = FreeSpaceMap(cams, bounds=(LO, HI), voxel_size=S, margin=0.0)
    # open scene: only the floor; every camera sees every visible voxel above the floor free
    base = {c.id: embree_depth(c, [FLOOR]) for c in cams}
    target = (10, 10, 6)  # voxel centre (0.05, 0.05, 0.65)
    flat = np.ravel_multi_index(target, fs.shape)
    assert all(fs.projection(flat, ci) is not None for ci in range(len(cams)))

    def with_surface(img, ci):
        # put the measured depth of camera ci's pixel of the voxel at the voxel centre depth
        img = img.copy()
        p, z = fs.projection(flat, ci)
        img.reshape(-1)[p] = z
        return img

    for n_free in (0, 1, 2, 3):
        depths = {}
        for ci, c in enumerate(cams):
            if ci == 0:
                depths[c.id] = with_surface(base[c.id], 0)
            elif ci <= n_free:
                depths[c.id] = base[c.id]
            else:  # this camera says nothing about the voxel: its pixel is invalid
                img = base[c.id].copy()
                img.reshape(-1)[fs.projection(flat, ci)[0]] = 0.0
                depths[c.id] = img
        occ = fs.update(depths)
        assert occ[target] == (n_free < 3), n_free
    # and with no surface seen, one free view is enough ("once free, free")
    depths = {c.id: base[c.id] for c in cams[:1]}
    assert not fs.update(depths)[target]


def test_hidden_voxel_is_not_set_back_by_an_occluded_camera():
    # a camera whose view of the voxel is blocked (surface in front of it) does not undo
    # another camera's free verdict: occlusion is "no information", not "surface"
    cams = four_cams()
    fs = FreeSpaceMap(cams[:2], bounds=(LO, HI), voxel_size=S)
    target = (10, 10, 6)
    flat = np.ravel_multi_index(target, fs.shape)
    d0 = embree_depth(cams[0], [FLOOR])
    d1 = embree_depth(cams[1], [FLOOR])
    p, z = fs.projection(flat, 1)
    d1.reshape(-1)[p] = z - 0.5  # occluder well in front of the voxel
    assert not fs.update({"c0": d0, "c1": d1})[target]


def test_invalid_pixels_never_free_anything():
    cams = four_cams()
    fs = FreeSpaceMap(cams, bounds=(LO, HI), voxel_size=S)
    for bad in (0.0, np.nan, np.inf, 100.0, 0.1):  # no return, NaN, inf, beyond / below range
        depths = {c.id: np.full(c.shape, bad, np.float32) for c in cams}
        assert fs.update(depths).all(), bad


@pytest.mark.parametrize("full", [False, True])
def test_a_return_beyond_the_rated_range_frees_up_to_it_and_marks_no_surface(full):
    """R28 (issue 30), as the product's distances read it: a depth in ``(max_range, 3 max_range]``
    is free up to ``max_range`` and unknown behind — the same free voxels as a measurement at
    ``max_range`` itself, and no surface anywhere; farther than that it is invalid."""
    cams = [cam_at(f"c{k}", (2.4 * np.cos(a), 2.4 * np.sin(a), 2.0)) for k, a in enumerate([0.0, 2.0])]
    cams = [Camera(c.id, c.width, c.height, c.fx, c.fy, c.cx, c.cy, world_from_camera=c.world_from_camera,
                   min_range=0.2, max_range=2.8) for c in cams]       # the box's far side lies beyond 2.8 m
    fs = FreeSpaceMap(cams, (LO, HI), S, footprint="full" if full else "centre")
    beyond = ~fs.update({c.id: np.full(c.shape, 6.0, np.float32) for c in cams}).copy()
    _, ns = fs.counts()
    assert ns.sum() == 0
    at = ~fs.update({c.id: np.full(c.shape, 2.8, np.float32) for c in cams}).copy()
    assert beyond.any() and not beyond.all() and np.array_equal(beyond, at)
    assert fs.update({c.id: np.full(c.shape, 9.0, np.float32) for c in cams}).all()     # > 3 x 2.8 m
    imgs = [np.full(c.shape, 6.0, np.float32) for c in cams]
    ref = free_space_update_numpy(imgs, fs.grid.size, *fs.twin_args(), fs.margin, fs.min_free_views, full=full)
    assert np.array_equal(~beyond.ravel(), ref)


def test_machine_volume_is_free():
    cams = four_cams()
    fs = FreeSpaceMap(cams, bounds=(LO, HI), voxel_size=S)
    machine = [Capsule.between([-0.5, 0.0, 0.6], [0.5, 0.0, 0.6], radius=0.15),
               Box.from_bounds([0.3, 0.3, 0.0], [0.6, 0.6, 0.9])]
    boxes = [((-0.65, -0.15, 0.45), (0.65, 0.15, 0.75)), ((0.3, 0.3, 0.0), (0.6, 0.6, 0.9)), FLOOR]
    depths = {c.id: embree_depth(c, boxes) for c in cams}
    fs.update(depths)
    mask = fs.add_free_volume(machine)
    occ = fs.occupied
    c = fs.grid.centres()
    inside = np.zeros(len(c), bool)
    for p in machine:
        inside |= p.sdf(c) <= 0
    inside = inside.reshape(fs.shape)
    assert inside.sum() > 50
    assert mask[inside].all() and not occ[inside].any()
    # touched = every voxel the machine meets: a voxel whose centre is within s/2 of the
    # capsule surface along an axis (so the cube certainly meets it) is included
    near = np.zeros(len(c), bool)
    for p in machine:
        near |= p.sdf(c) <= S / 2
    assert mask[near.reshape(fs.shape)].all()
    # and nothing farther than half a diagonal from it
    far = np.ones(len(c), bool)
    for p in machine:
        far &= p.sdf(c) > S * np.sqrt(3) / 2 + 1e-9
    assert not mask[far.reshape(fs.shape)].any()
    # the next update forgets the machine (it moves)
    fs.update(depths)
    assert not fs.machine.any()


def test_accumulate_keeps_free_until_reset():
    cams = four_cams()
    fs = FreeSpaceMap(cams, bounds=(LO, HI), voxel_size=S)
    open_ = {c.id: embree_depth(c, [FLOOR]) for c in cams}
    person = ((0.2, 0.2, 0.0), (0.5, 0.5, 1.0))
    crowded = {c.id: embree_depth(c, [person, FLOOR]) for c in cams}
    t = truth_occupied(fs.grid, [person])
    free_open = ~fs.update(open_).copy()
    assert free_open[t].sum() > 20
    occ_acc = fs.update(crowded, accumulate=True).copy()  # sticky: still free from before
    assert not occ_acc[t & free_open].any()
    occ_now = fs.update(crowded).copy()        # snapshot (default): the person is an obstacle
    assert occ_now[t].all()
    fs.reset()
    assert fs.occupied.all()


@pytest.mark.parametrize("full,background", [(False, False), (True, False), (False, True)])
@pytest.mark.parametrize("depth_test", ["centre", "extent"])
def test_kernel_matches_numpy_twin(full, background, depth_test):
    rng = np.random.default_rng(3)
    cams = four_cams()
    # with a background the box reaches into the floor: voxels inside the shell exist
    # (5 cm voxels: centres 2.5 cm above the floor, where noise puts the floor inside them)
    lo = LO - np.array([0.0, 0.0, 0.2]) if background else LO
    fs = FreeSpaceMap(cams, bounds=(lo, HI), voxel_size=S / 2 if background else S, margin=0.02,
                      footprint="full" if full else "centre", depth_test=depth_test)
    boxes = [BOX, ((0.4, -0.8, 0.0), (0.7, -0.5, 1.1)), FLOOR]
    imgs = []
    for c in cams:
        d = embree_depth(c, boxes)
        d += rng.normal(0, 0.01, d.shape).astype(np.float32) * (d > 0)
        d[rng.random(d.shape) < 0.05] = 0.0
        d[rng.random(d.shape) < 0.01] = np.nan
        imgs.append(d)
    if background:
        bgs = {c.id: floor_background(c) for c in cams}
        bgs["c3"] = bgs["c3"].copy()
        bgs["c3"][:, :40] = 0.0          # part of one image without a background
        fs.set_background(bgs, tolerance=0.05)
    occ = fs.update({c.id: d for c, d in zip(cams, imgs)}).ravel().copy()
    kw = fs.background_twin_args()
    assert bool(kw) == background
    ref = free_space_update_numpy(imgs, fs.grid.size, *fs.twin_args(), fs.margin, fs.min_free_views,
                                  full=full, **kw)
    assert np.array_equal(occ, ref)
    # the rule is exercised both ways: some voxels freed with a surface seen (>= 3 free views)
    nf, ns = voxel_counts_numpy(imgs, fs.grid.size, *fs.twin_args(), fs.margin, full, **kw)
    knf, kns = fs.counts()
    assert np.array_equal(knf.ravel(), nf) and np.array_equal(kns.ravel(), ns)
    assert ((nf >= 1) & (nf < 3) & (ns >= 1)).any() and (nf >= 1).sum() > 500
    if not full:
        assert ((nf >= 3) & (ns >= 1)).any()
    if background:
        # the background changed the counts: shell matches dropped; never a free view more
        nf0, ns0 = voxel_counts_numpy(imgs, fs.grid.size, *fs.twin_args(), fs.margin, full)
        assert (ns < ns0).sum() > 100 and (nf <= nf0).all()
        # and removing it restores the plain rule exactly
        fs.set_background(None)
        occ0 = fs.update({c.id: d for c, d in zip(cams, imgs)}).ravel().copy()
        assert np.array_equal(occ0, free_space_update_numpy(imgs, fs.grid.size, *fs.twin_args(), fs.margin,
                                                            fs.min_free_views, full=full))


def floor_background(cam: Camera) -> np.ndarray:
    """Expected depth of the known shell (the floor slab), rendered with the project's renderer."""
    from depthguard.render import render_depth
    return render_depth(cam, [trimesh.creation.box(bounds=np.array(FLOOR, float))])


def test_background_frees_the_layer_on_the_floor_and_keeps_what_is_on_or_in_it():
    # 5 cm voxels, the box reaching 10 cm into the floor slab: layers k = 0, 1 lie inside the
    # floor, k = 2 (centres 2.5 cm above it) is the free layer along the floor
    cams = four_cams()
    s = 0.05
    lo = np.array([-1.0, -1.0, -0.1])
    plain = FreeSpaceMap(cams, bounds=(lo, HI), voxel_size=s, margin=0.02)
    shell = FreeSpaceMap(cams, bounds=(lo, HI), voxel_size=s, margin=0.02)
    shell.set_background({c.id: floor_background(c) for c in cams}, tolerance=0.02 + 3 * 0.01)
    # the background is the renderer's floor; the measurement (Embree) agrees with it
    for c in cams:
        e, b = embree_depth(c, [FLOOR]), floor_background(c)
        both = (e > 0) & (b > 0)
        assert both.mean() > 0.5 and np.percentile(np.abs(e - b)[both], 99) < 2e-3
    ideal = {c.id: embree_depth(c, [BOX, FLOOR]) for c in cams}
    truth = truth_occupied(plain.grid, [BOX, FLOOR])
    c = plain.grid.centres()
    gap = np.maximum(np.abs(c[:, :2]) - np.array([0.25, 0.2]), 0).max(axis=1).reshape(plain.shape)
    layer = np.zeros(plain.shape, bool)
    layer[:, :, 2] = True
    layer &= (gap > 2 * s) & (plain.view_counts() >= 1)
    assert layer.sum() > 500
    rng = np.random.default_rng(11)
    for trial in range(5):
        depths = {k: (d + rng.normal(0, 0.01, d.shape).astype(np.float32) * (d > 0)) for k, d in ideal.items()}
        occ_p = plain.update(depths).copy()
        occ_s = shell.update(depths).copy()
        # without the background the noise makes cameras measure the floor inside voxels of
        # the layer on it: part of it stays occupied; with the background it is free
        assert occ_p[layer].mean() > 0.02, trial
        assert occ_s[layer].mean() < 0.1 * occ_p[layer].mean(), trial
        # nothing that is truly occupied becomes free: the box's interior and the floor itself
        assert occ_s[truth].all(), trial
        assert occ_s[:, :, :2].all(), trial
        # the background only ever frees more (never occupies what the plain rule frees)
        assert not (occ_s & ~occ_p).any(), trial


def test_background_bad_input():
    cams = four_cams()
    fs = FreeSpaceMap(cams, bounds=(LO, HI), voxel_size=S)
    with pytest.raises(ValueError, match="unknown camera"):
        fs.set_background({"nope": np.zeros((120, 160), np.float32)})
    with pytest.raises(ValueError, match="shape"):
        fs.set_background({"c0": np.zeros((10, 10), np.float32)})
    with pytest.raises(ValueError, match="tolerance"):
        fs.set_background({}, tolerance=-1.0)
    full = FreeSpaceMap(cams, bounds=(LO, HI), voxel_size=S, footprint="full")
    with pytest.raises(ValueError, match="footprint"):
        full.set_background({})


def test_full_footprint_catches_a_thin_pole_the_centre_rule_misses():
    # a 2 cm pole off every voxel-centre ray: centre sampling frees voxels it passes through;
    # every pixel of the footprint with the extent depth test keeps them all occupied
    cams = four_cams()
    pole = ((0.515, 0.515, 0.0), (0.535, 0.535, 1.2))
    depths = {c.id: embree_depth(c, [pole, FLOOR]) for c in cams}
    centre = FreeSpaceMap(cams, bounds=(LO, HI), voxel_size=S, footprint="centre")
    full = FreeSpaceMap(cams, bounds=(LO, HI), voxel_size=S, footprint="full", depth_test="extent")
    i = int((0.525 - LO[0]) / S)
    j = int((0.525 - LO[1]) / S)
    col = (i, j, slice(2, 11))
    occ_c = centre.update(depths)[col].copy()
    occ_f = full.update(depths)[col].copy()
    assert occ_f.all()          # conservative: the pole's voxels stay occupied
    assert not occ_c.all()      # the paper's centre rule loses part of it


def test_bad_input():
    cams = four_cams()
    with pytest.raises(ValueError, match="voxel_size"):
        FreeSpaceMap(cams, bounds=(LO, HI), voxel_size=0.0)
    with pytest.raises(ValueError, match="hi must exceed lo"):
        FreeSpaceMap(cams, bounds=(HI, LO), voxel_size=S)
    with pytest.raises(ValueError, match="footprint"):
        FreeSpaceMap(cams, bounds=(LO, HI), voxel_size=S, footprint="corner")
    with pytest.raises(ValueError, match="unique"):
        FreeSpaceMap(cams + cams[:1], bounds=(LO, HI), voxel_size=S)
    fs = FreeSpaceMap(cams, bounds=(LO, HI), voxel_size=S)
    with pytest.raises(ValueError, match="unknown camera"):
        fs.update({"nope": np.zeros((120, 160), np.float32)})
    with pytest.raises(ValueError, match="shape"):
        fs.update({"c0": np.zeros((10, 10), np.float32)})


def test_extent_depth_test_never_frees_a_voxel_holding_a_seen_surface():
    # a thin plate through the far half of voxels: "centre" may free them, "extent" must not
    cams = four_cams()
    plate = ((-0.5, -0.5, 0.58), (0.5, 0.5, 0.59))   # inside layer k = 5 (0.5-0.6), above its centre
    depths = {c.id: embree_depth(c, [plate, FLOOR]) for c in cams}
    ext = FreeSpaceMap(cams, bounds=(LO, HI), voxel_size=S, depth_test="extent")
    occ = ext.update(depths)
    # cameras above look down: the plate is in front of (above) the layer-5 centres for
    # all of them; the layer-6 voxels just above are free, layer 5 under the plate occupied
    assert occ[6:14, 6:14, 5].all()
    cen = FreeSpaceMap(cams, bounds=(LO, HI), voxel_size=S, depth_test="centre")
    assert cen.update(depths)[6:14, 6:14, 5].all()
    # a plate below the centres (in the voxels' lower half): the centre test frees the
    # voxels (their centres are in front of it), the extent test keeps them occupied
    plate2 = ((-0.5, -0.5, 0.51), (0.5, 0.5, 0.52))
    depths2 = {c.id: embree_depth(c, [plate2, FLOOR]) for c in cams}
    assert ext.update(depths2)[6:14, 6:14, 5].all()
    assert not cen.update(depths2)[6:14, 6:14, 5].any()


@pytest.mark.parametrize("full, background", [(False, False), (False, True), (True, False)])
def test_robot_pixels_free_in_front_and_never_count_a_surface(full, background):
    """Issue 30: pixels that see the robot (here: the box, rendered alone) keep every free view
    and count no surface; kernel == numpy twin (the twin reads a robot pixel's depth negated)."""
    rng = np.random.default_rng(5)
    cams = four_cams()
    lo = LO - np.array([0.0, 0.0, 0.2]) if background else LO
    fs = FreeSpaceMap(cams, bounds=(lo, HI), voxel_size=S, margin=0.02, footprint="full" if full else "centre")
    if background:
        fs.set_background({c.id: floor_background(c) for c in cams}, tolerance=0.05)
    kw = fs.background_twin_args()
    imgs, masks = [], {}
    for c in cams:
        d = embree_depth(c, [BOX, FLOOR])
        d += rng.normal(0, 0.01, d.shape).astype(np.float32) * (d > 0)
        d[rng.random(d.shape) < 0.02] = 0.0
        robot = embree_depth(c, [BOX])
        masks[c.id] = robot_pixels(d, robot, 0.05, np.zeros(d.shape, bool))
        assert np.array_equal(masks[c.id], robot_pixels_numpy(d, robot, 0.05))
        imgs.append(d)
    plain = fs.update({c.id: d for c, d in zip(cams, imgs)}).ravel().copy()
    nf0, ns0 = (a.ravel().copy() for a in fs.counts())
    occ = fs.update({c.id: d for c, d in zip(cams, imgs)}, robot=masks).ravel().copy()
    nf, ns = (a.ravel().copy() for a in fs.counts())
    signed = [np.where(masks[c.id], -d, d) for c, d in zip(cams, imgs)]
    ref = free_space_update_numpy(signed, fs.grid.size, *fs.twin_args(), fs.margin, fs.min_free_views,
                                  full=full, **kw)
    assert np.array_equal(occ, ref)
    tnf, tns = voxel_counts_numpy(signed, fs.grid.size, *fs.twin_args(), fs.margin, full, **kw)
    assert np.array_equal(nf, tnf) and np.array_equal(ns, tns)
    assert np.array_equal(nf, nf0)                       # every free view kept
    assert (ns <= ns0).all() and (ns < ns0).sum() > 20   # the box's surface is no longer counted
    assert (occ <= plain).all()                          # nothing becomes occupied by it


def test_margin_grows_with_each_voxels_own_depth():
    """R17/R21 (issue 30): with ``margin_growth`` a camera's margin at a voxel is ``margin + g z^2``
    at the voxel's own centre depth ``z``. Truth: a camera 3 m above a floor, looking straight down,
    measures 3 m everywhere (a plane square to the optical axis), so a voxel whose centre is at
    height ``c`` (depth ``3 - c``) is seen free exactly when ``c > margin + g (3 - c)^2``."""
    H, m, g = 3.0, 0.002, 0.02
    T = np.eye(4)
    T[:3, :3] = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]]).T    # columns: x, y, optical axis down
    T[:3, 3] = (0.0, 0.0, H)
    cam = Camera("down", 160, 120, 110.0, 110.0, 79.5, 59.5, world_from_camera=T, min_range=0.2, max_range=8.0)
    depth = np.full((120, 160), H, np.float32)
    fs = FreeSpaceMap([cam], (LO, HI), 0.05, margin=m, margin_growth={"down": g})
    occ = fs.update({"down": depth}).copy()
    nviews = fs.view_counts() > 0
    c = fs.grid.centres()[:, 2].reshape(fs.grid.shape)
    truth_free = c > m + g * (H - c) ** 2
    assert truth_free[nviews].any() and (~truth_free[nviews]).any()       # the threshold lies in the box
    assert np.array_equal(~occ[nviews], truth_free[nviews])
    # one margin everywhere (the far end's) frees less; the numpy twin agrees with the kernel
    flat = FreeSpaceMap([cam], (LO, HI), 0.05, margin=m + g * H ** 2)
    assert (~flat.update({"down": depth})[nviews]).sum() < (~occ[nviews]).sum()
    ref = free_space_update_numpy([depth], fs.grid.size, *fs.twin_args(), fs.margin, fs.min_free_views,
                                  **fs.background_twin_args())
    assert np.array_equal(occ.ravel(), ref)
    with pytest.raises(ValueError, match="margin_growth"):
        FreeSpaceMap([cam], (LO, HI), 0.05, margin_growth={"nope": 0.1})
