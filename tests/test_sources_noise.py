"""Noise models of the simulated depth cameras: statistics against the models' equations."""

import dataclasses

import numba
import numpy as np
import pytest
from scipy.stats import norm

from depthguard.sensors import sensor_model
from depthguard.sources import noise
from depthguard.sources.noise import NoiseWorkspace, apply_noise, depth_edges, depth_edges_kernel, kinect_quantise

H, W = 240, 320
FX = 300.0


def flat(z):
    return np.full((H, W), z, np.float32)


def measured(model, ideal, seed=0, **kw):
    return apply_noise(ideal, model, FX, np.random.default_rng(seed), **kw)


@pytest.mark.parametrize("name", ["realsense_d435", "tof"])
@pytest.mark.parametrize("z", [1.0, 3.0])
def test_gaussian_noise_std_matches_model(name, z):
    m = dataclasses.replace(sensor_model(name), edge_dropout=0.0)
    out = measured(m, flat(z)).astype(np.float64)
    assert (out > 0).all()  # a flat wall has no edges and is in range
    sigma = m.sigma_a + m.sigma_z2 * z * z  # the model's equation
    n = out.size
    # sample std has relative standard error 1/sqrt(2n) (~0.26 %); allow 5 of them
    assert abs(out.std() / sigma - 1) < 5 / np.sqrt(2 * n)
    assert abs(out.mean() - z) < 5 * sigma / np.sqrt(n)


def test_d435_noise_grows_with_z_squared():
    m = dataclasses.replace(sensor_model("realsense_d435"), sigma_a=0.0, edge_dropout=0.0)
    s1 = measured(m, flat(1.0)).std()
    s3 = measured(m, flat(3.0)).std()
    assert s3 / s1 == pytest.approx(9.0, rel=0.02)


def test_kinect_quantisation_steps_match_fb_over_z2():
    m = sensor_model("kinect_v1")
    fb = FX * m.baseline
    z = np.linspace(0.5, 3.9, 200000)
    q = np.unique(kinect_quantise(z, FX, m.baseline, m.disparity_bits))
    gaps = np.diff(q)
    mid = (q[1:] + q[:-1]) / 2
    # depth step of a 1/8-pixel disparity step: dz = z^2 / (f b) / 8, to first order
    np.testing.assert_allclose(gaps, mid ** 2 / fb / 8, rtol=0.02)
    # every output lies on the lattice f b / (k / 8)
    k = fb / q * 8
    np.testing.assert_allclose(k, np.rint(k), atol=1e-6)


def kinect_law(m, z):
    """Independent truth of a Kinect pixel at depth ``z``: disparity ``d0 = fb / z`` plus
    N(0, s_d), ``s_d = sigma_z2 * fb``, rounded to 1/8 px; each level's probability from the
    normal CDF, its depth ``fb / level``. Returns the measured depth's (mean, std)."""
    fb = FX * m.baseline
    sd = m.sigma_z2 * fb
    d0 = fb / z
    k = np.arange(np.floor((d0 - 8 * sd) * 8), np.ceil((d0 + 8 * sd) * 8) + 1)
    p = norm.cdf((k + 0.5) / 8, d0, sd) - norm.cdf((k - 0.5) / 8, d0, sd)
    depth = fb / (k / 8)
    mean = (p * depth).sum() / p.sum()
    return mean, np.sqrt((p * (depth - mean) ** 2).sum() / p.sum())


@pytest.mark.parametrize("z", [1.0, 3.0])
def test_kinect_std_matches_quantised_gaussian_disparity(z):
    m = dataclasses.replace(sensor_model("kinect_v1"), edge_dropout=0.0)
    out = measured(m, flat(z), seed=3).astype(np.float64)
    mean, std = kinect_law(m, z)
    n = out.size
    assert out.std() == pytest.approx(std, rel=6 / np.sqrt(2 * n) + 0.01)
    assert abs(out.mean() - mean) < 6 * std / np.sqrt(n)


@pytest.mark.parametrize("name", ["kinect_v1", "realsense_d435", "tof", "ideal"])
def test_deterministic_under_seed(name):
    m = sensor_model(name)
    img = step_image()
    a = measured(m, img, seed=7)
    b = measured(m, img, seed=7)
    np.testing.assert_array_equal(a, b)
    if name != "ideal":
        c = measured(m, img, seed=8)
        assert not np.array_equal(a, c)


