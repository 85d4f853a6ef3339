"""``realsense-file:`` plays SDK recordings as a D435 and the SDK write them (issue 31, item 5).

Each recording is written through the SDK's own ``software_device`` and
recorder at a mode depthguard did not choose (6 to 90 Hz, 424x240 to 1280x720),
with a colour stream beside depth, stamped in the device's hardware clock or in
the SDK's global time, with the per-frame metadata a D400 attaches, raw or LZ4
compressed, in both containers: ROS 2 ``.db3`` by the installed SDK, ROS 1
``.bag`` (most recordings in circulation) by pyrealsense2 2.57 in a subprocess
(``make venv`` installs it; a skip saying so without it), both played by the
installed SDK. The truth: the depth images in the file, counted with sqlite3 or
rosbags' ROS 1 reader (not the SDK), and the stamps injected. Two recordings
also hold what a D435i records beside depth: infrared in the depth sensor and a
motion module (gyro, accel). Every depth frame must come out of the source once, in order,
with its stamp on the host clock (global time: as injected; hardware clock: the
device's stamp moved onto the host clock by the first frame's arrival time, see
docs/REALSENSE.md). Skipped, with the reason, when ``import pyrealsense2`` fails.
"""

import dataclasses
import math
import time

import numpy as np
import pytest

from depthguard.sources.realsense_device import RealSenseUnavailable, import_sdk

try:
    rs = import_sdk()
except RealSenseUnavailable as _exc:
    pytest.skip(f"RealSense SDK not importable here: {_exc}", allow_module_level=True)

from realsense_recordings import count_depth_messages, write_bag_recording, write_recording  # noqa: E402

from depthguard.sim.cells import load_cell  # noqa: E402
from depthguard.sources.base import open_source  # noqa: E402

MODES = [  # (fps, width, height, domain, frames, container, compressed, D435i's other streams too); .bag: SDK 2.57
    pytest.param(6, 640, 480, "hardware_clock", 6, ".db3", False, False, id="6Hz-640x480-hardware-db3"),
    pytest.param(6, 640, 480, "hardware_clock", 6, ".bag", False, False, id="6Hz-640x480-hardware-bag"),
    pytest.param(15, 424, 240, "global_time", 8, ".db3", False, False, id="15Hz-424x240-global"),
    pytest.param(15, 424, 240, "hardware_clock", 8, ".db3", True, False, id="15Hz-424x240-hardware-lz4"),
    pytest.param(15, 1280, 720, "global_time", 6, ".bag", True, False, id="15Hz-1280x720-global-bag-lz4"),
    pytest.param(30, 1280, 720, "hardware_clock", 8, ".db3", False, False, id="30Hz-1280x720-hardware"),
    pytest.param(30, 848, 480, "global_time", 8, ".bag", False, False, id="30Hz-848x480-global-bag"),
    pytest.param(90, 848, 480, "global_time", 18, ".db3", False, False, id="90Hz-848x480-global"),
    pytest.param(90, 424, 240, "hardware_clock", 18, ".db3", False, False, id="90Hz-424x240-hardware"),
    pytest.param(90, 424, 240, "hardware_clock", 18, ".bag", True, False, id="90Hz-424x240-hardware-bag-lz4"),
    pytest.param(30, 848, 480, "hardware_clock", 8, ".db3", False, True, id="30Hz-848x480-hardware-d435i-db3"),
    pytest.param(6, 640, 480, "global_time", 6, ".bag", True, True, id="6Hz-640x480-global-d435i-bag-lz4"),
]


def rig_for(width: int, height: int):
    """flacco-cell's rig with one camera, cam0, of the recording's size and intrinsics."""
    rig = load_cell("flacco-cell").rig
    cam = dataclasses.replace(rig.camera("cam0"), width=width, height=height, fx=0.9 * width, fy=0.9 * width,
                              cx=(width - 1) / 2, cy=(height - 1) / 2)
    return dataclasses.replace(rig, cameras=[cam])


def recording(tmp_path, suffix: str, **mode):
    """A recording at ``tmp_path/rec{suffix}`` by the SDK's own recorder: ``.db3`` by the installed
    SDK, ``.bag`` (ROS 1) by pyrealsense2 2.57 in a subprocess (a skip saying so where it is absent)."""
    path = tmp_path / f"rec{suffix}"
    if suffix == ".bag":
        return path, write_bag_recording(path, **mode)
    return path, write_recording(rs, path, **mode)


