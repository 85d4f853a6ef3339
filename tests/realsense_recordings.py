"""SDK recordings as a D400 and the SDK's own recorder write them, for the ``realsense-file:`` tests (issue 31).

:func:`write_recording` streams a depth sensor ("Stereo Module") and, beside it, a
colour sensor ("RGB Camera") of a ``software_device`` into ``rs.recorder``, at the
mode and in the timestamp domain given — not the ones depthguard would choose —
and with the metadata a D400 attaches to each frame (``time_of_arrival``: the
host's clock in ms when the frame arrived, ``frame_timestamp``: the device's clock
in us). :func:`count_depth_messages` counts the depth images in a ``.db3`` with
``sqlite3`` alone, in a ``.bag`` with ``rosbags``' ROS 1 reader: the written truth
the playback is compared with, read without the SDK.

The installed SDK (>= 2.58) writes only ROS 2 ``.db3``; the ROS 1 ``.bag`` that most
recordings in circulation are comes from an older SDK: :func:`write_bag_recording`
runs :func:`write_recording` in a subprocess with pyrealsense2 :data:`BAG_SDK_VERSION`,
which ``make venv`` installs into ``.venv/realsense-2.57`` (``pip install --target``;
never downloaded by a test: without it the test skips, saying so). :func:`run_monitor` runs ``depthguard monitor`` on one in a subprocess, as a user
does; :func:`error_line` is the one line a user error must print.
"""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

DEPTH_TOPIC = "/device_0/sensor_0/Depth_0/image/data"

#: the pyrealsense2 that writes ROS 1 ``.bag`` recordings (2.57 is the last; 2.58 moved to ROS 2 ``.db3``)
BAG_SDK_VERSION = "2.57.7.10387"
#: the start of the sentence a test skips with when that SDK is absent (tests/conftest.py: required in CI)
NO_BAG_SDK = "no RealSense SDK that writes .bag"