@pytest.mark.parametrize("name", ["kinect_v1", "realsense_d435", "tof"])
def test_noiseless_is_rendered_depth_within_range(name):
    """Noiseless: the ideal depth within [min_range, return_range] (beyond the rated
    max_range too: a real sensor still returns there), 0 outside."""
    m = sensor_model(name)
    hr = m.returns_to()
    assert hr > m.max_range
    ideal = np.linspace(0.0, hr + 1.0, H * W).reshape(H, W).astype(np.float32)
    ideal[0, :5] = np.nan
    out = measured(m, ideal, noiseless=True)
    inside = (ideal >= m.min_range) & (ideal <= hr)
    np.testing.assert_array_equal(out[inside], ideal[inside])
    assert (out[~inside] == 0).all()
    assert (out > m.max_range).any()
    assert out.dtype == np.float32


def test_return_ranges_of_the_presets():
    assert sensor_model("kinect_v1").returns_to() == 8.0
    assert sensor_model("realsense_d435").returns_to() == 10.0
    assert sensor_model("tof").returns_to() == 12.0
    ideal = sensor_model("ideal")
    assert ideal.returns_to() == ideal.max_range and ideal.returns_to(3.0) == 3.0
    assert sensor_model("kinect_v1").returns_to(9.0) == 9.0      # a camera rated farther
    with pytest.raises(ValueError, match="return_range"):
        dataclasses.replace(sensor_model("kinect_v1"), return_range=3.0)


@pytest.mark.parametrize("name", ["kinect_v1", "realsense_d435", "tof"])
def test_out_of_range_and_nothing_is_zero(name):
    m = sensor_model(name)
    assert (measured(m, flat(1.25 * m.returns_to())) == 0).all()   # the measured depth is cut
    assert (measured(m, flat(m.min_range * 0.5)) == 0).all()
    assert (measured(m, flat(0.0)) == 0).all()
    # the ideal model returns nothing beyond its (the camera's) max_range
    ideal = sensor_model("ideal")
    assert (measured(ideal, flat(ideal.max_range + 0.5)) == 0).all()
    assert (measured(ideal, flat(3.5), max_range=3.0) == 0).all()


@pytest.mark.parametrize("name,z", [("kinect_v1", 6.0), ("realsense_d435", 8.0), ("tof", 10.0)])
def test_beyond_rated_range_returns_with_the_same_noise_law(name, z):
    """A surface between max_range and return_range is measured (not 0), with the noise of
    the model's law at that depth; the rated range stays the camera's max_range."""
    m = dataclasses.replace(sensor_model(name), edge_dropout=0.0)
    assert m.max_range < z < m.returns_to()
    out = measured(m, flat(z)).astype(np.float64)
    ok = out > 0
    assert ok.mean() > 0.99
    assert abs(out[ok].mean() - z) < 0.02 * z
    if m.kind != "structured_light":
        assert out[ok].std() == pytest.approx(noise.depth_sigma(m, z), rel=0.05)
    # a camera whose rated range is cut shorter still returns up to the model's return range
    short = measured(m, flat(z), max_range=m.max_range - 1.0)
    assert (short > 0).mean() > 0.99


