"""A refused frame reaches the user when it happens (issue 33 item 2, R27, R28): the stale
camera's stop reason says why its frames are refused, and a --fast run in which a camera never
had a frame accepted ends with exit status 2 and that reason in one line."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from depthguard.filtering.expected import ExpectedDepth
from depthguard.runtime.monitor import Monitor
from depthguard.sim import load_cell
from depthguard.sources.frame import Frame

DG = [sys.executable, "-m", "depthguard.cli"]
# flush waits on a condition (every pushed frame processed); the first frames of a module compile
# the workers' kernels, minutes with a cold numba cache on a loaded machine (the default 10 s
# timed out here once, at load 10): a generous deadline, not a sleep
FLUSH_S = 600.0


def _still(rig, cam, q0):
    return np.array(ExpectedDepth(cam, rig.robot, rig.static_meshes()).known(q0), copy=True)


def test_a_stale_cameras_reason_names_its_refused_frames_until_one_is_accepted():
    rig = load_cell("flacco-cell").rig
    q0 = np.asarray(rig.robot_q0, dtype=np.float64)
    cam0, cam1 = rig.cameras[0], rig.cameras[1]
    good0, good1 = _still(rig, cam0, q0), _still(rig, cam1, q0)
    limit = rig.monitor.camera_stale_limit
    with Monitor(rig, rig.monitor.with_changes(invalid="free")) as mon:
        for k in range(400):
            mon.push_joints(k * 0.002, q0)
        mon.push_frame(Frame(cam0.id, good0 / 1000.0, 0.001))       # metres written into a millimetre PNG
        mon.push_frame(Frame(cam1.id, good1, 0.001))
        mon.flush(timeout=FLUSH_S)
        r = mon.step(0.01)
        assert "hold metres" in r.reasons[f"stale:{cam0.id}"] and "refused" in r.reasons[f"stale:{cam0.id}"]
        last = mon.stats()["cameras"][cam0.id]["last_refusal"]
        assert last.count(f"camera {cam0.id}") == 1, last      # named once, not "camera X: camera X:"
        assert "refused" not in r.reasons.get(f"stale:{cam1.id}", "")   # stale too (no grid yet), not refusing
        mon.push_frame(Frame(cam0.id, good0, 0.02))                  # a good frame: the refusal is history
        mon.push_frame(Frame(cam1.id, good1, 0.02))
        mon.flush(timeout=FLUSH_S)
        assert f"stale:{cam0.id}" not in mon.step(0.03).reasons
        mon.push_frame(Frame(cam0.id, good0 / 1000.0, 0.04))        # bad again; the good frame grows old
        mon.push_frame(Frame(cam1.id, good1, 0.02 + limit))
        mon.flush(timeout=FLUSH_S)
        r = mon.step(0.02 + limit + 0.01)
        assert "hold metres" in r.reasons[f"stale:{cam0.id}"]
        assert "refused" not in r.reasons.get(f"stale:{cam1.id}", "")


def test_a_cameras_stale_reason_without_refusals_stays_as_it_was():
    rig = load_cell("flacco-cell").rig
    q0 = np.asarray(rig.robot_q0, dtype=np.float64)
    with Monitor(rig) as mon:
        mon.push_joints(0.0, q0)
        r = mon.step(0.5)
        assert all(m.endswith("stale data (R27)") for k, m in r.reasons.items() if k.startswith("stale:"))


def test_a_fast_run_whose_camera_never_had_a_frame_accepted_exits_2_naming_why(tmp_path):
    """A recording whose cam0 PNGs hold metres (values 1000 x too small as millimetres): the
    status says so while it runs, the log's reasons too, and the run exits 2 with one line."""
    from depthguard.sim.cells import cell_rig_path
    from depthguard.sources.images import write_image_dir
    from depthguard.sources.sim_source import SimFrames, SimWorld

    world = SimWorld("flacco-cell", alone=True, noiseless=True)
    sim = SimFrames(world)
    T0, dur = 1.7e9, 0.3
    world.advance(dur + 0.05)
    frames = []
    for k in range(int(dur * 30) + 1):
        for i, cid in enumerate(sim.camera_ids):
            tc = k / 30 + i * 0.011 + 0.005
            d = sim.render(cid, tc, world.history.at(tc))
            frames.append(Frame(cid, d / 1000.0 if cid == "cam0" else d, T0 + tc))
    write_image_dir(tmp_path / "rec", sorted(frames, key=lambda f: f.stamp))
    rows = ["stamp," + ",".join(f"q{j + 1}" for j in range(world.robot.dof))]
    for k in range(int((dur + 0.05) * 500)):
        rows.append(f"{T0 + k / 500!r}," + ",".join(repr(float(x)) for x in world.history.at(k / 500)))
    (tmp_path / "joints.csv").write_text("\n".join(rows) + "\n")
    out = tmp_path / "out"
    res = subprocess.run(DG + ["monitor", "--rig", str(cell_rig_path("flacco-cell")), "--source",
                               f"images:{tmp_path / 'rec'}", "--joints", f"csv:{tmp_path / 'joints.csv'}",
                               "--fast", "--out", str(out)], capture_output=True, text=True, timeout=600)
    assert res.returncode == 2, (res.stdout, res.stderr)
    errors = [x for x in res.stderr.splitlines() if "error" in x]
    assert len(errors) == 1 and "camera cam0 never had a frame accepted" in errors[0] and "hold metres" in errors[0]
    assert "cam1" not in errors[0] and "Traceback" not in res.stderr
    assert "camera cam0 refuses its frames" in res.stderr                     # the status, while it ran
    log = [json.loads(x) for x in (out / "log.jsonl").read_text().splitlines()]
    assert any("hold metres" in r["reasons"].get("stale:cam0", "") for r in log)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stats"]["cameras"]["cam0"]["frames"] == 0
    assert summary["stats"]["cameras"]["cam1"]["frames"] > 0


