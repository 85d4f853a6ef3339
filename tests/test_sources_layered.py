"""A simulated camera's frames as a static scene plus moving layers (issue 29): ``sources/layered.py``.

Truth: the former way, kept as ``reference_frame`` — the static scene copied, each layer combined
with ``nearest_depth``, ``apply_noise`` (with ``use_numpy=True`` its plain-numpy twins: a second
implementation written without spans), the invalid policy and the dark pixels on whole images.
The frames must be equal bit for bit, frame after frame (a frame restores what the one before it
changed), for every sensor model, policy and draw (exact or from the normal bank).
"""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.geometry.decimate import SIM_CELL
from depthguard.filtering.expected import ExpectedDepth
from depthguard.render import Renderer
from depthguard.sensors import SENSOR_MODELS, sensor_model
from depthguard.sim import load_cell
from depthguard.sources.layered import LayeredCamera, layer_spans, reference_frame
from depthguard.sources.noise import NormalBank
from depthguard.sources.simulated import frame_rng

H, W = 40, 56


def _bits(a):
    return np.ascontiguousarray(a, dtype=np.float32).view(np.uint32)


def _static(rng):
    """A small static scene: planes at steps (depth edges), holes (0), a few NaN, inf and negative
    pixels (what no render gives, but the rule for them must hold)."""
    s = np.full((H, W), 2.5, np.float32)
    s[:, W // 2:] = 3.4
    s[H // 3:, :W // 4] = 1.2
    s[rng.random((H, W)) < 0.05] = 0.0
    s[:4, 10:20] = 0.0                    # a hole touching the top border
    s[5, 5], s[6, 40], s[30, 3] = np.nan, np.inf, -1.0
    return s


def _layer(rng, k):
    """A moving layer: blobs at random places (some on the image's borders), 0 elsewhere; a few
    odd values (-0.0, NaN) that span finding must treat as 'something' and combining as nothing."""
    out = np.zeros((H, W), np.float32)
    for _ in range(int(rng.integers(1, 4))):
        v0, u0 = int(rng.integers(-3, H - 2)), int(rng.integers(-3, W - 2))
        hh, ww = int(rng.integers(2, 14)), int(rng.integers(2, 20))
        out[max(v0, 0):v0 + hh, max(u0, 0):u0 + ww] = rng.uniform(0.3, 4.0)
    if k % 3 == 0:
        out[int(rng.integers(0, H)), int(rng.integers(0, W))] = -0.0
        out[int(rng.integers(0, H)), int(rng.integers(0, W))] = np.nan
    return out


def _cases():
    for name in sorted(SENSOR_MODELS):
        for invalid in (None, "unknown", "free"):
            yield name, invalid


@pytest.mark.parametrize("name,invalid", list(_cases()))
def test_frames_equal_the_numpy_twin_frame_after_frame(name, invalid):
    """Every sensor model and policy, noise and noiseless, exact and banked draws, dark or not:
    a sequence of frames whose layers come and go (and a frame with none) equals the former way
    on its plain-numpy twins, bit for bit."""
    model = sensor_model(name)
    rng = np.random.default_rng(7)
    static = _static(rng)
    fx, lo, max_range = 60.0, model.min_range, model.max_range
    hi = model.returns_to(max_range)
    bank = NormalBank(3, size=1 << 14)
    for noiseless in (False, True):
        cam = LayeredCamera(static, model, fx, lo, hi, max_range, noiseless=noiseless, invalid=invalid)
        for k in range(8):
            robot = _layer(rng, k) if k % 4 != 3 else None
            person = _layer(rng, k + 1) if k % 2 == 0 else None
            dark = k % 3 == 1
            b = bank if k % 2 else None
            got = cam.frame(robot, person, frame_rng(1, "c", k / 30), bank=b, dark=dark)
            want = reference_frame(static, robot, person, model, fx, lo, hi, max_range, frame_rng(1, "c", k / 30),
                                   bank=b, noiseless=noiseless, invalid=invalid, dark=dark, use_numpy=True)
            assert got.dtype == np.float32 and got.shape == (H, W)
            np.testing.assert_array_equal(_bits(got), _bits(want), err_msg=f"frame {k}, noiseless {noiseless}")


def _bar(u0, u1, v0, v1, z):
    out = np.zeros((H, W), np.float32)
    out[max(v0, 0):v1, max(u0, 0):u1] = z
    return out


@pytest.mark.parametrize("name", ["realsense_d435", "tof", "kinect_v1"])
def test_two_layers_apart_on_the_same_rows(name):
    """The robot's and the person's pixels are worked as two intervals per row (not their hull):
    two bars on the same rows, apart by 0 to 6 pixels (touching, within the edge test's reach of
    one another, apart), swapping sides, overlapping, one leaving, frame after frame — each frame
    equal to the former way on its plain-numpy twins, bit for bit (a frame restores what the one
    before changed, in either interval or between them)."""
    model = sensor_model(name)
    static = _static(np.random.default_rng(3))
    fx, lo, max_range = 60.0, model.min_range, model.max_range
    hi = model.returns_to(max_range)
    cam = LayeredCamera(static, model, fx, lo, hi, max_range, invalid="unknown")
    k = 0
    for gap in (0, 1, 2, 3, 6, -4, 20):
        for left_robot in (True, False):
            for rows in ((5, 30), (0, 12), (25, H)):
                a = _bar(3, 20, *rows, 1.0)                      # the left bar
                b = _bar(20 + gap, 40 + gap, rows[0] + 2, rows[1] + 2, 2.0 + 0.1 * gap)
                robot, person = (a, b) if left_robot else (b, a)
                if k % 5 == 4:
                    person = None
                got = cam.frame(robot, person, frame_rng(1, "c", k / 30), dark=k % 3 == 0)
                want = reference_frame(static, robot, person, model, fx, lo, hi, max_range, frame_rng(1, "c", k / 30),
                                       invalid="unknown", dark=k % 3 == 0, use_numpy=True)
                np.testing.assert_array_equal(_bits(got), _bits(want), err_msg=f"frame {k}: gap {gap}, rows {rows}")
                k += 1


def test_layer_spans_hold_every_nonzero_pixel():
    """Per row the span is exactly first..last pixel whose float32 bits are not +0.0 (numpy's
    ``flatnonzero`` on the bits), (0, 0) for an empty row; also for rows wider than the 16-word scan."""
    rng = np.random.default_rng(2)
    for width in (5, 16, 17, 64, 100):
        a = np.zeros((30, width), np.float32)
        mask = rng.random(a.shape) < 0.03
        a[mask] = rng.uniform(0.1, 5.0, mask.sum())
        a[3, width - 1] = -0.0
        a[4, 0] = np.nan
        spans = np.full((30, 2), -7, np.int32)
        total = layer_spans(a.view(np.uint32), spans, -5, 99, -3, width + 8)     # a window beyond the image
        want = []
        for row in a.view(np.uint32):
            nz = np.flatnonzero(row)
            want.append((nz[0], nz[-1] + 1) if len(nz) else (0, 0))
        np.testing.assert_array_equal(spans, np.array(want))
        assert total == sum(b - a_ for a_, b in want)
        vv, uu = np.nonzero(a.view(np.uint32))                  # the tightest window: the same spans
        layer_spans(a.view(np.uint32), spans, vv.min(), vv.max() + 1, uu.min(), uu.max() + 1)
        np.testing.assert_array_equal(spans, np.array(want))


def test_mesh_window_holds_every_pixel_the_renderer_draws():
    """Truth: the renderer itself. Random triangles in front of a ur3-cell camera, some partly
    outside the image: every pixel drawn lies in the window; a vertex behind the near plane
    widens it to the whole image."""
    from depthguard.geometry.mesh import Mesh
    from depthguard.sources.layered import mesh_window

    cam = load_cell("ur3-cell").rig.cameras[0]
    r = Renderer(cam)
    R, t = np.ascontiguousarray(cam.R, dtype=np.float64), np.ascontiguousarray(cam.t, dtype=np.float64)
    rng = np.random.default_rng(5)
    for k in range(30):
        centre = cam.position + (0.6 + 2.5 * rng.random()) * cam.R[2] + rng.normal(0, 0.8, 3)
        v = centre + rng.normal(0, 0.05 + 0.3 * rng.random(), (6, 3))
        mesh = Mesh(v, np.array([[0, 1, 2], [3, 4, 5], [0, 2, 1], [3, 5, 4]], np.int32))
        depth = np.array(r.render([mesh])[0])
        win = np.array([1 << 30, -(1 << 30), 1 << 30, -(1 << 30)], np.int64)
        inside = mesh_window(mesh.vertices, R, t, cam.fx, cam.fy, cam.cx, cam.cy, r.near, win)
        vv, uu = np.nonzero(depth)
        if inside and len(vv):
            assert win[0] <= vv.min() and vv.max() < win[1] and win[2] <= uu.min() and uu.max() < win[3], k
        if not inside:
            assert win[0] < 0 and win[1] > cam.height and win[2] < 0 and win[3] > cam.width
    behind = cam.position - 0.5 * cam.R[2]
    win = np.zeros(4, np.int64)
    assert not mesh_window(np.array([behind]), R, t, cam.fx, cam.fy, cam.cx, cam.cy, r.near, win)


def test_layers_may_be_read_only_views():
    """A renderer may hand out read-only views of its images: they are read, never written."""
    rng = np.random.default_rng(4)
    static = _static(rng)
    model = sensor_model("realsense_d435")
    hi = model.returns_to(model.max_range)
    robot = _layer(rng, 1)
    view = robot.view()
    view.flags.writeable = False
    cam = LayeredCamera(static, model, 60.0, model.min_range, hi, model.max_range)
    got = cam.frame(view, view, frame_rng(0, "c", 0.0), dark=True)
    want = reference_frame(static, robot, robot, model, 60.0, model.min_range, hi, model.max_range,
                           frame_rng(0, "c", 0.0), dark=True)
    np.testing.assert_array_equal(_bits(got), _bits(want))
    with pytest.raises(ValueError, match="C-contiguous float32"):
        cam.frame(robot[:, ::2], None, frame_rng(0, "c", 0.0))


def test_a_cell_s_frames_equal_the_former_way():
    """ur3-cell, a 640x480 D435 with the robot moving and a person walking in: the frames of
    consecutive captures equal the former way (numba kernels; the first also the numpy twins),
    exact draws and the real-time bank alike."""
    cell = load_cell("ur3-cell")
    bank = NormalBank(0)
    for cam in cell.rig.cameras[:1]:
        model = sensor_model(cam.sensor)
        hi = model.returns_to(cam.max_range)
        ex = ExpectedDepth(cam, cell.scene.robot, cell.scene.static_meshes, robot_cell=SIM_CELL)
        people = Renderer(cam)
        layered = LayeredCamera(ex.static, model, cam.fx, cam.min_range, hi, cam.max_range, invalid="unknown")
        seen = 0
        for k, t in enumerate((2.4, 2.9, 3.0, 3.1, 3.6)):
            moving, _ = cell.scene.moving_meshes_at(t)
            person = np.array(people.render(moving)[0]) if moving else None
            seen += person is not None and bool((person > 0).any())
            robot = np.array(ex.robot(cell.scene.robot_q(t)))
            b = bank if k % 2 else None
            got = layered.frame(robot, person, frame_rng(0, cam.id, t), bank=b, dark=k == 3)
            want = reference_frame(ex.static, robot, person, model, cam.fx, cam.min_range, hi, cam.max_range,
                                   frame_rng(0, cam.id, t), bank=b, dark=k == 3, use_numpy=k == 0)
            np.testing.assert_array_equal(_bits(got), _bits(want), err_msg=f"{cam.id} t = {t}")
        assert seen >= 3, "the check needs a person in view"
