"""``depthguard view DIR|BAG``: a monitor's run with the depth of its bag, with a time slider (R29, R31).

Truths, each independent of the code under test:

- the frame shown at a log record is the one the monitor used: its capture stamp is the
  record's ``t - age_s`` (the log, read with ``json``), and its pixels are those that the
  ``mcap`` reader with ``mcap_ros2``'s CDR decoder reads from the bag; its capture joints are
  the bag's joint states interpolated with ``numpy.interp``;
- a bag written by another writer (``mcap_ros2.writer``) whose log times are not its stamps
  and whose images are not in stamp order gives back, image by image, what was written;
- ``depthguard view BAG`` replays the bag with the ``monitor`` command itself (``--fast``):
  every control cycle of the bag is in its log, and its summary names the bag;
- in a real browser (headless Chromium; skipped where none is installed), with the time
  slider moved on the server as a browser's slider does, the robot's pixels in the client's
  canvas render cover the robot's meshes projected by depthguard's own z-buffer at the
  joints of the log's record at that time, and not those of the other time.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

from depthguard.sources.bag import BagError
from depthguard.viz.browser import find_browser
from ros_defs import IMAGE_DEF, INFO_DEF, JOINT_DEF, _stamp

mcap_reader = pytest.importorskip("mcap.reader", reason="the mcap package (test extra) is the independent reader")
mcap_decoder = pytest.importorskip("mcap_ros2.decoder", reason="mcap-ros2-support (test extra) decodes CDR")
mcap_writer = pytest.importorskip("mcap_ros2.writer", reason="mcap-ros2-support (test extra) writes the foreign bag")

DG = [sys.executable, "-m", "depthguard"]
SECONDS = 2.0                   # of flacco-cell's "reach": the robot's first joint turns by about 0.17 rad


@pytest.fixture(scope="module")
def rig():
    from depthguard.sim import load_cell

    return load_cell("flacco-cell").rig


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A recorded bag and the output folder of ``depthguard view BAG``'s replay of it (the command
    ``monitor --source bag:BAG --fast``, kept with ``--out``): ``(bag, folder)``. In this process:
    the commands themselves, without a second interpreter's start-up."""
    from typer.main import get_command

    from depthguard.cli import app
    from depthguard.cli.view import _replay_bag

    root = tmp_path_factory.mktemp("replay")
    bag, out = root / "reach", root / "run"
    get_command(app).main(args=["record", "--cell", "flacco-cell", "--source", "sim:flacco-cell:reach",
                                "--duration", str(SECONDS), "--out", str(bag)], standalone_mode=False)
    folder, cleanup = _replay_bag(bag, None, "flacco-cell", out)
    assert folder == out and cleanup == []                       # --out: kept
    return bag, out


def _log(folder) -> list[dict]:
    return [json.loads(x) for x in (folder / "log.jsonl").read_text().splitlines()]


def _read_bag(bag):
    """Per camera ``{stamp: depth (H, W) float64 m}`` and the joint states ``(stamps (n,), q (n, dof))``,
    read by the mcap library and mcap_ros2's decoder."""
    images: dict[str, dict[float, np.ndarray]] = {}
    js_t, js_q = [], []
    path = bag if bag.is_file() else next(bag.glob("*.mcap"))
    with open(path, "rb") as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[mcap_decoder.DecoderFactory()])
        for _schema, channel, _message, msg in reader.iter_decoded_messages():
            stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9 if hasattr(msg, "header") else None
            if channel.topic.endswith("/depth/image_rect_raw"):
                cid = channel.topic.split("/")[1]
                assert msg.encoding == "16UC1"
                raw = np.frombuffer(bytes(msg.data), dtype="<u2").reshape(msg.height, msg.width)
                images.setdefault(cid, {})[stamp] = raw / 1000.0
            elif channel.topic == "/joint_states":
                js_t.append(stamp)
                js_q.append(list(msg.position))
    return images, (np.array(js_t), np.array(js_q))