def write_recording(rs, path, *, width: int, height: int, fps: int, frames: int, domain: str = "hardware_clock",
                    colour: bool = True, arrival: bool = True, depth: bool = True, hw0_ms: float = 81234.567,
                    fx: float | None = None, cx: float | None = None, cy: float | None = None,
                    compressed: bool = False, wrap_ms: float | None = None, d435i: bool = False) -> list[dict]:
    """Write ``frames`` depth frames (and as many colour ones when ``colour``) at ``path`` (must
    end in what the SDK's recorder accepts). Depth frame ``i`` holds ``1000 + i`` mm everywhere,
    is numbered ``i + 1`` and stamped ``hw0_ms + i * 1000 / fps`` ms in ``domain``
    (``hardware_clock``, ``global_time`` or ``system_time``); with ``arrival`` it carries the
    metadata ``time_of_arrival`` = the host clock (ms) when it was handed to the SDK.
    ``depth=False``: the colour stream only. ``compressed``: the recorder's LZ4 compression, as
    the SDK's own tools record by default (else raw). ``wrap_ms``: the stamps injected wrap around
    at that many ms, as a D400's 32-bit microsecond hardware counter does (the ``stamp_ms``
    returned stay unwrapped: the truth). ``d435i``: the other streams a D435i's recording holds
    too, each frame beside each depth frame: infrared 1 (y8) in the depth sensor, opened with
    depth, and a "Motion Module" with gyro and accel (``motion_xyz32f``). Returns per depth frame ``{number, stamp_ms,
    arrival_ms}``. Frames are injected one period apart (the recorder drops frames injected
    back to back)."""
    path = Path(path)
    dev = rs.software_device()
    intr = rs.intrinsics()
    intr.width, intr.height = width, height
    intr.fx = intr.fy = float(fx if fx is not None else 0.9 * width)
    intr.ppx = float(cx if cx is not None else (width - 1) / 2)
    intr.ppy = float(cy if cy is not None else (height - 1) / 2)
    intr.model, intr.coeffs = rs.distortion.brown_conrady, [0.0] * 5
    sensors = []
    if depth:
        ds = dev.add_sensor("Stereo Module")
        vs = rs.video_stream()
        vs.type, vs.index, vs.uid = rs.stream.depth, 0, 0
        vs.width, vs.height, vs.fps, vs.bpp, vs.fmt, vs.intrinsics = width, height, fps, 2, rs.format.z16, intr
        sensors.append(("depth", ds, ds.add_video_stream(vs), 2))
        ds.add_read_only_option(rs.option.depth_units, 0.001)
        if d435i:
            vs = rs.video_stream()
            vs.type, vs.index, vs.uid = rs.stream.infrared, 1, 2
            vs.width, vs.height, vs.fps, vs.bpp, vs.fmt, vs.intrinsics = width, height, fps, 1, rs.format.y8, intr
            sensors.append(("infrared", ds, ds.add_video_stream(vs), 1))
    if colour:
        cs = dev.add_sensor("RGB Camera")
        vs = rs.video_stream()
        vs.type, vs.index, vs.uid = rs.stream.color, 0, 1
        vs.width, vs.height, vs.fps, vs.bpp, vs.fmt, vs.intrinsics = width, height, fps, 3, rs.format.rgb8, intr
        sensors.append(("colour", cs, cs.add_video_stream(vs), 3))
    if d435i:
        ms = dev.add_sensor("Motion Module")
        for kind, stream, uid, rate in (("gyro", rs.stream.gyro, 3, 200), ("accel", rs.stream.accel, 4, 100)):
            mst = rs.motion_stream()
            mst.type, mst.index, mst.uid, mst.fps, mst.fmt = stream, 0, uid, rate, rs.format.motion_xyz32f
            sensors.append((kind, ms, ms.add_motion_stream(mst), 0))
    dev.register_info(rs.camera_info.serial_number, "843112070001")
    dev.register_info(rs.camera_info.name, "Intel RealSense D435")
    recorder = rs.recorder(str(path), dev, bool(compressed))
    queues, opened = [], {}
    for _, sensor, profile, _ in sensors:                   # each sensor opened once, with all its streams
        opened.setdefault(id(sensor), (sensor, []))[1].append(profile)
    for sensor, profiles in opened.values():
        q = rs.frame_queue(16)
        sensor.open(profiles if len(profiles) > 1 else profiles[0])
        sensor.start(q)
        queues.append(q)
    kept, written = [], []
    dom = getattr(rs.timestamp_domain, domain)
    period = 1.0 / fps
    try:
        for i in range(frames):
            t0 = time.perf_counter()
            stamp = hw0_ms + i * 1000.0 / fps
            for kind, sensor, profile, bpp in sensors:
                if kind in ("gyro", "accel"):
                    m = rs.software_motion_frame()
                    m.data = rs.vector()
                    m.data.x, m.data.y, m.data.z = 0.0, -9.81 if kind == "accel" else 0.0, 0.0
                    m.timestamp, m.domain, m.frame_number = stamp % wrap_ms if wrap_ms else stamp, dom, i + 1
                    m.profile = profile.as_motion_stream_profile()
                    sensor.on_motion_frame(m)
                    continue
                if kind == "depth":
                    pixels = np.full((height, width), 1000 + i, dtype=np.uint16)
                elif kind == "infrared":
                    pixels = np.full((height, width), (7 * i) % 256, dtype=np.uint8)
                else:
                    pixels = np.full((height, width, 3), i % 256, dtype=np.uint8)
                kept.append(pixels)                          # the SDK reads the buffer later
                f = rs.software_video_frame()
                f.pixels, f.bpp, f.stride = pixels, bpp, width * bpp
                raw = stamp + (0.3 if kind == "colour" else 0.0)
                raw = raw % wrap_ms if wrap_ms else raw
                f.timestamp, f.domain, f.frame_number = raw, dom, i + 1
                f.profile = profile.as_video_stream_profile()
                if kind == "depth" and hasattr(f, "depth_units"):      # not in SDK 2.54's frames
                    f.depth_units = 0.001
                arrival_ms = int(time.time() * 1000)
                if arrival:
                    sensor.set_metadata(rs.frame_metadata_value.time_of_arrival, arrival_ms)
                    sensor.set_metadata(rs.frame_metadata_value.frame_timestamp, int(raw * 1000))
                sensor.on_video_frame(f)
                if kind == "depth":
                    written.append({"number": i + 1, "stamp_ms": stamp, "arrival_ms": arrival_ms})
            for q in queues:
                while q.poll_for_frame():
                    pass
            time.sleep(max(0.0, period - (time.perf_counter() - t0)))
        time.sleep(0.1)
    finally:
        for sensor, _ in opened.values():
            sensor.stop()
            sensor.close()
        del recorder                                         # closes the file
    return written


