"""The live view in a real browser (headless Chromium): a running monitor on the demo cell (R29, R31).

The truth is geometric and independent of the browser: the robot's link
meshes at the joints the view shows, rendered by depthguard's own z-buffer
into a pinhole camera with the pose and field of view the test asks the
browser to render from (OpenCV axes, as viser's), must cover the same pixels
as the robot's orange in the browser's WebGL canvas. Skips where no
Chromium is installed.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from depthguard.viz.browser import find_browser

pytestmark = pytest.mark.skipif(find_browser() is None,
                                reason="no Chromium: install the Debian package `chromium` (or set DEPTHGUARD_BROWSER)")

W, H = 480, 360                     # the render asked of the browser (px)
FOV = math.radians(45.0)            # vertical field of view (rad)


def _look(eye, target):
    """world_from_camera (4, 4), OpenCV axes (x right, y down, z forward), world +z up."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = eye
    return T


def _robot_mask(robot, q, T) -> np.ndarray:
    """(H, W) bool: pixels of the robot's link meshes at ``q`` seen from pose ``T`` (depthguard's renderer)."""
    from depthguard.camera import Camera
    from depthguard.render import Renderer

    f = (H / 2.0) / math.tan(FOV / 2.0)
    cam = Camera("viewer", W, H, f, f, W / 2.0 - 0.5, H / 2.0 - 0.5, T, min_range=0.05, max_range=30.0)
    depth = Renderer(cam).render(robot.link_meshes(q), cull_back=False)[0]
    return np.asarray(depth) > 0


def _orange(img: np.ndarray) -> np.ndarray:
    """(H, W) bool: the robot's colour (orange, any shade) in an RGBA render."""
    rgb = img[..., :3].astype(int)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    drawn = img[..., 3] > 128 if img.shape[-1] == 4 else np.ones(r.shape, bool)
    return drawn & (r > 90) & (r - b > 60) & (g < 0.75 * r) & (g > b)


def _iou(a, b) -> float:
    return float((a & b).sum()) / max(1, int((a | b).sum()))


def test_browser_shows_the_running_monitor_with_the_robot_where_it_projects():
    from viser import transforms as vtf

    from depthguard.viz.browser import HeadlessBrowser, wait_for_client
    from depthguard.viz.live import LAYERS
    from depthguard.viz.live_demo import live_monitor

    T = _look((1.9, -1.1, 1.2), (-0.3, 0.0, 0.35))
    wxyz = vtf.SO3.from_matrix(T[:3, :3]).wxyz
    out = {}

    def during(view, mon):
        end = time.monotonic() + 20.0
        while (view.shown_q is None or not any(w.product is not None for w in mon.fusion.workers.values())) \
                and time.monotonic() < end:
            time.sleep(0.1)
        assert view.shown_q is not None, "the view never showed a reaction"
        with HeadlessBrowser(view.url, size=(1024, 768)) as browser:
            client = wait_for_client(view.server, 30.0)
            time.sleep(1.0)                                       # the client draws the scene once
            out["full"] = client.get_render(H, W, wxyz=wxyz, position=T[:3, 3], fov=FOV,
                                            transport_format="png", timeout=60.0)
            out["updates_with_browser"] = view.updates
            view.freeze(True)                                      # the robot stays where it is drawn
            for name in LAYERS:
                view.set_layer(name, name == "robot")
            time.sleep(3 * view.period)
            out["q"] = view.shown_q
            # the browser applies the hidden layers and the last poses when it gets to them (a
            # loaded machine's software WebGL can answer a render first): the robot alone is the
            # first render with no other layer's colour that the next render repeats
            out["robot"], out["robot_renders"] = _settled_render(client, wxyz, T[:3, 3], deadline=30.0)
            out["browser_alive"] = browser.proc.poll() is None
        return view.updates

    t0 = time.monotonic()
    updates, summary = live_monitor(during)
    wall = time.monotonic() - t0
    assert summary["view_errors"] == []
    assert out["browser_alive"]

    # the whole scene: not blank, and the layers drawn in their colours
    full = out["full"]
    assert full.shape == (H, W, 4)
    drawn = full[..., 3] > 128
    assert drawn.mean() > 0.5, f"only {drawn.mean():.0%} of the canvas is drawn"
    rgb = full[..., :3].astype(int)
    blue_points = drawn & (rgb[..., 2] > 150) & (rgb[..., 0] < 120)          # frame points not explained (blue)
    grey = drawn & (np.ptp(rgb, axis=2) < 20) & (rgb.mean(axis=2) > 60)      # the cell's static meshes
    assert _orange(full).sum() > 300, "no robot in the full render"
    assert blue_points.sum() > 30, "no frame points in the full render"
    assert grey.mean() > 0.2, "no cell in the full render"

    # the robot alone: its pixels where its projection from the requested pose says they are
    seen = _orange(out["robot"])
    robot = _rig().robot
    truth = _robot_mask(robot, out["q"], T)
    assert truth.sum() > 2000, "the chosen viewpoint hardly sees the robot (test set-up)"
    iou = _iou(seen, truth)
    ys, xs = np.nonzero(seen)
    yt, xt = np.nonzero(truth)
    shift = math.hypot(xs.mean() - xt.mean(), ys.mean() - yt.mean())
    # a wrong pose must not pass: the robot with its first joint turned by 0.3 rad
    q_wrong = out["q"].copy()
    q_wrong[0] += 0.3
    iou_wrong = _iou(seen, _robot_mask(robot, q_wrong, T))
    print(f"robot IoU {iou:.3f} (pose off by 0.3 rad: {iou_wrong:.3f}), centroid shift {shift:.2f} px, "
          f"{seen.sum()} px seen / {truth.sum()} px projected; {updates} view updates; "
          f"{out['robot_renders']} renders to settle; {wall:.1f} s")
    assert iou > 0.85, f"robot pixels overlap their projection by only IoU {iou:.3f}"
    assert shift < 2.0, f"robot centroid {shift:.2f} px from its projection"
    assert iou_wrong < iou - 0.2


def _others(img: np.ndarray) -> int:
    """Pixels drawn in another layer's colour than the robot's (the cell's grey, the points' blue)."""
    drawn = img[..., 3] > 128
    rgb = img[..., :3].astype(int)
    grey = drawn & (np.ptp(rgb, axis=2) < 20) & (rgb.mean(axis=2) > 60)
    blue = drawn & (rgb[..., 2] > 150) & (rgb[..., 0] < 120)
    return int(grey.sum() + blue.sum())


def _settled_render(client, wxyz, position, deadline: float):
    """The browser's render once it shows nothing but the robot and repeats itself; (image, renders)."""
    end = time.monotonic() + deadline
    prev, n = None, 0
    while True:
        img = client.get_render(H, W, wxyz=wxyz, position=position, fov=FOV, transport_format="png", timeout=60.0)
        n += 1
        settled = prev is not None and _others(img) < 20 and np.array_equal(_orange(img), _orange(prev))
        if settled or time.monotonic() > end:
            return img, n
        prev = img
        time.sleep(0.3)


def _rig():
    from depthguard.sim import load_cell

    return load_cell("flacco-cell").rig
