"""ROS 2 bags in the topic layouts of the common depth drivers (R31, issue 31 point 5).

Each bag is written with ``rosbags`` (the independent writer: its own typestore and CDR
serialiser) in the layout a driver publishes — its topic names, message types, encodings and
frames, with colour and infrared topics beside the depth (infrared in ``mono16`` like 16-bit
depth) and the driver's ``/tf_static`` chain under a user's mount transform. ``rig from-bag``
must find the depth cameras (and only them), their intrinsics and their poses; ``bag:`` must
then serve every depth frame with the values written. The truth: each camera's optical pose is
chosen first (``look_at`` below, numpy) and the TF edges are derived from it (scipy's rotation
as the quaternion converter); the intrinsics are the numbers written.
"""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from depthguard.rig import Rig
from depthguard.sources.bag import BagFrames, BagReplay
from depthguard.sources.rig_draft import draft_rig

rosbag2 = pytest.importorskip("rosbags.rosbag2", reason="rosbags is the independent writer")
from rosbags.typesys import Stores, get_typestore  # noqa: E402

TS = get_typestore(Stores.ROS2_HUMBLE)
T = {n: TS.types[n] for n in ("sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo", "sensor_msgs/msg/RegionOfInterest",
                                "std_msgs/msg/Header", "builtin_interfaces/msg/Time", "tf2_msgs/msg/TFMessage",
                                "geometry_msgs/msg/TransformStamped", "geometry_msgs/msg/Transform",
                                "geometry_msgs/msg/Vector3", "geometry_msgs/msg/Quaternion")}
N_FRAMES = 4
HZ = 15.0
W, H = 64, 48                     # small images: the layout is what is tested, not the size
WORKSPACE = "workspace: {min: [-2.0, -2.0, 0.0], max: [2.0, 2.0, 2.5]}\n"
#: optical frame in a ROS body frame (x forward, y left, z up): z forward, x right, y down
BODY_FROM_OPTICAL = np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 0, 1]], dtype=float)


def look_at(eye, target) -> np.ndarray:
    """world_from_optical of a camera at ``eye`` looking at ``target`` (world z up)."""
    z = np.subtract(target, eye, dtype=float)
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    M = np.eye(4)
    M[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    M[:3, 3] = eye
    return M


def _stamp(s: float):
    ns = round(s * 1e9)
    return T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)


def _header(s, frame):
    return T["std_msgs/msg/Header"](stamp=_stamp(s), frame_id=frame)


def _info(s, frame, k, d=(), model="plumb_bob", p=None):
    fx, fy, cx, cy = k
    K = np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1], float)
    P = np.array(p if p is not None else [fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0], float)
    roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return T["sensor_msgs/msg/CameraInfo"](header=_header(s, frame), height=H, width=W, distortion_model=model,
                                           d=np.array(d, float), k=K, r=np.eye(3).ravel(), p=P,
                                           binning_x=0, binning_y=0, roi=roi)


def _image(s, frame, encoding, values: np.ndarray):
    data = np.ascontiguousarray(values).view(np.uint8).ravel()
    return T["sensor_msgs/msg/Image"](header=_header(s, frame), height=H, width=W, encoding=encoding, is_bigendian=0,
                                      step=W * values.dtype.itemsize, data=data)


def _tf(parent, child, M):
    q = Rotation.from_matrix(M[:3, :3]).as_quat()          # x, y, z, w
    tr = T["geometry_msgs/msg/Transform"](translation=T["geometry_msgs/msg/Vector3"](x=M[0, 3], y=M[1, 3], z=M[2, 3]),
                                          rotation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]))
    return T["geometry_msgs/msg/TransformStamped"](header=_header(0.0, parent), child_frame_id=child, transform=tr)


def _depth_values(k: int, encoding: str) -> tuple[np.ndarray, np.ndarray]:
    """(values as written, metres as float64: 0 = no return)."""
    rng = np.random.default_rng(k)
    m = rng.uniform(0.5, 3.0, size=(H, W))
    m[rng.random((H, W)) < 0.1] = 0.0
    if encoding == "32FC1":
        v = m.astype("<f4")
        v[m == 0] = np.nan                                    # REP 117: no return
        return v, np.where(m == 0, 0.0, v.astype(np.float64))
    v = np.rint(m * 1000).astype("<u2")
    return v, v / 1000.0