def count_depth_messages(path) -> int:
    """The depth images in a ``.db3`` recording, counted with sqlite3 (a compressed one holds them
    as ``sensor_msgs/CompressedImage`` on ``.../image/data/compressedDepth``), or in a ``.bag``
    (ROS 1, LZ4 chunks when compressed), counted with ``rosbags.rosbag1`` (not the SDK)."""
    if Path(path).suffix == ".bag":
        from rosbags.rosbag1 import Reader

        with Reader(Path(path)) as reader:
            conns = [c for c in reader.connections if c.topic == DEPTH_TOPIC]
            return sum(1 for _ in reader.messages(connections=conns)) if conns else 0
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        (n,) = con.execute("SELECT COUNT(*) FROM messages m JOIN topics t ON m.topic_id = t.id WHERE t.name IN (?, ?)",
                           (DEPTH_TOPIC, DEPTH_TOPIC + "/compressedDepth")).fetchone()
    finally:
        con.close()
    return int(n)


SRC = Path(__file__).resolve().parents[1] / "src"
TESTS = Path(__file__).resolve().parent


def bag_sdk_dir() -> Path | None:
    """Where pyrealsense2 :data:`BAG_SDK_VERSION` is installed for :func:`write_bag_recording`:
    ``$DEPTHGUARD_BAG_SDK``, else ``realsense-2.57`` in the venv running the tests (``make venv``);
    None when absent."""
    d = Path(os.environ.get("DEPTHGUARD_BAG_SDK") or Path(sys.prefix) / "realsense-2.57")
    return d if (d / "pyrealsense2" / "__init__.py").is_file() else None


def write_bag_recording(path, **mode) -> list[dict]:
    """:func:`write_recording` of ``mode`` at ``path`` (``.bag``), by the SDK's own recorder of
    pyrealsense2 :data:`BAG_SDK_VERSION` in a subprocess (the installed SDK cannot write ``.bag``);
    a skip naming what to run when that SDK is absent. The subprocess checks that it imported that
    SDK, not the installed one."""
    import pytest

    sdk = bag_sdk_dir()
    if sdk is None:
        pytest.skip(f"{NO_BAG_SDK} here: `make venv` installs pyrealsense2 {BAG_SDK_VERSION} into "
                    f"{Path(sys.prefix) / 'realsense-2.57'} (or set DEPTHGUARD_BAG_SDK to such a directory)")
    code = ("import json, sys\n"
            f"sys.path[:0] = [{str(sdk)!r}, {str(TESTS)!r}]\n"
            "import pyrealsense2 as rs\n"
            f"assert rs.__file__.startswith({str(sdk)!r}), rs.__file__\n"
            "from realsense_recordings import write_recording\n"
            "mode = json.loads(sys.argv[2])\n"
            "print(json.dumps(write_recording(rs, sys.argv[1], **mode)))\n")
    r = subprocess.run([sys.executable, "-c", code, str(path), json.dumps(mode)], capture_output=True, text=True,
                       timeout=120, env={k: v for k, v in os.environ.items() if k != "PYTHONPATH"})
    assert r.returncode == 0, f"pyrealsense2 {BAG_SDK_VERSION} could not write {path}: {r.stderr[-2000:]}"
    return json.loads(r.stdout.splitlines()[-1])


def run_monitor(tmp_path, source: str, joints: Path, cell: str = "flacco-cell"):
    """``depthguard monitor --cell CELL --source SOURCE --joints csv:JOINTS --fast`` in a subprocess:
    ``(CompletedProcess, its --out folder)``."""
    env = dict(os.environ, PYTHONPATH=str(SRC) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = tmp_path / f"run{time.monotonic_ns()}"
    r = subprocess.run([sys.executable, "-m", "depthguard.cli", "monitor", "--cell", cell, "--source", source,
                        "--joints", f"csv:{joints}", "--fast", "--out", str(out), "--quiet"],
                       capture_output=True, text=True, env=env, timeout=600)
    return r, out


def error_line(r) -> str:
    """The one line a user error prints, exit status 2 (and nothing else: no traceback, no SDK
    abort); progress lines (``[hh:mm:ss] ...``) aside."""
    lines = [x for x in r.stderr.splitlines() if x.strip() and not x.startswith("[")]
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    assert len(lines) == 1 and lines[0].startswith("depthguard: error: "), r.stderr[-2000:]
    return lines[0]
