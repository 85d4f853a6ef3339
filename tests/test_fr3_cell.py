"""The fr3-cell and the closed loop through franky-sim (issue 32 part 3; R27, R30, R31, R33).

- The FR3's model (``robot: fr3``, read from franky-sim's URDF) against the simulator's own
  kinematics: MuJoCo's bodies of franky-sim's MJCF (Google DeepMind's menagerie model, written
  by others from another source than the URDF).
- Simulated cameras that follow a live joint source render the robot at that source's joints.
- The loop: ``depthguard monitor --cell fr3-cell --joints franky:HOST --sink
  franky:HOST,path=fr3-cell`` against franky-sim; the truth is franky-sim's joint state after
  each physics step and the scene's people, not what depthguard says.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
import types

import numpy as np
import pytest

pytest.importorskip("franky_sim", reason="franky-sim (extras test, franka) has the FR3's model and simulates it")

from depthguard.robot import load_robot  # noqa: E402
from depthguard.sim import load_cell  # noqa: E402
from depthguard.sim.ground_truth import true_distance  # noqa: E402


def _mujoco_fr3():
    """franky-sim's MuJoCo model of one FR3 (not started) and its arm joints' qpos addresses."""
    import mujoco
    from franky_sim.mujoco_simulator import MujocoSimulator, _get_joint_addresses

    sim = MujocoSimulator(enable_visualization=False)
    sim.add_robot()
    import xml.etree.ElementTree as ET

    model = mujoco.MjModel.from_xml_string(ET.tostring(sim.scene, encoding="unicode"))
    return mujoco, model, _get_joint_addresses(model, "robot0_")[0]


def test_fr3_model_is_franky_sims_robot():
    mujoco, model, qadr = _mujoco_fr3()
    robot = load_robot("fr3")
    data = robot.create_data()
    d = mujoco.MjData(model)
    rng = np.random.default_rng(3)
    names = [f"fr3_link{i}" for i in range(1, 8)]
    worst = 0.0
    for _ in range(20):
        q = rng.uniform(robot.chain.q_min, robot.chain.q_max)
        d.qpos[qadr] = q
        mujoco.mj_kinematics(model, d)
        robot.forward(q, data)
        for n in names:
            ours = data.link_poses[robot.chain.link_index(n)]
            body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"robot0_{n}")
            worst = max(worst, float(np.abs(ours[:3, 3] - d.xpos[body]).max()))
            worst = max(worst, float(np.abs(ours[:3, :3] - d.xmat[body].reshape(3, 3)).max()))
    assert worst < 1e-3, worst                  # positions m and rotation entries: the same robot
    # the cell's robot stands where franky-sim's starts; the URDF's joint limits hold every joint
    # position the simulated robot can take (MuJoCo's ranges: the FR3 data sheet's, narrower),
    # so no state it reports is refused as outside the rig's limits
    cell = load_cell("fr3-cell")
    assert np.allclose(cell.rig.robot_q0, robot.q_home)
    jnt = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"robot0_fr3_joint{i}") for i in range(1, 8)]
    assert np.all(model.jnt_range[jnt, 0] >= robot.chain.q_min) and np.all(model.jnt_range[jnt, 1] <= robot.chain.q_max)


def test_simulated_cameras_render_the_robot_a_live_source_reports(tmp_path):
    """Frames of a world that follows a joint source show the robot at that source's joints, not
    at the cell's scripted path; frames captured before its first state are not rendered."""
    from depthguard.sources.base import open_source
    from depthguard.sources.joints import CsvJointSource
    from depthguard.sources.sim_source import FollowedJoints

    cell = load_cell("fr3-cell")
    q_live = np.array([-1.0, 0.5, 0.0, -1.2, 0.0, 1.9, 0.785])       # far from the path's start
    t0 = 1000.0
    csv = tmp_path / "q.csv"
    csv.write_text("stamp," + ",".join(f"j{i}" for i in range(1, 8)) + "\n"
                   + "".join(f"{t0 + 0.05 + k * 0.004:.3f}," + ",".join(map(str, q_live)) + "\n" for k in range(100)))
    context: dict = {}
    frames = open_source("sim:fr3-cell:alone:noiseless", cell.rig, context)
    joints = FollowedJoints(frames.world, CsvJointSource(csv, cell.rig), "csv:q")
    frames.start_clock(t0)
    assert joints.states_until(t0 + 0.3)
    got = frames.frames_until(t0 + 0.3)
    assert got and all(t0 + 0.05 <= f.stamp <= t0 + 0.3 for f in got)
    assert frames.counters()["no_robot_state"] >= 2 and frames.counters()["follows"] == "csv:q"
    path_q = cell.scene.robot_q(0.0)
    for f in got[:2]:
        at_live = frames.sim.depth(f.camera_id, f.stamp - t0, q_live, [], dark=False)
        at_path = frames.sim.depth(f.camera_id, f.stamp - t0, path_q, [], dark=False)
        assert np.array_equal(f.depth, at_live)
        assert np.count_nonzero(at_live != at_path) > 200               # the robot moved in the image
    frames.world.on_reaction(types.SimpleNamespace(override=0.0))        # the real robot takes reactions
    assert frames.world.advance(t0 + 5.0) == []                            # its own robot does not move