def test_frames_refused_one_by_one_for_one_cause_are_told_once_per_camera_until_accepted():
    """Frames arriving before any joint state (simulated cameras with live joints that have not
    started, issue 33's first-contact check) are each refused with their own stamp in the reason;
    the command told each one (60 lines a second). Told: once per camera, again after a frame is
    accepted and the refusals start over. The truth: the monitor's own reasons, cycle by cycle."""
    from depthguard.cli.monitor import RefusalTeller

    rig = load_cell("flacco-cell").rig
    q0 = np.asarray(rig.robot_q0, dtype=np.float64)
    still = {c.id: _still(rig, c, q0) for c in rig.cameras}
    lines: list[str] = []
    tell = RefusalTeller(lines.append)
    reasons_seen = {c.id: set() for c in rig.cameras}
    with Monitor(rig, rig.monitor.with_changes(invalid="free")) as mon:
        for k in range(6):                                   # no joint state yet: every frame refused
            for c in rig.cameras:
                mon.push_frame(Frame(c.id, still[c.id], 0.01 + k / 30))
            mon.flush(timeout=FLUSH_S)
            r = mon.step(0.02 + k / 30)
            tell(r)
            for c in rig.cameras:
                reasons_seen[c.id].add(r.reasons.get(f"stale:{c.id}", ""))
        for c in rig.cameras:                                # each frame's own stamp: the reasons differ
            assert len(reasons_seen[c.id]) >= 3 and all("refused" in m for m in reasons_seen[c.id]), reasons_seen
            assert sum(f"camera {c.id} refuses" in x for x in lines) == 1, lines
        assert len(lines) == len(rig.cameras)
        for j in range(200):                                 # joints come; the next frames are accepted
            mon.push_joints(0.2 + j * 0.002, q0)
        for c in rig.cameras:
            mon.push_frame(Frame(c.id, still[c.id], 0.3))
        mon.flush(timeout=FLUSH_S)
        tell(mon.step(0.31))
        assert len(lines) == len(rig.cameras)                # accepted: nothing new to tell
        mon.push_frame(Frame(rig.cameras[0].id, still[rig.cameras[0].id] / 1000.0, 0.4))   # metres: refused again
        mon.flush(timeout=FLUSH_S)
        tell(mon.step(0.41))
        assert len(lines) == len(rig.cameras) + 1 and "hold metres" in lines[-1], lines


def test_a_camera_that_delivers_nothing_is_named_when_the_run_ends(tmp_path):
    """A recording with cam1's frames only, on the two-camera rig: cam0 never delivers, so the robot
    is stopped for it all along (R27) — the run's last lines say which camera and why, not only
    "override min 0.00"."""
    from typer.testing import CliRunner

    from depthguard.cli import app
    from depthguard.sim.cells import cell_rig_path
    from depthguard.sources.images import write_image_dir
    from depthguard.sources.sim_source import SimFrames, SimWorld

    world = SimWorld("flacco-cell", alone=True, noiseless=True)
    sim = SimFrames(world)
    T0, dur = 1.7e9, 0.3
    world.advance(dur + 0.05)
    frames = [Frame("cam1", sim.render("cam1", k / 30 + 0.005, world.history.at(k / 30 + 0.005)), T0 + k / 30 + 0.005)
              for k in range(int(dur * 30) + 1)]
    write_image_dir(tmp_path / "rec", frames)
    rows = ["stamp," + ",".join(f"q{j + 1}" for j in range(world.robot.dof))]
    rows += [f"{T0 + k / 500!r}," + ",".join(repr(float(x)) for x in world.history.at(k / 500))
             for k in range(int((dur + 0.05) * 500))]
    (tmp_path / "joints.csv").write_text("\n".join(rows) + "\n")
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["monitor", "--rig", str(cell_rig_path("flacco-cell")), "--source",
                                   f"images:{tmp_path / 'rec'}", "--joints", f"csv:{tmp_path / 'joints.csv'}",
                                   "--fast", "--quiet", "--out", str(out)])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stats"]["cameras"]["cam0"]["frames"] == 0 and not summary["stats"]["cameras"]["cam0"]["refused"]
    assert summary["stats"]["cameras"]["cam1"]["frames"] > 0 and summary["stopped_s"] > 0.9 * summary["run_time_s"]
    said = [x for x in res.output.splitlines() if "delivered no frame" in x]
    assert len(said) == 1 and "camera cam0 delivered no frame" in said[0] and "cam1" not in said[0], res.output
