"""Bench group ``monitor.build``: the fusion's build per frame on every cell, with and without a person (issue 29).

The cost of a camera frame must be bounded by the design, not by the cell. For
each cell below, once with a person in view and once without (the same robot
motion, the same noise seed):

* ``flacco-cell`` (two Kinect v1 640x480, a 7 x 7 m room): scene time 10-11 s,
  the robot starting its swing away from home; with the person whose right
  hand reached for the end effector (situation ``reach``) and who then turns
  away;
* ``ur3-cell`` (four RealSense D435 640x480, a room with walls): scene time
  8.5-9.5 s, the UR3 moving from one pose to the next; with the operator
  standing at the table's edge;
* ``fr3-cell`` (two RealSense D435 640x480 at 15 Hz on tripods, a Franka FR3 whose model
  comes from the installed franky-sim; full runs only, not ``--quick``): scene time 6-7 s, the
  FR3 swinging along its path; with the person walking up to the path's edge and standing
  there; "failed" in the note where franky-sim is not installed;
* ``ur5-urdf-posts``, a cell of the kind a new user writes from the docs
  (:data:`URDF_RIG`): a UR5 from example-robot-data's URDF on a table, two D435
  640x480 on posts 2 m up looking down at the robot, no floor and no walls;
  the robot swings its shoulder joints back and forth; with a person
  (:mod:`depthguard.sim.people`) beside the table reaching towards the robot.

The built-in cells without a robot in their rig (``flacco-walls``,
``c-arm-room``, whose C-arm is the scene's machine) have no monitor
(``Monitor`` needs a robot) and are named in the notes.

Every camera's frames (the simulator's noisy depth, the cameras half or a
quarter period apart: not synchronised) and the joint states at 500 Hz are
made **before** any clock, and the monitor's kernels are compiled first
(:func:`depthguard.runtime.monitor.warm_up`). A real :class:`Monitor` with the
rig's ``monitor:`` settings, in its real-time configuration
(``Monitor.real_time()``: one grid, the classify-ahead band), is then fed in
capture order: the joints up to a little after the frame's stamp, the frame,
and a wait until it is fused (``flush``), so that each build loads exactly the
one camera that changed, alone on the machine's cores. The figure is
``monitor.fusion.build_seconds`` (the fusion worker's own clock around a build:
the robot's volume at the capture joints, ``set_frames`` with the changed
camera, the query that classifies the cells around the control points ahead);
the first two rounds of frames (every camera's first frames, which make the
grid) are not counted.

Rows, per case ``<cell>`` and ``<cell>+person``:

* ``monitor.build_p50_ms.<case>`` — median build per frame, ms. Goal <= 2.5.
* ``monitor.build_p99_ms.<case>`` — 99th percentile, ms. Goal <= 6.

Peer, in the same run on the same frames: the eager reach-limited depth grid
(``set_frames(..., lazy=False, reach=DepthGridMap.robot_reach(capsules, rho))``
and the query at the control points, on the bench's thread), timed around the
same work (capsules at the capture joints, load, query) on the first frames
after every camera's first (quick 1, full 6: it takes up to seconds a frame);
the robot depths of both come from the simulator's expected depth, rendered
before the clock. In quick mode (the tests) that untimed first load is lazy: it
loads the cameras' states and pyramids without the eager classification of
every column (about 1.5 CPU-s a case), which only the one timed frame does;
that frame then also loads the eager kernel from numba's cache.
"""

from __future__ import annotations

import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from depthguard.evaluation.bench import BenchContext, BenchRow, group

CAMERA_HZ = 30.0
JOINT_HZ = 500.0
FRAMES_FULL = 31              # frames per camera (one second of the path)
FRAMES_QUICK = 4
PEER_FRAMES_FULL = 6          # frames timed for the peer (seconds each on the larger cells)
PEER_FRAMES_QUICK = 1
WARM_ROUNDS = 2               # rounds of frames (one per camera each) not counted
JOINT_LEAD = 0.004            # s of joint states pushed beyond a frame's stamp (the robot's controller is ahead)