def _other_values(encoding: str) -> np.ndarray:
    chans = {"rgb8": 3, "bgra8": 4, "mono8": 1}.get(encoding)
    if chans is None:                                       # mono16 infrared: looks like 16-bit depth
        return np.full((H, W), 700, dtype="<u2")
    return np.full((H, W * chans), 90, dtype=np.uint8)


def write_bag(path, streams, tf_edges, storage="mcap"):
    """``streams``: ``(image topic, encoding, frame, info kwargs or None)``; returns
    ``{topic: [(stamp, metres)]}`` of the depth topics."""
    written: dict[str, list] = {}
    plugin = rosbag2.StoragePlugin.MCAP if storage == "mcap" else rosbag2.StoragePlugin.SQLITE3
    with rosbag2.Writer(path, version=8, storage_plugin=plugin) as w:
        img_c = {t: w.add_connection(t, "sensor_msgs/msg/Image", typestore=TS) for t, *_ in streams}
        info_c = {t: w.add_connection(t.rsplit("/", 1)[0] + "/camera_info", "sensor_msgs/msg/CameraInfo", typestore=TS)
                  for t, _e, _f, info in streams if info is not None}
        tf_c = w.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=TS)
        w.write(tf_c, 1, TS.serialize_cdr(T["tf2_msgs/msg/TFMessage"](transforms=[_tf(*e) for e in tf_edges]),
                                          "tf2_msgs/msg/TFMessage"))
        for n in range(N_FRAMES):
            s = 100.0 + n / HZ
            for i, (topic, enc, frame, info) in enumerate(streams):
                if enc in ("16UC1", "32FC1") or "depth" in topic:
                    values, metres = _depth_values(1000 * i + n, enc)
                    written.setdefault(topic, []).append((s, metres))
                else:
                    values = _other_values(enc)
                log = round(s * 1e9) + 1000 * i
                if info is not None:
                    w.write(info_c[topic], log, TS.serialize_cdr(_info(s, frame, **info), "sensor_msgs/msg/CameraInfo"))
                w.write(img_c[topic], log + 1, TS.serialize_cdr(_image(s, frame, enc, values), "sensor_msgs/msg/Image"))
    return written


# ------------------------------------------------------------------ the layouts
K_DEPTH = (52.1, 52.3, 31.7, 23.9)
K_COLOR = (61.0, 60.8, 32.2, 24.1)
WORLD_FROM_CAM = look_at([1.3, -0.9, 2.0], [0.0, 0.0, 0.8])
COLOR_FROM_DEPTH = np.eye(4)
COLOR_FROM_DEPTH[:3, 3] = (-0.015, 0.0, 0.0)                 # the colour imager 15 mm to the depth's left


def realsense(mount: np.ndarray, name: str = "camera"):
    """realsense-ros 4.x, camera_namespace = camera_name = ``name`` (default ``camera``), align_depth.enable:
    true; its frames are prefixed with the camera's name (``camera_link``, ``camera_depth_optical_frame``)."""
    ns = f"/{name}/{name}"
    world_from_link = mount @ np.linalg.inv(BODY_FROM_OPTICAL)        # camera_link: x forward, z up
    color_frame = BODY_FROM_OPTICAL @ np.linalg.inv(COLOR_FROM_DEPTH) @ np.linalg.inv(BODY_FROM_OPTICAL)
    f = name
    streams = [(f"{ns}/depth/image_rect_raw", "16UC1", f"{f}_depth_optical_frame", {"k": K_DEPTH, "d": [0.0] * 5}),
               (f"{ns}/aligned_depth_to_color/image_raw", "16UC1", f"{f}_color_optical_frame", {"k": K_COLOR, "d": [0.0] * 5}),
               (f"{ns}/color/image_raw", "rgb8", f"{f}_color_optical_frame", {"k": K_COLOR, "d": [0.0] * 5}),
               (f"{ns}/infra1/image_rect_raw", "mono8", f"{f}_infra1_optical_frame", {"k": K_DEPTH, "d": [0.0] * 5})]
    tf = [("world", f"{f}_link", world_from_link), (f"{f}_link", f"{f}_depth_frame", np.eye(4)),
          (f"{f}_depth_frame", f"{f}_depth_optical_frame", BODY_FROM_OPTICAL),
          (f"{f}_link", f"{f}_color_frame", color_frame),
          (f"{f}_color_frame", f"{f}_color_optical_frame", BODY_FROM_OPTICAL)]
    return streams, tf, {name: (f"{ns}/depth/image_rect_raw", K_DEPTH, mount)}


