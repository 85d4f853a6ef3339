"""A person steps onto the path ahead of the moving robot: the path watch against distances alone
(R13, R14, R21, R22, R37; issue 30).

**The scenario** (``ur3-cell``, the cell's static scene, none of its own people): the UR3 runs a
planned joint path — its shoulder pans from ``pan[0]`` to ``pan[1]`` rad about the rig's joints
in ``path_s`` s, ``waypoints`` waypoints, the end effector sweeping an arc over the table. A person
walks up to the table's -y edge, reaches with the right hand into a point of that arc the robot has
not reached yet (``hand_at`` of the path, 2 cm above the end effector's axis there), holds it there
from ``t_hold[0]`` to ``t_hold[1]`` s, withdraws and walks away.

**The loop** (simulated time, the runtime :class:`~depthguard.runtime.monitor.Monitor` fed by the
simulator as in :mod:`depthguard.evaluation.closed_loop.loop`): the rig's four cameras at 30 Hz with
their noise models, each frame delivered one period after its capture; the monitor's step at every
500 Hz control cycle; the free-space map rebuilt every ``1 / free_space_hz`` s of *simulated* time
(the worker without its thread: its wall-clock rate is not the simulation's); the robot is the
package's obeying robot (:class:`~depthguard.sim.obeying_robot.PathFollower`: path time advances at
the reaction's speed scale within its joint-velocity box). Two runs, the same frames' noise:

- ``distances``: the rig's own reactions (ur3-cell: ``repulsion``, R13, R14);
- ``path watch``: the same plus ``path_watch``, given the path with ``Monitor.watch_path``.

**Ground truth** (not the system's): the robot's collision capsules against the person's primitives
(:class:`PersonTruth`, axis points every 1 cm). Figures
per run (:func:`figures`): the minimum true separation (m); the first stop (path speed below 1 %):
its time, path time and segment, and the separation there; ``short`` — the robot stood before the
first path time at which it would touch the person as the person stood then, with a positive
separation; ``left_s`` — from when the rest of the path (from the stop on) is truly free of the person
for good (``clear_s``: clear by the product's ``robot_padding``); ``t_resume`` — the robot moving
again (it may before ``left_s``: the path watch lets it go on towards a segment still blocked far
ahead as long as it can stop short of it); ``progress`` — the share of the path done at the end.

``depthguard reproduce path-watch`` prints the table of both runs.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

__all__ = ["OntoPath", "run_onto_path", "figures", "compare", "table"]


@dataclass(frozen=True)
class OntoPath:
    """The scenario's numbers (module docstring); times in s, angles in rad."""
    cell: str = "ur3-cell"
    pan: tuple[float, float] = (-3.3, -1.7)   # shoulder pan about the rig's joints, start and end
    path_s: float = 5.5                       # the planned path's duration
    waypoints: int = 56
    hand_at: float = 0.95                     # where on the path (share of its duration) the hand goes
    t_walk: float = 0.6                       # the person is at the table
    t_hold: tuple[float, float] = (1.1, 5.0)  # the hand on the path
    t_gone: float = 7.5                       # out of the workspace again
    duration: float = 10.0                    # simulated seconds of a run
    cameras: tuple[str, ...] | None = None    # the rig's cameras that run (None: all)
    control_hz: float | None = None           # the monitor's control rate (None: the rig's, 500 Hz)

    def path(self, rig) -> tuple[np.ndarray, np.ndarray]:
        """``(stamps (n,) s, q (n, dof) rad)``: the planned path."""
        q0 = np.asarray(rig.robot_q0, dtype=np.float64)
        stamps = np.linspace(0.0, self.path_s, self.waypoints)
        pan = np.linspace(self.pan[0], self.pan[1], self.waypoints)
        q = np.repeat(q0[None], self.waypoints, axis=0)
        q[:, 0] += pan
        return stamps, q

    def person(self, rig):
        """The person (:class:`~depthguard.sim.people.Person`) whose right hand comes onto the path."""
        from depthguard.sim.people import Key, Person

        stamps, q = self.path(rig)
        data = rig.robot.create_data()
        rig.robot.forward(_interp(stamps, q, self.hand_at * self.path_s), data)
        hand = tuple(float(v) for v in data.cp_positions[0] + np.array([0.0, 0.0, 0.02]))
        up = math.pi / 2                                            # facing +y, the table
        far, near = (float(hand[0]) - 0.6, -1.4), (float(hand[0]) - 0.15, -0.62)
        keys = [Key(0.0, far, up), Key(self.t_walk, near, up), Key(self.t_hold[0], near, up, right=hand),
                Key(self.t_hold[1], near, up, right=hand), Key(self.t_hold[1] + 0.8, near, up),
                Key(self.t_gone, (-1.5, -2.0), -math.pi / 2)]
        return Person("person", keys, floor_z=0.0)


