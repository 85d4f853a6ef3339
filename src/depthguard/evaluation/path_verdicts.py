"""Path verdicts against the simulator's ground truth on the built-in cells (R22, R37; issue 30).

For every built-in cell with a robot and each of its situations: the cameras' frames at the
situation's time (noise model of each camera, seeded), the robot removed at the frame's joints,
the runtime's free-space map with the product's defaults (:class:`RuntimeFreeSpace`: 5 cm voxels,
the rig's ``robot_offset`` and ``robot_padding``, the known scene as background) — then random
joint paths from the robot's pose (``paths`` per situation, 20 segments over 2 s, each joint
moving up to ``spread`` rad, inside its limits), each judged per segment (safe / maybe / unsafe,
padding = the rig's ``robot_padding``).

Truth per segment: the robot's capsules (no padding) at 10 poses per segment, points every
``1 cm`` along each axis, :func:`~depthguard.sim.ground_truth.true_distance` to the scene's
obstacles (static objects, people, props; not the robot) — the segment truly collides when some
point of a capsule that moves along the path is within its radius of an obstacle (a capsule
whose axis stays put, like the base on its mount, sweeps nothing new). The figure that must be 0: segments that
truly collide judged ``safe``. Reported: the share of truly free segments judged safe (the rest
are ``maybe``: space no camera could judge, or ``unsafe``: within the padding of something seen).

``python -m depthguard.evaluation.path_verdicts [paths]`` prints the table (markdown).
"""

from __future__ import annotations

import sys

import numpy as np

from depthguard.control.path_check import capsule_ends
from depthguard.filtering.expected import ExpectedDepth
from depthguard.runtime.free_space_map import RuntimeFreeSpace, check_path_in
from depthguard.sim import list_cells, load_cell
from depthguard.sim.ground_truth import true_distance
from depthguard.sources.simulated import SimSource

__all__ = ["random_paths", "true_collisions", "evaluate_situation", "run", "table"]


def random_paths(robot, q0, n: int, rng, spread: float = 1.2, segments: int = 20, duration: float = 2.0):
    """``n`` straight joint paths from ``q0`` (dof,) rad to random targets within ``spread`` rad per
    joint, clipped to the limits: list of ``(stamps (segments+1,), q (segments+1, dof))``."""
    lo, hi = np.asarray(robot.q_min, float), np.asarray(robot.q_max, float)
    out = []
    for _ in range(n):
        target = np.clip(q0 + rng.uniform(-spread, spread, size=len(q0)), lo, hi)
        out.append((np.linspace(0.0, duration, segments + 1), np.linspace(q0, target, segments + 1)))
    return out


def _distance_within(obstacles, points, reach: float) -> np.ndarray:
    """:func:`true_distance` of ``points`` (N, 3), exact wherever it is <= ``reach`` m: a mesh
    solid's own (slow) ``sdf`` is evaluated only at the points inside its bounds grown by ``reach``
    (elsewhere it is farther than ``reach``; its lower bound, the distance to the bounds, stands)."""
    from depthguard.geometry.packed import PackedSolids

    packed, rest = PackedSolids.split(obstacles)
    d = true_distance([o for o in obstacles if o not in rest], points) if len(rest) < len(obstacles) \
        else np.full(len(points), np.inf)
    for prim in rest:
        lo, hi = prim.bounds()
        gap = np.linalg.norm(np.maximum(np.maximum(lo - points, points - hi), 0.0), axis=1)
        near = gap <= reach
        if near.any():
            gap[near] = np.maximum(prim.sdf(points[near]), 0.0)
        np.minimum(d, gap, out=d)
    return d


