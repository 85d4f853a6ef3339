"""The product's safe defaults, checked on the built-in cells: availability and safety together (R32).

Two runs of the monitor (:class:`depthguard.runtime.Monitor`, the rig's own
``monitor:`` settings, the cameras' noise models), as fast as possible:

- **robot alone** (``sim:CELL:alone``): the robot follows its path with nobody
  in the cell. Truth: each control point's exact distance to the cell's fixed
  objects (the primitives' signed distance). Counted: cycles whose override
  drops below 1, the time the robot ran slower than its path (the joint
  limits of R14 slow it near an obstacle), and readings more than ``tolerance`` nearer than
  ``min(truth, rho)`` (the robot seeing itself, or its shadow); and, for
  safety, readings farther than the truth by more than the discretisation.
  Where there are false readings, :func:`depthguard.evaluation.coverage.blind_spots`
  looks at their times for space that no camera sees (a fault of the layout, not of
  the monitor: unknown is an obstacle).
- **dark person** (``sim:CELL:dark``, the person's pixels all invalid) beside
  the same run with the person visible: the closest approach of the person to
  the end effector, and how the robot reacted to each (its lowest speed along
  the path and the time it was slowed and stopped, lowest override, largest
  repulsion, smallest reported distance at the end effector).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["robot_alone", "dark_person"]


def _run(rig, spec: str, duration: float, config, every: int):
    from depthguard.runtime import runner
    from depthguard.runtime.monitor import Monitor, warm_up
    from depthguard.sources.base import open_joints, open_source

    warm_up(rig, config)
    ctx: dict = {}
    src = open_source(spec, rig, ctx)
    joints = open_joints("sim", rig, ctx)
    world = src.world
    kept = []

    def keep(r):
        if len(kept) == 0 or round(r.t / config.dt) % every == 0:
            kept.append(r)
    with Monitor(rig, config, sinks=[world.on_reaction, keep]) as mon:
        stats, wall = runner.run(mon, [src], joints, duration=duration, fast=True)
        summary = runner.summarise(mon, stats, wall, {"frames": [spec], "joints": "sim"})
    return kept, world, summary


def robot_alone(cell_name: str, duration: float = 60.0, tolerance: float = 0.05, every: int = 10,
                config=None) -> dict:
    """The robot alone for ``duration`` s (module docstring); truth every ``every``-th cycle."""
    from depthguard.sim import load_cell
    from depthguard.sim.ground_truth import true_distance

    cell = load_cell(cell_name)
    rig = cell.rig
    cfg = config or rig.monitor
    kept, world, summary = _run(rig, f"sim:{cell_name}:alone", duration, cfg, every)
    static = list(cell.scene.static)
    worst, false_n, miss_n, n = math.inf, 0, 0, 0
    rep_max = max((float(np.linalg.norm(r.repulsion)) for r in kept), default=0.0)
    worst_at = None
    false_times: list = []
    for r in kept:
        m = int(np.sum(~r.is_watch))
        P = rig.robot.control_point_positions(r.q)
        truth = true_distance(static, P)
        for i in range(m):
            if not r.observed[i]:
                continue
            n += 1
            d = float(r.distance[i])
            ref = min(float(truth[i]), cfg.rho)
            if math.isfinite(d):
                if d - ref < worst:
                    worst, worst_at = d - ref, (r.names[i], round(r.t, 3))
                if d < ref - tolerance:
                    false_n += 1
                    if not false_times or r.t - false_times[-1] >= 0.5:
                        false_times.append(r.t)
            elif truth[i] < cfg.rho - 0.02:           # nothing reported where a fixed object is within rho
                miss_n += 1
    spots = []
    if false_times:                     # explain them: space that no camera sees (the layout's fault)?
        from depthguard.evaluation.coverage import blind_spots

        spots = [str(b) for b in blind_spots(cell, false_times[:12], rho=cfg.rho, padding=cfg.robot_padding,
                                              tolerance=tolerance)]
    return {"cell": cell_name, "duration_s": duration, "readings": n,
            "override_min": summary["override_min"], "stopped_s": summary["stopped_s"],
            "robot_speed_min": round(world.scale_min, 4), "robot_slowed_s": round(world.slowed_s, 3),
            "episodes": [e["reason"] for e in summary["episodes"]],
            "unobserved_cycles": summary["unobserved_cycles"],
            "worst_m": None if worst_at is None else round(worst, 4), "worst_at": worst_at,
            "false_near": false_n, "missed_within_rho": miss_n, "tolerance_m": tolerance,
            "repulsion_max_m_s": round(rep_max, 4), "blind_spots": spots,
            "real_time_factor": summary["real_time_factor"]}


def dark_person(cell_name: str = "flacco-cell", duration: float = 12.0, every: int = 5, config=None) -> dict:
    """The person of the cell's script, visible and dark (module docstring)."""
    from depthguard.sim import load_cell
    from depthguard.sim.ground_truth import true_distance

    cell = load_cell(cell_name)
    rig = cell.rig
    cfg = config or rig.monitor
    out = {"cell": cell_name, "duration_s": duration}
    for label, spec in (("visible", f"sim:{cell_name}"), ("dark", f"sim:{cell_name}:dark")):
        kept, world, summary = _run(rig, spec, duration, cfg, every)
        closest, near_ee, rep = math.inf, math.inf, 0.0
        for r in kept:
            dyn = world.dynamic(r.t)
            if dyn:
                p = rig.robot.control_point_positions(r.q)[:1]
                closest = min(closest, float(true_distance(dyn, p)[0]))
            if r.observed[0] and math.isfinite(r.distance[0]):
                near_ee = min(near_ee, float(r.distance[0]))
            rep = max(rep, float(np.linalg.norm(r.repulsion)))
        out[label] = {"person_to_ee_min_m": round(closest, 4), "override_min": summary["override_min"],
                      "robot_speed_min": round(world.scale_min, 4), "robot_slowed_s": round(world.slowed_s, 3),
                      "robot_stopped_s": round(world.stopped_s, 3),
                      "ee_reported_min_m": None if not math.isfinite(near_ee) else round(near_ee, 4),
                      "repulsion_max_m_s": round(rep, 3)}
    return out
