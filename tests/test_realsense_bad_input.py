"""Bad recordings given to ``realsense-file:`` are one line, exit 2, through the CLI (issue 31, item 5).

A recording that holds no depth stream (written by the SDK's own recorder with a
colour stream only) names what it holds instead; a file that is not a recording
(random bytes, an SQLite file of another kind) and a folder each get one line. Run
in a subprocess as a user runs it: no traceback, no SDK abort. Skipped, with the
reason, when ``import pyrealsense2`` fails.
"""

import sqlite3

import pytest

from depthguard.sources.realsense_device import RealSenseUnavailable, import_sdk

try:
    rs = import_sdk()
except RealSenseUnavailable as _exc:
    pytest.skip(f"RealSense SDK not importable here: {_exc}", allow_module_level=True)

from realsense_recordings import error_line, run_monitor, write_recording  # noqa: E402


@pytest.fixture
def joints(tmp_path):
    path = tmp_path / "joints.csv"
    path.write_text("stamp,j0,j1,j2,j3,j4,j5,j6\n")
    return path


def test_a_recording_without_depth_names_what_it_holds(tmp_path, joints):
    path = tmp_path / "colour.db3"
    write_recording(rs, path, width=640, height=480, fps=30, frames=4, depth=False, fx=585.0, cx=319.5, cy=239.5)
    r, _ = run_monitor(tmp_path, f"realsense-file:cam0={path}", joints)
    line = error_line(r)
    assert str(path) in line and "no depth stream" in line
    assert "color 640x480 rgb8 30 Hz" in line                    # what the file holds instead


@pytest.mark.parametrize("kind", ["random bytes", "sqlite of another kind", "empty"])
def test_a_file_that_is_not_a_recording_is_one_line(tmp_path, joints, kind):
    path = tmp_path / ("junk.bag" if kind == "random bytes" else "junk.db3")
    if kind == "random bytes":
        path.write_bytes(bytes(range(256)) * 20)
    elif kind == "sqlite of another kind":
        con = sqlite3.connect(path)
        con.execute("CREATE TABLE x (a)")
        con.commit()
        con.close()
    else:
        path.write_bytes(b"")
    r, _ = run_monitor(tmp_path, f"realsense-file:cam0={path}", joints)
    line = error_line(r)
    assert str(path) in line and "cannot read it as a recording" in line


def test_a_folder_is_one_line_saying_so(tmp_path, joints):
    folder = tmp_path / "recordings"
    folder.mkdir()
    r, _ = run_monitor(tmp_path, f"realsense-file:cam0={folder}", joints)
    line = error_line(r)
    assert str(folder) in line and "is a folder" in line
