"""``depthguard run --scenario NAME --out DIR``: one closed-loop scenario (R13–R15, R27)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from depthguard.cli.app import app


def _scenario_help() -> str:
    from depthguard.control.scenarios import SCENARIOS
    return "; ".join(f"{k}: {v}" for k, v in SCENARIOS.items())


@app.command("run")
def run(
    scenario: str = typer.Option(..., "--scenario", "-s", help="Scenario name: reach, plate, elbow, shadow, camera_dropout, empty."),
    out: Path = typer.Option(..., "--out", "-o", help="Report folder: summary.json and plots."),
    duration: Optional[float] = typer.Option(None, "--duration", help="Simulated seconds (default: the scenario's)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the cameras' noise."),
    cameras: str = typer.Option("all", "--cameras", help="all: every camera of the rig fused by the depth grid map (R12, Flacco 2015); principal: the principal camera only (Flacco 2014), the one-camera comparison."),
    distance_hz: Optional[float] = typer.Option(None, "--distance-hz", help="Rate of the distance computation (default: every 500 Hz control cycle, R15)."),
    no_noise: bool = typer.Option(False, "--no-noise", help="Ideal depth images (no sensor noise)."),
    camera_latency: Optional[float] = typer.Option(None, "--camera-latency", help="Seconds from a frame's capture to its delivery (default: one camera period; 0: each frame is used in the cycle it is captured)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress output."),
) -> None:
    """Run the LWR's hexagon task on flacco-cell with a scenario's obstacles, closing the loop.

    Cameras at 30 Hz with their noise model (each frame delivered one camera
    period after its capture), distances and reactions at every
    500 Hz control cycle (repulsion at the end effector, joint-velocity limits
    for the other control points, SNS), safe stop on stale frames. Writes
    DIR/summary.json (min_true_distance_m, collision, ee_tracking_rms_m,
    avoidance_rate_hz, real_time_factor, safe_stops ...) and plots.
    """
    from depthguard.control.loop import LoopConfig
    from depthguard.control.scenarios import SCENARIOS, run_scenario
    from depthguard.progress import track

    if scenario not in SCENARIOS:
        raise typer.BadParameter(f"unknown scenario {scenario!r}; choose one of {', '.join(SCENARIOS)}",
                                 param_hint="--scenario")
    if cameras not in ("all", "principal"):
        raise typer.BadParameter(f"must be 'all' or 'principal' (got {cameras!r})", param_hint="--cameras")
    fusion = "grid" if cameras == "all" else "single"
    if duration is not None and not duration > 0:
        raise typer.BadParameter("must be > 0 seconds", param_hint="--duration")
    if distance_hz is not None and not distance_hz > 0:
        raise typer.BadParameter("must be > 0 Hz", param_hint="--distance-hz")
    if camera_latency is not None and not (0.0 <= camera_latency < 1.0):
        raise typer.BadParameter("must be >= 0 and below 1 second", param_hint="--camera-latency")
    cfg = LoopConfig(fusion=fusion, noise=not no_noise, distance_hz=distance_hz, camera_latency=camera_latency)

    def progress(it, total):
        return track(it, f"scenario {scenario}", total=total, quiet=quiet)

    summary, _ = run_scenario(scenario, out=out, duration=duration, seed=seed, config=cfg, progress=progress)
    typer.echo(_one_line(summary))
    typer.echo(f"wrote {out}/summary.json and plots")


def _one_line(s: dict) -> str:
    rms = s["ee_tracking_rms_m"]
    dyn = s.get("min_true_distance_dynamic_m")
    parts = [f"{s['scenario']}: min true distance {s['min_true_distance_m'] * 100:.1f} cm"
             + ("" if dyn is None else f" (to moving obstacles {dyn * 100:.1f} cm)"),
             "COLLISION" if s["collision"] else "no collision",
             f"EE tracking RMS {rms * 1000:.1f} mm" if rms is not None else "EE tracking RMS n/a",
             f"{s['avoidance_rate_hz']:.0f} Hz avoidance", f"real-time factor {s['real_time_factor']:.2f}"]
    if s["safe_stops"]:
        parts.append("safe stops: " + "; ".join(st["reason"] for st in s["safe_stops"]))
    return ", ".join(parts)
