"""A process that opened an SDK recording exits cleanly, whatever ends it (issue 33 item 10).

``monitor --source realsense-file:REC --fast`` without ``--joints`` printed its usage error and
then aborted (``FATAL: exception not rethrown``, exit 134, or a segmentation fault): the
recording was opened before the arguments were checked and never closed, and the SDK's thread,
blocked in the stream's callback waiting for room, was torn down by the interpreter's shutdown.
The recordings are written by the SDK's own recorder (as in test_realsense_file.py); skipped,
with the reason, when ``import pyrealsense2`` fails.
"""

import subprocess
import sys

import pytest

from depthguard.sources.realsense_device import RealSenseUnavailable, import_sdk

try:
    rs = import_sdk()
except RealSenseUnavailable as _exc:
    pytest.skip(f"RealSense SDK not importable here: {_exc}", allow_module_level=True)

from depthguard.sources.realsense_device import record_depth  # noqa: E402
from depthguard.sources.sim_source import SimFrames, SimWorld  # noqa: E402

DG = [sys.executable, "-m", "depthguard.cli"]


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """One second of flacco-cell's cam0 (30 frames: more than a stream buffers, 4)."""
    world = SimWorld("flacco-cell", situation="reach", seed=3)
    frames = [f for f in SimFrames(world).frames_until(1.0) if f.camera_id == "cam0"]
    path = tmp_path_factory.mktemp("rs") / "cam0.db3"
    record_depth(path, [(f.depth, f.stamp) for f in frames], world.rig.camera("cam0"), serial="100",
                 units=0.001, period_s=0.01)
    return world.rig, path


@pytest.mark.parametrize("attempt", [1, 2])
def test_a_usage_error_after_a_recording_is_named_gives_one_line_and_exit_2(recording, tmp_path, attempt):
    from depthguard.sim.cells import cell_rig_path

    _, path = recording
    res = subprocess.run(DG + ["monitor", "--rig", str(cell_rig_path("flacco-cell")), "--source",
                               f"realsense-file:{path}", "--fast", "--out", str(tmp_path / "o")],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 2, (res.returncode, res.stderr)
    assert "needs --joints" in res.stderr
    assert "FATAL" not in res.stderr and "Traceback" not in res.stderr


def test_a_recording_left_open_at_exit_does_not_abort_the_interpreter(recording):
    """The source opened and never closed, its stream's buffer full: the interpreter exits 0."""
    _, path = recording
    code = ("import time\n"
            "from depthguard.sim.cells import load_cell\n"
            "from depthguard.sources.base import open_source\n"
            f"src = open_source('realsense-file:cam0={path}', load_cell('flacco-cell').rig)\n"
            "time.sleep(0.5)\n"
            "print('opened', src.first_stamp)\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, (res.returncode, res.stderr)
    assert res.stdout.startswith("opened") and "FATAL" not in res.stderr