def step_image(near=1.0, far=2.0):
    img = np.full((H, W), far, np.float32)
    img[:, : W // 2] = near
    return img


def test_edges_found_on_both_sides_of_a_step_and_at_silhouettes():
    img = step_image()
    img[100:120, 10:20] = 0.0  # a hole: its border pixels are silhouette edges
    edge, other = depth_edges(img)
    cols = np.nonzero(edge[50])[0]
    assert set(cols) == {W // 2 - 1, W // 2}
    assert other[50, W // 2 - 1] == 2.0 and other[50, W // 2] == 1.0
    assert edge[99, 10:20].all() and edge[120, 10:20].all() and edge[100:120, 9].all()
    assert not edge[100:120, 10:20].any()  # invalid pixels are never edges
    assert other[99, 15] == 0.0


def test_edge_dropout_rate():
    m = dataclasses.replace(sensor_model("realsense_d435"), edge_dropout=0.3)
    img = step_image()
    out = measured(m, img, seed=11)
    edge, _ = depth_edges(img)
    dropped = (out == 0) & edge
    n = edge.sum()
    rate = dropped.sum() / n
    assert abs(rate - 0.3) < 5 * np.sqrt(0.3 * 0.7 / n)
    assert (out[~edge] > 0).all()  # no dropout off the edges


def test_tof_flying_pixels_between_the_two_sides():
    m = dataclasses.replace(sensor_model("tof"), sigma_a=0.0, edge_dropout=0.0, flying_fraction=0.5)
    img = step_image()
    out = measured(m, img, seed=5)
    edge, _ = depth_edges(img)
    np.testing.assert_array_equal(out[~edge], img[~edge])  # noise off: only edges change
    e = out[edge]
    assert ((e >= 1.0) & (e <= 2.0)).all()
    flying = (e > 1.0) & (e < 2.0)
    n = e.size
    assert abs(flying.mean() - 0.5) < 5 * np.sqrt(0.25 / n)
    # flying depths are spread over the gap (uniform between the sides)
    assert abs(e[flying].mean() - 1.5) < 0.1


def test_bad_input_names_the_problem():
    with pytest.raises(ValueError, match="2-D"):
        apply_noise(np.zeros(5), sensor_model("tof"), FX, np.random.default_rng(0))


def random_scene_image(rng, h=60, w=80):
    """Blocks at random depths, holes, and a slanted plane: many kinds of edges."""
    img = np.full((h, w), 3.0) + np.linspace(0, 0.5, w)[None, :]
    for _ in range(8):
        v, u = rng.integers(0, h - 10), rng.integers(0, w - 10)
        img[v:v + rng.integers(3, 20), u:u + rng.integers(3, 20)] = rng.uniform(0.2, 5.0)
    img[rng.random((h, w)) < 0.03] = 0.0
    img[0, 0] = np.nan
    return img.astype(np.float32)


def test_edge_kernel_matches_numpy_twin(rng):
    for _ in range(5):
        img = random_scene_image(rng)
        e_ref, o_ref = depth_edges(img)
        z = np.nan_to_num(img.astype(np.float64))
        edge, other = np.empty(z.shape, bool), np.empty(z.shape)
        starts = np.empty((2, z.shape[0] + 1), np.int64)
        n, n_valid = depth_edges_kernel(z, 0.03, 0.02, edge, other, starts[0], starts[1])
        np.testing.assert_array_equal(edge, e_ref)
        np.testing.assert_array_equal(other, o_ref)
        assert n == e_ref.sum() and n_valid == (z > 0).sum()


@pytest.mark.parametrize("name", ["kinect_v1", "realsense_d435", "tof"])
def test_noise_kernel_matches_numpy_twin(rng, name):
    m = sensor_model(name)
    if name == "kinect_v1":
        m = dataclasses.replace(m, sigma_a=0.002)  # exercise the second normal draw too
    ws = NoiseWorkspace((60, 80))
    for seed in range(4):
        img = random_scene_image(rng)
        a = apply_noise(img, m, FX, np.random.default_rng(seed), ws=ws)
        b = apply_noise(img, m, FX, np.random.default_rng(seed), use_numpy=True)
        np.testing.assert_array_equal(a == 0, b == 0)
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)


def parallel_test_images(rng):
    """Odd-sized images with holes, NaN / inf, empty rows and columns, depth steps and silhouettes."""
    imgs = [random_scene_image(rng, 97, 131) for _ in range(2)]
    img = random_scene_image(rng, 97, 131)
    img[10:14] = 0.0                      # whole rows without a valid pixel
    img[:, 60] = 0.0                      # a column of nothing: silhouettes on both sides
    img[40:50, 70:90] = np.inf
    img[20:23, 5:9] = -1.0                # negative: nothing hit, like 0, NaN and inf
    img[24, 5:9] = -np.inf
    img[-1, :] = 0.5                      # a near strip along the bottom border
    imgs.append(img)
    imgs.append(np.zeros((97, 131), np.float32))   # nothing valid: no draws at all
    return imgs


PARALLEL_MODELS = {
    "kinect_v1": sensor_model("kinect_v1"),
    "kinect_v1+sigma_a": dataclasses.replace(sensor_model("kinect_v1"), sigma_a=0.002),   # second normal
    "realsense_d435": sensor_model("realsense_d435"),
    "tof": sensor_model("tof"),
    "ideal+dropout": dataclasses.replace(sensor_model("ideal"), edge_dropout=0.3),      # kind 0 in the kernel
}


@pytest.mark.parametrize("name", list(PARALLEL_MODELS))
def test_parallel_kernels_bit_identical_to_numpy_twins_on_1_and_2_threads(rng, name):
    m = PARALLEL_MODELS[name]
    params = noise._params(m, FX)
    lo, hi = m.min_range, m.returns_to()
    thread_counts = sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)})
    ws = NoiseWorkspace((97, 131))   # reused across images: no state may leak from call to call
    prev = numba.get_num_threads()
    try:
        for seed, img in enumerate(parallel_test_images(rng)):
            z = np.where(np.isfinite(img) & (img > 0), img, 0).astype(np.float64)
            e_ref, o_ref = depth_edges(z)
            valid = z > 0
            n_e, n_v = int(e_ref.sum()), int(valid.sum())
            g, g2, u_fly, u_drop = (a.copy() for a in noise._draws(m, np.random.default_rng(seed), ws, n_e, n_v))
            ref = noise.measure_numpy(z, e_ref, o_ref, g, g2, u_fly, u_drop, *params, lo, hi)
            ref_apply = apply_noise(img, m, FX, np.random.default_rng(seed), use_numpy=True)
            for threads in thread_counts:
                numba.set_num_threads(threads)
                ws.edge[...] = True
                ws.other[...] = -1.0
                ws.valid_start[...] = -1
                ws.edge_start[...] = -1
                counts = depth_edges_kernel(z, noise.EDGE_JUMP_ABS, noise.EDGE_JUMP_REL, ws.edge, ws.other,
                                            ws.valid_start, ws.edge_start)
                assert np.array_equal(np.asarray(counts), [n_e, n_v])
                assert np.array_equal(ws.edge, e_ref) and np.array_equal(ws.other, o_ref)
                assert np.array_equal(ws.valid_start, np.concatenate([[0], np.cumsum(valid.sum(axis=1))]))
                assert np.array_equal(ws.edge_start, np.concatenate([[0], np.cumsum(e_ref.sum(axis=1))]))
                out = np.full(z.shape, np.nan, np.float32)
                noise.measure_kernel(z, ws.edge, ws.other, ws.valid_start, ws.edge_start, g, g2, u_fly, u_drop,
                                     *params, lo, hi, out)
                assert np.array_equal(out, ref)
                got = apply_noise(img, m, FX, np.random.default_rng(seed), ws=ws)
                assert np.array_equal(got, ref_apply)
                if m.kind != "ideal":
                    assert np.array_equal(got, ref)
    finally:
        numba.set_num_threads(prev)


