"""Hamersma 2011 on ``c-arm-room``: the placement check (R23, the paper's fig. 4) on the empty
room, run by :mod:`depthguard.evaluation.hamersma2011`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from depthguard.evaluation.hamersma2011_room import Room, outside_box, shell_primitives


PLACEMENT_RINGS = [(2.35, (0.0, 0.0, 0.6)), (0.6, (0.0, 0.0, 1.8))]   # wall rings: height, target
WALL_CLEARANCE = 0.8            # interior (working volume): 0.8 m from the walls ...
INTERIOR_Z = (0.3, 2.2)         # ... from 0.3 m above the floor to 0.3 m below the ceiling


def placement_check(room: Room, vs: float, out: Path, log=print) -> dict:
    """R23 on the empty room: the criterion over the whole box and over its interior
    (``WALL_CLEARANCE`` from the walls, heights ``INTERIOR_Z``); the greedy improver over
    wall rings + ceiling, aiming at 99.5 % of what all candidates together reach."""
    from depthguard.evaluation.placement import (azimuths, candidate_cameras, greedy_placement,
                                                 passes_criterion, share_vs_cameras, visibility)
    from depthguard.geometry.voxel_grid import VoxelGrid

    shell = shell_primitives(room)
    meshes = [p.mesh() for p in shell]
    cands = candidate_cameras(room.lo, room.hi, target=(0.0, 0.0, 0.9), template=room.cameras[0],
                              spacing=0.5, rings=PLACEMENT_RINGS)
    # a camera cannot hang inside (or right against) the room's fixed furniture (cabinets ...)
    furniture = [p for p in room.scene.static if not outside_box(p, room.lo, room.hi)]
    if furniture:
        from depthguard.geometry import sdf_union
        free = sdf_union(furniture, np.stack([c.position for c in cands])) > 0.10
        cands = [c for c, ok in zip(cands, free) if ok]
    res = {"voxel": vs, "rig_cameras": len(room.cameras), "candidates": len(cands),
           "shell": [p.name for p in shell], "rings": PLACEMENT_RINGS, "regions": {}}
    clear = np.array([WALL_CLEARANCE, WALL_CLEARANCE, 0.0])
    ilo = room.lo + clear
    ihi = room.hi - clear
    ilo[2], ihi[2] = INTERIOR_Z
    for region, (lo, hi) in (("box", (room.lo, room.hi)), ("interior", (ilo, ihi))):
        grid = VoxelGrid(lo, hi, vs)
        pts = grid.centres()
        seen, az = visibility(room.cameras, pts, meshes), azimuths(room.cameras, pts)
        ok = passes_criterion(seen, az)
        g_rig = greedy_placement(seen, az, room.cameras, target_share=1.0, max_cameras=len(room.cameras), prune=False)
        curve_rig = share_vs_cameras(seen, az, g_rig.chosen)
        sc, ac = visibility(cands, pts, meshes), azimuths(cands, pts)
        reach = float(passes_criterion(sc, ac).mean())
        g = greedy_placement(sc, ac, cands, target_share=0.995 * reach, max_cameras=40)
        curve = share_vs_cameras(sc, ac, g.chosen)
        by_z = ok.reshape(grid.shape).mean(axis=(0, 1))
        res["regions"][region] = {
            "lo": np.asarray(lo).tolist(), "hi": np.asarray(hi).tolist(), "rig_share": float(ok.mean()),
            "rig_share_by_z": by_z.tolist(), "rig_curve": curve_rig.tolist(),
            "candidates_all_share": reach, "improver_cameras": len(g.chosen), "improver_share": g.final_share,
            "improver_curve": curve.tolist(), "improver_positions": [c.position.round(3).tolist() for c in g.cameras],
            "improver": g.cameras}
        log(f"placement {region}: rig {100 * ok.mean():.1f} %, improver {len(g.chosen)} cameras -> "
            f"{100 * g.final_share:.1f} % (all candidates {100 * reach:.1f} %)")
    r = res["regions"]
    _plot_fig4(out / "fig4_placement.png", r["interior"]["rig_curve"], r["interior"]["improver_curve"],
               len(room.cameras))
    return res


def _plot_fig4(path, curve_rig, curve_imp, n_rig):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(np.arange(1, len(curve_rig) + 1), 100 * np.asarray(curve_rig), "o-", label=f"the cell's {n_rig} cameras, best first")
    ax.plot(np.arange(1, len(curve_imp) + 1), 100 * np.asarray(curve_imp), "s-", label="greedy improver (walls + ceiling)")
    ax.axvline(21, color="gray", ls=":", label="paper: 21 cameras")
    ax.set_xlabel("number of cameras"); ax.set_ylabel("voxels passing [%]")
    ax.set_title("R23: >= 3 views pairwise >= 100° apart (empty room, interior)")
    ax.grid(alpha=0.3); ax.legend(fontsize=8)
    fig.tight_layout(); fig.savefig(path, dpi=110); plt.close(fig)