def _interp(stamps, q, t: float) -> np.ndarray:
    """The path's joints at path time ``t`` (linear between waypoints, held at the ends)."""
    t = min(max(float(t), float(stamps[0])), float(stamps[-1]))
    i = min(int(np.searchsorted(stamps, t, side="right")) - 1, len(stamps) - 2)
    u = (t - stamps[i]) / (stamps[i + 1] - stamps[i])
    return (1.0 - u) * q[i] + u * q[i + 1]


@dataclass
class OntoPathRun:
    """One run's series (T samples, one per control cycle) and what it needs for :func:`figures`."""
    label: str
    t: np.ndarray          # (T,) s
    tau: np.ndarray        # (T,) s, path time
    rate: np.ndarray       # (T,) path speed (1 = as planned)
    sep: np.ndarray        # (T,) m, true separation robot <-> person (<= 0: contact)
    reasons: list          # (t, reasons) where the override fell below 1 or the scale was limited
    stamps: np.ndarray
    q: np.ndarray
    setup: OntoPath
    wall_s: float
    map_builds: int


def run_onto_path(path_watch: bool, setup: OntoPath = OntoPath(), seed: int = 0, duration: float | None = None,
                  cameras: tuple[str, ...] | None = None, progress=None) -> OntoPathRun:
    """One run of the scenario (module docstring) with or without the path watch."""
    from depthguard.evaluation.closed_loop.camera_pipeline import CameraPipeline, threadsafe_numba
    from depthguard.runtime.monitor import Monitor, warm_up
    from depthguard.sim import load_cell
    from depthguard.sim.obeying_robot import ObeyingRobot, PathFollower
    from depthguard.sources.camera_sim import CameraSchedule, CameraSim
    from depthguard.sources.frame import Frame

    cell = load_cell(setup.cell)
    rig, robot = cell.rig, cell.rig.robot
    cameras = setup.cameras if cameras is None else cameras
    cams = [c for c in rig.cameras if cameras is None or c.id in cameras]
    base = rig.monitor if setup.control_hz is None else rig.monitor.with_changes(control_hz=setup.control_hz)
    reactions = tuple(base.policies) + (("path_watch",) if path_watch else ())
    cfg = base.with_changes(reactions=reactions, free_space=False, cameras=tuple(c.id for c in cams),
                            principal=cams[0].id, joint_wait_s=0.0, joints_stale_s=max(10 * base.dt, 0.01),
                            joint_history_s=2.0)
    dt, hz = cfg.dt, cfg.free_space_hz
    stamps, Q = setup.path(rig)
    person = setup.person(rig)
    memo: dict = {}

    def moving(t):
        if memo.get("t") != t:
            memo["t"], memo["p"] = t, list(person.primitives(t))
        return memo["p"]

    sim = CameraSim(cams, robot=robot, static_meshes=[p.mesh() for p in cell.scene.static], seed=seed,
                    invalid=cfg.invalid, parallel=False)
    timing: dict = {"camera_sim": 0.0, "self_removal": 0.0}
    ids = [c.id for c in cams]
    pipe = CameraPipeline(lambda i, t, q: tuple(sim.shot(ids[i], t, q, [p.mesh() for p in moving(t)],
                                                         keep_robot=True)),
                          ids, 1.0 / cfg.camera_hz, timing, threaded=threadsafe_numba())
    schedule = CameraSchedule(len(ids), cfg.camera_hz)
    truth = PersonTruth(robot, Q[0])
    bot = ObeyingRobot(PathFollower(lambda tau: _interp(stamps, Q, tau)), robot.dof)
    warm_up(rig, cfg)
    T = int(round(float(setup.duration if duration is None else duration) / dt))
    out = {k: np.zeros(T) for k in ("t", "tau", "rate", "sep")}
    reasons = []
    wall0 = time.perf_counter()
    mon = Monitor(rig, cfg, start_override=1.0)
    try:
        mon.start_free_space(threaded=False)
        if path_watch:
            mon.watch_path(stamps, Q)
        for j in range(40, 0, -1):
            mon.push_joints(-j * dt, bot.q)
        pipe.start(bot.q)
        next_map = 0.0
        steps = range(T) if progress is None else progress(range(T), T)
        with mon.replay():
            for k in steps:
                t = k * dt
                q = bot.q
                for i in range(len(ids)):
                    if schedule.due(i, t):
                        schedule.take(i, t)
                        pipe.capture(i, t, q)
                mon.push_joints(t, q)
                delivered = list(pipe.deliver(t))
                for _i, cid, t_cap, _q, depth, _rd in delivered:
                    mon.push_frame(Frame(cid, depth, float(t_cap)))
                if delivered:
                    mon.flush()
                if t + 1e-9 >= next_map:               # the map's period, in simulated time
                    mon.free_space.update_now()
                    next_map += 1.0 / hz
                react = mon.step(t, q)
                bot.obey(react)
                bot.command(dt)
                if react.speed_scale < 1.0 and (not reasons or reasons[-1][1] != dict(react.reasons)):
                    reasons.append((t, dict(react.reasons)))
                out["t"][k], out["tau"][k], out["rate"][k] = t, bot.tau, bot.rate
                out["sep"][k] = truth(q, moving(t))
                bot.move(dt)
        builds = mon.free_space.builds
    finally:
        mon.close()
        pipe.close()
    return OntoPathRun("path watch" if path_watch else "distances", out["t"], out["tau"], out["rate"], out["sep"],
                       reasons, stamps, Q, setup, time.perf_counter() - wall0, builds)


