"""Free-space commands: ``depthguard reproduce hamersma2011`` and ``depthguard placement``."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Optional

import typer

from depthguard.cli.app import app
from depthguard.cli.reproduce import reproduce_app


@reproduce_app.command("hamersma2011")
def hamersma2011(
    out: Path = typer.Option(Path("out/hamersma2011"), "--out", help="Directory for report.md, results.json and the pictures."),
    voxel: Optional[list[float]] = typer.Option(None, "--voxel", help="Voxel size in metres (repeatable); default 0.05 and 0.10."),
    seed: int = typer.Option(0, "--seed", help="Seed of the simulated sensor noise."),
    quick: bool = typer.Option(False, "--quick", help="Two setups, no approach series: a smoke run, not figures to quote."),
    no_placement: bool = typer.Option(False, "--no-placement", help="Skip the sensor placement study (R23)."),
    no_calibration: bool = typer.Option(False, "--no-calibration", help="Skip the calibration study."),
) -> None:
    """Hamersma 2011 on the c-arm-room cell: free-space accuracy (tables 1-2), motion verdicts
    (table 4), calibration study, sensor placement (fig. 4) and pictures (fig. 9)."""
    from depthguard.evaluation.hamersma2011 import run
    from depthguard.progress import log

    voxels = voxel or [0.05, 0.10]
    for v in voxels:
        if not (0.01 <= v <= 0.5):
            raise typer.BadParameter(f"voxel size must lie in [0.01, 0.5] m, got {v}", param_hint="--voxel")
    from depthguard.cli.common import check_output_dir

    check_output_dir(out)      # before any work is done
    res = run(out, voxels=voxels, seed=seed, quick=quick, log=log, placement=not no_placement,
              calibration=not no_calibration)
    typer.echo((out / "report.md").read_text())
    for label, rr in res["rigs"].items():
        n = sum(len(rows) for rows in rr["verdicts"].values())
        n_u = sum(r["verdict"] == "u" for rows in rr["verdicts"].values() for r in rows)
        typer.echo(f"rig {label}: {n_u} unsafe verdicts of {n}")
    typer.echo(f"report: {out / 'report.md'}")


@app.command("placement")
def placement(
    rig: Optional[Path] = typer.Option(None, "--rig", help="Your rig file (YAML): its cameras are checked over its workspace."),
    cell: Optional[str] = typer.Option(None, "--cell", help="Built-in cell whose rig is checked (default c-arm-room when no --rig)."),
    voxel: float = typer.Option(0.10, "--voxel", help="Voxel size of the space of interest, metres."),
    clearance: Optional[float] = typer.Option(None, "--clearance", help="Space of interest: the workspace shrunk by this much from the walls (metres; 0 = the whole box). Default 0.8 for a built-in cell, 0 for --rig (the rig's workspace is its box of interest)."),
    min_separation: float = typer.Option(100.0, "--min-separation", help="Pairwise horizontal angle in degrees."),
    improve: bool = typer.Option(True, "--improve/--no-improve", help="Also run the greedy improver over wall and ceiling positions."),
    spacing: float = typer.Option(0.5, "--spacing", help="Spacing of the improver's candidate positions, metres."),
    joints: Optional[str] = typer.Option(None, "--joints", help="A recorded joint path (csv:FILE with stamp,q1..qn, or bag:FILE): the space next to the robot is checked along it instead of at the rig joints."),
    every: float = typer.Option(0.5, "--every", help="With --joints: check the path every this many seconds (and at its last state)."),
) -> None:
    """R23: share of the (empty) space of interest seen by >= 3 cameras pairwise >= 100° apart in
    the horizontal plane, by number of cameras, and how many cameras a greedy placement on the
    walls (two rings) and the ceiling needs. Works on a built-in cell or your rig file (R2); the
    static objects outside the workspace (walls) hide what lies behind them. With a robot in the
    rig: the space next to it (within rho, at its rig joints, or along a recorded path with
    ``--joints``) that no camera sees, and what hides it from each camera — unknown is an
    obstacle, so the robot alone would read it (R12, R32)."""
    import numpy as np

    from depthguard.cli.common import load_rig_or_cell
    from depthguard.evaluation.placement import (azimuths, candidate_cameras, greedy_placement,
                                                 passes_criterion, share_vs_cameras, visibility)
    from depthguard.geometry.voxel_grid import VoxelGrid

    if not (0.02 <= voxel <= 1.0):
        raise typer.BadParameter(f"voxel must lie in [0.02, 1.0] m, got {voxel}", param_hint="--voxel")
    if not (0 < min_separation <= 120):
        raise typer.BadParameter(f"must lie in (0, 120] degrees, got {min_separation}", param_hint="--min-separation")
    if not (math.isfinite(every) and every > 0):
        raise typer.BadParameter(f"must be a number of seconds > 0, got {every}", param_hint="--every")
    the_rig, c = load_rig_or_cell(rig, cell, default="c-arm-room", simulate=True)
    label = c.name if rig is None else f"{the_rig.name} ({rig})"
    path = None
    if joints is not None:
        path = _recorded_path(joints, the_rig, every)
    if clearance is None:
        clearance = 0.0 if rig is not None else 0.8
    lo, hi = np.asarray(the_rig.workspace.lo, float), np.asarray(the_rig.workspace.hi, float)
    if not (0 <= clearance < 0.5 * float(np.min(hi[:2] - lo[:2]))):
        raise typer.BadParameter(f"clearance {clearance} m leaves no space of interest", param_hint="--clearance")
    ilo, ihi = lo.copy(), hi.copy()
    ilo[:2] += clearance
    ihi[:2] -= clearance
    pts = VoxelGrid(ilo, ihi, voxel).centres()

    def outside(o):
        b = np.asarray(o.bounds())
        return bool(np.any(b[1] <= lo + 0.01) or np.any(b[0] >= hi - 0.01))

    shell = [o.mesh() for o in c.scene.static if outside(o)]
    kw = dict(min_separation_deg=min_separation)
    seen, az = visibility(the_rig.cameras, pts, shell), azimuths(the_rig.cameras, pts)
    ok = passes_criterion(seen, az, **kw)
    typer.echo(f"{label}: {len(the_rig.cameras)} cameras")
    robot = the_rig.robot
    if robot is not None and len(getattr(robot, "control_points", ())) > 0:
        from depthguard.evaluation.coverage import blind_spots
        from depthguard.progress import track

        if path is None:                           # the robot at its rig joints (R12, R32)
            where, spots = "at its rig joints", blind_spots(c, [0.0])
        else:
            times, q_at = path
            where = f"along {joints} ({len(times)} poses, every {every:g} s from {times[0]:g} to {times[-1]:g} s)"
            spots = blind_spots(c, times, q_at=q_at, progress=lambda ts: track(ts, "placement: the path"))
        if spots:
            typer.echo(f"next to the robot {where}: {len(spots)} control point(s) have space that no "
                       f"camera sees nearer than the fixed objects (unknown is an obstacle: the robot alone "
                       f"reads it there){' at ' + str(len({b.t for b in spots})) + ' poses' if path else ''}:")
            shown = spots[:5]
            if path is not None:                   # along a path: the nearest at each pose, up to 10 poses
                per_pose: dict = {}
                for b in spots:
                    if b.t not in per_pose or b.distance < per_pose[b.t].distance:
                        per_pose[b.t] = b
                shown = list(per_pose.values())[:10]
            for b in shown:
                typer.echo(f"  {b}")
            if len(spots) > len(shown):
                typer.echo(f"  ... and {len(spots) - len(shown)} more")
        else:
            typer.echo(f"next to the robot {where}: some camera sees around every control point "
                       "(within rho, outside the robot's padding)")
    elif path is not None:
        raise typer.BadParameter(f"the rig {the_rig.name!r} has no robot with control points to move along a "
                                 f"path", param_hint="--joints")
    # the free-space criterion second: what a free-space map needs (R21-R23), far more than distances
    typer.echo(f"free-space criterion (Hamersma 2011, R23: >= 3 views pairwise >= {min_separation:g} deg apart, "
               f"what a free-space map needs): {len(pts)} voxels of {voxel * 100:.0f} cm in "
               f"{ilo.round(2).tolist()}..{ihi.round(2).tolist()}: {100 * ok.mean():.1f} % pass")
    g = greedy_placement(seen, az, the_rig.cameras, target_share=1.0, max_cameras=len(the_rig.cameras), prune=False,
                         **kw)
    curve = share_vs_cameras(seen, az, g.chosen, **kw)
    typer.echo("  share vs cameras (best first): " + ", ".join(f"{i + 1}:{100 * v:.1f}" for i, v in enumerate(curve)))
    if improve:
        mid = (lo + hi) / 2
        h = hi[2] - lo[2]
        rings = [(hi[2] - 0.15, (mid[0], mid[1], lo[2] + 0.24 * h)), (lo[2] + 0.6, (mid[0], mid[1], lo[2] + 0.72 * h))]
        cands = candidate_cameras(lo, hi, target=(mid[0], mid[1], lo[2] + 0.36 * h), template=the_rig.cameras[0],
                                  spacing=spacing, rings=rings)
        furniture = [o for o in c.scene.static if not outside(o)]
        if furniture:  # no camera inside (or right against) the fixed furniture
            from depthguard.geometry import sdf_union
            keep = sdf_union(furniture, np.stack([k.position for k in cands])) > 0.10
            cands = [k for k, ok in zip(cands, keep) if ok]
        sc, ac = visibility(cands, pts, shell), azimuths(cands, pts)
        reach = float(passes_criterion(sc, ac, **kw).mean())
        r = greedy_placement(sc, ac, cands, target_share=0.995 * reach, max_cameras=60, **kw)
        paper = "; paper: 21 cameras" if rig is None and c.name == "c-arm-room" else ""
        typer.echo(f"  greedy improver: {len(r.chosen)} cameras on the walls and ceiling reach "
                   f"{100 * r.final_share:.1f} % (all {len(cands)} candidates: {100 * reach:.1f} %{paper}); "
                   f"--no-improve leaves this out")
        for cam in r.cameras[:5]:
            p = cam.position
            typer.echo(f"    {cam.id} at ({p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f})")
        if len(r.cameras) > 5:
            typer.echo(f"    ... and {len(r.cameras) - 5} more")


def _recorded_path(spec: str, rig, every: float):
    """``(times, q_at)`` of the recorded joint path ``spec`` (:func:`depthguard.evaluation.coverage.recorded_path`);
    a live source (zenoh:, ros2:) or the simulator has no recording to walk along."""
    from depthguard.evaluation.coverage import recorded_path
    from depthguard.sources.base import open_joints, split_spec

    scheme = split_spec(spec)[0]
    if scheme not in ("csv", "bag"):
        raise typer.BadParameter(f"{spec!r}: placement walks a recorded path (csv:FILE or bag:FILE), not "
                                 f"{scheme}:", param_hint="--joints")
    src = open_joints(spec, rig, {})
    try:
        states = src.states_until(math.inf)
    finally:
        close = getattr(src, "close", None)
        if close is not None:
            close()
    if not states:
        raise typer.BadParameter(f"{spec!r} holds no joint state", param_hint="--joints")
    return recorded_path(states, every)
