"""FreeSpaceProduct (R21): the product's free-space map equals its pieces assembled by hand."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from depthguard.camera import Camera
from depthguard.fusion.free_space import FreeSpaceMap
from depthguard.fusion.free_space_product import (MARGIN_SIGMAS, STILL_FRAMES, TOLERANCE_SIGMAS,
                                                  FreeSpaceProduct, product_margins)
from depthguard.fusion.temporal import StillFusion
from depthguard.geometry import Box
from depthguard.render import render_depth
from depthguard.sensors import SENSOR_MODELS, sensor_model
from depthguard.transforms import look_at

LO = np.array([-1.0, -1.0, 0.0])
HI = np.array([1.0, 1.0, 1.2])
S = 0.1


def cam_at(name, eye, target=(0.0, 0.0, 0.4), w=120, h=90, f=85.0):
    return Camera(name, w, h, f, f, (w - 1) / 2, (h - 1) / 2,
                  world_from_camera=look_at(np.asarray(eye, float), np.asarray(target, float)),
                  min_range=0.2, max_range=8.0)


def small_scene():
    """Four cameras around a box on a floor slab; the floor is the known shell."""
    cams = [cam_at(f"c{k}", (2.4 * np.cos(a), 2.4 * np.sin(a), 2.0))
            for k, a in enumerate(np.deg2rad([0.0, 95.0, 190.0, 280.0]))]
    floor = Box.from_bounds((-3.0, -3.0, -0.2), (3.0, 3.0, 0.0), name="floor").mesh()
    box = Box.from_bounds((-0.25, -0.2, 0.0), (0.25, 0.2, 0.5), name="box").mesh()
    return cams, floor, box


def noisy_frames(cams, meshes, sigma, n, seed=3):
    """``n`` frames (dicts id -> (H, W) float32) of the still scene with Gaussian noise and a
    few dropouts (0)."""
    rng = np.random.default_rng(seed)
    ideal = {c.id: render_depth(c, meshes) for c in cams}
    out = []
    for _ in range(n):
        f = {}
        for cid, z in ideal.items():
            d = (z + rng.normal(0.0, sigma, z.shape)).astype(np.float32)
            d[(z <= 0) | (rng.random(z.shape) < 0.02)] = 0.0
            f[cid] = d
        out.append(f)
    return out


def test_product_map_equals_the_hand_assembled_one():
    cams, floor, box = small_scene()
    tof = sensor_model("tof")
    assert tof.sigma_z2 == 0.0 and tof.sigma_a > 0
    frames = noisy_frames(cams, [floor, box], tof.sigma_a, STILL_FRAMES)

    prod = FreeSpaceProduct(cams, (LO, HI), S, tof, [floor])
    occ = prod.update(frames).copy()

    # by hand: StillFusion of the frames, FreeSpaceMap with 2 fused sigma, the floor as
    # background with 5 fused sigma
    fusion = StillFusion.for_sensor(tof, 3)
    sig = fusion.sigma(0.0)
    fs = FreeSpaceMap(cams, (LO, HI), S, margin=2 * sig)
    fs.set_background({c.id: render_depth(c, [floor]) for c in cams}, tolerance=5 * sig)
    fused = {c.id: fusion.fuse([f[c.id] for f in frames]) for c in cams}
    ref = fs.update(fused).copy()

    assert occ.shape == fs.grid.shape and occ.dtype == bool
    assert np.array_equal(occ, ref)
    assert 0 < (~occ).sum() < occ.size          # something freed, something not
    for c in cams:
        np.testing.assert_array_equal(prod.backgrounds[c.id], render_depth(c, [floor]))
    assert prod.map.margin == fs.margin and prod.map.background_tolerance == fs.background_tolerance

    # a ready StillFusion gives the same map; the machine volume passes through
    prod2 = FreeSpaceProduct(cams, (LO, HI), S, fusion, [floor])
    assert np.array_equal(prod2.update(frames), ref)
    m = prod2.add_free_volume([Box.from_bounds((-0.25, -0.2, 0.0), (0.25, 0.2, 0.5))], padding=0.05)
    fs.add_free_volume([Box.from_bounds((-0.25, -0.2, 0.0), (0.25, 0.2, 0.5))], padding=0.05)
    assert m.any() and np.array_equal(prod2.machine, fs.machine)
    assert np.array_equal(prod2.occupied, fs.occupied)


def test_product_without_shell_has_no_background():
    cams, floor, box = small_scene()
    tof = sensor_model("tof")
    frames = noisy_frames(cams, [floor, box], tof.sigma_a, STILL_FRAMES, seed=5)
    prod = FreeSpaceProduct(cams, (LO, HI), S, tof)
    assert prod.backgrounds == {} and prod.map.background_twin_args() == {}
    fs = FreeSpaceMap(cams, (LO, HI), S, margin=prod.margin)
    assert np.array_equal(prod.update(frames), fs.update(prod.fuse(frames)))


def test_margins_are_two_and_five_fused_sigma():
    tof = sensor_model("tof")
    for n in (1, 3, 5):
        f = StillFusion.for_sensor(tof, n)
        margin, tol = product_margins(f)
        assert (MARGIN_SIGMAS, TOLERANCE_SIGMAS) == (2.0, 5.0)
        assert margin == pytest.approx(2 * f.factor * tof.sigma_a)
        assert tol == pytest.approx(5 * f.factor * tof.sigma_a)
    cams, floor, _ = small_scene()
    prod = FreeSpaceProduct(cams, (LO, HI), S, tof, [floor])
    assert prod.frames == STILL_FRAMES == 3
    assert prod.margin == pytest.approx(2 * prod.fusion.sigma(0.0))
    assert prod.tolerance == pytest.approx(5 * prod.fusion.sigma(0.0))
    assert 0.013 < prod.margin < 0.014           # 1 cm ToF, 3 frames: c_3 ≈ 0.670
    assert FreeSpaceProduct(cams, (LO, HI), S, tof, frames=5).margin < prod.margin


def test_depth_dependent_noise_is_refused():
    cams, floor, _ = small_scene()
    depth_dependent = [m for m in SENSOR_MODELS.values() if m.sigma_z2 > 0]   # structured light, stereo
    assert depth_dependent
    tof = sensor_model("tof")
    stereo_like = dataclasses.replace(tof, name="z2", sigma_z2=0.002)
    for sensor in [stereo_like, StillFusion(3, 0.0005, 0.002)] + depth_dependent:
        with pytest.raises(ValueError, match="depth-independent sensor noise"):
            FreeSpaceProduct(cams, (LO, HI), S, sensor, [floor])
        with pytest.raises(ValueError, match="sigma_z2"):
            product_margins(sensor if isinstance(sensor, StillFusion) else StillFusion.for_sensor(sensor, 3))


def test_bad_inputs():
    cams, floor, _ = small_scene()
    tof = sensor_model("tof")
    with pytest.raises(ValueError, match="differs"):
        FreeSpaceProduct(cams, (LO, HI), S, StillFusion.for_sensor(tof, 3), frames=5)
    with pytest.raises(ValueError, match="SensorModel"):
        FreeSpaceProduct(cams, (LO, HI), S, 0.01)
    prod = FreeSpaceProduct(cams, (LO, HI), S, tof, [floor])
    frames = noisy_frames(cams, [floor], tof.sigma_a, 2)
    with pytest.raises(ValueError, match="need 3 frames"):
        prod.update(frames)
    frames = noisy_frames(cams, [floor], tof.sigma_a, 3)
    del frames[2]["c1"]
    with pytest.raises(ValueError, match="no image of cameras"):
        prod.update(frames)