class PersonTruth:
    """The true separation (m) of the robot's collision capsules at ``q`` from the person's
    primitives: points every ``step`` m along each capsule axis (lengths at ``q_start``), their
    exact distance to the primitives less the capsule's radius (overestimates by at most
    ``step / 2``; <= 0: contact)."""

    def __init__(self, robot, q_start, step: float = 0.01):
        self.robot = robot
        ab, _ = robot.collision_segments(np.asarray(q_start, dtype=np.float64))
        n = np.maximum(2, np.ceil(np.linalg.norm(ab[:, 1] - ab[:, 0], axis=1) / step).astype(int) + 1)
        self._cap = np.concatenate([np.full(k, i) for i, k in enumerate(n)])
        self._u = np.concatenate([np.linspace(0.0, 1.0, k) for k in n])[:, None]

    def points(self, q) -> tuple[np.ndarray, np.ndarray]:
        """``(X (N, 3), r (N,))``: the axis points at ``q`` and their capsules' radii."""
        ab, r = self.robot.collision_segments(np.asarray(q, dtype=np.float64))
        c = self._cap
        return ab[c, 0] * (1.0 - self._u) + ab[c, 1] * self._u, r[c]

    def __call__(self, q, prims) -> float:
        from depthguard.sim.ground_truth import true_distance

        X, r = self.points(q)
        return float(np.min(true_distance(prims, X) - r)) if prims else math.inf


def _clearance_to_path(truth: PersonTruth, prims, stamps, Q, tau0: float, step: float = 0.05) -> float:
    """m: the least true separation between ``prims`` and the robot at every pose of the path from
    path time ``tau0`` on (poses every ``step`` s)."""
    from depthguard.sim.ground_truth import true_distance

    pts = [truth.points(_interp(stamps, Q, tau)) for tau in np.append(np.arange(tau0, stamps[-1], step), stamps[-1])]
    X, r = np.concatenate([p[0] for p in pts]), np.concatenate([p[1] for p in pts])
    return float(np.min(true_distance(prims, X) - r))


def _first_contact(truth: PersonTruth, prims, stamps, Q, tau0: float, step: float = 0.01) -> float:
    """Path time (s) of the first pose from ``tau0`` on whose capsules touch ``prims`` (inf: none)."""
    for tau in np.arange(tau0, stamps[-1] + 0.5 * step, step):
        if truth(_interp(stamps, Q, tau), prims) <= 0.0:
            return float(tau)
    return math.inf


