"""The live view without a browser: what it draws, its cost to the control thread, playback (R29, R31)."""

from __future__ import annotations

import json
import math
import shutil
import time

import numpy as np
import pytest
from typer.testing import CliRunner

from depthguard.camera import Camera
from depthguard.viz import live_scene as scene

# ------------------------------------------------------------------ what is drawn (pure arrays)


def test_pixel_labels_follow_the_robot_offset_and_the_noise_tolerance():
    depth = np.array([[1.00, 1.95, 0.0, 3.0, 2.50, 4.70]], np.float32)
    robot = np.array([[1.05, 0.0, 1.0, 0.0, 0.0, 0.0]], np.float32)
    static = np.array([[2.0, 2.0, 2.0, 0.0, 3.0, 5.0]], np.float32)
    lab = scene.pixel_labels(depth, robot, static, robot_offset=0.08)
    # robot: 1.00 >= 1.05 - 0.08; known: 1.95 >= 2.0 - (0.04 + 0.012 * 4); invalid: 0;
    # other: nothing rendered; other: 2.50 well in front of the table at 3.0 (tolerance 0.148 m);
    # known: 4.70 >= 5.0 - (0.04 + 0.012 * 25) = 4.66 (the far wall, within the sensor's noise)
    assert lab.tolist() == [[scene.ROBOT, scene.KNOWN, scene.INVALID, scene.OTHER, scene.OTHER, scene.KNOWN]]
    with pytest.raises(ValueError, match="shape"):
        scene.pixel_labels(depth, robot[:, :3], static, 0.08)


def test_frame_points_are_the_cameras_own_back_projection():
    T = np.eye(4)
    T[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]            # looks along world +x
    T[:3, 3] = [0.5, -0.2, 1.0]
    cam = Camera("c", 64, 48, 50.0, 52.0, 31.2, 23.7, T)
    rng = np.random.default_rng(1)
    depth = rng.uniform(0.8, 3.0, (48, 64)).astype(np.float32)
    depth[5, 7] = 0.0
    zero = np.zeros_like(depth)
    pts, lab = scene.frame_points(cam, depth, zero, zero, 0.08, stride=1)
    assert np.all(lab == scene.OTHER)
    ref = cam.depth_to_points(depth)                                  # the camera's own, the one place
    np.testing.assert_allclose(pts, ref, atol=1e-5)
    pts4, _ = scene.frame_points(cam, depth, zero, zero, 0.08, stride=4)
    mask = np.zeros(depth.shape, bool)
    mask[::4, ::4] = True
    np.testing.assert_allclose(pts4, cam.depth_to_points(depth, mask=mask), atol=1e-5)


def test_near_mask_is_a_distance_test():
    pts = np.array([[0, 0, 0], [0.39, 0, 0], [0.41, 0, 0], [1, 1, 1]], np.float32)
    cps = np.array([[0, 0, 0], [5, 5, 5]], float)
    assert scene.near_mask(pts, cps, 0.4).tolist() == [True, True, False, False]
    assert scene.near_mask(pts, np.zeros((0, 3)), 0.4).tolist() == [False] * 4


def test_colours_keep_cannot_judge_apart_from_nothing_near():
    d = np.array([math.inf, math.inf, 0.0, 0.2, 0.4])
    obs = np.array([True, False, True, True, True])
    col = scene.distance_colours(d, obs, rho=0.4)
    assert tuple(col[0]) == scene.CLEAR_COLOUR                  # nothing within rho
    assert tuple(col[1]) == scene.UNOBSERVED_COLOUR             # cannot judge, though its distance is inf too
    assert tuple(col[0]) != tuple(col[1])
    assert col[2][0] > 200 and col[2][1] < 10                   # touching: red
    assert col[4][1] == 200 and col[4][0] < 10                  # at rho: green
    assert scene.state_colour("fresh") != scene.state_colour("stale") != scene.state_colour("waiting")
    assert scene.state_colour("something new") == scene.STATE_COLOURS["untrusted"]


# ------------------------------------------------------------------ from a real monitor
@pytest.fixture(scope="module")
def rig():
    from depthguard.sim import load_cell

    return load_cell("flacco-cell").rig


@pytest.fixture(scope="module")
def reactions(rig):
    from depthguard.runtime.monitor import Monitor

    q0 = np.asarray(rig.robot_q0, float)
    out = []
    with Monitor(rig) as mon:
        for i in range(5):
            mon.push_joints(i * 0.002, q0)
            out.append(mon.step(i * 0.002 + 0.001))
    return out