# ------------------------------------------------------------------ the loop through franky-sim
@pytest.fixture
def fr3_sim():
    """franky-sim's FR3 on a free loopback address; ``truth``: (wall s, q, dq) after each physics step."""
    pytest.importorskip("franky", reason="franky-control (extra depthguard[franka]) drives the robot")
    from franky_sim import SimulationServer
    from franky_sim.mujoco_simulator import MujocoSimulator

    with MujocoSimulator(enable_visualization=False) as sim:
        robot = sim.add_robot()
        truth: list = []
        lock = threading.Lock()

        def record(_sim):
            st = robot.inner_state
            with lock:
                truth.append((time.time(), np.array(st.q, dtype=float), np.array(st.dq, dtype=float)))

        sim.register_post_step_callback(record)
        with SimulationServer(sim) as server:
            server.run_async()
            yield types.SimpleNamespace(host=robot.hostname, truth=truth, lock=lock)


def _separation(cell, q, scene_t) -> float:
    """The true distance (m) between the robot's capsules at ``q`` and the people at scene time
    ``scene_t`` (inf when nobody is there): capsule axes sampled every 5 mm, minus the radius."""
    people = [p for p in cell.scene.dynamic_at(scene_t)]
    if not people:
        return np.inf
    robot = cell.rig.robot
    data = robot.create_data()
    robot.forward(q, data)
    best = np.inf
    for k, c in enumerate(robot.capsules):
        T = data.link_poses[robot.chain.link_index(c.link)]
        a, b = T[:3, :3] @ c.a + T[:3, 3], T[:3, :3] @ c.b + T[:3, 3]
        n = max(2, int(np.linalg.norm(b - a) / 0.005) + 1)
        pts = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
        best = min(best, float(true_distance(people, pts).min()) - c.radius)
    return best