#: a new user's cell (docs/ARCHITECTURE.md "Rig files"): ``{urdf}`` is example-robot-data's UR5
URDF_RIG = """\
name: ur5-urdf-posts
workspace: {{min: [-1.0, -1.0, 0.0], max: [1.0, 1.0, 2.0]}}
cameras:
  - id: left
    sensor: realsense_d435
    width: 640
    height: 480
    pose: {{look_at: {{eye: [1.0, -1.0, 2.0], target: [0.0, 0.0, 0.9], up: [0, 0, 1]}}}}
  - id: right
    sensor: realsense_d435
    width: 640
    height: 480
    pose: {{look_at: {{eye: [1.0, 1.0, 2.0], target: [0.0, 0.0, 0.9], up: [0, 0, 1]}}}}
robot:
  urdf: {urdf}
  base: {{translation: [0.0, 0.0, 0.8]}}
  joints: [0.0, -1.57, 1.57, -1.57, -1.57, 0.0]
objects:
  - {{name: table, box: {{size: [1.2, 0.8, 0.05]}}, pose: {{translation: [0.0, 0.0, 0.775]}}}}
  - {{name: post_left, cylinder: {{radius: 0.04, length: 2.1}}, pose: {{translation: [1.15, -1.15, 1.05]}}}}
  - {{name: post_right, cylinder: {{radius: 0.04, length: 2.1}}, pose: {{translation: [1.15, 1.15, 1.05]}}}}
"""

#: (cell, scene time of the window's start, the person's part) of the built-in cells; a window
#: lasts the frames' span (full: one second)
BUILTIN_WINDOWS = (("flacco-cell", 10.0, "the person's hand by the end effector, then turning away"),
                   ("ur3-cell", 8.5, "the operator at the table's edge"))
#: built-in cells measured in full runs only (the suite runs the group ``--quick``)
#: (fr3-cell's robot stands still from 6 s on: its window started there until 2026-11-27, a robot at rest)
FULL_ONLY_WINDOWS = (("fr3-cell", 5.0, "the person walking up to the path's edge"),)
URDF_PERSON = "a person beside the table reaching towards the robot"


# ---------------------------------------------------------------- the cells
def _urdf_world(person: bool, seed: int):
    """The new user's cell (:data:`URDF_RIG`) as a simulator world, its robot swinging along a
    joint path, with or without a person; ``None`` when example-robot-data is not installed."""
    from depthguard.rig import Rig
    from depthguard.robot.urdf import example_robot_data_dir
    from depthguard.sim.people import Key, Person
    from depthguard.sim.scene import JointPath, Scene
    from depthguard.sources.sim_source import SimWorld

    share = example_robot_data_dir()
    urdf = share / "robots" / "ur_description" / "urdf" / "ur5_robot.urdf" if share else None
    if urdf is None or not urdf.is_file():
        return None
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "ur5-urdf-posts.yaml"
        path.write_text(URDF_RIG.format(urdf=urdf))
        rig = Rig.load(path)
    q0 = np.asarray(rig.robot_q0, dtype=np.float64)
    dq = np.zeros(rig.robot.dof)
    dq[0], dq[1] = 0.6, 0.25
    robot_path = JointPath([(0.0, q0), (1.0, q0 + dq), (2.0, q0)])
    people = [Person("visitor", [Key(0.0, (-0.95, 0.1), 0.0, right=(-0.45, 0.05, 1.05))], floor_z=0.0)]
    world = SimWorld(None, rig=rig, alone=not person, seed=seed)
    world.scene = Scene(rig.objects, robot=rig.robot, robot_path=robot_path, robot_q0=q0,
                        people=people, duration=2.0, name=rig.name)
    return world, 0.0


def _builtin_world(name: str, start: float, person: bool, seed: int):
    from depthguard.sources.sim_source import SimWorld

    return SimWorld(name, alone=not person, seed=seed), start