def two_realsense(mount: np.ndarray):
    """Two realsense-ros cameras started as ``left`` and ``right`` (docs/OWN_CELL.md), one bag."""
    s1, t1, c1 = realsense(mount, "left")
    s2, t2, c2 = realsense(look_at([1.0, 1.0, 2.0], [0.0, 0.0, 0.8]), "right")
    return s1 + s2, t1 + t2, {**c1, **c2}


def orbbec(mount: np.ndarray):
    """OrbbecSDK_ROS2 (camera_name = camera): depth, colour and infrared in mono16."""
    world_from_link = mount @ np.linalg.inv(BODY_FROM_OPTICAL)
    streams = [("/camera/depth/image_raw", "16UC1", "camera_depth_optical_frame", {"k": K_DEPTH, "d": [0.0] * 5}),
               ("/camera/ir/image_raw", "mono16", "camera_ir_optical_frame", {"k": K_DEPTH, "d": [0.0] * 5}),
               ("/camera/color/image_raw", "rgb8", "camera_color_optical_frame", {"k": K_COLOR, "d": [0.0] * 5})]
    tf = [("world", "camera_link", world_from_link), ("camera_link", "camera_depth_frame", np.eye(4)),
          ("camera_depth_frame", "camera_depth_optical_frame", BODY_FROM_OPTICAL)]
    return streams, tf, {"camera": ("/camera/depth/image_raw", K_DEPTH, mount)}


RATIONAL = [0.52, -2.71, 0.0001, -0.0002, 1.51, 0.39, -2.54, 1.43]     # k1 k2 p1 p2 k3 k4 k5 k6 (a K4A's kind)
P_RECT = (49.0, 49.2, 32.0, 24.0)


def azure(mount: np.ndarray):
    """Azure_Kinect_ROS_Driver (depth_unit 32FC1), its raw depth with the lens's rational_polynomial
    distortion and image_proc's rectified depth beside it (P = the rectified intrinsics)."""
    px, py, pcx, pcy = P_RECT
    p = [px, 0, pcx, 0, 0, py, pcy, 0, 0, 0, 1, 0]
    base_from_depth = BODY_FROM_OPTICAL.copy()
    base_from_depth[2, 3] = 0.0018
    world_from_base = mount @ np.linalg.inv(base_from_depth)
    raw = {"k": K_DEPTH, "d": RATIONAL, "model": "rational_polynomial", "p": p}
    streams = [("/depth/image_raw", "32FC1", "depth_camera_link", raw),
               ("/depth/image_rect", "32FC1", "depth_camera_link", None),          # its CameraInfo: /depth/camera_info
               ("/depth_to_rgb/image_raw", "32FC1", "rgb_camera_link", {"k": K_COLOR, "d": RATIONAL, "model": "rational_polynomial"}),
               ("/ir/image_raw", "mono16", "depth_camera_link", raw),
               ("/rgb/image_raw", "bgra8", "rgb_camera_link", {"k": K_COLOR, "d": RATIONAL, "model": "rational_polynomial"})]
    tf = [("world", "camera_base", world_from_base), ("camera_base", "depth_camera_link", base_from_depth),
          ("depth_camera_link", "rgb_camera_link", np.linalg.inv(COLOR_FROM_DEPTH))]
    return streams, tf, {"depth": ("/depth/image_rect", P_RECT, mount)}


def _load_draft(bag, tmp_path, name):
    out = tmp_path / f"{name}.yaml"
    text, notes = draft_rig(bag, out)
    out.write_text(text + WORKSPACE)
    return Rig.load(out), text, notes


@pytest.mark.parametrize("layout, storage", [(realsense, "mcap"), (two_realsense, "mcap"), (orbbec, "sqlite3"),
                                             (azure, "mcap")])