def true_collisions(robot, q, obstacles, per_segment: int = 10, step: float = 0.01) -> np.ndarray:
    """(n-1,) bool: segment ``i`` of the path ``q`` (n, dof) truly brings the robot (capsules, no
    padding) into an obstacle (module docstring)."""
    radii = np.array([c.radius for c in robot.capsules])
    f = np.linspace(0.0, 1.0, per_segment + 1)
    seg_of, poses = [], []
    for i in range(len(q) - 1):
        poses.append(q[i] + f[:, None] * (q[i + 1] - q[i]))
        seg_of.append(np.full(len(f), i))
    poses, seg_of = np.concatenate(poses), np.concatenate(seg_of)
    A, B = capsule_ends(robot, poses)                          # (P, K, 3)
    L = np.linalg.norm(B - A, axis=2).max()
    u = np.linspace(0.0, 1.0, max(2, int(np.ceil(L / step)) + 1))
    pts = A[:, :, None, :] + u[None, None, :, None] * (B - A)[:, :, None, :]     # (P, K, U, 3)
    d = _distance_within(obstacles, pts.reshape(-1, 3), float(radii.max())).reshape(pts.shape[:3])
    # capsules whose axis does not move along the path (the base, a column turning about its own
    # axis) sweep nothing new: their contact with the mount they stand on is not the motion's
    moving = np.max(np.linalg.norm(np.concatenate([A - A[:1], B - B[:1]], axis=0), axis=2), axis=0) > 1e-3
    hit = np.any((d <= radii[None, :, None]) & moving[None, :, None], axis=(1, 2))      # (P,)
    out = np.zeros(len(q) - 1, bool)
    np.logical_or.at(out, seg_of, hit)
    return out


def evaluate_situation(cell, situation: str, paths: int = 20, seed: int = 0) -> dict:
    """One row of the table (module docstring)."""
    rig = cell.rig
    t = cell.time_of(situation)
    q_now = cell.scene.robot_q(t)
    frames = SimSource(cell, seed=seed).frames(t)
    rdepth = {c.id: np.asarray(ExpectedDepth(c, rig.robot, []).robot(q_now)) for c in rig.cameras}
    cfg = rig.monitor
    space = RuntimeFreeSpace(rig, voxel_size=cfg.free_space_voxel, robot_offset=cfg.robot_offset,
                             robot_padding=cfg.robot_padding, scene_padding=cfg.free_space_scene_padding)
    snap = space.build({k: f.depth for k, f in frames.items()}, rdepth, q_now, {k: t for k in frames})
    obstacles = cell.scene.obstacles_at(t)
    rng = np.random.default_rng(seed)
    counts = {"segments": 0, "truly_colliding": 0, "truly_free": 0, "free_judged_safe": 0,
              "free_judged_maybe": 0, "free_judged_unsafe": 0, "colliding_judged_safe": 0,
              "colliding_judged_maybe": 0, "colliding_judged_unsafe": 0}
    for stamps, q in random_paths(rig.robot, q_now, paths, rng):
        v = check_path_in(snap, rig.robot, stamps, q, cfg.robot_padding)
        truth = true_collisions(rig.robot, q, obstacles)
        for s, hit in zip(v.segments, truth):
            counts["segments"] += 1
            key = "colliding" if hit else "free"
            counts["truly_colliding" if hit else "truly_free"] += 1
            counts[f"{key}_judged_{s.verdict}"] += 1
    counts.update(snap.counts())
    return {"cell": cell.name, "situation": situation, **counts}


def run(paths: int = 20, seed: int = 0, cells=None, log=print) -> list[dict]:
    """Every built-in cell with a robot and each of its situations; rows of :func:`evaluate_situation`."""
    rows = []
    for name in (cells or list_cells()):
        cell = load_cell(name)
        if cell.rig.robot is None:
            log(f"{name}: no robot in the rig (its machine's motions: `depthguard reproduce hamersma2011`)")
            continue
        for sit in cell.situations:
            rows.append(evaluate_situation(cell, sit, paths, seed))
            log(f"{name}/{sit}: done")
    return rows


def table(rows) -> str:
    """Markdown: per cell and situation, segments, truly colliding judged safe (must be 0), share of
    truly free judged safe / maybe / unsafe, and how colliding ones were judged."""
    head = ("| cell | situation | segments | colliding: judged safe | colliding: maybe / unsafe | "
            "free: judged safe | free: maybe | free: unsafe |\n|---|---|---|---|---|---|---|---|")
    lines = [head]
    for r in rows:
        nf = max(r["truly_free"], 1)
        lines.append(f"| {r['cell']} | {r['situation']} | {r['segments']} | **{r['colliding_judged_safe']}** | "
                     f"{r['colliding_judged_maybe']} / {r['colliding_judged_unsafe']} | "
                     f"{100 * r['free_judged_safe'] / nf:.1f} % | {100 * r['free_judged_maybe'] / nf:.1f} % | "
                     f"{100 * r['free_judged_unsafe'] / nf:.1f} % |")
    return "\n".join(lines)


if __name__ == "__main__":
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 20
    rows = run(n, log=lambda m: print(m, file=sys.stderr))
    print(table(rows))
