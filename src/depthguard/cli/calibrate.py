"""``depthguard calibrate``: check and refine each camera's pose against the known scene (R34).

    depthguard calibrate --rig RIG (--source SPEC | --depth CAM=FILE ...) [--frames N] [--out RIG2]
    depthguard calibration-study [--cell NAME ...] [--n 20]

Guide: ``docs/CALIBRATION.md``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import List, Optional

import numpy as np
import typer

from depthguard.cli.app import app

#: a camera that checks good keeps its pose unless the refinement moves it by at least this much
MIN_CHANGE_DEG = 0.05
MIN_CHANGE_M = 0.002


def _parse_depth(items: list[str], rig) -> dict:
    from depthguard.depth_io import read_depth

    out: dict = {}
    for it in items:
        cid, sep, f = it.partition("=")
        if not sep or not cid or not f:
            raise typer.BadParameter(f"expected CAMERA=FILE, got {it!r}", param_hint="--depth")
        rig.camera(cid)                                  # ValueError naming the rig's cameras
        out.setdefault(cid, []).append(read_depth(Path(f)))
    return out


def _collect(spec: str, rig, frames: int, joints: Optional[str], timeout_s: float, log) -> tuple[dict, dict]:
    """``({camera: [depth, ...]}, {camera: [q, ...]})``: ``frames`` frames of each camera of the rig
    that the source serves. A ``sim:CELL`` source is the cell as it truly is (its own rig): the
    rig given is what is checked against it."""
    from depthguard.robot.joint_history import JointHistory, OutsideHistory
    from depthguard.sources.base import open_joints, open_source, split_spec

    scheme, arg = split_spec(spec)
    context: dict = {}
    world_rig = None if (scheme == "sim" and arg.split(":")[0]) else rig
    src = open_source(spec, world_rig, context)
    from depthguard.sources.sim_source import sim_world

    jspec = joints or ("sim" if sim_world(context) is not None else (spec if scheme == "bag" else None))
    jsrc = open_joints(jspec, world_rig, context) if (jspec and rig.robot is not None) else None
    hist = JointHistory(rig.robot.dof, 60.0) if jsrc is not None else None
    want = [c for c in src.camera_ids if c in rig.camera_ids]
    if not want:
        raise ValueError(f"source {spec} serves cameras {', '.join(src.camera_ids)}, none of the rig's "
                         f"({', '.join(rig.camera_ids)})")
    got: dict = {c: [] for c in want}
    stamps: dict = {c: [] for c in want}
    live = bool(getattr(src, "live", False))
    t = float(getattr(src, "first_stamp", 0.0) or 0.0)
    wall_end = time.perf_counter() + timeout_s
    try:
        while any(len(v) < frames for v in got.values()):
            if live:
                t = time.time()
                time.sleep(0.01)
            else:
                t += 1.0 / 30.0
            if jsrc is not None:
                for ts, q in jsrc.states_until(t):
                    hist.push(ts, q)
            for f in src.frames_until(t):
                if f.camera_id in got and len(got[f.camera_id]) < frames:
                    got[f.camera_id].append(np.asarray(f.depth, dtype=np.float32))
                    stamps[f.camera_id].append(float(f.stamp))
            if src.lost:
                raise ValueError(f"source {spec}: {src.lost}")
            if src.done or time.perf_counter() > wall_end:
                break
    finally:
        src.close()
        if jsrc is not None:
            jsrc.close()
    short = {c: len(v) for c, v in got.items() if len(v) < frames}
    if short:
        log(f"calibrate: fewer frames than asked ({frames}): " + ", ".join(f"{c}: {n}" for c, n in short.items()))
    got = {c: v for c, v in got.items() if v}
    if not got:
        raise ValueError(f"source {spec} delivered no frame of the rig's cameras within {timeout_s:g} s")
    qs: dict = {}
    if rig.robot is not None:
        for c in got:
            qs[c] = []
            for s in stamps[c]:
                try:
                    qs[c].append(hist.at(s) if hist is not None else rig.robot_q0)
                except OutsideHistory:
                    qs[c].append(rig.robot_q0)
    return got, qs


@app.command("calibrate")
def calibrate(
    rig: Optional[Path] = typer.Option(None, "--rig", help="Your rig file (YAML): the poses to check."),
    cell: Optional[str] = typer.Option(None, "--cell", help="A built-in cell's rig instead of --rig."),
    source: Optional[str] = typer.Option(None, "--source", help="Frame source SCHEME:ARG (sim:CELL, bag:PATH, images:DIR, realsense:...)."),
    depth: List[str] = typer.Option([], "--depth", help="CAMERA=FILE depth image (.png mm or .npy m), repeatable (several per camera are fused)."),
    frames: int = typer.Option(10, "--frames", help="Frames per camera from --source, fused per pixel (median)."),
    joints: Optional[str] = typer.Option(None, "--joints", help="Joint source for the robot's removal (default: the sim's or the bag's; else the rig's joints)."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="The corrected rig file to write (must not exist). Without it nothing is written."),
    timeout: float = typer.Option(30.0, "--timeout", help="Seconds to wait for the frames of a source."),
    check_only: bool = typer.Option(False, "--check-only", help="Only check the poses (residuals and verdicts), no refinement."),
) -> None:
    """Check each camera's pose against the expected depth of the static scene (robot removed,
    people ignored), refine it by robust point-to-plane ICP, report what the scene does not
    constrain, and write the corrected rig with a diff of each pose (R34). Exit status 1 when a
    camera is still wrong or cannot be judged after refinement."""
    from depthguard.calibration import calibrate_rig, pose_diff
    from depthguard.calibration.rig_file import write_calibrated_rig
    from depthguard.cli.common import load_rig_or_cell
    from depthguard.progress import log

    if frames < 1:
        raise typer.BadParameter("must be >= 1", param_hint="--frames")
    if (source is None) == (not depth):
        raise ValueError("give --source SPEC or --depth CAMERA=FILE (one of them)")
    if out is not None and out.exists():
        raise ValueError(f"--out {out} exists already; calibrate never overwrites a file (choose a new name)")
    if out is not None and check_only:
        raise ValueError("--check-only writes nothing: leave out --out")
    the_rig, _ = load_rig_or_cell(rig, cell, default=None)
    if depth:
        fr, qs = _parse_depth(depth, the_rig), {}
        if the_rig.robot is not None:
            qs = {c: [the_rig.robot_q0] for c in fr}
            log("calibrate: the robot is taken to stand at the rig's joints (robot: joints:) in the --depth images")
    else:
        fr, qs = _collect(source, the_rig, frames, joints, timeout, log)
    res = calibrate_rig(the_rig, fr, qs, refine=not check_only, log=log)
    poses, bad = {}, []
    for cid, cal in res.items():
        for line in cal.report():
            typer.echo(line)
        if check_only:
            if cal.before.verdict in ("wrong", "unknown"):
                bad.append(cid)
            continue
        ref = cal.refinement
        deg, m = cal.correction
        small = cal.before.verdict == "good" and deg < MIN_CHANGE_DEG and m < MIN_CHANGE_M
        better = (cal.after.verdict in ("good", "suspicious") and ref.converged and not small
                  and not (cal.after.share_far > cal.before.share_far + 0.005))
        if better:
            poses[cid] = cal.refined.world_from_camera
            typer.echo(pose_diff(cal.camera, cal.refined))
        else:
            why = ("did not converge" if not ref.converged else
                   f"the refined pose is {cal.after.verdict}" if cal.after.verdict not in ("good", "suspicious")
                   else f"the pose checks good and the correction ({deg:.3f} deg, {m * 1e3:.1f} mm) is below "
                        f"{MIN_CHANGE_DEG} deg and {MIN_CHANGE_M * 1e3:.0f} mm" if small
                   else "the refined pose fits no better")
            typer.echo(f"camera {cid}: pose kept as given ({why})")
        if cal.after.verdict in ("wrong", "unknown") or not better and cal.before.verdict in ("wrong", "unknown"):
            bad.append(cid)
    if out is not None:
        src_path = Path(rig) if rig is not None else _cell_path(cell)
        stamp = time.strftime("%Y-%m-%d %H:%M:%S")
        moved = ", ".join(f"{c} ({res[c].correction[0]:.3f} deg, {res[c].correction[1] * 1e3:.1f} mm)"
                          for c in poses) or "none"
        header = (f"calibrated by `depthguard calibrate` on {stamp} from {src_path.name}: poses refined of {moved}"
                  + ("\nunconstrained directions were kept as given: see the command's output"
                     if any(res[c].refinement.degenerate for c in poses) else ""))
        write_calibrated_rig(src_path, out, poses, header=header)
        typer.echo(f"calibrate: wrote {out} ({len(poses)} of {len(res)} cameras' poses changed; the rest of "
                   f"{src_path.name} as it was)")
    elif not check_only:
        typer.echo("calibrate: no --out given: nothing written")
    if bad:
        typer.echo(f"calibrate: still wrong or not judged: {', '.join(sorted(set(bad)))}", err=True)
        raise typer.Exit(1)


def _cell_path(cell: Optional[str]) -> Path:
    from depthguard.sim.cells import cell_rig_path
    return cell_rig_path(cell)


@app.command("calibration-study")
def calibration_study(
    cell: List[str] = typer.Option([], "--cell", help="Built-in cells (default: all four)."),
    n: int = typer.Option(20, "--n", help="Perturbations per cell (cameras in turn)."),
    rot: float = typer.Option(3.0, "--rot", help="Largest rotation error, degrees."),
    trans: float = typer.Option(0.05, "--trans", help="Largest translation error, metres."),
    seed: int = typer.Option(0, "--seed", help="Seed of the perturbations and the noise."),
) -> None:
    """R34's recovery study: random pose errors (up to --rot degrees, --trans metres) on the built-in
    cells with the noisy simulator, refined back; median and worst error per cell."""
    from depthguard.calibration.study import recovery_study, summarise
    from depthguard.progress import log
    from depthguard.sim.cells import CELL_NAMES

    if n < 1:
        raise typer.BadParameter("must be >= 1", param_hint="--n")
    cells = list(cell) or list(CELL_NAMES)
    typer.echo("| cell | n | median deg | median mm | worst deg | worst mm | constrained: median deg / mm, "
               "worst deg / mm | degenerate | not converged | s per camera |")
    typer.echo("|---|---|---|---|---|---|---|---|---|---|")
    for c in cells:
        s = summarise(recovery_study(c, n=n, rot_deg=rot, trans_m=trans, seed=seed, log=log))
        typer.echo(f"| {c} | {s['n']} | {s['median_deg']:.4f} | {s['median_mm']:.2f} | {s['worst_deg']:.4f} | "
                   f"{s['worst_mm']:.2f} | {s['median_constrained_deg']:.4f} / {s['median_constrained_mm']:.2f}, "
                   f"{s['worst_constrained_deg']:.4f} / {s['worst_constrained_mm']:.2f} | {s['degenerate']} | "
                   f"{s['not_converged']} | {s['seconds_median']:.2f} |")
