"""Test helpers for ROS 2 over Zenoh, written from rmw_zenoh's ``docs/design.md`` (Jazzy), not with
depthguard's module: hand-written message definitions, the independent CDR codec
(``mcap_ros2``), a real Zenoh router fixture, and :class:`ForeignNode`, a "ROS camera node" that
publishes as rmw_zenoh does. Shared by ``test_ros2_zenoh.py`` and ``test_ros2_zenoh_monitor.py``.
"""

from __future__ import annotations

import json
import socket
import struct
import time

import numpy as np
import pytest

zenoh = pytest.importorskip("zenoh", reason="eclipse-zenoh is the transport")
mcap_dynamic = pytest.importorskip("mcap_ros2._dynamic", reason="mcap-ros2-support (test extra) is the independent CDR codec")

from ros_defs import IMAGE_DEF, INFO_DEF, JOINT_DEF, _stamp  # noqa: E402

FLOAT64_DEF = "float64 data"
_SEP = "\n" + "=" * 80 + "\n"
_HDR = "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id" + _SEP + "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec"
_VEC = "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z"
MARKERS_DEF = (
    "visualization_msgs/Marker[] markers" + _SEP +
    "MSG: visualization_msgs/Marker\nstd_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\n"
    "geometry_msgs/Pose pose\ngeometry_msgs/Vector3 scale\nstd_msgs/ColorRGBA color\nbuiltin_interfaces/Duration lifetime\n"
    "bool frame_locked\ngeometry_msgs/Point[] points\nstd_msgs/ColorRGBA[] colors\nstring texture_resource\n"
    "sensor_msgs/CompressedImage texture\nvisualization_msgs/UVCoordinate[] uv_coordinates\nstring text\n"
    "string mesh_resource\nvisualization_msgs/MeshFile mesh_file\nbool mesh_use_embedded_materials" + _SEP + _HDR + _SEP +
    "MSG: geometry_msgs/Pose\ngeometry_msgs/Point position\ngeometry_msgs/Quaternion orientation" + _SEP +
    "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z" + _SEP +
    "MSG: geometry_msgs/Quaternion\nfloat64 x\nfloat64 y\nfloat64 z\nfloat64 w" + _SEP + _VEC + _SEP +
    "MSG: std_msgs/ColorRGBA\nfloat32 r\nfloat32 g\nfloat32 b\nfloat32 a" + _SEP +
    "MSG: builtin_interfaces/Duration\nint32 sec\nuint32 nanosec" + _SEP +
    "MSG: sensor_msgs/CompressedImage\nstd_msgs/Header header\nstring format\nuint8[] data" + _SEP +
    "MSG: visualization_msgs/UVCoordinate\nfloat32 u\nfloat32 v" + _SEP +
    "MSG: visualization_msgs/MeshFile\nstring filename\nuint8[] data")
REACTION_DEF = (
    "std_msgs/Header header\nfloat64 override\ngeometry_msgs/Vector3 repulsion\nfloat64[] qd_min\nfloat64[] qd_max\n"
    "string[] names\nbool[] watch\nbool[] observed\nbool[] within_rho\nfloat64[] distance\n"
    "geometry_msgs/Vector3[] direction\nstring[] reason_keys\nstring[] reason_texts\nstring[] cameras\n"
    "string[] camera_states\nfloat64[] camera_age_s\nfloat64 joints_age_s\nfloat64[] q" + _SEP + _HDR + _SEP + _VEC)


def decoder(name: str, definition: str):
    return mcap_dynamic.generate_dynamic(name, definition)[name]


def encoder(name: str, definition: str):
    return mcap_dynamic.serialize_dynamic(name, definition)[name]


def free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