# ---------------------------------------------------------------- the input, before any clock
class _Frames:
    """Every camera's frames over one window, in capture order, with the joints at 500 Hz and
    the robot's expected depth of each frame (for the peer)."""

    def __init__(self, world, start: float, n_frames: int):
        from depthguard.filtering.expected import ExpectedDepth
        from depthguard.sources.sim_source import SimFrames

        self.rig = world.rig
        scene = world.scene
        sim = SimFrames(world)
        cams = list(self.rig.cameras)
        robot = self.rig.robot
        self.span = n_frames / CAMERA_HZ
        self.joints = [(i / JOINT_HZ, np.asarray(scene.robot_q(start + i / JOINT_HZ), dtype=np.float64))
                       for i in range(int(self.span * JOINT_HZ) + 8)]
        experts = {c.id: ExpectedDepth(c, robot, self.rig.static_meshes()) for c in cams}
        self.frames = []                         # (stamp, camera id, depth, robot depth, q at capture)
        for k, cam in enumerate(cams):
            phase = k / (len(cams) * CAMERA_HZ)
            for j in range(n_frames):
                s = j / CAMERA_HZ + phase
                q = self.q_at(s)
                depth = np.array(sim.render(cam.id, start + s, q), dtype=np.float32, copy=True)
                self.frames.append((s, cam.id, depth, np.array(experts[cam.id].robot(q), copy=True), q))
        self.frames.sort(key=lambda f: f[0])
        self.n_cams = len(cams)

    def q_at(self, s: float) -> np.ndarray:
        """The joints at stamp ``s`` (linear between the 500 Hz states)."""
        x = s * JOINT_HZ
        i = min(int(x), len(self.joints) - 2)
        w = x - i
        return (1.0 - w) * self.joints[i][1] + w * self.joints[i + 1][1]


# ---------------------------------------------------------------- the monitor's builds
def _monitor_builds(frames: _Frames, cfg) -> np.ndarray:
    """Seconds of each counted fusion build of a real Monitor fed ``frames`` (module docstring)."""
    from depthguard.runtime.monitor import Monitor, warm_up
    from depthguard.sources.frame import Frame

    warm_up(frames.rig, cfg)
    skip = WARM_ROUNDS * frames.n_cams
    with Monitor(frames.rig, cfg) as mon, mon.real_time():
        j = 0
        counted_from = None
        for i, (s, cid, depth, _, _) in enumerate(frames.frames):
            while j < len(frames.joints) and frames.joints[j][0] <= s + JOINT_LEAD:
                mon.push_joints(*frames.joints[j])
                j += 1
            if i == skip:
                counted_from = len(mon.fusion.build_seconds)
            mon.push_frame(Frame(cid, depth, s))
            mon.flush(timeout=60.0)
        st = mon.stats()
        builds = np.asarray(mon.fusion.build_seconds[counted_from:], dtype=np.float64)
        errors = st["fusion_errors"]
        refused = sum(sum(c["refused"].values()) for c in st["cameras"].values())
    if errors or refused:
        raise RuntimeError(f"{errors} fusion errors, {refused} frames refused ({st['fusion_last_error']})")
    return builds


# ---------------------------------------------------------------- the peer: eager, reach-limited
def _eager_builds(frames: _Frames, cfg, n_timed: int, lazy_first: bool = False) -> np.ndarray:
    """Seconds per frame of the eager reach-limited grid on the same frames (module docstring): the
    first load of every camera untimed (it compiles and fills; ``lazy_first``: without the eager
    classification, the quick mode's), then ``n_timed`` frames."""
    from depthguard.fusion.depth_grid import DepthGridMap

    rig, robot = frames.rig, frames.rig.robot
    cams = list(rig.cameras)
    d_min, d_max = rig.workspace.depth_span(cams[0])
    grid = DepthGridMap(cams, principal=cams[0].id, d_min=d_min, d_max=d_max, delta_d=cfg.delta_d)
    data = robot.create_data()
    depths, rdepths, q_caps = {}, {}, {}
    out, loads = [], 0
    for s, cid, depth, rdepth, q in frames.frames:
        depths[cid], rdepths[cid], q_caps[cid] = depth, rdepth, q
        if len(depths) < len(cams):
            continue
        if len(out) >= n_timed:
            break
        robot.forward(frames.q_at(s + JOINT_LEAD), data)
        t0 = time.perf_counter()
        segs, radii = zip(*(robot.collision_segments(qc, cfg.robot_padding) for qc in q_caps.values()))
        caps = (np.concatenate(segs), np.concatenate(radii))
        reach = DepthGridMap.robot_reach(caps, cfg.query_rho)
        grid.set_frames(depths, rdepths, robot_offset=cfg.robot_offset, robot_capsules=caps, invalid=cfg.invalid,
                        robot_in_others=cfg.robot_in_others, changed={cid} if loads else None,
                        silhouette_px=cfg.silhouette_px, gap_px=cfg.gap_px, lazy=lazy_first and not loads,
                        reach=reach)
        grid.query(data.cp_positions, rho=cfg.query_rho, method=cfg.method)
        if loads:
            out.append(time.perf_counter() - t0)
        loads += 1
    return np.asarray(out, dtype=np.float64)


