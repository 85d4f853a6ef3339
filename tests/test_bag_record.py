"""``depthguard record`` refuses what it cannot do in one line and never overwrites a bag; the
bench bag has the schedule it claims (R31)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from depthguard.evaluation.bench.bag import make_bench_bag, replay_seconds
from depthguard.sim import load_cell
from depthguard.sources.bag import BagError
from depthguard.sources.bag_record import BagRecorder

DG = [sys.executable, "-m", "depthguard.cli"]


@pytest.mark.parametrize("args, words", [
    (["--source", "sim:flacco-cell"], "never ends: give --duration"),
    (["--source", "sim:flacco-cell", "--duration", "1", "--encoding", "rgb8"], "record 16UC1 (mm) or 32FC1 (m)"),
])
def test_bad_record_arguments_give_one_line(tmp_path, args, words):
    res = subprocess.run(DG + ["record", "--cell", "flacco-cell", "--out", str(tmp_path / "bag"), *args],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and words in res.stderr and "Traceback" not in res.stderr, res.stderr


def test_an_existing_bag_is_never_overwritten(tmp_path):
    rig = load_cell("flacco-cell").rig
    out = tmp_path / "bag"
    with BagRecorder(out, rig) as rec:
        rec.write_joints(0.0, rig.robot_q0)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    with pytest.raises(BagError, match="exists already"):
        BagRecorder(out, rig)
    res = subprocess.run(DG + ["record", "--cell", "flacco-cell", "--duration", "0.1", "--out", str(out)],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and "exists already" in res.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_the_bench_bag_replays_every_frame_and_joint_state_of_its_schedule(tmp_path):
    seconds = 0.3
    raw, _wall = make_bench_bag(tmp_path / "b", seconds)
    n_frames = 2 * int(seconds * 30)                         # two cameras at 30 Hz
    assert raw == n_frames * 640 * 480 * 2
    wall, frames, states, cpu = replay_seconds(tmp_path / "b")
    assert frames == n_frames and states == int(seconds * 500) + 1
    assert np.isfinite(wall) and wall > 0 and cpu > 0


def test_recording_a_bag_again_gives_the_same_frames_and_joint_states(tmp_path):
    """16UC1 millimetres survive a second recording exactly (bag -> record -> bag)."""
    from depthguard.sources.bag import BagFrames, BagJoints, BagReplay
    from depthguard.sources.frame import Frame

    rig = load_cell("flacco-cell").rig
    rng = np.random.default_rng(3)
    first = tmp_path / "first"
    with BagRecorder(first, rig) as rec:
        for k in range(60):
            rec.write_joints(0.002 * k, np.asarray(rig.robot_q0) + 1e-3 * k)
        for k, c in enumerate(rig.cameras * 2):
            d = (rng.integers(400, 4000, (c.height, c.width)) / 1000.0).astype(np.float32)
            rec.write_frame(Frame(c.id, d, 0.013 + 0.05 * k))
    second = tmp_path / "second"
    res = subprocess.run(DG + ["record", "--cell", "flacco-cell", "--source", f"bag:{first}", "--out", str(second)],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    a, b = BagReplay(first), BagReplay(second)
    fa, fb = BagFrames(a, rig).frames_until(99.0), BagFrames(b, rig).frames_until(99.0)
    assert len(fa) == len(fb) == 4
    for x, y in zip(fa, fb):
        assert (x.camera_id, x.stamp) == (y.camera_id, y.stamp) and np.array_equal(x.depth, y.depth)
    ja, jb = BagJoints(a, rig).states_until(99.0), BagJoints(b, rig).states_until(99.0)
    assert len(ja) == len(jb) == 60 and all(s == t and np.array_equal(p, q) for (s, p), (t, q) in zip(ja, jb))


def test_depth_beyond_16uc1_is_counted_and_read_back_as_no_measurement(tmp_path):
    """A return beyond 65.535 m cannot be 16UC1 millimetres: it is written as 0 (no measurement,
    never a wrapped-around near value) and counted, so that `record` can say so."""
    from depthguard.sources.bag import BagFrames, BagReplay
    from depthguard.sources.frame import Frame

    rig = load_cell("flacco-cell").rig
    cam = rig.cameras[0]
    d = np.full((cam.height, cam.width), 2.0, np.float32)
    d[:5, :7] = 70.0
    with BagRecorder(tmp_path / "bag", rig) as rec:
        rec.write_joints(0.0, rig.robot_q0)
        rec.write_joints(1.0, rig.robot_q0)
        for c in rig.cameras:
            rec.write_frame(Frame(c.id, d if c.id == cam.id else np.full_like(d, 2.0), 0.5))
    assert rec.clipped == 35
    replay = BagReplay(tmp_path / "bag")
    try:
        (f,) = [f for f in BagFrames(replay, rig).frames_until(1.0) if f.camera_id == cam.id]
    finally:
        replay.close()
    assert np.all(f.depth[:5, :7] == 0.0) and np.allclose(f.depth[5:], 2.0)
