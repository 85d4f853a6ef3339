"""Blind spots of a camera layout next to the robot: space no camera sees (R12, R32).

Unknown space is an obstacle (R12: a cell no camera clears stays one), so a pocket
that every camera has hidden — behind the robot from some, behind a fixture from
the others — is reported as an obstacle, nearer than anything really there. That
is the right answer for the monitor (a hand could be in it) and a fault of the
layout. This module finds such pockets without the depth grid, from geometry
alone: the cell's fixed objects and the robot rendered into every camera with
no noise, and points on a lattice around each control point tested one by one
(a point is seen when some camera has it in view, within its rated range, and
its ideal depth there is more than ``margin`` behind the point, or nothing is modelled
along that ray).

``blind_spots(cell, times)`` lists, per time and control point, the nearest
lattice point that no camera sees, outside the robot's padded volume (cells in
it are never obstacles, R12), when it lies more than ``tolerance`` nearer than
``min(truth, rho)`` — the readings the monitor cannot help giving — and what
hides it from each camera. ``depthguard safe-defaults`` runs it on the path of
a robot-alone run that gave false readings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

__all__ = ["BlindSpot", "blind_spots", "recorded_path"]


@dataclass(frozen=True)
class BlindSpot:
    """A control point with space nobody sees nearer than the cell's fixed objects.

    ``t`` scene time (s); ``point`` the control point's name; ``distance`` (m) from it to
    the nearest unseen lattice point ``where`` (3,) world metres; ``truth`` (m) its
    distance to the fixed objects; ``hidden_by`` camera id -> what that camera sees in
    front of ``where`` (a mesh name; ``"out of view"``, ``"too near"`` or ``"too far"`` when it cannot).
    """
    t: float
    point: str
    distance: float
    truth: float
    where: tuple
    hidden_by: dict

    def __str__(self) -> str:
        by = ", ".join(f"{c}: {w}" for c, w in self.hidden_by.items())
        x, y, z = self.where
        return (f"t={self.t:.2f} s {self.point}: nothing seen at ({x:.2f}, {y:.2f}, {z:.2f}) m, "
                f"{self.distance:.3f} m away (fixed objects {self.truth:.3f} m) — hidden by {by}")


def _lattice(rho: float, step: float) -> np.ndarray:
    ax = np.arange(-rho, rho + 1e-9, step)
    grid = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3)
    return grid[np.linalg.norm(grid, axis=1) <= rho]


def _outside_capsules(points: np.ndarray, segments: np.ndarray, radii: np.ndarray) -> np.ndarray:
    out = np.ones(len(points), dtype=bool)
    for (a, b), r in zip(segments, radii):
        ab = b - a
        s = np.clip((points - a) @ ab / max(float(ab @ ab), 1e-12), 0.0, 1.0)
        out &= np.linalg.norm(points - (a + s[:, None] * ab), axis=1) > r
    return out


def blind_spots(cell, times, rho: float | None = None, padding: float | None = None,
                step: float = 0.02, tolerance: float = 0.05, margin: float = 0.01,
                q_at: Callable[[float], np.ndarray] | None = None,
                progress: Callable | None = None) -> list[BlindSpot]:
    """Blind spots along the robot's path (module docstring).

    cell : a :class:`depthguard.sim.Cell` (its rig's cameras, fixed objects, robot and path).
    times : times (s) to look at.
    rho, padding : metres; default the rig's ``monitor:`` ``rho`` and ``robot_padding``.
    step : lattice spacing (m); ``tolerance`` (m) how much nearer than ``min(truth, rho)``
        counts; ``margin`` (m) how far behind a point the camera's surface must be.
    q_at : ``t -> (dof,)`` joints of the path (default the cell's scripted path,
        ``cell.scene.robot_q``; :func:`recorded_path` for a recording).
    progress : ``progress(times) -> iterable`` around the loop over the times (e.g. a
        progress bar: each time renders every camera).
    """
    from depthguard.render import Renderer
    from depthguard.robot.volume import robot_volume
    from depthguard.sim.ground_truth import true_distance

    rig, scene = cell.rig, cell.scene
    robot = rig.robot
    if robot is None:
        raise ValueError(f"cell {cell.name!r} has no robot")
    cfg = rig.monitor
    rho = cfg.rho if rho is None else float(rho)
    padding = cfg.robot_padding if padding is None else float(padding)
    offsets = _lattice(rho, step)
    static = list(scene.static)
    renderers = {c.id: Renderer(c) for c in rig.cameras}
    names = [cp.name for cp in robot.control_points]
    q_at = scene.robot_q if q_at is None else q_at
    found = []
    for t in (times if progress is None else progress(times)):
        q = np.asarray(q_at(float(t)), dtype=np.float64)
        meshes = [p.mesh() for p in static] + list(robot.link_meshes(q))
        mesh_names = [p.name for p in static] + [f"robot/{n}" for n in robot.link_names]
        views = {}
        for cam in rig.cameras:
            depth, labels = renderers[cam.id].render(meshes)
            views[cam.id] = (np.array(depth, copy=True), np.array(labels, copy=True))
        segments, radii = robot_volume(robot, [q], padding)
        P = robot.control_point_positions(q)
        truth = true_distance(static, P)
        for i, p in enumerate(P):
            Y = p + offsets
            seen = np.zeros(len(Y), dtype=bool)
            for cam in rig.cameras:
                ds = cam.world_to_depth_space(Y)
                u, v = cam.pixel_of(ds[:, 0], ds[:, 1])
                ok = ((ds[:, 2] >= cam.min_range) & (ds[:, 2] <= cam.max_range) & (u >= 0) & (u < cam.width)
                      & (v >= 0) & (v < cam.height))
                d = np.zeros(len(Y))
                d[ok] = views[cam.id][0][v[ok], u[ok]]
                seen |= ok & ((d == 0) | (d > ds[:, 2] + margin))
            blind = ~seen & _outside_capsules(Y, segments, radii)
            if not blind.any():
                continue
            dist = np.where(blind, np.linalg.norm(offsets, axis=1), np.inf)
            k = int(np.argmin(dist))
            ref = min(float(truth[i]), rho)
            if dist[k] >= ref - tolerance:
                continue
            hidden = {}
            for cam in rig.cameras:
                ds = cam.world_to_depth_space(Y[k:k + 1])[0]
                u, v = (int(x) for x in cam.pixel_of(ds[0], ds[1]))
                if not (0 <= u < cam.width and 0 <= v < cam.height) or not ds[2] > 0:
                    hidden[cam.id] = "out of view"
                elif ds[2] < cam.min_range:
                    hidden[cam.id] = "too near"
                elif ds[2] > cam.max_range:
                    hidden[cam.id] = "too far"
                else:
                    lab = int(views[cam.id][1][v, u])
                    hidden[cam.id] = mesh_names[lab] if lab >= 0 else "nothing"
            found.append(BlindSpot(float(t), names[i], float(dist[k]), float(truth[i]),
                                   tuple(float(x) for x in Y[k]), hidden))
    return found


def recorded_path(states, every: float) -> tuple[np.ndarray, Callable[[float], np.ndarray]]:
    """The times to check along a recorded joint path and the joints at any of them.

    states : ``[(stamp s, q (dof,)), ...]`` in increasing stamp order (a joint source's,
        e.g. ``csv:FILE``), at least one. every : s > 0 between two checked times.
    Returns ``(times, q_at)``: every ``every`` s from the first stamp, and the last stamp;
    ``q_at(t)`` the joints linearly interpolated between the two states around ``t``
    (the robot moves between two recorded states; R30 interpolates the same way).
    """
    if not (isinstance(every, (int, float)) and math.isfinite(every) and every > 0):
        raise ValueError(f"every must be a number of seconds > 0 (got {every!r})")
    if not states:
        raise ValueError("the joint path has no states")
    stamps = np.array([float(s) for s, _ in states])
    Q = np.array([np.asarray(q, dtype=np.float64) for _, q in states])
    times = np.arange(stamps[0], stamps[-1], every)
    times = np.append(times, stamps[-1]) if len(times) == 0 or times[-1] < stamps[-1] else times

    def q_at(t: float) -> np.ndarray:
        return np.array([np.interp(t, stamps, Q[:, j]) for j in range(Q.shape[1])])

    return times, q_at
