"""The simulator as a source: ``sim:CELL[:OPTION...]`` frames and ``sim`` joint states (R29, R31).

A built-in cell (``depthguard.sim.load_cell``) or a user's rig (then the scene
is the rig's static objects and the robot at rest) seen by the rig's cameras
with their noise models. The robot **obeys the monitor**: it follows the
cell's scripted joint path, but its path time advances at the largest speed
that the latest reaction allows (``SimWorld.on_reaction``, a sink): the speed
override, and the joint-velocity limits of R14 (an obstacle near a control
point slows the joints that move towards it). A stop stops it.

Options after the cell name, separated by ``:``:

- a situation of the cell (``reach``, ``carry``, ...): the scene starts there;
- ``alone``: no people and no props (the robot alone in its cell);
- ``dark``: every pixel that sees a person or a prop returns no measurement
  (dark clothing), so the person is only "unknown";
- ``noiseless``: ideal images;
- ``seed=N``: the noise seed.

Cameras deliver at ``camera_hz`` (the rig's ``monitor.camera_hz``; each with its own phase: not synchronised);
each frame is rendered at its capture time with the robot where it was then,
and stamped with that time. The scene loops over its scripted duration.

The simulator's time starts at the run's clock origin (``start_clock``, called by
the runner): 0 for a run of the simulator alone, a recording's first stamp, or
the wall clock ``time.time()`` when a live source (``zenoh:`` or ``ros2:`` joint
states) sets the run's clock. Its frames and joint states are stamped on that
clock, so that they meet a live source's stamps. The robot never catches up more
than ``states``' span (5 s) of joint ticks in one call: a world that is further
behind jumps ahead (``skipped_ticks`` counts the ticks never computed), so that
one call's work and memory are bounded whatever ``t`` it is given.

**A live robot instead** (``--joints franky:HOST`` or ``ur-rtde:HOST`` beside ``sim:``):
the world *follows* that robot (:class:`FollowedJoints`, :meth:`SimWorld.follow`). Its own
robot does not move; the live joint states the monitor receives (stamped on the host's wall
clock when they arrive) are also the simulated robot's, and each frame is rendered with the
robot where that robot was at the frame's capture time (interpolated between the two states
around it, never extrapolated: a frame waits for the state after it). The run's clock is
then the wall clock, the people walk on it, and the reaction goes to the real robot (its
sink), not to the simulator. A frame captured before the first state kept is not rendered
(``no_robot_state`` in :meth:`SimFrames.counters`); while the states stop coming (a lost
robot) no frame is due either: the cameras go stale with the joints (R27).

In a real-time run (the runner says so) each camera renders on its own thread
(:meth:`SimFrames.camera_streams`), woken at its own next capture, as real cameras
deliver independently of each other; the world they share (``advance``, the joint
history, the scene's posing) is under locks, each camera's buffers its own. A camera
that falls more than a period
behind drops the frames it could not render, and the cameras take their noise's
normals from a pre-drawn bank (:class:`~depthguard.sources.noise.NormalBank`: the
same law per frame, 3 ms of a 640x480 frame's 10 ms saved). Fast runs keep the
exact draws: their logs are a function of the seed.
"""

from __future__ import annotations

import math
import threading
from collections import deque

import numpy as np

from depthguard.config import PRODUCT_CAMERA_HZ
from depthguard.robot.joint_history import JointHistory, OutsideHistory
from depthguard.sim.obeying_robot import ObeyingRobot, PathFollower
from depthguard.sim.posed import PosedMeshes
from depthguard.sources.base import register_joints, register_source
from depthguard.sources.camera_sim import CameraSchedule, CameraSim
from depthguard.sources.frame import Frame
from depthguard.sources.sim_streams import CameraStream, _Counts

__all__ = ["SimWorld", "SimFrames", "SimJoints", "CameraStream", "FollowedJoints", "parse_sim_spec", "sim_world"]

_FLAGS = ("alone", "dark", "noiseless")