def test_a_log_record_and_the_live_reaction_give_the_same_snapshot(reactions):
    r = reactions[-1]
    live = scene.snapshot_of_reaction(r)
    rec = json.loads(json.dumps(r.to_dict()))
    logged = scene.snapshot_of_record(rec)
    assert logged.names == live.names
    np.testing.assert_array_equal(logged.observed, live.observed)
    assert np.all(np.isinf(logged.distance[np.isinf(live.distance)]))   # null -> inf, never 0
    assert logged.cameras.keys() == live.cameras.keys()
    assert logged.reasons == live.reasons
    np.testing.assert_allclose(logged.q, live.q, atol=1e-6)             # the log carries the joints
    assert scene.snapshot_of_record({k: v for k, v in rec.items() if k != "q"}).q is None   # older logs
    bad = dict(rec)
    del bad["cameras"]
    with pytest.raises(ValueError, match="'cameras' is missing"):
        scene.snapshot_of_record(bad, "log line 3")
    with pytest.raises(ValueError, match="log line 4: not a monitor record"):
        scene.snapshot_of_record({**rec, "points": [{"name": "ee"}]} | {"points": 7}, "log line 4")


def test_the_sink_only_hands_over_and_the_view_draws_each_period_not_each_reaction(rig, reactions):
    """The control thread's sink call keeps the newest reaction; the view's own thread draws it
    at ``rate_hz``. Counted, not timed (the speed of the call is in ``depthguard bench``): a
    burst of 20000 calls and 1.5 s of calls at the control rate draw at most one frame per
    period, and the view does draw meanwhile, the newest reaction's joints last."""
    from depthguard.viz.live import LiveView

    rate_hz = 15.0
    with LiveView(rig, port=0, rate_hz=rate_hz) as view:
        assert view.url.startswith("http://127.0.0.1:")           # loopback unless told otherwise
        n = 20000
        u0, t0 = view.updates, time.perf_counter()
        for i in range(n):
            view(reactions[i % len(reactions)])
        burst = time.perf_counter() - t0
        assert view.received == n
        assert view.updates - u0 <= burst * rate_hz + 2           # not a draw per call
        # reactions at the control rate for 1.5 s: the view draws each period, not each reaction
        u0 = view.updates
        t_end = time.perf_counter() + 1.5
        k = 0
        while time.perf_counter() < t_end:
            view(reactions[k % len(reactions)])
            k += 1
            time.sleep(0.002)
        drawn = view.updates - u0
        assert 3 <= drawn <= 1.5 * rate_hz + 2, f"the view drew {drawn} times in 1.5 s ({k} reactions)"
        assert view.errors == []
        assert view.shown_q is not None
        np.testing.assert_array_equal(view.shown_q, reactions[-1].q)


def test_the_rho_slider_sets_the_monitors_rho_and_showing_it_does_not(rig):
    from depthguard.config import MonitorConfig
    from depthguard.runtime.monitor import Monitor
    from depthguard.viz.live import LiveView

    cfg = rig.monitor.with_changes(rho=0.375)
    assert isinstance(cfg, MonitorConfig)
    with Monitor(rig, cfg) as mon, LiveView(rig, port=0, monitor=mon, start=False) as view:
        assert mon.config.rho == 0.375                 # the slider shows 0.38 but does not round the monitor's
        view.gui_rho.value = 0.55                      # as a browser's slider does
        assert mon.config.rho == 0.55 and view.rho == 0.55
        view.set_layer("points", False)
        assert all(not h.visible for h in view.layers["points"])
        with pytest.raises(ValueError, match="no layer"):
            view.set_layer("people", True)


# ------------------------------------------------------------------ the CLI
@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    from depthguard.cli import app

    out = tmp_path_factory.mktemp("view") / "run"
    res = CliRunner().invoke(app, ["monitor", "--fast", "--duration", "0.6", "-q", "--out", str(out),
                                   "--sink", "view:0"])
    assert res.exit_code == 0, res.output
    return out


def test_monitor_view_runs_beside_the_log(run_dir):
    lines = (run_dir / "log.jsonl").read_text().splitlines()
    assert len(lines) == 301                                     # 0.6 s at 500 Hz, nothing lost to the view


def test_playback_keeps_the_changes_and_refuses_bad_logs(run_dir, tmp_path):
    from depthguard.viz.playback import load_run, rig_of_run

    rec = load_run(run_dir, keep_hz=50.0)
    assert rec.lines == 301
    assert rec.times[0] == 0.0 and rec.times[-1] <= 0.6
    assert len(rec.times) < 301
    assert max(np.diff(rec.times)) <= 0.02 + 0.002 + 1e-9          # at least 50 Hz (one control period late)
    every = [json.loads(x) for x in (run_dir / "log.jsonl").read_text().splitlines()]
    kept = set(rec.times)
    for a, b in zip(every, every[1:]):                              # every change of the reasons is kept
        if set(a["reasons"]) != set(b["reasons"]):
            assert b["t"] in kept
    assert rig_of_run(rec).name == "flacco-cell"
    bad = tmp_path / "bad"
    shutil.copytree(run_dir, bad)
    lines = (bad / "log.jsonl").read_text().splitlines()
    lines[7] = lines[7][:20]
    (bad / "log.jsonl").write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"log.jsonl line 8: not JSON"):
        load_run(bad)
    with pytest.raises(FileNotFoundError, match="not the output folder"):
        load_run(tmp_path)


