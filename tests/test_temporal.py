"""Fusion of several frames of a still scene (fusion/temporal.py, R21, R25)."""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.fusion.temporal import StillFusion, fuse_kernel, fuse_numpy, median_noise_factor, range_quantile


def test_noise_factor_and_range_quantile_match_sampling():
    """The integrals against 400k sampled sets of standard normals."""
    r = np.random.default_rng(0).standard_normal((400_000, 5))
    for n in (3, 5):
        assert median_noise_factor(n) == pytest.approx(np.median(r[:, :n], axis=1).std(), rel=0.01)
        assert range_quantile(n, 0.99) == pytest.approx(np.quantile(np.ptp(r[:, :n], axis=1), 0.99), rel=0.01)
    assert median_noise_factor(1) == pytest.approx(1.0, abs=1e-6) and range_quantile(1) == 0.0
    with pytest.raises(ValueError, match="odd"):
        median_noise_factor(4)


def _stack(rng, n, H=40, W=50):
    """A still wall at 2-3 m with Gaussian noise, a near box in front, flying pixels and holes."""
    z = np.full((H, W), 2.5) + np.linspace(0, 0.5, W)[None, :]
    z[10:25, 15:30] = 1.2                                          # the box
    st = z[None] + rng.normal(0.0, 0.01, (n, H, W))
    fly = rng.random((n, H, W)) < 0.05                             # flying pixels: anywhere in between
    st[fly] = 1.2 + rng.random(fly.sum()) * 1.5
    st[rng.random((n, H, W)) < 0.05] = 0.0                         # dropouts
    st[0, 0, 0] = np.nan
    return st.astype(np.float32), z


@pytest.mark.parametrize("n", [1, 3, 5])
def test_kernel_equals_numpy_twin_and_rules_hold(n):
    rng = np.random.default_rng(n)
    st, z = _stack(rng, n)
    f = StillFusion(n, sigma_a=0.01)
    got = f.fuse(st)
    np.testing.assert_array_equal(got, fuse_numpy(st, f.k, f.sigma_a, f.sigma_z2))
    valid = np.isfinite(st) & (st > 0)
    nv = valid.sum(0)
    lo = np.where(valid, st, np.inf).min(0)
    assert np.all(got[2 * nv < n + 1] == 0)                        # invalid in more than half
    kept = 2 * nv >= n + 1
    # never behind the median of the valid samples: the median or the nearest
    srt = np.sort(np.where(valid, st, np.inf), axis=0)
    assert np.all((got[kept] == srt[n // 2][kept]) | (got[kept] == lo[kept]))
    if n > 1:
        # a sample that flew (or dropped out) never yields the median: the nearest instead
        spread = np.where(nv == n, np.ptp(np.where(valid, st, 0), axis=0), np.inf)
        disagree = kept & (spread > f.k * 0.01 + 1e-6)
        assert disagree.sum() > 50 and np.all(got[disagree] == lo[disagree])


def test_fused_noise_on_a_still_wall_is_the_median_noise():
    """Where the samples agree the fused depth has the median's noise c_n * sigma."""
    rng = np.random.default_rng(3)
    n, sigma = 5, 0.01
    st = (2.0 + rng.normal(0.0, sigma, (n, 200, 300))).astype(np.float32)
    f = StillFusion(n, sigma_a=sigma)
    got = f.fuse(st)
    assert (got - 2.0).std() == pytest.approx(f.sigma(2.0), rel=0.03)
    assert f.sigma(2.0) == pytest.approx(0.536 * sigma, rel=0.01)
    assert np.mean(np.ptp(st, axis=0) > f.k * sigma) < 0.003    # the agreement test passes ~99.9 %


def test_depth_dependent_noise_and_bad_input():
    f = StillFusion.for_sensor(type("M", (), {"sigma_a": 0.0, "sigma_z2": 0.0026})(), 3)
    assert f.sigma(2.0) == pytest.approx(f.factor * 0.0026 * 4)
    with pytest.raises(ValueError, match="need 3 frames"):
        f.fuse(np.zeros((2, 4, 4)))
    with pytest.raises(ValueError, match="out must be float32"):
        f.fuse(np.zeros((3, 4, 4)), out=np.zeros((4, 4)))
    with pytest.raises(ValueError, match="sensor noise"):
        StillFusion(3, 0.0, 0.0)
    st = np.ones((3, 2, 2), np.float32)
    out = np.empty((2, 2), np.float32)
    assert fuse_kernel(st, 5.0, 0.01, 0.0, out) is out and np.all(out == 1)
