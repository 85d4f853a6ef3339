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
