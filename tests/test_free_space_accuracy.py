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