@pytest.mark.parametrize("z", [1.0, 3.0])
def test_noise_from_a_bank_keeps_the_kinects_law_and_frames_differ(z):
    """Real-time simulations take the normals from a pre-drawn bank (noise.NormalBank): each
    frame still follows the quantised Gaussian disparity law (the same independent truth as
    above), two frames are not the same noise, and the bank is not used unless given."""
    from depthguard.sources.noise import NormalBank

    m = dataclasses.replace(sensor_model("kinect_v1"), edge_dropout=0.0)
    bank = NormalBank(seed=5, size=1 << 20)
    a = measured(m, flat(z), seed=3, bank=bank).astype(np.float64)
    b = measured(m, flat(z), seed=4, bank=bank).astype(np.float64)
    mean, std = kinect_law(m, z)
    for out in (a, b):
        assert out.std() == pytest.approx(std, rel=6 / np.sqrt(2 * out.size) + 0.01)
        assert abs(out.mean() - mean) < 6 * std / np.sqrt(out.size)
    assert abs(np.corrcoef(a.ravel(), b.ravel())[0, 1]) < 0.02           # not the same noise twice
    exact = measured(m, flat(z), seed=3)
    assert not np.array_equal(exact, a.astype(np.float32))                 # the bank changes the draws ...
    assert np.array_equal(exact, measured(m, flat(z), seed=3))             # ... only when it is given
    assert NormalBank(seed=1, size=10).take(np.random.default_rng(0), 11) is None   # too small: drawn instead
    small = NormalBank(seed=1, size=100)
    np.testing.assert_array_equal(measured(m, flat(z), seed=3, bank=small), exact)
