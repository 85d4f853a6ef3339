"""Accuracy bookkeeping (R24) and the free-space bench group (quick mode)."""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.evaluation.accuracy import Confusion, cases, confusion, plot_case_slices


def test_confusion_counts_the_four_cases_of_table1():
    truth = np.zeros((4, 3, 2), bool)
    recon = np.zeros((4, 3, 2), bool)
    truth[0] = True                 # 6 occupied voxels
    recon[0, :2] = True             # 4 of them reconstructed occupied, 2 seen as free
    recon[3, 0] = True              # 2 free voxels seen as object
    c = confusion(recon, truth)
    assert (c.correct_free, c.free_as_object, c.correct_object, c.object_as_free) == (16, 2, 4, 2)
    assert c.free_accuracy == pytest.approx(16 / 18) and c.object_accuracy == pytest.approx(4 / 6)
    k = cases(recon, truth)
    assert [(k == i).sum() for i in (1, 2, 3, 4)] == [16, 2, 4, 2]
    # a mask leaves voxels out of every count
    m = np.ones_like(truth)
    m[3] = False
    c2 = confusion(recon, truth, mask=m)
    assert c2.free_as_object == 0 and c2.correct_free == 12
    assert (c + c2).correct_object == 8
    assert np.isnan(Confusion(0, 0, 0, 0).object_accuracy)
    with pytest.raises(ValueError, match="shape"):
        confusion(recon, truth[:2])


def test_case_picture(tmp_path):
    rng = np.random.default_rng(0)
    k = rng.integers(0, 5, (20, 20, 10)).astype(np.int8)
    p = plot_case_slices(k, [0, 0, 0], 0.1, tmp_path / "fig9.png", title="t")
    assert p.exists() and p.stat().st_size > 1000


@pytest.mark.slow
def test_bench_group_quick():
    from depthguard.evaluation.bench import BenchContext, load_groups
    rows = load_groups()["freespace"](BenchContext(quick=True, repeats=3))
    names = {r.name: r for r in rows}
    assert "freespace.21cam.5cm_ms" in names and "freespace.21cam.10cm_ms" in names
    r = names["freespace.21cam.5cm_ms"]
    assert r.value > 0 and r.peer == "numpy twin" and r.peer_value > 0


def test_calibration_disturbance_stays_within_bounds():
    from depthguard.camera import Camera
    from depthguard.evaluation.hamersma2011 import perturbed_cameras
    from depthguard.transforms import look_at
    cams = [Camera(f"c{k}", 64, 48, 50.0, 50.0, 31.5, 23.5, look_at([2.0, k * 0.5, 2.0], [0, 0, 0.5]))
            for k in range(20)]
    rng = np.random.default_rng(1)
    for rot, tr in ((1.0, 0.0), (0.0, 0.01)):
        out = perturbed_cameras(cams, rng, rot, tr)
        for a, b in zip(cams, out):
            dR = a.world_from_camera[:3, :3].T @ b.world_from_camera[:3, :3]
            ang = np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))
            dt = b.position - a.position
            assert ang <= np.sqrt(3) * rot + 1e-4          # three angles, each within ±rot
            assert np.all(np.abs(dt) <= tr + 1e-12)
            assert (a.fx, a.width, a.id) == (b.fx, b.width, b.id)
        moved = [np.abs(b.world_from_camera - a.world_from_camera).max() for a, b in zip(cams, out)]
        assert min(moved) > 0


def test_product_fuses_consecutive_frames_with_a_margin_of_two_fused_sigma():
    """The reproduction's product: 3 consecutive frames per camera (independent noise) fused by
    StillFusion; margin 2 sigma and shell tolerance 5 sigma of the fused depth of the ToF model."""
    from depthguard.evaluation import hamersma2011
    from depthguard.fusion.temporal import StillFusion
    from depthguard.sensors import sensor_model

    room = hamersma2011.load_room()
    cams = room.cameras[:2]
    setup = room.setups[0]
    tof = sensor_model("tof")
    margin, tol = hamersma2011.product_margins(room, cams)
    c3 = StillFusion(3, tof.sigma_a).factor
    assert margin == pytest.approx(2 * c3 * tof.sigma_a) and tol == pytest.approx(5 * c3 * tof.sigma_a)
    assert 0.013 < margin < 0.014
    ideal = hamersma2011.ideal_frames(room, setup, cameras=cams)
    frames = [hamersma2011.measured_frames(room, setup, ideal, 0, cameras=cams, frame=k) for k in range(hamersma2011.STILL_FRAMES)]
    c0 = cams[0].id
    assert not np.array_equal(frames[0][c0], frames[1][c0])          # each frame its own noise
    fused = hamersma2011.still_frames(room, setup, ideal, 0, cameras=cams)
    f = hamersma2011.still_fusion(room, cams)
    for c in cams:
        np.testing.assert_array_equal(fused[c.id], f.fuse([fr[c.id] for fr in frames]))
    # where all three agree the fused depth is nearer the truth than a single frame
    z = ideal[c0]
    flat = (z > 0) & (np.ptp(np.stack([fr[c0] for fr in frames]), axis=0) < 0.03)
    assert np.std((fused[c0] - z)[flat]) < 0.8 * np.std((frames[0][c0] - z)[flat])