# ------------------------------------------------------------------ the index, against the log and the bag
def test_each_record_shows_the_frame_the_monitor_used_decoded_on_demand(run, rig):
    from depthguard.viz.live_scene import snapshot_of_record
    from depthguard.viz.replay_index import BagDepth

    bag, out = run
    images, (js_t, js_q) = _read_bag(bag)
    t0 = time.perf_counter()
    depth = BagDepth(bag, rig, cache=4)
    open_s = time.perf_counter() - t0
    try:
        assert depth.decoded == 0                                   # indexing decodes no image
        for cid in ("cam0", "cam1"):
            np.testing.assert_allclose(depth.stamps[cid], sorted(images[cid]), atol=1e-9)
        records = _log(out)
        used = waiting = 0
        for rec in records:
            snap = snapshot_of_record(rec)
            for cid, st in rec["cameras"].items():
                i = depth.index_of_record(cid, snap)
                if st["age_s"] is None:
                    assert i is None and st["state"] == "waiting"
                    waiting += 1
                    continue
                assert i is not None, f"t={rec['t']}: {cid}'s frame in use is not in the index"
                assert abs(depth.stamps[cid][i] - (rec["t"] - st["age_s"])) <= 2e-6
                used += 1
        assert used > 0.9 * 2 * len(records)
        # a sample of records: the pixels and the capture joints, against the independent reader
        checked = 0
        for rec in records[:: max(1, len(records) // 6)]:
            prods = depth.products_of_record(snapshot_of_record(rec))
            for cid, p in prods.items():
                if p is None:
                    continue
                truth = images[cid][min(images[cid], key=lambda s: abs(s - p.stamp))]
                np.testing.assert_allclose(p.depth, truth, atol=1e-6)
                q_truth = [np.interp(p.stamp, js_t, js_q[:, j]) for j in range(js_q.shape[1])]
                np.testing.assert_allclose(p.q, q_truth, atol=1e-9)
                assert (p.robot_depth > 0).sum() > 1000          # the robot, rendered at those joints
                checked += 1
        assert checked >= 10
        assert len(depth._frames) <= depth.cache                  # decoded frames are forgotten
        assert depth.decoded <= checked
        print(f"index of {sum(len(s) for s in depth.stamps.values())} images in {open_s:.2f} s; "
              f"{used} frames in use matched, {waiting} waiting; {checked} decoded and compared")
    finally:
        depth.close()


def _write_foreign(path, rig, joints=True, bad_at=None):
    """An .mcap by mcap_ros2.writer: 4 frames per camera, log time = stamp + 30 ms, written in reverse
    stamp order (``bad_at``: and one image of cam0 at that stamp in an encoding that is not depth);
    returns ``{camera: {stamp: depth}}``."""
    rng = np.random.default_rng(7)
    written: dict[str, dict[float, np.ndarray]] = {}
    with open(path, "wb") as fh:
        w = mcap_writer.Writer(fh)
        s_img = w.register_msgdef("sensor_msgs/msg/Image", IMAGE_DEF)
        s_info = w.register_msgdef("sensor_msgs/msg/CameraInfo", INFO_DEF)
        s_js = w.register_msgdef("sensor_msgs/msg/JointState", JOINT_DEF)
        if joints:
            for k in range(60):
                s = 0.01 * k
                w.write_message("/joint_states", s_js, {"header": {"stamp": _stamp(s), "frame_id": ""},
                                                        "name": list(rig.robot.joint_names),
                                                        "position": list(map(float, rig.robot_q0)), "velocity": [],
                                                        "effort": []}, log_time=round(s * 1e9), publish_time=round(s * 1e9))
        for k in reversed(range(4)):
            for cam in rig.cameras:
                s = 0.1 * k + 0.05
                mm = rng.integers(0, 4000, size=(cam.height, cam.width)).astype("<u2")
                written.setdefault(cam.id, {})[s] = mm / 1000.0
                hdr = {"stamp": _stamp(s), "frame_id": f"{cam.id}_optical"}
                log = round(s * 1e9) + 3 * 10**7
                w.write_message(f"/{cam.id}/depth/image_rect_raw", s_img,
                                {"header": hdr, "height": cam.height, "width": cam.width, "encoding": "16UC1",
                                 "is_bigendian": 0, "step": cam.width * 2, "data": mm.tobytes()},
                                log_time=log, publish_time=log)
                w.write_message(f"/{cam.id}/depth/camera_info", s_info,
                                {"header": hdr, "height": cam.height, "width": cam.width, "distortion_model": "plumb_bob",
                                 "d": [0.0] * 5, "k": [cam.fx, 0, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1],
                                 "r": [1.0, 0, 0, 0, 1, 0, 0, 0, 1], "p": [cam.fx, 0, cam.cx, 0, 0, cam.fy, cam.cy, 0, 0, 0, 1, 0],
                                 "binning_x": 0, "binning_y": 0,
                                 "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}},
                                log_time=log, publish_time=log)
        if bad_at is not None:
            cam = rig.cameras[0]
            w.write_message(f"/{cam.id}/depth/image_rect_raw", s_img,
                            {"header": {"stamp": _stamp(bad_at), "frame_id": "x"}, "height": cam.height,
                             "width": cam.width, "encoding": "rgb8", "is_bigendian": 0, "step": cam.width * 3,
                             "data": bytes(cam.width * cam.height * 3)},
                            log_time=round(bad_at * 1e9), publish_time=round(bad_at * 1e9))
        w.finish()
    return written


def test_another_writers_bag_gives_back_each_image_by_its_stamp(rig, tmp_path):
    from depthguard.viz.replay_index import BagDepth

    path = tmp_path / "foreign.mcap"
    written = _write_foreign(path, rig)
    depth = BagDepth(path, rig, cache=2)
    try:
        for cid, frames in written.items():
            np.testing.assert_allclose(depth.stamps[cid], sorted(frames), atol=1e-9)
            for i in (2, 0, 3, 1):                               # random access, backwards too
                np.testing.assert_allclose(depth.depth(cid, i), frames[sorted(frames)[i]], atol=1e-6)
            assert depth.index_at(cid, 0.2) == 1 and depth.index_at(cid, 0.04) is None
        assert depth.decoded == 8
    finally:
        depth.close()
    with pytest.raises(BagError, match="JointState"):            # a bag without joints: named
        BagDepth(_write_foreign_path(tmp_path, rig), rig)
    # an image that cannot be decoded: named when it is shown, the other camera is still drawn
    from depthguard.viz.live_scene import Snapshot

    path = tmp_path / "bad.mcap"
    _write_foreign(path, rig, bad_at=0.45)
    depth = BagDepth(path, rig)
    try:
        cams = {c.id: {"age_s": 0.0, "state": "fresh"} for c in rig.cameras}
        cams[rig.cameras[1].id]["age_s"] = 0.1                      # its frame at 0.35 s
        snap = Snapshot(0.45, 1.0, {}, (), np.zeros(0), np.zeros((0, 3)), np.zeros(0, bool), np.zeros(0, bool), cams)
        errors: list = []
        prods = depth.products_of_record(snap, errors)
        assert prods[rig.cameras[0].id] is None and prods[rig.cameras[1].id].stamp == pytest.approx(0.35)
        assert len(errors) == 1 and "cannot be read" in errors[0] and "rgb8" in errors[0]
        with pytest.raises(BagError, match="cannot be read"):
            depth.products_of_record(snap)
    finally:
        depth.close()


def _write_foreign_path(tmp_path, rig):
    path = tmp_path / "no_joints.mcap"
    _write_foreign(path, rig, joints=False)
    return path


# ------------------------------------------------------------------ a bag alone; bad input
def test_a_bag_alone_is_replayed_by_the_monitor_as_fast_as_possible(run):
    bag, out = run
    summary = json.loads((out / "summary.json").read_text())
    assert summary["sources"] == {"frames": [f"bag:{bag}"], "joints": f"bag:{bag}"}
    assert summary["fast"] is True and not summary["interrupted"]
    records = _log(out)
    assert len(records) == round(SECONDS / 0.002) + 1                # every control cycle of the bag
    assert records[0]["t"] == 0.0 and records[-1]["t"] == pytest.approx(SECONDS)


def test_play_moves_the_slider_at_the_chosen_speed_and_draws_the_bags_frames(run):
    from depthguard.viz.live import LiveView
    from depthguard.viz.replay import Replay, open_run

    source = open_run(run[1])
    try:
        with LiveView(source.rig, port=0) as view:
            replay = Replay(view, source)
            replay.speed_box.value = 0.5                       # as a browser's number box does
            assert replay.speed == 0.5
            replay.seek(0.1)
            w0 = time.monotonic()
            replay.play.value = True
            time.sleep(1.0)
            replay.play.value = False
            wall = time.monotonic() - w0
            time.sleep(3 * view.period)
            t = float(replay.slider.value)
            assert 0.1 + 0.5 * (wall - 0.3) <= t <= 0.1 + 0.5 * wall + 0.05, f"slider at {t} after {wall:.2f} s"
            assert replay.shown.t <= t and abs(replay.shown.t - t) < 0.03
            drawn = {cid: v for cid, v in view._versions.items()}
            assert all(v is not None for v in drawn.values()) and set(drawn) == {"cam0", "cam1"}
            assert len(view._clouds["cam0"][0].points) > 100        # the bag's frame, subsampled, minus the known scene
            replay.close()
            assert view.errors == []
    finally:
        source.close()


def test_bad_input_is_one_clear_error(run, rig, tmp_path):
    from depthguard.viz.replay import bag_of_run, open_run
    from depthguard.viz.playback import load_run

    bag, out = run

    def view(*args):
        return subprocess.run(DG + ["view", *map(str, args)], capture_output=True, text=True, timeout=120)

    empty = tmp_path / "empty"
    empty.mkdir()
    r = view(empty)
    assert r.returncode == 2 and "no log.jsonl" in r.stderr and "Traceback" not in r.stderr
    cut = tmp_path / "cut"
    shutil.copytree(out, cut)
    lines = (cut / "log.jsonl").read_text().splitlines()
    (cut / "log.jsonl").write_text("\n".join(lines[:-1] + [lines[-1][:37]]) + "\n")    # a killed monitor's last line
    with pytest.raises(ValueError, match=f"log.jsonl line {len(lines)}: not JSON"):
        open_run(cut, bag=bag)
    no_joints = _write_foreign_path(tmp_path, rig)
    r = view(no_joints)
    assert r.returncode == 2 and "JointState" in r.stderr and "Traceback" not in r.stderr
    with pytest.raises(BagError, match="does not hold the frames this run used"):
        other = tmp_path / "other.mcap"
        _write_foreign(other, rig)
        open_run(out, bag=other)
    with pytest.raises(FileNotFoundError, match="no such bag"):
        open_run(out, bag=tmp_path / "nothing.mcap")
    # the summary names the run's bag: found here, or a sentence saying to give --bag
    rec = load_run(out)
    assert bag_of_run(rec)[0] == bag
    rec.summary["sources"]["frames"] = ["bag:/nowhere/reach"]
    assert bag_of_run(rec)[0] is None and "--bag" in bag_of_run(rec)[1]
    rec.summary["sources"]["frames"] = ["sim:flacco-cell"]
    assert bag_of_run(rec)[0] is None and "not from a bag" in bag_of_run(rec)[1]


# ------------------------------------------------------------------ in a real browser
W, H = 480, 360
FOV = math.radians(45.0)


def _look(eye, target):
    """world_from_camera (4, 4), OpenCV axes, world +z up."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    T[:3, 3] = eye
    return T


def _robot_mask(robot, q, T) -> np.ndarray:
    from depthguard.camera import Camera
    from depthguard.render import Renderer

    f = (H / 2.0) / math.tan(FOV / 2.0)
    cam = Camera("viewer", W, H, f, f, W / 2.0 - 0.5, H / 2.0 - 0.5, T, min_range=0.05, max_range=30.0)
    return np.asarray(Renderer(cam).render(robot.link_meshes(q), cull_back=False)[0]) > 0


def _orange(img) -> np.ndarray:
    rgb = img[..., :3].astype(int)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    return (img[..., 3] > 128) & (r > 90) & (r - b > 60) & (g < 0.75 * r) & (g > b)


def _iou(a, b) -> float:
    return float((a & b).sum()) / max(1, int((a | b).sum()))


@pytest.mark.skipif(find_browser() is None,
                    reason="no Chromium: install the Debian package `chromium` (or set DEPTHGUARD_BROWSER)")
def _settled_render(client, wxyz, position, deadline: float = 30.0):
    """The browser's render once two in a row show the robot's pixels alike (a loaded machine's
    software WebGL may answer before it has applied the last poses and hidden layers)."""
    end = time.monotonic() + deadline
    prev = None
    while True:
        img = client.get_render(H, W, wxyz=wxyz, position=position, fov=FOV, transport_format="png", timeout=60.0)
        if (prev is not None and np.array_equal(_orange(img), _orange(prev))) or time.monotonic() > end:
            return img
        prev = img
        time.sleep(0.3)


def test_browser_shows_the_robot_at_the_sliders_time(run, rig):
    from viser import transforms as vtf

    from depthguard.viz.browser import HeadlessBrowser, wait_for_client
    from depthguard.viz.live import LAYERS, LiveView
    from depthguard.viz.replay import Replay, open_run

    bag, out = run
    records = _log(out)
    t_a, t_b = 0.2, SECONDS - 0.2
    q_at = {t: np.array([r for r in records if r["t"] <= t + 1e-9][-1]["q"]) for t in (t_a, t_b)}
    assert abs(q_at[t_a] - q_at[t_b]).max() > 0.1, "the robot hardly moved (test set-up)"
    T = _look((1.9, -1.1, 1.2), (-0.3, 0.0, 0.35))
    wxyz = vtf.SO3.from_matrix(T[:3, :3]).wxyz
    source = open_run(out)                                       # the bag named in the summary
    assert source.depth is not None
    t0 = time.monotonic()
    renders, panels = {}, {}
    try:
        with LiveView(source.rig, port=0) as view, HeadlessBrowser(view.url, size=(1024, 768)) as browser:
            replay = Replay(view, source)
            client = wait_for_client(view.server, 30.0)

            def shown(t):
                replay.seek(t)                                   # the slider, moved on the server
                # the view's robot at the slider's joints, and its panel's text (written at most 4
                # times a second, so it can come a few periods after the robot); a loaded machine
                # takes its time: wait on both, up to a generous deadline
                end = time.monotonic() + 30.0
                while ((view.shown_q is None or abs(view.shown_q - q_at[t]).max() > 2e-3
                        or f"t = {t:.2f} s" not in view.gui_panel.content) and time.monotonic() < end):
                    time.sleep(0.05)
                time.sleep(4 * view.period)                      # the client's draw
                panels[t] = view.gui_panel.content

            shown(t_a)
            renders["full"] = client.get_render(H, W, wxyz=wxyz, position=T[:3, 3], fov=FOV,
                                                transport_format="png", timeout=60.0)
            for name in LAYERS:
                view.set_layer(name, name == "robot")
            for t in (t_a, t_b):
                shown(t)
                renders[t] = _settled_render(client, wxyz, T[:3, 3])
            assert browser.proc.poll() is None
            replay.close()
            assert view.errors == []
    finally:
        source.close()
    full = renders["full"]
    rgb = full[..., :3].astype(int)
    drawn = full[..., 3] > 128
    points = drawn & (rgb[..., 2] > 150) & (rgb[..., 1] < 130)             # frame points: blue / violet
    assert _orange(full).sum() > 300 and points.sum() > 30, "robot or the bag's points missing"
    for t in (t_a, t_b):
        assert f"t = {t:.2f} s" in panels[t]
    ious = {}
    for t, other in ((t_a, t_b), (t_b, t_a)):
        seen = _orange(renders[t])
        ious[t] = (_iou(seen, _robot_mask(rig.robot, q_at[t], T)), _iou(seen, _robot_mask(rig.robot, q_at[other], T)))
    print(f"robot IoU at its time / at the other time: {ious}; frame points {points.sum()} px; "
          f"{time.monotonic() - t0:.1f} s")
    for t, (right, wrong) in ious.items():
        assert right > 0.85, f"t={t}: robot pixels overlap their projection by only IoU {right:.3f}"
        assert right > wrong + 0.1, f"t={t}: the other time's joints fit as well ({wrong:.3f})"