@pytest.mark.slow
@pytest.mark.realtime
def test_fr3_stops_for_the_person_and_resumes_through_franky_sim(fr3_sim, tmp_path):
    out = tmp_path / "run"
    res = subprocess.run([sys.executable, "-m", "depthguard.cli", "monitor", "--cell", "fr3-cell",
                          "--joints", f"franky:{fr3_sim.host}", "--sink", f"franky:{fr3_sim.host},path=fr3-cell",
                          "--duration", "18", "--out", str(out), "--quiet"],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, (res.stdout, res.stderr[-3000:])
    summary = json.loads((out / "summary.json").read_text())
    counts = summary["source_counts"]["sim:fr3-cell"]
    assert counts["follows"] == f"franky:{fr3_sim.host}"
    origin = counts["clock_origin_s"]
    cell = load_cell("fr3-cell")
    with fr3_sim.lock:
        steps = [x for x in fr3_sim.truth if origin <= x[0] <= origin + 18.0]
    truth = steps[::max(1, len(steps) // 2000)]                                          # <= ~2000 samples
    t = np.array([w - origin for w, _q, _dq in truth])                                  # the scene's time
    q = np.array([x[1] for x in truth])
    v = np.array([np.abs(x[2]).max() for x in truth])
    sep = np.array([_separation(cell, qi, ti) for ti, qi in zip(t, q)])
    i = int(np.argmin(sep))
    report = (f"min true separation {sep[i] * 100:.1f} cm at scene t {t[i]:.2f} s, franky-sim |dq|max there "
              f"{v[i]:.4f} rad/s; franky-sim ran {len(steps) / 18.0:.0f} physics steps per second (1000 in real time)")
    # not vacuous: the path, followed without a reaction, passes within 35 cm of the standing person
    wps = np.loadtxt(cell_path(), delimiter=",", comments="#", ndmin=2)
    swept = np.concatenate([a + np.linspace(0.0, 1.0, 40)[:, None] * (b - a) for a, b in zip(wps[:-1], wps[1:])])
    assert min(_separation(cell, qk, 7.5) for qk in swept) < 0.35
    assert sep[i] > 0.0, report                                    # and the robot never reached them
    # when the person was nearest the robot was at most in its stop's tail (measured 0.000-0.022 rad/s:
    # the person reaches the path's edge at 6 s while SSM still slows the robot; it stands above) —
    # where they came near at all: a franky-sim far below real time (375 steps/s once in CI) left the
    # robot behind on its path, 76 cm away when the person arrived, and SSM lets it move there
    if sep[i] < 0.35:
        assert v[i] < 0.05, report
    records = [json.loads(x) for x in (out / "log.jsonl").read_text().splitlines()]
    records = [r for r in records if "t" in r]
    assert any(6.0 < r["t"] - origin < 9.0 and any(k.startswith("ssm:") for k in r["reasons"]) for r in records)
    stale = [(a["override"], b["override"]) for a, b in zip(records, records[1:])
             if "stale:joints" in a["reasons"] and "stale:joints" in b["reasons"]]
    assert all(y <= x + 1e-9 for x, y in stale)                    # stale joints: the override only falls (R27)
    # moving before the person comes within the 2 m looked at, and again after they left: only
    # where the monitor had fresh data; on a machine too busy to render the cameras in real time
    # the robot must stand instead (R27: stale cameras), and then the return is not judged here
    before, after = t < 4.5, t > 13.5                              # more than 2 m away; gone at 12.5 s
    fresh = {w: np.mean([not any(k.startswith("stale:") for k in r["reasons"]) for r in records
                         if lo < r["t"] - origin < hi]) for w, (lo, hi) in {"before": (0, 4.5), "after": (13.5, 18)}.items()}
    report += f"; cycles with fresh data: before {fresh['before']:.0%}, after {fresh['after']:.0%}"
    first = next((r["t"] - origin for r in records
                  if not any("no frame yet" in str(m) for m in r["reasons"].values())), float("nan"))
    report += f"; every camera's first frame at scene t {first:.2f} s"
    stale_keys = sorted({k for r in records for k in r["reasons"] if k.startswith("stale:")})
    report += "; stale cycles by reason: " + ", ".join(
        f"{k} {np.mean([k in r['reasons'] for r in records]):.0%}" for k in stale_keys)
    print(report)
    if min(fresh.values()) < 0.5 or len(steps) < 0.2 * 18000:
        pytest.skip(f"the robot was never reached ({report}), but this machine could not keep the simulated "
                    "cameras or franky-sim near real time, so the robot stood for stale data (R27) or hardly "
                    "moved, and its return to the path was not judged")
    assert v[before].max() > 0.2 and v[after].max() > 0.2, (v[before].max(), v[after].max(), report)
    # back on the path: joint 1 swings between the waypoints, the others stay at the path's values
    assert np.abs(q[after][:, 1:] - wps[0, 1:]).max() < 0.05
    assert np.ptp(q[after][:, 0]) > 0.3, (np.ptp(q[after][:, 0]), report)
    # standing while the person is at the path's edge (scene t 6-9 s): the monitor stopped the robot
    # before they got there and held it until it let it go again, and the robot stood once
    # franky-sim had had 1 s of its own time to brake (the FR3 stops from 2 rad/s in 0.74 s of it).
    # Franky-sim's time, not the wall clock: it ran at 250-490 steps/s beside the monitor here, and
    # a stop then lasted 1.5-4 s of the wall clock (a median 0.017 rad/s over 6-9 s in CI, when
    # slowing down also braked softly)
    scale = [(r["t"] - origin, r["speed_scale"]) for r in records]
    t_stop = max((x for x, k in scale if 4.5 < x < 9.0 and k > 0.0), default=4.5)
    assert t_stop < 6.0, (t_stop, report)                          # the last cycle that let it move
    t_go = min((x for x, k in scale if x > t_stop and k > 0.0), default=18.0)
    assert t_go > 9.0, (t_go, report)                              # held while the person stood there
    k_stop = next(k for k, x in enumerate(steps) if x[0] - origin > t_stop)
    held = [x for x in steps[k_stop + 1000:] if x[0] - origin < t_go]
    report += (f"; stopped at scene t {t_stop:.2f} s, let go at {t_go:.2f} s, standing judged over {len(held)} "
               "of franky-sim's steps")
    if len(held) < 100:
        pytest.skip(f"franky-sim ran too slowly to judge the standing robot after its stop ({report})")
    v_held = np.array([np.abs(x[2]).max() for x in held])
    assert np.median(v_held) < 2e-3, (np.median(v_held), report)                   # franky-sim: standing
    assert np.ptp(np.array([x[1] for x in held]), axis=0).max() < 2e-3, report     # rad: it does not creep
    print(report)


def cell_path():
    from depthguard.sim.cells import cell_path_file

    return cell_path_file("fr3-cell")