def test_each_driver_layout_plays_with_its_intrinsics_and_pose(tmp_path, layout, storage):
    streams, tf, cameras = layout(WORLD_FROM_CAM)
    bag = tmp_path / "bag"
    written = write_bag(bag, streams, tf, storage)
    rig, text, notes = _load_draft(bag, tmp_path, layout.__name__)
    assert sorted(rig.camera_ids) == sorted(cameras), text               # only the depth cameras, once each
    for cid, (topic, (fx, fy, cx, cy), world_from_optical) in cameras.items():
        cam = next(c for c in rig.cameras if c.id == cid)
        assert rig.topics[cid] == topic
        assert (cam.width, cam.height) == (W, H)
        np.testing.assert_allclose([cam.fx, cam.fy, cam.cx, cam.cy], [fx, fy, cx, cy], atol=1e-9)
        np.testing.assert_allclose(cam.world_from_camera, world_from_optical, atol=1e-6)
        forward = cam.world_from_camera[:3, 2]                               # the optical axis hits the target
        to_target = np.subtract([0.0, 0.0, 0.8], cam.world_from_camera[:3, 3])
        assert np.dot(forward, to_target / np.linalg.norm(to_target)) > 0.999999
    replay = BagReplay(bag)
    frames = BagFrames(replay, rig)
    try:
        got = frames.frames_until(math.inf)
    finally:
        frames.close()
        replay.close()
    assert frames.skipped == 0, frames.counts
    for cid, (topic, _k, _p) in cameras.items():
        mine = [f for f in got if f.camera_id == cid]
        assert len(mine) == len(written[topic]) == N_FRAMES
        for f, (s, metres) in zip(mine, written[topic]):
            assert f.stamp == pytest.approx(s, abs=1e-9)
            np.testing.assert_allclose(f.depth, metres, rtol=0, atol=1e-6)


def test_what_was_left_out_is_said(tmp_path):
    streams, tf, _ = azure(WORLD_FROM_CAM)
    write_bag(tmp_path / "bag", streams, tf)
    _rig, _text, notes = _load_draft(tmp_path / "bag", tmp_path, "azure")
    said = "\n".join(notes)
    assert "/depth/image_raw: CameraInfo has non-zero distortion (rational_polynomial" in said   # the raw lens image
    assert "/depth_to_rgb/image_raw: CameraInfo has non-zero distortion" in said
    assert "/ir/image_raw" in said and "/rgb/image_raw" in said and "not depth" in said
    streams, tf, _ = realsense(WORLD_FROM_CAM)
    write_bag(tmp_path / "rs", streams, tf)
    _rig, _text, notes = _load_draft(tmp_path / "rs", tmp_path, "rs")
    assert any(n.startswith("/camera/camera/aligned_depth_to_color/image_raw: the depth of camera camera again")
               for n in notes), notes


def test_a_rectified_topic_must_agree_with_P_not_K(tmp_path):
    """A rig written with the raw K for image_proc's rectified depth is refused with a sentence."""
    from depthguard.sources.bag import BagError

    streams, tf, _ = azure(WORLD_FROM_CAM)
    write_bag(tmp_path / "bag", streams, tf)
    rig, text, _ = _load_draft(tmp_path / "bag", tmp_path, "azure")
    wrong = tmp_path / "wrong.yaml"
    fx, fy, cx, cy = K_DEPTH
    wrong.write_text(text.replace(f"fx: {P_RECT[0]!r}", f"fx: {fx!r}") + WORKSPACE)
    replay = BagReplay(tmp_path / "bag")
    frames = BagFrames(replay, Rig.load(wrong))
    try:
        with pytest.raises(BagError, match=r"/depth/camera_info .* disagrees with camera depth of the rig: fx=49 \(rig 52.1\)"):
            frames.frames_until(math.inf)
    finally:
        frames.close()
        replay.close()


DG = [sys.executable, "-m", "depthguard.cli"]


def test_a_bag_without_depth_or_without_camera_info_is_one_line(tmp_path):
    streams, tf, _ = orbbec(WORLD_FROM_CAM)
    no_depth = [s for s in streams if "/depth/" not in s[0]]
    write_bag(tmp_path / "nodepth", no_depth, tf)
    no_info = [(t, e, f, None) for t, e, f, _i in streams]
    write_bag(tmp_path / "noinfo", no_info, tf)
    for bag, words in (("nodepth", "no depth Image topic with a usable CameraInfo beside it (image topics: "
                                   "/camera/color/image_raw (rgb8), /camera/ir/image_raw (mono16)"),
                       ("noinfo", "/camera/depth/image_raw: no CameraInfo on /camera/depth/camera_info")):
        res = subprocess.run(DG + ["rig", "from-bag", str(tmp_path / bag), "--out", str(tmp_path / f"{bag}.yaml")],
                             capture_output=True, text=True, timeout=120)
        assert res.returncode == 2, res.stderr
        assert words in res.stderr and "Traceback" not in res.stderr, res.stderr
        assert len(res.stderr.strip().splitlines()) == 1, res.stderr