# ---------------------------------------------------------------- the group
def _cases(ctx: BenchContext):
    """(case name, who is in view, make world) of every cell with a robot, without and with a person."""
    for name, start, who in BUILTIN_WINDOWS + (() if ctx.quick else FULL_ONLY_WINDOWS):
        for person in (False, True):
            yield (name + ("+person" if person else ""), who if person else "nobody (the cell's 'alone')",
                   lambda name=name, start=start, person=person: _builtin_world(name, start, person, ctx.seed))
    for person in (False, True):
        yield ("ur5-urdf-posts" + ("+person" if person else ""), URDF_PERSON if person else "nobody",
               lambda person=person: _urdf_world(person, ctx.seed))


def _ms(xs, q) -> float:
    return float(np.percentile(xs, q) * 1e3) if len(xs) else math.nan


@group("monitor.build")
def bench_builds(ctx: BenchContext) -> list[BenchRow]:
    """The group, with the thread switch interval of a real-time run (``runtime.runner``), in which
    the fusion worker builds."""
    from depthguard.runtime.runner import REAL_TIME_SWITCH_INTERVAL_S

    old = sys.getswitchinterval()
    sys.setswitchinterval(REAL_TIME_SWITCH_INTERVAL_S)
    try:
        return _bench_builds(ctx)
    finally:
        sys.setswitchinterval(old)


def _bench_builds(ctx: BenchContext) -> list[BenchRow]:
    from depthguard.sim.cells import list_cells, load_cell

    n_frames = FRAMES_QUICK if ctx.quick else FRAMES_FULL
    no_robot = [c for c in list_cells() if load_cell(c).rig.robot is None]
    rows = []
    for case, who, make in _cases(ctx):
        note, mon, peer, peer_note = "", np.empty(0), np.empty(0), ""
        try:
            made = make()
            if made is None:
                note = "example-robot-data's UR5 URDF is not installed: not measured; "
            else:
                frames = _Frames(*made, n_frames)
                cfg = frames.rig.monitor
                mon = _monitor_builds(frames, cfg)
                try:
                    peer = _eager_builds(frames, cfg, PEER_FRAMES_QUICK if ctx.quick else PEER_FRAMES_FULL,
                                         lazy_first=ctx.quick)
                except Exception as exc:     # the peer's interface may change under a rewrite
                    peer_note = f"; the peer failed: {type(exc).__name__}: {exc}"
                cams = ", ".join(f"{c.id} {c.width}x{c.height}" for c in frames.rig.cameras)
                note = (f"{frames.n_cams} cameras ({cams}), {len(mon)} builds counted (peer {len(peer)}) of "
                        f"{len(frames.frames)} frames over {frames.span:.2f} s of robot motion, in view: {who}; "
                        f"rig monitor: settings "
                        f"(rho {cfg.rho:g} m, invalid={cfg.invalid!r}); ")
        except Exception as exc:
            note = f"failed: {type(exc).__name__}: {exc}; "
        ctx.log(f"  build {case}: p50 {_ms(mon, 50):.2f} p99 {_ms(mon, 99):.2f} ms; eager reach-limited "
                f"p50 {_ms(peer, 50):.2f} p99 {_ms(peer, 99):.2f} ms{peer_note}")
        if not rows:
            note += (f"not measured (no robot in the rig; the monitor needs one): {', '.join(no_robot)}; "
                     f"switch interval {sys.getswitchinterval() * 1e3:g} ms (a real-time run's); ")
        peer_name = "eager reach-limited grid (lazy=False, reach=robot_reach), same frames"
        rows.append(BenchRow(f"monitor.build_p50_ms.{case}", _ms(mon, 50), "ms", peer=peer_name,
                             peer_value=_ms(peer, 50),
                             note=(f"fusion build per frame (Monitor.fusion.build_seconds, real-time settings, "
                                   f"one camera changed), median; {note}goal <= 2.5 ms{peer_note}")))
        rows.append(BenchRow(f"monitor.build_p99_ms.{case}", _ms(mon, 99), "ms", peer=peer_name,
                             peer_value=_ms(peer, 99),
                             note="99th percentile of the builds of the row above; goal <= 6 ms"))
    return rows
