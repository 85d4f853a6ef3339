"""Bad recordings given to ``realsense-file:`` are one line, exit 2, through the CLI (issue 31, item 5).

A recording that holds no depth stream (written by the SDK's own recorder with a
colour stream only; ROS 2 ``.db3`` by the installed SDK, ROS 1 ``.bag`` by 2.57)
names what it holds instead; a file that is not a recording (random bytes, an
SQLite file of another kind) and a folder each get one line. An SDK recording given
to ``bag:`` (the ROS 2 drivers' bags) is one line naming ``realsense-file:``. Run
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

from realsense_recordings import error_line, run_monitor, write_bag_recording, write_recording  # noqa: E402

from depthguard.sim.cells import load_cell  # noqa: E402
from depthguard.sources.bag import BagError, BagFrames, BagReplay  # noqa: E402
from depthguard.sources.base import open_source  # noqa: E402


@pytest.fixture
def joints(tmp_path):
    path = tmp_path / "joints.csv"
    path.write_text("stamp,j0,j1,j2,j3,j4,j5,j6\n")
    return path


COLOUR_ONLY = dict(width=640, height=480, fps=30, frames=4, depth=False, fx=585.0, cx=319.5, cy=239.5)


def test_a_recording_without_depth_names_what_it_holds(tmp_path, joints):
    path = tmp_path / "colour.db3"
    write_recording(rs, path, **COLOUR_ONLY)
    r, _ = run_monitor(tmp_path, f"realsense-file:cam0={path}", joints)
    line = error_line(r)
    assert str(path) in line and "no depth stream" in line
    assert "color 640x480 rgb8 30 Hz" in line                    # what the file holds instead


def test_a_ros1_bag_recording_without_depth_names_what_it_holds(tmp_path):
    """The same for a ``.bag`` of SDK 2.57 (the source's sentence: the CLI's line is the one above)."""
    path = tmp_path / "colour.bag"
    write_bag_recording(path, **COLOUR_ONLY)
    with pytest.raises(ValueError, match=r"holds no depth stream; it holds color 640x480 rgb8 30 Hz") as err:
        open_source(f"realsense-file:cam0={path}", load_cell("flacco-cell").rig)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


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


@pytest.mark.parametrize("suffix", [".db3", ".bag"])
def test_an_sdk_recording_given_to_bag_names_realsense_file(tmp_path, suffix):
    """``bag:`` reads the ROS 2 drivers' bags; an SDK recording (either container) is one sentence
    saying what it is and how to play it (a BagError: one line from the CLI, tests/test_bag_bad.py)."""
    mode = dict(width=640, height=480, fps=30, frames=3, fx=585.0, cx=319.5, cy=239.5)
    path = tmp_path / f"sdk{suffix}"
    write_bag_recording(path, **mode) if suffix == ".bag" else write_recording(rs, path, **mode)
    with pytest.raises(BagError, match=r"RealSense SDK recording .*realsense-file:") as err:
        BagFrames(BagReplay(path), load_cell("flacco-cell").rig)
    assert f"--source realsense-file:{path}" in str(err.value) and "\n" not in str(err.value)


def test_a_truncated_bag_recording_is_one_sentence_saying_so(tmp_path):
    """A ``.bag`` cut short (its recorder killed before it wrote the index at the end): the SDK's
    reason and what probably happened (the source's sentence; the CLI's line as above)."""
    whole = tmp_path / "whole.bag"
    write_bag_recording(whole, width=640, height=480, fps=30, frames=4, fx=585.0, cx=319.5, cy=239.5)
    cut = tmp_path / "cut.bag"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    with pytest.raises(ValueError, match=r"cannot read it as a recording \(.*truncated or damaged\?") as err:
        open_source(f"realsense-file:cam0={cut}", load_cell("flacco-cell").rig)
    assert str(cut) in str(err.value) and "\n" not in str(err.value)
