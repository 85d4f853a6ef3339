"""Clearing latency of the runtime's free-space map against the simulator's truth (R21, R37; issue 30).

Scenario: ``ur3-cell`` from 10 s, the person puts the box down and walks out of the workspace
(out of the box by about 11.5 s, gone at 14 s); the robot keeps moving. Truth: the person's own
primitives (``Person.primitives``) on the map's voxels, centre rule
(:func:`~depthguard.sim.ground_truth.occupancy`), every ``step`` s (default 10 ms). A voxel the person
occupied in ``[t0, t1]`` and not at ``t1`` is *vacated*; it is truly free from the first sample
after its last occupied one. Only vacated voxels the map has free at ``t1`` count (the others no
camera can judge once the person is gone: they stay unknown, which is not a clearing delay).

The monitor's timing, in simulation time: every camera delivers a frame every ``1/fps`` s (all
cameras at the same instants, no transport delay: the camera's own latency is not the map's); the
map is rebuilt every ``1/hz`` s (phase ``phase``) by :meth:`RuntimeFreeSpace.build` from each
camera's newest frame (robot removed at that frame's joints, the product's defaults) and is
published when the build is done (its measured wall time, ``build_s``, is added).

Figures: ``last_s`` — from the moment the person's last vacated voxel is truly free to the first
published map that has it free (the issue's figure; goal <= 0.2 s, MoveIt users report about 2 s);
``worst_s`` — the same, the largest over every vacated voxel. ``python -m
depthguard.evaluation.clearing_latency`` prints them for three phases of the map against the frames.
"""

from __future__ import annotations

import sys

import numpy as np

from depthguard.filtering.expected import ExpectedDepth
from depthguard.runtime.free_space_map import FREE, RuntimeFreeSpace
from depthguard.sim import load_cell
from depthguard.sim.ground_truth import occupancy
from depthguard.sources.simulated import SimSource

__all__ = ["vacated_truth", "clearing_latency"]


def vacated_truth(cell, grid, person: str, t0: float, t1: float, step: float = 0.01):
    """``(vacated (nx, ny, nz) bool, t_free (nx, ny, nz) s)``: the voxels ``person`` occupies at
    some sample of ``[t0, t1]`` and not at ``t1``, and the moment each is truly free (NaN elsewhere)."""
    p = next((q for q in cell.scene.people if q.name == person), None)
    if p is None:
        raise ValueError(f"cell {cell.name!r} has no person {person!r}")
    ts = np.arange(t0, t1 + 0.5 * step, step)
    last = np.full(grid.shape, -1, np.int64)
    for i, t in enumerate(ts):
        occ = occupancy(p.primitives(float(t)), grid.lo, grid.hi, grid.voxel_size, mode="centre")
        last[occ] = i
    vacated = (last >= 0) & (last < len(ts) - 1)
    t_free = np.full(grid.shape, np.nan)
    t_free[vacated] = ts[last[vacated] + 1]
    return vacated, t_free


class _Frames:
    """The cell's camera frames at ``k / fps`` and the robot's rendered depth at their joints, made once."""

    def __init__(self, cell, fps: float, seed: int):
        self.cell, self.fps = cell, float(fps)
        self.src = SimSource(cell, seed=seed)
        self.exp = {c.id: ExpectedDepth(c, cell.rig.robot, []) for c in cell.rig.cameras}
        self._cache = {}

    def newest(self, t: float):
        """(depths, robot depths, q, stamp) of the newest frame at or before ``t``."""
        k = int(np.floor(t * self.fps + 1e-9))
        if k not in self._cache:
            ts = k / self.fps
            q = self.cell.scene.robot_q(ts)
            fr = self.src.frames(ts)
            self._cache[k] = ({c: f.depth for c, f in fr.items()},
                              {c: np.asarray(e.robot(q)) for c, e in self.exp.items()}, q, ts)
        return self._cache[k]


def clearing_latency(cell_name: str = "ur3-cell", person: str = "operator", t0: float = 10.0, t1: float = 14.5,
                     hz: float = 10.0, fps: float = 30.0, phase: float = 0.0, seed: int = 0, step: float = 0.01,
                     every_voxel: bool = True, frames: _Frames | None = None) -> dict:
    """The figures of the module docstring for one phase (s) of the map's period."""
    cell = load_cell(cell_name)
    rig, cfg = cell.rig, cell.rig.monitor
    space = RuntimeFreeSpace(rig, voxel_size=cfg.free_space_voxel, robot_offset=cfg.robot_offset,
                             robot_padding=cfg.robot_padding, scene_padding=cfg.free_space_scene_padding)
    vacated, t_free = vacated_truth(cell, space.grid, person, t0, t1, step)
    frames = frames or _Frames(cell, fps, seed)

    def build(t):
        d, rd, q, ts = frames.newest(t)
        snap = space.build(d, rd, q, {c: ts for c in d})
        return snap.state == FREE, t + snap.build_s

    final, _ = build(t1)
    judged = vacated & final
    if not judged.any():
        raise ValueError(f"no voxel the person left in [{t0}, {t1}] s is free in the final map")
    tf = t_free[judged]
    order = np.argsort(tf)
    t_last = float(tf[order[-1]])
    first_update = (np.floor((float(tf.min() if every_voxel else t_last) - phase) * hz) + 1) / hz + phase
    cleared = np.full(len(tf), np.nan)
    t, builds = first_update, []
    while np.isnan(cleared).any() and t <= t1:
        free, published = build(t)
        builds.append(published - t)
        now = free[judged] & (tf <= t) & np.isnan(cleared)
        cleared[now] = published
        t += 1.0 / hz
    lat = cleared - tf
    return {"cell": cell_name, "phase_s": phase, "vacated": int(vacated.sum()), "judged": int(judged.sum()),
            "t_last_free_s": t_last, "last_s": float(lat[order[-1]]),
            "worst_s": float(np.nanmax(lat)) if every_voxel else float("nan"),
            "never": int(np.isnan(lat).sum()), "build_ms_median": 1e3 * float(np.median(builds))}


def main(argv=None) -> None:
    hz, fps = 10.0, 30.0
    frames = None
    print("| phase (s) | vacated voxels | judged by the map | person's last voxel free at (s) | "
          "latency of the last voxel (s) | worst voxel (s) | build (ms, median) |\n|---|---|---|---|---|---|---|")
    for phase in (0.0, 1.0 / (3 * hz), 2.0 / (3 * hz)):
        if frames is None:
            frames = _Frames(load_cell("ur3-cell"), fps, 0)
        r = clearing_latency(phase=phase, hz=hz, fps=fps, frames=frames)
        print(f"| {phase:.3f} | {r['vacated']} | {r['judged']} | {r['t_last_free_s']:.2f} | **{r['last_s']:.3f}** | "
              f"{r['worst_s']:.3f} | {r['build_ms_median']:.1f} |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