def parse_sim_spec(arg: str) -> dict:
    """``"flacco-cell:reach:dark"`` -> ``{"cell": ..., "situation": ..., "alone": ..., ...}``."""
    parts = [p.strip() for p in arg.split(":")] if arg else []
    out = {"cell": parts[0] if parts and parts[0] else "flacco-cell", "situation": None, "seed": 0,
           **{f: False for f in _FLAGS}}
    for p in parts[1:]:
        if p in _FLAGS:
            out[p] = True
        elif p.startswith("seed="):
            try:
                out["seed"] = int(p[5:])
            except ValueError:
                raise ValueError(f"sim source: seed must be an integer (got {p!r})") from None
        elif p:
            if out["situation"] is not None:
                raise ValueError(f"sim source: two situations given ({out['situation']!r}, {p!r})")
            out["situation"] = p
    return out


class SimWorld:
    """The simulated cell shared by its frame and joint sources (module docstring).

    ``advance(t)`` moves the robot to run time ``t`` in ticks of ``1 / joint_hz``
    (path time advances by ``override * dt`` each tick); ``history`` holds its joints.
    """

    def __init__(self, cell_name: str, rig=None, situation: str | None = None, alone: bool = False,
                 dark: bool = False, noiseless: bool = False, seed: int = 0, joint_hz: float = 500.0,
                 camera_hz: float | None = None):
        from depthguard.sim.cells import cell_from_rig, load_cell

        cell = load_cell(cell_name) if (rig is None or cell_name) else cell_from_rig(rig)
        self.rig, self.scene = (rig or cell.rig), cell.scene
        self.start = cell.time_of(situation) if situation else 0.0
        if self.rig.robot is None:
            raise ValueError(f"sim source: rig {self.rig.name!r} has no robot")
        self.robot = self.rig.robot
        self.alone, self.dark, self.noiseless, self.seed = alone, dark, noiseless, seed
        if camera_hz is None:           # the rig's monitor.camera_hz, as a RealSense is asked for
            camera_hz = getattr(getattr(self.rig, "monitor", None), "camera_hz", None) or PRODUCT_CAMERA_HZ
        self.joint_hz, self.camera_hz = float(joint_hz), float(camera_hz)
        self.history = JointHistory(self.robot.dof, span_s=5.0)
        self.states: deque = deque(maxlen=int(5.0 * joint_hz))   # (stamp, q) of every tick, newest last
        self._lock = threading.Lock()
        self._path_end = float(getattr(self.scene.robot_path, "end", 0.0))   # a JointPath loops; a callable does not
        self._memo: dict = {}                     # tau -> q of the last path ticks (_path_q)
        self._reaction = None                     # the newest reaction not yet obeyed (on_reaction)
        # the package's one obeying robot (sim/obeying_robot.py), here on the cell's joint path
        self.robot_sim = ObeyingRobot(PathFollower(self._path_q), self.robot.dof, tau=self.start)
        self._tick = 0                  # next joint tick index (time = origin + tick / joint_hz)
        self.origin = 0.0               # the run's clock at the simulator's time 0 (start_clock)
        self.skipped_ticks = 0          # joint ticks jumped over by a world far behind (advance)
        self.followed: str | None = None  # the live joint source the robot follows (module docstring)
        self.qd_nominal = np.zeros(self.robot.dof)   # the path's velocity at scale 1 (commanded_qd)

    def on_reaction(self, reaction) -> None:
        """A sink: the robot takes each reaction — the override and the joint-velocity limits
        (R14) scale the speed along its path (a joint path cannot follow the end effector's
        repulsion, which this robot ignores): :class:`~depthguard.sim.obeying_robot.PathFollower`.

        Called on the control thread (500 Hz), it never waits (issue 29: it waited on the world's
        lock while a camera thread rendered or the joints pump ticked): the reaction is only
        kept, and :meth:`advance` has the robot obey the newest one before its next tick. Every
        tick still follows the newest reaction given before it (obeying sets the whole command,
        so the reactions in between change nothing), as when it obeyed here."""
        self._reaction = reaction               # one reference stored: atomic, no lock

    def _obey_newest(self) -> None:
        """The robot obeys the newest reaction given since the last call (under ``_lock``)."""
        r = self._reaction
        if r is not None:
            self._reaction = None
            if self.followed is None:           # a followed robot takes the reaction through its own sink
                self.robot_sim.obey(r)

    def follow(self, spec: str) -> None:
        """From now on the robot is the live robot of joint source ``spec`` (module docstring):
        :meth:`advance` no longer moves it, :meth:`take_states` does."""
        with self._lock:
            self.followed = spec

    def take_states(self, states) -> None:
        """The followed robot's new ``(stamp s, q (dof,) rad)`` states, in stamp order: the
        robot's poses for the frames (a state not after the newest is not kept)."""
        with self._lock:
            for ts, q in states:
                if self.history.push(float(ts), q):
                    self.states.append((float(ts), q))

    @property
    def scale(self) -> float:
        """The speed scale along the path of the last tick (0 = standing)."""
        return self.robot_sim.rate

    @property
    def scale_min(self) -> float:
        """The lowest scale so far."""
        return self.robot_sim.rate_min

    @property
    def slowed_s(self) -> float:
        """Seconds below 0.95 of the path's speed."""
        return self.robot_sim.slowed_s

    @property
    def stopped_s(self) -> float:
        """Seconds below 1 % of it."""
        return self.robot_sim.stopped_s

    def scene_time(self, t: float) -> float:
        """The scene's time at run time ``t`` (it loops over its scripted duration)."""
        s = self.start + t
        d = self.scene.duration
        return s % d if d > 0 else s

    def _path_q(self, tau: float) -> np.ndarray:
        """(dof,) rad, the cell's path at path time ``tau`` (s): ``scene.robot_q``, looping.

        The path follower asks for the same times again (each tick the joint speed at ``tau``
        and ``tau + dt``, then the new ``tau``: at full speed that is the next tick's
        ``tau``), so the last few answers are kept (copies handed out; issue 29, with
        :class:`~depthguard.sim.scene.JointPath`'s ``bisect``: numpy's dispatch on a 6-element
        array, 500 ticks a second, was a quarter of the joints pump's time)."""
        memo = self._memo
        q = memo.get(tau)
        if q is None:
            q = self._path_eval(tau)
            if len(memo) >= 4:
                memo.pop(next(iter(memo)))
            memo[tau] = q
        return q.copy()

    def _path_eval(self, tau: float) -> np.ndarray:
        return self.scene.robot_q(tau % self._path_end if self._path_end > 0 else tau)

    def start_clock(self, origin: float) -> None:
        """Put the simulator's time 0 at ``origin`` s of the run's clock (module docstring); only
        before the robot has moved (a world already advanced keeps its clock)."""
        if not math.isfinite(origin):
            raise ValueError(f"sim source: the clock origin must be finite (got {origin!r})")
        with self._lock:
            if self._tick == 0:
                self.origin = float(origin)

    def advance(self, t: float) -> list[tuple[float, np.ndarray]]:
        """Move the robot to run time ``t`` (s, the run's clock); the new ``(stamp, q)`` states, in
        order, at most ``states.maxlen`` of them (a world further behind jumps ahead, keeping the
        speed scale of its last tick; ``skipped_ticks`` counts the jump)."""
        new = []
        with self._lock:
            self._obey_newest()
            if self.followed is not None:
                return new                      # the live robot's states come through take_states
            dt = 1.0 / self.joint_hz
            local = t - self.origin
            due = math.floor(local / dt + 1e-9)         # the newest tick due at t
            if due - self._tick >= self.states.maxlen:
                skip = due - self._tick - self.states.maxlen + 1
                if self._tick > 0:
                    self.robot_sim.coast(skip, dt)
                self.skipped_ticks += skip
                self._tick += skip
            while self._tick * dt <= local + 1e-12:
                ts = self.origin + self._tick * dt
                q = self.robot_sim.step(dt) if self._tick > 0 else self.robot_sim.q
                self.history.push(ts, q)
                self.states.append((ts, q))
                new.append((ts, q))
                self._tick += 1
            if new:                               # a new array: a reader keeps the one it has
                self.qd_nominal = self.robot_sim.controller.qd_nominal(self.robot_sim, dt)
        return new

    def commanded_qd(self, q=None) -> np.ndarray:
        """(dof,) rad/s: the cell's path's joint velocity at scale 1 where the robot is on it — what
        SSM scales (R33, :meth:`SimJoints.attach`); ``q`` is not read. Never written by the caller."""
        return self.qd_nominal

    def dynamic(self, t: float) -> list:
        """The people and props at the simulator's time ``t`` (s from its start, not the run's clock)."""
        return [] if self.alone else list(self.scene.dynamic_at(self.scene_time(t)))


