"""``depthguard run --scenario NAME --out DIR``: one closed-loop scenario (R13–R15, R27) on
``flacco-cell``, another built-in cell (``--cell``) or a user's rig file (``--rig``, R2)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from depthguard.cli.app import app


def _scenario_help() -> str:
    from depthguard.evaluation.closed_loop.scenarios import SCENARIOS
    return "; ".join(f"{k}: {v}" for k, v in SCENARIOS.items())


@app.command("run")
def run(
    scenario: str = typer.Option(..., "--scenario", "-s", help="Scenario name: reach, plate, elbow, shadow, camera_dropout, empty."),
    out: Path = typer.Option(..., "--out", "-o", help="Report folder: summary.json and plots."),
    rig: Optional[Path] = typer.Option(None, "--rig", help="Your rig file (YAML): its robot, cameras and static objects (no people); the robot starts at its rig joints."),
    cell: Optional[str] = typer.Option(None, "--cell", help="A built-in cell with a robot (default flacco-cell when no --rig)."),
    hexagon_centre: Optional[str] = typer.Option(None, "--hexagon-centre", help="X,Y,Z (m) of the end effector's hexagon, in the plane x = X (default: flacco-cell the paper's (-0.6, 0, 0.6); otherwise the end effector at the rig's joints)."),
    hexagon_radius: Optional[float] = typer.Option(None, "--hexagon-radius", help="Radius of the hexagon, m (default: flacco-cell 0.2; otherwise the largest of 0.2, 0.15, 0.1, 0.05 the robot reaches clear of the static objects)."),
    duration: Optional[float] = typer.Option(None, "--duration", help="Simulated seconds (default: the scenario's)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the cameras' noise."),
    cameras: str = typer.Option("all", "--cameras", help="all: every camera of the rig fused by the depth grid map (R12, Flacco 2015); principal: the principal camera only (Flacco 2014), the one-camera comparison."),
    distance_hz: Optional[float] = typer.Option(None, "--distance-hz", help="Rate of the distance computation (default: every 500 Hz control cycle, R15)."),
    no_noise: bool = typer.Option(False, "--no-noise", help="Ideal depth images (no sensor noise)."),
    camera_latency: Optional[float] = typer.Option(None, "--camera-latency", help="Seconds from a frame's capture to its delivery (default: one camera period; 0: each frame is used in the cycle it is captured)."),
    reaction: Optional[str] = typer.Option(None, "--reaction", help="repulsion (R13, R14), ssm (speed and separation monitoring, ISO/TS 15066, R33; docs/SSM.md) or both (default: the rig's monitor: reaction, repulsion when it sets none)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress output."),
) -> None:
    """Run the robot's hexagon task with a scenario's obstacles, closing the loop: the LWR on
    flacco-cell (Flacco 2014 §5.3), or the robot of a built-in cell or of your rig file (R2).

    Cameras at 30 Hz with their noise model (each frame delivered one camera
    period after its capture), distances and reactions at every
    500 Hz control cycle (repulsion at the end effector, joint-velocity limits
    for the other control points, SNS), safe stop on stale frames. Writes
    DIR/summary.json (min_true_distance_m, collision, ee_tracking_rms_m,
    avoidance_rate_hz, real_time_factor, safe_stops ...) and plots.

    On a cell other than flacco-cell the scenarios are placed relative to the
    hexagon, the robot's base and the principal (first) camera; the hexagon
    lies in the vertical plane x = const through the end effector at the rig's
    joints (--hexagon-centre, --hexagon-radius to choose another).
    """
    import dataclasses

    from depthguard.cli.common import load_rig_or_cell, parse_vector3
    from depthguard.evaluation.closed_loop.loop import LoopConfig
    from depthguard.evaluation.closed_loop.scenarios import SCENARIOS, rig_hexagon, run_scenario
    from depthguard.progress import track

    if scenario not in SCENARIOS:
        raise typer.BadParameter(f"unknown scenario {scenario!r}; choose one of {', '.join(SCENARIOS)}",
                                 param_hint="--scenario")
    if cameras not in ("all", "principal"):
        raise typer.BadParameter(f"must be 'all' or 'principal' (got {cameras!r})", param_hint="--cameras")
    fusion = "grid" if cameras == "all" else "single"
    if reaction is not None and reaction not in ("repulsion", "ssm", "both"):
        raise typer.BadParameter(f"must be repulsion, ssm or both (got {reaction!r})", param_hint="--reaction")
    if duration is not None and not duration > 0:
        raise typer.BadParameter("must be > 0 seconds", param_hint="--duration")
    if distance_hz is not None and not distance_hz > 0:
        raise typer.BadParameter("must be > 0 Hz", param_hint="--distance-hz")
    if camera_latency is not None and not (0.0 <= camera_latency < 1.0):
        raise typer.BadParameter("must be >= 0 and below 1 second", param_hint="--camera-latency")
    centre = None if hexagon_centre is None else parse_vector3(hexagon_centre, "--hexagon-centre")
    if hexagon_radius is not None and not hexagon_radius > 0:
        raise typer.BadParameter("must be > 0 m", param_hint="--hexagon-radius")
    the_rig, the_cell = load_rig_or_cell(rig, cell, default="flacco-cell", simulate=True)
    if the_rig.robot is None:
        raise ValueError(f"{rig if rig is not None else the_cell.name}: the rig has no robot to drive "
                         f"(add a robot: section)")
    # the rig's monitor: reaction unless --reaction is given (issue 33 item 6: the option's default won)
    reaction_from = "--reaction" if reaction is not None else "the rig's monitor: reaction"
    reaction = reaction if reaction is not None else the_rig.monitor.reaction
    if not quiet:
        typer.echo(f"run: reaction {reaction} (from {reaction_from})", err=True)
    cfg = LoopConfig(fusion=fusion, noise=not no_noise, distance_hz=distance_hz, camera_latency=camera_latency,
                     reaction=reaction)
    paper_task = rig is None and the_cell.name == "flacco-cell"
    if not paper_task or centre is not None or hexagon_radius is not None:
        if paper_task:   # the paper's hexagon, with the centre or radius the user set
            centre = cfg.hexagon.center if centre is None else centre
            hexagon_radius = cfg.hexagon.radius if hexagon_radius is None else hexagon_radius
        cfg = dataclasses.replace(cfg, hexagon=rig_hexagon(the_cell, centre=centre, radius=hexagon_radius))

    def progress(it, total):
        return track(it, f"scenario {scenario}", total=total, quiet=quiet)

    summary, res = run_scenario(scenario, out=out, duration=duration, seed=seed, config=cfg,
                                cell=the_cell.name if rig is None else the_cell, progress=progress)
    import json

    summary = dict(summary, reaction=reaction, reaction_from=reaction_from)
    typer.echo(_one_line(summary))
    if reaction != "repulsion":                     # R33: the SSM's figures, also in summary.json
        from depthguard.evaluation.ssm_compare import row_of
        row = row_of(summary, res, reaction)
        summary = dict(summary, ssm_compare=row)
        typer.echo(f"SSM: task progress {row['progress']:.2f}, protective stops {row['protective_stops']}, "
                   f"time stopped {row['time_stopped_s']:.2f} s, SSM violations {row['ssm_violations']} "
                   f"(with Z_d {row['ssm_violations_with_Z_d']})")
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    typer.echo(f"wrote {out}/summary.json and plots")


def _one_line(s: dict) -> str:
    rms = s["ee_tracking_rms_m"]
    dyn = s.get("min_true_distance_dynamic_m")
    parts = [f"{s['scenario']} ({s['reaction']}, from {s['reaction_from']}): min true distance {s['min_true_distance_m'] * 100:.1f} cm"
             + ("" if dyn is None else f" (to moving obstacles {dyn * 100:.1f} cm)"),
             "COLLISION" if s["collision"] else "no collision",
             f"EE tracking RMS {rms * 1000:.1f} mm" if rms is not None else "EE tracking RMS n/a",
             f"{s['avoidance_rate_hz']:.0f} Hz avoidance", f"real-time factor {s['real_time_factor']:.2f}"]
    if s["safe_stops"]:
        parts.append("safe stops: " + "; ".join(st["reason"] for st in s["safe_stops"]))
    return ", ".join(parts)
