"""Closed-loop scenarios on ``flacco-cell`` (Flacco 2014 figs. 14–16, 2015 fig. 8; R27), and on
any cell with a robot: a built-in one or a user's rig file (R2).

Each scenario adds scripted obstacles (people from :mod:`depthguard.sim.people`,
props from :mod:`depthguard.geometry.primitives`) to the cell's own scene, placed
relative to the end-effector hexagon, the robot's base and the cameras, and may
stop a camera. On ``flacco-cell`` the hexagon is the paper's
(:class:`~depthguard.evaluation.closed_loop.trajectory.Hexagon` defaults); on any other cell
:func:`rig_hexagon` centres it at the end effector at the rig's joints, with a
radius the robot reaches clear of the static objects.

* ``reach``   — a person reaches for the end effector (2014 fig. 14);
* ``plate``   — a plate moves into the end effector's path, behind the robot
  as seen from the principal camera (2014 fig. 15);
* ``elbow``   — an obstacle comes down onto the elbow's path; the arm
  reconfigures through redundancy while the EE keeps the hexagon (fig. 16);
* ``shadow``  — a person walks between the principal camera and the robot,
  well away from the robot (2015 fig. 8); the second camera clears the person's
  shadow except the space the robot itself hides from it (R9: unknown, so an
  obstacle while the principal is blocked): the robot slows its task
  (measured: task scale down to 0.16, sensed 0.11 m at the arm) and goes on;
* ``camera_dropout`` — the second camera stops delivering at t = 2 s: the
  robot slows to a stop and reports why (R27).
* ``empty``   — no scripted obstacle (the cell as it is): the tracking baseline.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from depthguard.evaluation.closed_loop.trajectory import Hexagon

__all__ = ["Scenario", "SCENARIOS", "build_scenario", "list_scenarios", "run_scenario", "rig_hexagon",
           "HEXAGON_RADII"]


@dataclass
class Scenario:
    name: str
    description: str
    duration: float                                  # default simulated seconds
    obstacles: Callable[[float], list] = field(default=lambda t: [])
    dropout: dict[str, float] = field(default_factory=dict)
    snapshot_times: tuple[float, ...] = ()
    expect: str = ""                                 # what should happen


SCENARIOS = {
    "reach": "a person reaches for the end effector (Flacco 2014 fig. 14)",
    "plate": "a plate moves into the end effector's path, occluded by the robot from the principal camera (2014 fig. 15)",
    "elbow": "an obstacle comes down onto the elbow's path; the arm reconfigures, the EE keeps the hexagon (2014 fig. 16)",
    "shadow": "a person walks between the principal camera and the robot, away from it (2015 fig. 8)",
    "camera_dropout": "the second camera stops delivering frames at t = 2 s (R27)",
    "empty": "no scripted obstacle: the tracking baseline",
}


def list_scenarios() -> list[str]:
    return list(SCENARIOS)


def _floor_z(cell) -> float:
    """Top of the cell's floor object if it has one, else the workspace's lower z."""
    best = None
    for p in cell.scene.obstacles_at(0.0):
        if "floor" in (p.name or "").lower():
            z = float(p.bounds()[1, 2])
            best = z if best is None else max(best, z)
    return float(cell.rig.workspace.lo[2]) if best is None else best


def _union(*fns):
    def f(t):
        out = []
        for g in fns:
            out += g(t)
        return out
    return f


def _lerp_keys(keys: list[tuple[float, np.ndarray]]):
    """Piecewise smooth-step interpolation of positions over time, held at the ends."""
    ts = np.array([k[0] for k in keys])
    ps = np.stack([np.asarray(k[1], float) for k in keys])

    def at(t):
        if t <= ts[0]:
            return ps[0]
        if t >= ts[-1]:
            return ps[-1]
        i = int(np.searchsorted(ts, t, side="right")) - 1
        s = (t - ts[i]) / (ts[i + 1] - ts[i])
        s = s * s * (3 - 2 * s)
        return (1 - s) * ps[i] + s * ps[i + 1]
    return at


def build_scenario(name: str, cell, hexagon: Hexagon, robot=None) -> Scenario:
    """The scenario ``name`` for ``cell`` with the EE task ``hexagon`` (``ValueError`` if unknown)."""
    from depthguard.geometry.primitives import Box, Sphere
    from depthguard.sim.people import Key, Person
    from depthguard.transforms import pose

    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; choose one of {', '.join(SCENARIOS)}")
    c = np.asarray(hexagon.center, float)
    R = hexagon.radius
    fz = _floor_z(cell)
    cams = cell.rig.cameras
    desc = SCENARIOS[name]

    if name == "empty":
        return Scenario(name, desc, 6.0, snapshot_times=(0.0, 3.0),
                        expect="the EE tracks the hexagon")

    if name == "reach":
        # the person stands in front of the hexagon's plane (x = c[0]), on the side away from the
        # robot's base (flacco-cell: -x), and reaches with the right hand for the upper corners
        s = _front_side(cell, hexagon, robot)
        target = c + np.array([s * 0.10, -s * 0.02, 0.6 * R])   # just in front of the upper corners
        stand = (c[0] + s * 0.62, c[1] - s * 0.30)
        heading = 0.0 if s < 0 else float(np.pi)               # facing the hexagon
        p = Person("operator", [Key(0.0, stand, heading), Key(1.0, stand, heading),
                                Key(2.5, stand, heading, right=tuple(target)),
                                Key(5.0, stand, heading, right=tuple(target)),
                                Key(6.5, stand, heading)], floor_z=fz)
        return Scenario(name, desc, 8.0, obstacles=p.primitives, snapshot_times=(0.0, 2.5, 4.0, 6.5),
                        expect="the EE evades the hand; no collision")

    if name == "plate":
        # the plate comes in from the side of the hexagon that the robot hides from the principal camera
        cam0 = cams[0]
        side = 1.0 if cam0.world_from_camera[1, 3] < c[1] else -1.0
        start = c + np.array([0.0, side * (R + 0.9), 0.0])
        stop = c + np.array([0.0, side * (R + 0.03), 0.0])
        at = _lerp_keys([(0.0, start), (1.5, start), (3.5, stop), (6.0, stop), (8.0, start)])
        plate = Box(size=(0.30, 0.01, 0.30), name="plate")

        def plate_at(t):
            return [plate.at(pose(t=at(t)))]
        return Scenario(name, desc, 9.0, obstacles=plate_at, snapshot_times=(0.0, 3.0, 5.0, 7.5),
                        expect="the EE keeps away from the plate; no collision")

    if name == "elbow":
        # the elbow's highest point on the hexagon at the start posture, approximately above the shoulder
        el = _elbow_top(cell, hexagon, robot)
        top = el + np.array([0.0, 0.0, 0.9])
        low = el + np.array([0.0, 0.0, 0.24])
        at = _lerp_keys([(0.0, top), (2.0, top), (4.0, low)])
        ball = Sphere(radius=0.07, name="elbow_obstacle")

        def ball_at(t):
            return [ball.at(pose(t=at(t)))]
        return Scenario(name, desc, 10.0, obstacles=ball_at, snapshot_times=(0.0, 4.0, 7.0, 9.5),
                        expect="the elbow moves away through redundancy; the EE keeps the hexagon")

    if name == "shadow":
        cam0 = cams[0]
        eye = cam0.world_from_camera[:3, 3]
        u = c - eye
        u[2] = 0.0
        dist = float(np.linalg.norm(u))
        u /= dist
        w = np.array([-u[1], u[0], 0.0])
        mid = eye + u * max(0.45 * dist, dist - 1.3)           # stay >= ~1.3 m from the EE
        a = mid[:2] - 1.2 * w[:2]
        b = mid[:2] + 1.2 * w[:2]
        heading = float(np.arctan2(w[1], w[0]))
        p = Person("walker", [Key(0.0, tuple(a), heading), Key(1.0, tuple(a), heading),
                              Key(6.0, tuple(b), heading)], floor_z=fz)
        return Scenario(name, desc, 7.0, obstacles=p.primitives, snapshot_times=(0.0, 2.5, 3.5, 5.0),
                        expect="no collision; the second camera clears the shadow but for what the robot "
                               "hides from it (R9), so the robot slows while the person passes")

    # camera_dropout
    if len(cams) < 2:
        raise ValueError("camera_dropout needs a cell with two cameras")
    return Scenario(name, desc, 4.0, dropout={cams[1].id: 2.0}, snapshot_times=(0.0, 3.0),
                    expect="the robot slows to a stop and reports the stale camera")


def _front_side(cell, hexagon: Hexagon, robot=None) -> float:
    """-1 or +1: the side of the hexagon's plane ``x = center[0]`` away from the robot's base
    (-1 when the base lies on that plane, and on flacco-cell: base at x = 0, plane x = -0.6 m)."""
    robot = robot or cell.rig.robot
    base_x = float(np.asarray(getattr(robot, "base", np.eye(4)))[0, 3])
    return 1.0 if float(hexagon.center[0]) > base_x + 1e-9 else -1.0


def _elbow_top(cell, hexagon: Hexagon, robot=None) -> np.ndarray:
    """Highest position of the 'elbow' control point over one lap of kinematic tracking."""
    from depthguard.evaluation.closed_loop.loop import solve_ik
    from depthguard.control.joint_limits import position_limits
    from depthguard.control.sns import sns_velocity

    robot = robot or cell.rig.robot
    names = [cp.name for cp in robot.control_points]
    j = names.index("elbow") if "elbow" in names else len(names) // 2
    q_rig = getattr(cell.rig, "robot_q0", None)              # the rig's joints (flacco-cell: q_home)
    q = solve_ik(robot, hexagon.at(0.0)[0], robot.q_home if q_rig is None else q_rig)
    q0 = q.copy()
    data = robot.create_data()
    dt = 0.01
    best = None
    for k in range(int(hexagon.period / dt)):
        robot.forward(q, data)
        pd, vd = hexagon.at(k * dt)
        lo, hi = position_limits(q, robot.q_min, robot.q_max, robot.qd_max, dt)
        r = sns_velocity(data.cp_jacobians[0], vd + 5.0 * (pd - data.cp_positions[0]), lo, hi, qd0=q0 - q)
        p = data.cp_positions[j].copy()
        if best is None or p[2] > best[2]:
            best = p
        q = q + r.qd * dt
    return best


HEXAGON_RADII = (0.20, 0.15, 0.10, 0.05)   # m, tried in turn by rig_hexagon (0.2: Flacco 2014 §5.3)


def rig_hexagon(cell, centre=None, radius: float | None = None, clearance: float = 0.03,
                samples: int = 48) -> Hexagon:
    """The end-effector task (R15) for any cell's robot: a hexagon in the vertical plane
    ``x = centre[0]`` (:class:`~depthguard.evaluation.closed_loop.trajectory.Hexagon`, speed 0.4 m/s).

    ``centre`` (3,) m defaults to the end effector (control point 0) at the rig's joints
    (``rig.robot_q0``); ``radius`` (m) defaults to the largest of :data:`HEXAGON_RADII` that
    passes both checks, which a given radius must pass too:

    - **reach**: inverse kinematics (:func:`~depthguard.evaluation.closed_loop.loop.solve_ik`, position
      only, so any robot with >= 3 joints) follows ``samples`` points of one lap from the
      rig's joints, each seeded with the previous answer;
    - **clearance**: every sampled point lies at least the EE control point's radius plus
      ``clearance`` (m) from the cell's static objects.

    ``ValueError`` (naming ``--hexagon-centre`` / ``--hexagon-radius``) when none fits.
    """
    from depthguard.evaluation.closed_loop.loop import solve_ik

    rig = cell.rig
    robot = rig.robot
    if robot is None:
        raise ValueError(f"cell {cell.name!r} has no robot to drive (its rig has no robot: section)")
    q0 = np.asarray(rig.robot_q0 if rig.robot_q0 is not None else robot.q_home, dtype=np.float64)
    if centre is None:
        data = robot.create_data()
        robot.forward(q0, data)
        centre = data.cp_positions[0].copy()
    centre = tuple(float(v) for v in np.asarray(centre, dtype=np.float64).reshape(3))
    if radius is not None and not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"--hexagon-radius must be > 0 m, got {radius!r}")
    margin = float(getattr(robot.control_points[0], "radius", 0.0)) + clearance
    radii = (float(radius),) if radius is not None else HEXAGON_RADII
    where = "(" + ", ".join(f"{v:.3f}" for v in centre) + ")"
    why = ""
    for r in radii:
        hexagon = Hexagon(center=centre, radius=r)
        period = hexagon.period
        pts = np.stack([hexagon.at(k * period / samples)[0] for k in range(samples)])
        d = cell.scene.true_distance(pts, 0.0) if cell.scene.static else np.full(len(pts), np.inf)
        if float(d.min()) < margin:
            k = int(np.argmin(d))
            why = (f"radius {r:g} m: the path passes {float(d[k]) * 100:.1f} cm from a static object at "
                   f"{np.round(pts[k], 3).tolist()} (needs {margin * 100:.1f} cm)")
            continue
        q = q0
        try:
            for p in pts:
                q = solve_ik(robot, p, q)
        except ValueError as exc:
            why = f"radius {r:g} m: {exc}".replace("; choose another hexagon centre/radius", "")
            continue
        return hexagon
    tried = f"radius {radii[0]:g} m" if radius is not None else \
        f"radii {', '.join(f'{r:g}' for r in radii)} m"
    raise ValueError(f"no end-effector hexagon about {where} in the plane x = {centre[0]:.3f} m with {tried} "
                     f"is reachable by {robot.name} from the rig's joints and clear of the static objects "
                     f"({why}); set --hexagon-centre X,Y,Z and/or --hexagon-radius R (m)")


def run_scenario(name: str, out=None, duration: float | None = None, seed: int = 0, config=None,
                 cell="flacco-cell", progress=None, write: bool = True):
    """Run scenario ``name`` on ``cell``; write ``out``/summary.json and the plots.

    ``cell`` is a built-in cell's name or a :class:`~depthguard.sim.cells.Cell` (e.g.
    :func:`~depthguard.sim.cells.cell_from_rig` of a user's rig file, R2). Returns
    ``(summary dict, LoopResult)``. ``duration`` (s) defaults to the scenario's; ``config``
    is a :class:`~depthguard.evaluation.closed_loop.loop.LoopConfig` whose ``hexagon`` is the EE task
    (see :func:`rig_hexagon` for a cell other than flacco-cell).
    """
    from depthguard.evaluation.closed_loop.loop import ClosedLoop, LoopConfig
    from depthguard.evaluation.closed_loop.report import summarize, write_report
    from depthguard.sim import load_cell

    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; choose one of {', '.join(SCENARIOS)}")
    cfg = config or LoopConfig()
    c = load_cell(cell) if isinstance(cell, str) else cell
    if c.rig.robot is None:
        raise ValueError(f"cell {c.name!r} has no robot to drive (its rig has no robot: section)")
    sc = build_scenario(name, c, cfg.hexagon, robot=c.rig.robot)
    dur = float(sc.duration if duration is None else duration)
    if not (np.isfinite(dur) and dur > 0):
        raise ValueError(f"duration must be > 0 s, got {duration!r}")
    if cfg.fusion == "single" and sc.dropout:
        # one camera only: the one that stops is the principal
        principal = cfg.principal or c.rig.cameras[0].id
        sc.dropout = {principal: min(sc.dropout.values())}
    loop = ClosedLoop(c, cfg, extra_obstacles=sc.obstacles, dropout=sc.dropout, seed=seed)
    res = loop.run(dur, progress=progress, snapshot_times=tuple(x for x in sc.snapshot_times if x < dur))
    extra = {"expect": sc.expect, "cell": c.name, "seed": seed, "dropout": sc.dropout}
    if not isinstance(cell, str) and c.rig.path is not None:
        extra["rig"] = str(c.rig.path)
    summary = summarize(res, name, sc.description, cfg, cfg.hexagon, extra=extra)
    if write and out is not None:
        write_report(out, res, summary, cfg.hexagon, cfg.rho, snapshots=res.snapshots)
    return summary, res