class SimJoints:
    """Joint source ``sim``: the simulated robot's joint states (``states_until``)."""

    def __init__(self, world: SimWorld):
        self.world = world
        self.on_reaction = world.on_reaction     # the robot obeys: the runner subscribes it to the reactions
        self.done = False
        self.lost = None
        self._last = -math.inf          # stamp of the newest state returned

    def start_clock(self, origin: float) -> None:
        """The run's clock origin (module docstring)."""
        self.world.start_clock(origin)

    def attach(self, monitor) -> None:
        """SSM scales the path's speed, not the robot's already slowed one (R33)."""
        monitor.commanded_qd = self.world.commanded_qd

    def states_until(self, t: float) -> list[tuple[float, np.ndarray]]:
        """The robot's states up to ``t`` not returned yet (the frame source may have moved the
        robot first: the states are the world's, whoever advanced it)."""
        self.world.advance(t)
        out = []
        with self.world._lock:          # newest first, back to the last state returned: the work is
            for ts, q in reversed(self.world.states):    # the new states, not the 5 s of history
                if ts <= self._last:
                    break
                if ts <= t + 1e-12:
                    out.append((ts, q))
        out.reverse()
        if out:
            self._last = out[-1][0]
        return out

    def close(self) -> None:
        pass


class SimFrames:
    """Frame source ``sim:...``: every rig camera's frames, rendered at their capture times."""

    def __init__(self, world: SimWorld, cameras=None):
        self.world = world
        self.on_reaction = world.on_reaction     # the robot obeys: the runner subscribes it to the reactions
        rig = world.rig
        cams = [rig.camera(c) for c in cameras] if cameras else list(rig.cameras)
        self.camera_ids = [c.id for c in cams]
        self._cams = cams
        # the package's one camera simulator and camera timing (camera_sim.py)
        self.sim = CameraSim(cams, robot=world.robot, static_meshes=rig.static_meshes(), seed=world.seed,
                             noiseless=world.noiseless, invalid="unknown")
        self.schedule = CameraSchedule(len(cams), world.camera_hz)
        self._posed = PosedMeshes(world.scene, alone=world.alone)   # the people and props, posed in place
        self._stopped: dict[str, float] = {}
        self.skip_behind = False        # set by a real-time run: frames a slow machine cannot render are dropped
        self.hand_robot = True          # frames_each's frames carry the robot layer (Frame.robot_image)
        self._counts = _Counts()        # frames_each's skipped and unposed (each stream keeps its own)
        self._streams: list[CameraStream] = []    # camera_streams: one per camera, real time
        self._scene_lock = threading.Lock()       # the scene posed by one camera thread at a time
        self.done = False
        self.lost = None

    def start_clock(self, origin: float) -> None:
        """The run's clock origin (module docstring): frames are stamped ``origin +`` their time."""
        self.world.start_clock(origin)

    def use_noise_bank(self) -> None:
        """Real time (set by the runner): the cameras take their noise's normals from one
        pre-drawn :class:`~depthguard.sources.noise.NormalBank` (same law per frame, 30 % of a
        frame's simulation saved); fast runs keep the exact draws, so their logs stay a
        function of the seed alone."""
        from depthguard.sources.noise import NormalBank

        self.sim.use_noise_bank(NormalBank(self.world.seed))

    def warm_up(self) -> None:
        """Render one frame per camera and throw it away (set by a real-time run before its clock
        starts): the first render of a process loads the renderer's and the noise's compiled
        kernels and touches their buffers. With the results sink's first write
        (:class:`~depthguard.runtime.mcap_results.McapResults` warms up too), those one-off
        costs put the simulator 0.1 s behind the clock at the start of every ``depthguard
        monitor`` run (2-4 frames skipped, a camera stale for a moment). Each frame's noise
        comes from its own stamp's generator, so the frames that follow are the same with or
        without it. Also at the first moment each person of the scene is in it (if not at the
        start): the first frames with a person loaded the posing's and the person's render
        kernels and built the posing's buffers, on every camera's thread at once, holding
        Python's interpreter lock (ur3-cell, whose operator walks in at 1 s: every camera stale
        from 1.07 s for 0.1-0.4 s in nearly every run, issue 29)."""
        q = self.world.robot_sim.q
        for t in self._warm_times():
            for cid in self.camera_ids:
                self.render(cid, t, q)

    def _warm_times(self) -> list[float]:
        """Run times to render before the clock: the start, and the first moment of each person's
        presence within the scene's first loop from the run's start (:meth:`warm_up`)."""
        times = [0.0]
        scene, d = self.world.scene, self.world.scene.duration
        s0 = self.world.scene_time(0.0)
        for person in getattr(scene, "people", ()):
            enter = float(getattr(person, "present", (-math.inf, math.inf))[0])
            if not math.isfinite(enter) or person.is_present(s0):
                continue
            t = (enter - s0) % d if d > 0 else enter - s0
            if t > 0 and person.is_present(self.world.scene_time(t)):
                times.append(t)
        return times

    def counters(self) -> dict:
        """``skipped_behind_real_time``: frames not rendered because the simulator was more than a
        camera period behind the run's clock (a real-time run on a busy or small machine; the
        monitor then sees late frames and stops the robot for them, as it must, R27). A world that
        follows a live robot adds ``follows`` (its joint source) and ``clock_origin_s`` (the run's
        clock at the scene's time 0, s: where the people were when, for a check against the
        robot's own record)."""
        out = {"skipped_behind_real_time": int(self.skipped)}
        if self.world.followed is not None:
            out.update(follows=self.world.followed, clock_origin_s=float(self.world.origin),
                       no_robot_state=int(self.unposed))
        return out

    @property
    def skipped(self) -> int:
        """Frames not rendered because the simulator was behind real time (:meth:`counters`)."""
        return self._counts.skipped + sum(s.counts.skipped for s in self._streams)

    @property
    def unposed(self) -> int:
        """Frames of a followed robot with no state around their capture (not rendered)."""
        return self._counts.unposed + sum(s.counts.unposed for s in self._streams)

    def camera_streams(self) -> list[CameraStream]:
        """Real time (the runner asks, R29): one :class:`CameraStream` per camera, each rendered on
        its own thread and woken at its own camera's next capture, as a real camera delivers on
        its own (issue 29: one thread rendering the four cameras of ur3-cell in turn, ~80 % busy,
        held a frame behind the others' renders, capture -> rendered p50 15-32 ms). Each stream
        poses the people and props into its own buffers and the robot into its camera's own
        (:meth:`CameraSim.own_robot_buffers`); the world (``advance``, the joint history) is shared
        under its lock. Call before the run starts; :meth:`frames_each` then is not to be used."""
        if not self._streams:
            self.sim.own_robot_buffers()
            self._streams = [CameraStream(self, i) for i in range(len(self.camera_ids))]
            for st in self._streams:        # each stream's buffers sized before the clock starts
                st._posed.at(self.world.scene_time(0.0))
        return list(self._streams)

    def stop_camera(self, camera_id: str, after: float = -math.inf) -> None:
        """Fault injection: camera ``camera_id`` delivers nothing captured after ``after`` s."""
        self._stopped[camera_id] = after

    def resume_camera(self, camera_id: str) -> None:
        self._stopped.pop(camera_id, None)

    def render(self, camera_id: str, t: float, q: np.ndarray) -> np.ndarray:
        """The measured (H, W) float32 depth of camera ``camera_id`` at run time ``t``, robot at ``q``."""
        return self._render(camera_id, t, q, self._posed)

    def _render(self, camera_id: str, t: float, q: np.ndarray, posed: PosedMeshes) -> np.ndarray:
        """:meth:`render` with the people and props posed into ``posed``'s buffers."""
        with self._scene_lock:          # the scene's memos, shared by the camera threads
            moving = posed.at(self.world.scene_time(t))         # world.dynamic(t), packed in place
        return self.sim.depth(camera_id, t, q, moving, dark=self.world.dark)

    def frames_until(self, t: float) -> list[Frame]:
        """The frames captured by ``t`` (s, the run's clock) not returned yet, stamped on that clock."""
        return list(self.frames_each(t))

    def frames_each(self, t: float):
        """:meth:`frames_until` one frame at a time, each rendered when the caller asks for it, in
        capture order: a real-time run hands each frame on as soon as it is rendered instead of
        when every camera due has been (issue 29: four cameras due at once held the first frame
        three renders long, ~15 ms of its age)."""
        return self._frames_each(t, range(len(self.camera_ids)), self._counts, self.render)

    def _frames_each(self, t: float, cameras, counts: _Counts, render):
        """:meth:`frames_each` of the cameras of indices ``cameras``; their skipped and unposed frames
        counted in ``counts``; ``render(camera_id, tc, q)`` makes a frame's depth."""
        self.world.advance(t)
        origin = self.world.origin
        t = min(t, self.world.history.newest_stamp) - origin   # a frame needs the robot's pose at its capture
        due = []
        sched = self.schedule
        for i in cameras:
            cid = self.camera_ids[i]
            if self.skip_behind and sched.next[i] + sched.period <= t + 1e-12:
                # behind by more than a period (real time, a slow machine): a camera drops the
                # frames it could not deliver rather than queue them; the latest due is captured
                counts.skipped += sched.skip_to_latest(i, t)      # frames not rendered
            while sched.due(i, t, tol=1e-12):
                tc = sched.next[i]
                sched.take(i, tc)
                if not (cid in self._stopped and tc >= self._stopped[cid]):
                    due.append((tc, i, cid))
        due.sort(key=lambda d: d[0])                           # stable: a tie keeps the camera order
        for tc, _i, cid in due:
            try:
                q = self.world.history.at(origin + min(tc, t))     # tc <= t up to rounding
            except OutsideHistory:          # a followed robot: before its first state, or after a gap
                counts.unposed += 1
                continue
            depth = render(cid, tc, q)
            # the robot layer drawn into it goes with the frame: the monitor's worker takes it for its
            # own render of the robot where it is the same bits (Frame.robot_image, issue 29)
            yield Frame(cid, depth, origin + tc, robot_image=self.sim.robot_image(cid) if self.hand_robot else None)

    def close(self) -> None:
        pass


