"""The clock of a RealSense recording against the joints' clock, through the CLI (issue 31, item 5).

Recordings in the device's hardware clock are written by the SDK's own
recorder (``realsense_recordings``). A recording whose clock cannot be related
to the host's (no arrival time in its metadata), or whose frames and joints are
on clocks seconds apart, stops ``depthguard monitor`` with one line and exit 2
naming the problem and the option ``:device_clock``; with that option the
recording runs on its own clock, joints given on that clock, every frame used.
Run in a subprocess, as a user runs it. Skipped, with the reason, when
``import pyrealsense2`` fails.
"""

import json
import time
from pathlib import Path

import pytest

from depthguard.sources.realsense_device import RealSenseUnavailable, import_sdk

try:
    rs = import_sdk()
except RealSenseUnavailable as _exc:
    pytest.skip(f"RealSense SDK not importable here: {_exc}", allow_module_level=True)

from realsense_recordings import count_depth_messages, error_line, run_monitor, write_recording  # noqa: E402

from depthguard.sim.cells import load_cell  # noqa: E402
from depthguard.sources.base import open_source  # noqa: E402

RIG = load_cell("flacco-cell").rig
CAM = RIG.camera("cam0")


def d435(path, *, arrival=True, frames=6, fps=30, **more):
    """A hardware-clock recording of flacco-cell's cam0 (640x480), colour beside depth."""
    return write_recording(rs, path, width=640, height=480, fps=fps, frames=frames, domain="hardware_clock",
                           arrival=arrival, fx=CAM.fx, cx=CAM.cx, cy=CAM.cy, **more)


def play(spec: str):
    src = open_source(spec, RIG)
    try:
        got = []
        while not src.done:
            got.extend(src.frames_until(float("inf")))
        return got, src.stats()["cam0"]
    finally:
        src.close()


def joints_csv(path, t0: float, t1: float) -> Path:
    """The robot at rest from ``t0`` to ``t1`` s every 10 ms."""
    q0 = [float(v) for v in RIG.robot_q0]
    rows = [f"{t0 + k * 0.01!r}," + ",".join(map(repr, q0)) for k in range(int((t1 - t0) / 0.01) + 1)]
    path.write_text("stamp," + ",".join(f"j{i}" for i in range(len(q0))) + "\n" + "\n".join(rows) + "\n")
    return path


def test_device_clock_gives_the_recordings_own_stamps(tmp_path):
    path = tmp_path / "own.db3"
    written = d435(path)
    src = open_source(f"realsense-file:cam0={path}:device_clock", RIG)
    try:
        got = []
        while not src.done:
            got.extend(src.frames_until(float("inf")))
    finally:
        src.close()
    assert [f.stamp for f in got] == pytest.approx([w["stamp_ms"] * 1e-3 for w in written], abs=1e-9)


def test_a_clock_without_arrival_times_is_one_line_naming_the_option(tmp_path):
    path = tmp_path / "bare.db3"
    d435(path, arrival=False)
    joints = joints_csv(tmp_path / "j.csv", time.time() - 5, time.time() + 5)
    r, _ = run_monitor(tmp_path, f"realsense-file:cam0={path}", joints)
    line = error_line(r)
    assert "hardware_clock" in line and "no host arrival time" in line and ":device_clock" in line


def test_joints_on_another_clock_are_one_line_naming_the_option(tmp_path):
    """Derived (host) clock for the frames, joints on the camera's clock: refused, never run silently."""
    path = tmp_path / "rec.db3"
    written = d435(path)
    joints = joints_csv(tmp_path / "j.csv", written[0]["stamp_ms"] * 1e-3 - 1, written[-1]["stamp_ms"] * 1e-3 + 1)
    r, out = run_monitor(tmp_path, f"realsense-file:cam0={path}", joints)
    line = error_line(r)
    assert "clocks are" in line and ":device_clock" in line and str(path) in line
    assert not (out / "summary.json").exists()


@pytest.mark.slow
def test_device_clock_runs_with_joints_on_that_clock(tmp_path):
    path = tmp_path / "rec.db3"
    written = d435(path)
    joints = joints_csv(tmp_path / "j.csv", written[0]["stamp_ms"] * 1e-3 - 1, written[-1]["stamp_ms"] * 1e-3 + 1)
    r, out = run_monitor(tmp_path, f"realsense-file:cam0={path}:device_clock", joints)
    assert r.returncode == 0, r.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    st = summary["stats"]["cameras"]["cam0"]
    assert summary["source_errors"] == [] and st["refused"] == {}
    assert st["frames"] == count_depth_messages(path) >= 5


def test_the_hardware_counter_wrapping_in_the_recording_is_unwrapped(tmp_path):
    """A D400's hardware stamps are a 32-bit microsecond counter: a recording that crosses its turn
    (frames 0-2 before, 3-7 after) plays with rising stamps, each frame where it was captured, on the
    derived clock and on the device's own clock (the truth: the unwrapped stamps injected)."""
    from depthguard.sources.realsense_clock import HW_WRAP_MS

    path = tmp_path / "wrap.db3"
    written = d435(path, frames=8, hw0_ms=2.0**32 * 1e-3 - 2.5 * 1000 / 30, wrap_ms=2.0**32 * 1e-3)
    assert HW_WRAP_MS == 2.0**32 * 1e-3
    assert count_depth_messages(path) == 8
    got, stats = play(f"realsense-file:cam0={path}")
    first = written[0]
    truth = [(first["arrival_ms"] + w["stamp_ms"] - first["stamp_ms"]) * 1e-3 for w in written]
    assert [f.stamp for f in got] == pytest.approx(truth, abs=1e-6)
    assert "unwrapped 1 time" in stats["clock"]
    got, stats = play(f"realsense-file:cam0={path}:device_clock")
    assert [f.stamp for f in got] == pytest.approx([w["stamp_ms"] * 1e-3 for w in written], abs=1e-6)


@pytest.mark.parametrize("domain", ["global_time", "system_time"])
def test_a_host_clock_recording_without_metadata_plays_as_stamped(tmp_path, domain):
    """Frames without any metadata (a camera on a kernel without the metadata patch: the SDK stamps
    them in system_time) need none: on the host clock they play with the stamps injected, every one."""
    path = tmp_path / "bare.db3"
    written = write_recording(rs, path, width=640, height=480, fps=30, frames=6, domain=domain, arrival=False,
                              hw0_ms=time.time() * 1e3, fx=CAM.fx, cx=CAM.cx, cy=CAM.cy)
    got, stats = play(f"realsense-file:cam0={path}")
    assert [f.stamp for f in got] == pytest.approx([w["stamp_ms"] * 1e-3 for w in written], abs=1e-6)
    assert len(got) == count_depth_messages(path) and stats["problem"] is None
    assert stats["clock"].startswith("the host clock")
