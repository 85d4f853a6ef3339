"""``depthguard monitor`` from the command line (R29, R31): a run writes its log and summary,
Ctrl-C stops it cleanly with the summary written, bad arguments give one line."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest


DG = [sys.executable, "-m", "depthguard.cli"]


def _lines(path: Path) -> list[dict]:
    return [json.loads(x) for x in path.read_text().splitlines()] if path.exists() else []


@pytest.mark.slow
def test_fast_run_writes_a_log_line_per_cycle_and_a_summary_that_agrees(tmp_path, monitor_kernels):
    out = tmp_path / "run"
    res = subprocess.run(DG + ["monitor", "--cell", "flacco-cell", "--source", "sim:flacco-cell:reach",
                               "--duration", "0.4", "--fast", "--out", str(out), "--quiet"],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    log = _lines(out / "log.jsonl")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["cycles"] == len(log) == 201                    # 0 ... 0.4 s at 500 Hz
    assert [r["t"] for r in log] == sorted(r["t"] for r in log)
    assert summary["override_min"] == pytest.approx(min(r["override"] for r in log))
    names = [p["name"] for p in log[-1]["points"]]
    assert names[0] == "ee" and set(log[-1]["cameras"]) == {"cam0", "cam1"}
    for r in log:                                                    # "none within rho" vs "cannot judge"
        for p in r["points"]:
            assert (p["distance"] is None) == (p["direction"] is None)
    assert summary["sources"] == {"frames": ["sim:flacco-cell:reach"], "joints": "sim"}
    assert summary["interrupted"] is False and summary["sinks_dropped"] == 0
    assert summary["frame_lag_at_push_ms"] == {}                 # no clock to be late on in a fast run


@pytest.mark.slow
@pytest.mark.realtime              # its real-time factor is the wall clock's: alone (tests/conftest.py)
def test_monitor_alone_runs_in_real_time_and_stops_cleanly_on_ctrl_c(tmp_path, monitor_kernels):
    out = tmp_path / "live"
    proc = subprocess.Popen(DG + ["monitor", "--out", str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        end = time.monotonic() + 300
        while time.monotonic() < end and proc.poll() is None:
            log = out / "log.jsonl"
            if log.exists() and log.stat().st_size > 1_000_000:     # about a second of cycles
                break
            time.sleep(0.2)
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    summary = json.loads((out / "summary.json").read_text())
    log = _lines(out / "log.jsonl")
    assert summary["interrupted"] is True and summary["cycles"] == len(log) > 50
    assert summary["real_time_factor"] == pytest.approx(1.0, abs=0.2)     # real time, not as fast as possible
    assert summary["source_errors"] == []                                   # the simulator kept delivering
    # the control thread ran under SCHED_FIFO 50 (the default), or the summary says why not
    assert summary["control_scheduling"] == "SCHED_FIFO 50" or "not permitted" in summary["control_scheduling"]
    assert all(c["fused"] > 0 for c in summary["stats"]["cameras"].values()), summary["stats"]
    # each camera's frames were handed over after their capture (causality), within the run, and
    # every frame a worker processed was counted when its source pushed it
    lag = summary["frame_lag_at_push_ms"]
    assert set(lag) == set(summary["stats"]["cameras"]), lag
    for cid, c in summary["stats"]["cameras"].items():
        assert 0.0 <= lag[cid]["p50"] <= lag[cid]["p99"] <= lag[cid]["max"] < 1e3 * summary["wall_s"], lag
        assert lag[cid]["frames"] >= c["frames"] > 0, (lag, c)
    assert "interrupted" in stdout


@pytest.mark.parametrize("args, words", [
    (["--rig", "x.yaml", "--cell", "flacco-cell"], "not both"),
    (["--source", "nope:x"], "scheme must be one of"),
    (["--cell", "no-such-cell"], "unknown cell"),
    (["--duration", "-1"], "must be > 0"),
])
def test_bad_arguments_give_one_clear_line(tmp_path, args, words):
    res = subprocess.run(DG + ["monitor", "--out", str(tmp_path / "o")] + args, capture_output=True,
                         text=True, timeout=120, cwd=tmp_path)
    assert res.returncode == 2, (res.stdout, res.stderr)
    assert words in res.stderr and "Traceback" not in res.stderr


def test_an_output_folder_holding_a_run_is_refused_before_any_work(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    (out / "log.jsonl").write_text("keep me\n")
    res = subprocess.run(DG + ["monitor", "--out", str(out), "--duration", "1"], capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 2 and "log.jsonl exists already" in res.stderr
    assert (out / "log.jsonl").read_text() == "keep me\n"


@pytest.mark.slow
@pytest.mark.parametrize("joint_hz, joint_offset", [(500, 0.0), (100, 0.0007)])
def test_a_recording_replays_from_its_first_stamp_with_the_robot_removed_at_capture_time(tmp_path, joint_hz,
                                                                                        joint_offset,
                                                                                        monitor_kernels):
    """A recorded cell (depth images + joint CSV, as a real cell's recorder would write them,
    stamps on a wall clock far from 0) replayed with --fast: the log's clock starts at the first
    stamp, every frame is used, and the robot moving through the images is not an obstacle —
    also with joint states slower than the control rate and not on its ticks (a frame then
    waits for the joint state after its capture instead of being refused as 'future')."""
    import numpy as np

    from depthguard.sim.cells import cell_rig_path
    from depthguard.sources.frame import Frame
    from depthguard.sources.images import write_image_dir
    from depthguard.sources.sim_source import SimFrames, SimWorld

    world = SimWorld("flacco-cell", alone=True, noiseless=True)
    sim = SimFrames(world)
    T0, dur = 1.7e9, 0.5                                       # seconds of a wall clock
    world.advance(dur + 0.05)
    frames = []
    for k in range(int(dur * 30) + 1):
        for i, cid in enumerate(sim.camera_ids):
            tc = k / 30 + i * 0.011 + 0.005                   # after the first joint state
            frames.append(Frame(cid, sim.render(cid, tc, world.history.at(tc)), T0 + tc))
    frames.sort(key=lambda f: f.stamp)
    write_image_dir(tmp_path / "rec", frames)
    rows = ["stamp," + ",".join(f"q{j + 1}" for j in range(world.robot.dof))]
    for k in range(int((dur + 0.05) * joint_hz)):
        tj = k / joint_hz + joint_offset
        q = world.history.at(tj)
        rows.append(f"{T0 + tj!r}," + ",".join(repr(float(x)) for x in q))
    (tmp_path / "joints.csv").write_text("\n".join(rows) + "\n")
    out = tmp_path / "out"
    res = subprocess.run(DG + ["monitor", "--rig", str(cell_rig_path("flacco-cell")), "--source",
                               f"images:{tmp_path / 'rec'}", "--joints", f"csv:{tmp_path / 'joints.csv'}",
                               "--fast", "--out", str(out), "--quiet"], capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    log = _lines(out / "log.jsonl")
    summary = json.loads((out / "summary.json").read_text())
    assert log[0]["t"] == pytest.approx(T0, abs=1e-3)
    used = {c: s["fused"] for c, s in summary["stats"]["cameras"].items()}
    assert sum(summary["stats"]["cameras"][c]["frames"] for c in used) == len(frames)
    assert all(not s["refused"] for s in summary["stats"]["cameras"].values())
    late = [r for r in log if r["t"] > T0 + 0.1]
    assert late and all(r["override"] > 0 for r in late)
    # the robot alone, noiseless, removed at capture time: nothing near its end effector
    ee = [r["points"][0] for r in late]
    assert all(p["observed"] for p in ee)
    assert min((p["distance"] for p in ee if p["distance"] is not None), default=np.inf) > 0.05


def test_the_age_line_is_for_late_frames_not_for_the_starts_wait():
    """The age line explains a stop for late frames; a run whose only stale stop was the start's
    wait for each camera's first frame (as every real-time run begins) gets none, nor does a stop
    of the joints or of an unobserved point. Episodes as ``summary.json`` gives them, with the
    supervisor's own reasons (``control.supervisor.stale_reason``)."""
    from depthguard.cli.monitor import late_frame_stop
    from depthguard.control.supervisor import stale_reason

    def episode(key, reason, t0):
        return {"reason": reason, "key": key, "t_start": t0, "t_end": t0 + 0.05, "t_stopped": t0}

    start = [episode(*stale_reason(c, 0.1, True), 0.0087) for c in ("camA", "camB")]
    start.append(episode("unobserved:ee", "control point ee is not observed by any camera (R26)", 0.0087))
    summary = {"cameras": ["camA", "camB"], "episodes": start}
    assert not late_frame_stop(summary)
    joints = episode("stale:joints", "joint states: none for more than 50 ms - stale data (R27)", 3.0)
    assert not late_frame_stop({**summary, "episodes": start + [joints]})
    late = episode(*stale_reason("camB", 0.1, False), 4.2)
    assert late_frame_stop({**summary, "episodes": start + [late]})
    assert not late_frame_stop({"cameras": ["camA"], "episodes": [late]})      # not a camera of this run
    assert not late_frame_stop({})


def test_the_frame_age_split_names_the_slowest_camera_and_the_monitors_part():
    """The closing line of a real-time run that stopped the robot for stale frames says whose
    lateness it was (R27): the slowest camera's age at delivery beside the monitor's part; a
    fast run (no delivery ages) or a run that used no frame gets no line."""
    from depthguard.cli.monitor import frame_age_split

    summary = {"frame_lag_at_push_ms": {"camA": {"p50": 9.0, "p99": 41.2, "max": 60.0, "frames": 230},
                                        "camB": {"p50": 12.0, "p99": 87.6, "max": 95.0, "frames": 228}},
               "frame_to_reaction_ms": {"p50": 20.0, "p99": 55.4}}
    line = frame_age_split(summary, 0.1)
    assert "stale limit of 100 ms" in line and "88 ms when the source delivered them (camera camB" in line
    assert "then 55 ms in the monitor" in line
    assert frame_age_split({**summary, "frame_lag_at_push_ms": {}}, 0.1) is None
    assert frame_age_split({**summary, "frame_to_reaction_ms": {"p50": None, "p99": None}}, 0.1) is None