def test_view_cli_errors_are_one_line(run_dir, tmp_path):
    import subprocess
    import sys

    def run(*args):
        return subprocess.run([sys.executable, "-m", "depthguard", "view", *args], capture_output=True,
                              text=True, timeout=120)

    r = run()
    assert r.returncode == 2 and "depthguard: error: give a monitor's output folder" in r.stderr
    r = run(str(tmp_path / "nothing"))
    assert r.returncode == 2 and "no such folder" in r.stderr
    shot = tmp_path / "x.png"
    shot.write_bytes(b"keep")
    r = run(str(run_dir), "--screenshot", str(shot))
    assert r.returncode == 2 and "exists already" in r.stderr and shot.read_bytes() == b"keep"
    r = run(str(run_dir), "--size", "12x9000")
    assert r.returncode == 2 and "--size" in r.stderr


def test_a_connection_closed_before_its_request_is_not_a_traceback():
    """websockets logs "opening handshake failed" with a traceback when a browser opens a
    speculative connection and closes it unused; the view's filter drops exactly that case."""
    import logging
    import sys

    from depthguard.viz.live import _ClosedBeforeRequest

    def record(exc):
        try:
            raise exc
        except Exception:
            info = sys.exc_info()
        return logging.LogRecord("websockets.server", logging.ERROR, __file__, 1, "opening handshake failed",
                                 None, info)

    closed = ValueError("did not receive a valid HTTP request")
    closed.__cause__ = EOFError("connection closed while reading HTTP request line")
    keep = _ClosedBeforeRequest()
    assert keep.filter(record(closed)) is False
    assert keep.filter(record(ValueError("bad Sec-WebSocket-Key"))) is True        # a real failure shows
    other = logging.LogRecord("websockets.server", logging.ERROR, __file__, 1, "something else", None, None)
    assert keep.filter(other) is True


def test_the_free_space_map_layer_is_the_maps_obstacle_voxels():
    """R37: a map handed to the view (``write_map``, as the monitor's map thread does) is drawn as
    the ``free-space map`` layer: its points are the centres of the voxels that are neither free
    nor the robot's body (truth: the map's own state array, voxel by voxel), coloured occupied /
    unknown apart; a later map in which that space is free clears it; the switch hides it."""
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.runtime.free_space_map import RuntimeFreeSpace
    from depthguard.sim import load_cell
    from depthguard.sources.simulated import SimSource
    from depthguard.viz.live import LiveView

    cell = load_cell("ur3-cell")
    rig = cell.rig
    t = cell.time_of("arm_reaching")
    q = cell.scene.robot_q(t)
    frames = SimSource(cell, seed=1).frames(t)
    rd = {c.id: np.asarray(ExpectedDepth(c, rig.robot, []).robot(q)) for c in rig.cameras}
    space = RuntimeFreeSpace(rig, robot_offset=rig.monitor.robot_offset, robot_padding=rig.monitor.robot_padding)
    snap = space.build({k: f.depth for k, f in frames.items()}, rd, q, {k: t for k in frames})
    with LiveView(rig, port=0, start=False) as view:
        assert len(view._map_cloud.points) == 0 and view.update() is False     # no map yet: nothing drawn
        view.write_map(snap)
        assert view.update() is True and view.maps_drawn == 1
        pts, cols = np.asarray(view._map_cloud.points), np.asarray(view._map_cloud.colors)
        g = snap.grid
        ijk = np.floor((pts - g.lo) / g.voxel_size).astype(int)
        np.testing.assert_allclose(pts, g.lo + (ijk + 0.5) * g.voxel_size, atol=1e-5)    # voxel centres
        drawn = np.zeros(g.shape, np.uint8)
        drawn[tuple(ijk.T)] = np.where((cols == scene.MAP_COLOURS[2]).all(axis=1), 2,
                                       np.where((cols == scene.MAP_COLOURS[1]).all(axis=1), 1, 9))
        want = np.where(snap.machine, 0, snap.state)
        assert np.array_equal(drawn, want) and len(pts) == np.count_nonzero(want)
        assert {1, 2} <= set(np.unique(drawn).tolist())
        assert view.update() is False                       # the same map is not drawn again
        cleared = type(snap)(**{**snap.__dict__, "state": np.zeros_like(snap.state)})   # every voxel seen free
        view.write_map(cleared)
        assert view.update() is True and len(view._map_cloud.points) == 0
        view.set_layer("free-space map", False)
        assert view._map_cloud.visible is False