def drain(src, limit_s: float = 30.0, dt: float = 1 / 90):
    """Every frame, taken as a ``--fast`` run does: frames_until(t) every ``dt`` s of recording time."""
    got, end, t = [], time.monotonic() + limit_s, src.first_stamp
    while not src.done and time.monotonic() < end:
        got.extend(src.frames_until(t))
        t += dt
    got.extend(src.frames_until(math.inf))
    assert src.done, "the recording did not end"
    return got


@pytest.mark.parametrize("fps, width, height, domain, frames, suffix, compressed, d435i", MODES)
def test_every_depth_frame_of_an_sdk_recording_plays(tmp_path, suffix, compressed, d435i, fps, width, height, domain,
                                                     frames):
    path, written = recording(tmp_path, suffix, width=width, height=height, fps=fps, frames=frames, domain=domain,
                              compressed=compressed, d435i=d435i)
    in_file = count_depth_messages(path)
    assert in_file >= frames - 1, f"the recorder kept {in_file} of {frames} frames"
    src = open_source(f"realsense-file:cam0={path}", rig_for(width, height))
    try:
        got = drain(src)
        stats = src.stats()["cam0"]
    finally:
        src.close()
    assert stats["problem"] is None
    assert len(got) == in_file
    assert stats["received"] == in_file and stats["overflow"] == 0
    by_number = {w["number"]: w for w in written}
    levels = [float(np.median(f.depth)) for f in got]
    numbers = [round(level * 1000) - 999 for level in levels]     # frame i holds 1000 + i mm
    assert numbers == sorted(numbers) and len(set(numbers)) == len(numbers)
    assert all(f.depth.shape == (height, width) and np.all(f.depth == f.depth.flat[0]) for f in got)
    stamps = [f.stamp for f in got]
    assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)
    first = by_number[numbers[0]]
    for f, n in zip(got, numbers):
        w = by_number[n]
        if domain == "hardware_clock":     # the device's clock, moved onto the host's by the first arrival
            truth = first["arrival_ms"] + (w["stamp_ms"] - first["stamp_ms"])
        else:
            truth = w["stamp_ms"]
        assert f.stamp == pytest.approx(truth * 1e-3, abs=1e-6)
    if domain == "hardware_clock":         # and that clock is the host's: near each frame's arrival
        # (the device's clock is 81 s from the host's here; the bound leaves room for the writer falling
        # behind its schedule on a loaded machine: it did by 0.6 s at 90 Hz, load 15 on 2 cores)
        lag = [by_number[n]["arrival_ms"] * 1e-3 - f.stamp for f, n in zip(got, numbers)]
        assert max(abs(x) for x in lag) < 5.0


@pytest.mark.slow
@pytest.mark.parametrize("suffix", [".db3", ".bag"])
def test_monitor_fast_runs_a_d435_hardware_clock_recording(tmp_path, suffix):
    """The user's command on the issue's recording: D435 depth 640x480 at 6 Hz, colour beside it,
    stamps in the device's hardware clock, ``.bag`` (SDK 2.57's LZ4, as most in circulation) or
    ``.db3``; joints on the host clock (a CSV); ``--fast``."""
    import json

    from typer.testing import CliRunner

    from depthguard.cli import app

    rig = load_cell("flacco-cell").rig
    cam = rig.camera("cam0")
    path = tmp_path / f"d435{suffix}"
    mode = dict(width=640, height=480, fps=6, frames=6, domain="hardware_clock", fx=cam.fx, cx=cam.cx, cy=cam.cy)
    if suffix == ".bag":
        written = write_bag_recording(path, compressed=True, **mode)
    else:
        written = write_recording(rs, path, **mode)
    in_file = count_depth_messages(path)
    t0, t1 = written[0]["arrival_ms"] * 1e-3 - 1.0, written[-1]["arrival_ms"] * 1e-3 + 1.0
    q0 = [float(v) for v in rig.robot_q0]
    joints = tmp_path / "joints.csv"
    rows = [f"{t0 + k * 0.01!r}," + ",".join(map(repr, q0)) for k in range(int((t1 - t0) / 0.01))]
    joints.write_text("stamp," + ",".join(f"j{i}" for i in range(len(q0))) + "\n" + "\n".join(rows) + "\n")
    out = tmp_path / "run"
    r = CliRunner().invoke(app, ["monitor", "--cell", "flacco-cell", "--source", f"realsense-file:cam0={path}",
                                 "--joints", f"csv:{joints}", "--fast", "--out", str(out), "--quiet"])
    assert r.exit_code == 0, r.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["source_errors"] == []
    st = summary["stats"]["cameras"]["cam0"]
    assert st["frames"] == in_file >= 5 and st["refused"] == {}