def figures(run: OntoPathRun, robot, person, padding: float) -> dict:
    """The run's figures against the ground truth (module docstring)."""
    stopped = run.rate < 0.01
    row = {"run": run.label, "min_sep_m": float(run.sep.min()), "contact": bool(run.sep.min() <= 0.0),
           "progress": float(min(run.tau[-1], run.stamps[-1]) / run.stamps[-1]), "stopped": bool(stopped.any()), "t_stop": None,
           "tau_stop": None, "segment": None, "sep_at_stop_m": None, "tau_contact": None, "short": False,
           "left_s": None, "clear_s": None, "t_resume": None, "resume_after_s": None, "wall_s": run.wall_s,
           "map_builds": run.map_builds}
    if not stopped.any():
        return row
    k = int(np.argmax(stopped))
    t_stop, tau_stop = float(run.t[k]), float(run.tau[k])
    seg = int(np.searchsorted(run.stamps, tau_stop, side="right")) - 1
    truth = PersonTruth(robot, run.q[0])
    tau_contact = _first_contact(truth, person.primitives(t_stop), run.stamps, run.q, tau_stop)
    row.update(t_stop=t_stop, tau_stop=tau_stop, segment=seg, sep_at_stop_m=float(run.sep[k]),
               tau_contact=tau_contact, short=bool(tau_stop < tau_contact and run.sep[k] > 0.0))
    # the rest of the path truly free for good (no contact with the person), and clear by the padding
    ts = np.arange(t_stop, run.t[-1], 0.05)
    c = np.array([_clearance_to_path(truth, person.primitives(float(t)), run.stamps, run.q, tau_stop) for t in ts])
    for key, bad in (("left_s", c <= 0.0), ("clear_s", c < padding)):
        i = int(np.nonzero(bad)[0][-1]) + 1 if bad.any() else 0
        row[key] = float(ts[i]) if i < len(ts) else None
    if row["left_s"] is not None:
        after = np.nonzero((run.t > t_stop) & ~stopped)[0]
        if len(after):
            row["t_resume"] = float(run.t[after[0]])
            row["resume_after_s"] = row["t_resume"] - row["left_s"]
    return row


def compare(setup: OntoPath = OntoPath(), seed: int = 0, duration: float | None = None,
            cameras: tuple[str, ...] | None = None, progress=None) -> list[dict]:
    """Both runs' figures: distances alone, then with the path watch."""
    from depthguard.sim import load_cell

    rig = load_cell(setup.cell).rig
    person = setup.person(rig)
    rows = []
    for watch in (False, True):
        run = run_onto_path(watch, setup, seed=seed, duration=duration, cameras=cameras,
                            progress=None if progress is None else (lambda it, n, w=watch: progress(it, n, w)))
        row = figures(run, rig.robot, person, rig.monitor.robot_padding)
        row["reasons"] = [(round(t, 3), r) for t, r in run.reasons[:3]]
        rows.append(row)
    return rows


def _s(v, fmt="{:.2f}", none="—"):
    return none if v is None or (isinstance(v, float) and not math.isfinite(v)) else fmt.format(v)


def table(rows: list[dict]) -> str:
    """The markdown table of :func:`compare`'s rows."""
    out = ["| run | min true separation (cm) | contact | stopped at (s) | path time there (s), segment | "
           "separation there (cm) | stopped short of the person | rest of the path truly free from (s) | "
           "moving again at (s) | path done |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        where = "—" if r["tau_stop"] is None else f"{r['tau_stop']:.2f}, {r['segment']}"
        short = "—" if not r["stopped"] else ("yes" if r["short"] else "no") + \
            f" (contact at path time {_s(r['tau_contact'])})"
        sep = None if r["sep_at_stop_m"] is None else r["sep_at_stop_m"] * 100
        out.append(f"| {r['run']} | **{r['min_sep_m'] * 100:.1f}** | {'YES' if r['contact'] else 'no'} | "
                   f"{_s(r['t_stop'])} | {where} | {_s(sep, '{:.1f}')} | {short} | {_s(r['left_s'])} | "
                   f"{_s(r['t_resume'])} | {r['progress'] * 100:.0f} % |")
    return "\n".join(out)