class FollowedJoints:
    """A live joint source (``franky:``, ``ur-rtde:``) whose states also pose the simulated robot
    of the run's ``sim:`` cameras (module docstring): ``states_until`` hands each state to the
    monitor and to :meth:`SimWorld.take_states`. Everything else (``live``, ``lost``, the
    counters, ``robot_stamps``) is the wrapped source's."""

    def __init__(self, world: SimWorld, source, spec: str):
        self.world, self.source = world, source
        world.follow(spec)

    def states_until(self, t: float) -> list[tuple[float, np.ndarray]]:
        states = self.source.states_until(t)
        if states:
            self.world.take_states(states)
        return states

    def __getattr__(self, name):
        return getattr(self.source, name)

    @property
    def done(self) -> bool:
        return self.source.done

    @property
    def lost(self) -> str | None:
        return self.source.lost

    def close(self) -> None:
        self.source.close()


def follow_beside_simulator(source, spec: str, context: dict):
    """``source`` itself, or, when the run's cameras are simulated (a ``sim:`` source opened with
    ``context``), a :class:`FollowedJoints` that poses the simulated robot at its states."""
    world = sim_world(context)
    return source if world is None else FollowedJoints(world, source, spec)


_WORLD = "sim_world"      # the context key the sim: sources share their world under (this module's)


def sim_world(context: dict) -> SimWorld | None:
    """The simulated world that the ``sim:`` sources opened with ``context`` share, or None."""
    return context.get(_WORLD)


def _world(arg: str, rig, context: dict) -> SimWorld:
    world = context.get(_WORLD)
    if world is None:
        spec = parse_sim_spec(arg or context.get("sim_spec", ""))
        cell = spec["cell"] if (arg or rig is None) else ""
        world = SimWorld(cell, rig=rig, situation=spec["situation"], alone=spec["alone"], dark=spec["dark"],
                         noiseless=spec["noiseless"], seed=spec["seed"])
        context[_WORLD] = world
    return world


@register_source("sim")
def open_sim_frames(arg: str, rig, context: dict) -> SimFrames:
    """``sim:CELL[:OPTION...]`` (module docstring); with a rig and no cell, the rig's own scene."""
    context.setdefault("sim_spec", arg)
    return SimFrames(_world(arg, rig, context))


@register_joints("sim")
def open_sim_joints(arg: str, rig, context: dict) -> SimJoints:
    """``sim``: the joint states of the simulated robot of the ``sim:`` frame source."""
    return SimJoints(_world(arg, rig, context))