@pytest.fixture(scope="module")
def router():
    """A real Zenoh router on loopback (what `rmw_zenohd` is), its endpoint."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"router"')
    cfg.insert_json5("listen/endpoints", json.dumps([ep]))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(cfg)
    yield ep
    session.close()


def client(ep: str):
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"client"')
    cfg.insert_json5("connect/endpoints", json.dumps([ep]))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(cfg)


def wait_for(pred, timeout=5.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.01)
    return pred()


def tokens(session, domain=0) -> set[str]:
    return {str(r.ok.key_expr) for r in session.liveliness().get(f"@ros2_lv/{domain}/**", timeout=2.0) if r.ok}


class ForeignNode:
    """A ROS 2 publisher as rmw_zenoh makes one, written from the design doc (not depthguard's module)."""

    def __init__(self, ep: str, domain: int = 0):
        from rosbags.typesys import Stores, get_typestore

        self.session, self.domain = client(ep), domain
        self.hash = get_typestore(Stores.ROS2_JAZZY).hash_rihs01
        self.seq: dict[str, int] = {}
        self.enc = {"Image": encoder("sensor_msgs/msg/Image", IMAGE_DEF),
                    "CameraInfo": encoder("sensor_msgs/msg/CameraInfo", INFO_DEF),
                    "JointState": encoder("sensor_msgs/msg/JointState", JOINT_DEF)}

    def key(self, topic: str, msgtype: str, hash_: str | None = None) -> str:
        pkg, _msg, name = msgtype.split("/")
        return f"{self.domain}/{topic.lstrip('/')}/{pkg}::msg::dds_::{name}_/{hash_ or self.hash(msgtype)}"

    def put(self, key: str, payload: bytes, attachment: bytes | None = b"default") -> None:
        if attachment == b"default":
            self.seq[key] = self.seq.get(key, 0) + 1
            attachment = struct.pack("<qqB", self.seq[key], time.time_ns(), 16) + bytes(range(16))
        self.session.put(key, payload, attachment=attachment, congestion_control=zenoh.CongestionControl.BLOCK)

    def send(self, topic: str, kind: str, body: dict) -> None:
        self.put(self.key(topic, f"sensor_msgs/msg/{kind}"), self.enc[kind](body))

    def image(self, cam, stamp: float, values: np.ndarray, encoding: str, topic: str | None = None, **over) -> None:
        body = {"header": {"stamp": _stamp(stamp), "frame_id": f"{cam.id}_optical"}, "height": values.shape[0],
                "width": values.shape[1], "encoding": encoding, "is_bigendian": 0,
                "step": values.shape[1] * values.itemsize, "data": values.tobytes()}
        body.update(over)
        self.send(topic or f"/{cam.id}/depth/image_rect_raw", "Image", body)

    def info(self, cam, stamp: float, fx: float | None = None, d=(0.0,) * 5) -> None:
        fx = cam.fx if fx is None else fx
        self.send(f"/{cam.id}/depth/camera_info", "CameraInfo", {
            "header": {"stamp": _stamp(stamp), "frame_id": f"{cam.id}_optical"}, "height": cam.height, "width": cam.width,
            "distortion_model": "plumb_bob", "d": list(d), "k": [fx, 0, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1],
            "r": [1.0, 0, 0, 0, 1, 0, 0, 0, 1], "p": [fx, 0, cam.cx, 0, 0, cam.fy, cam.cy, 0, 0, 0, 1, 0],
            "binning_x": 0, "binning_y": 0, "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}})

    def joints(self, stamp: float, names, q, topic: str = "/joint_states") -> None:
        self.send(topic, "JointState", {"header": {"stamp": _stamp(stamp), "frame_id": ""}, "name": list(names),
                                        "position": [float(x) for x in q], "velocity": [], "effort": []})

    def close(self) -> None:
        self.session.close()


def check_frames_used_live(log: list[dict], summary: dict, cameras=("cam0", "cam1")) -> None:
    """A live ``monitor --source ros2:`` run used the cameras' frames as they came, to the end.

    Not "fresh" (age <= 100 ms): that is the frame-to-reaction latency, which a loaded machine's
    fusion alone exceeds (build p50 60-100 ms, frame-to-reaction p50 130-200 ms at load ~10;
    ``depthguard bench`` measures it); the camera is then stale, rightly. What the ROS path must
    not add is a backlog: in the run's last second each camera's frames still arrive, none is
    stamped in the run's future, and the youngest in use is within the monitor's own
    push-to-reaction p99 + 0.1 s (a backlog of the source's 8-frame queue would add 0.27 s)."""
    t_end = log[-1]["t"]
    last = [r for r in log if r["t"] >= t_end - 1.0]
    f2r = summary["frame_to_reaction_ms"]["p99"] * 1e-3
    for cid in cameras:
        assert last[-1]["cameras"][cid]["frames"] > last[0]["cameras"][cid]["frames"], cid     # still coming
        ages = [r["cameras"][cid]["age_s"] for r in last if r["cameras"][cid]["age_s"] is not None]
        assert ages and min(ages) >= 0.0, (cid, ages[:5])
        assert min(ages) <= f2r + 0.1, (cid, min(ages), f2r)
