"""``depthguard demo``: the ``make demo`` job — the closed-loop human–robot cell (issue 5).

Runs the LWR's hexagon task on ``flacco-cell`` closing the loop through the
simulated Kinect (30 Hz, noise model, robot removed by rendering) with the
reactions of Flacco 2014 §5 at 500 Hz, for scenarios ``reach`` (a person
reaches for the end effector, fig. 14) and ``elbow`` (an obstacle on the
elbow's path, fig. 16); prints a summary table and writes one report folder
per scenario (``summary.json`` + plots). Then the contact sheets of
``flacco-cell`` (:func:`render_contact_sheets`, issue 2 §9) for a look at the
cell. :func:`render_contact_sheets` stays callable on its own.
"""

from __future__ import annotations

import json
from pathlib import Path

import typer

from depthguard.cli.app import app

DEMO_SCENARIOS = {"reach": 8.0, "elbow": 10.0}     # simulated seconds (the scenarios' defaults)


def render_contact_sheets(out: Path, seed: int = 0, noiseless: bool = False,
                          cells: list[str] | None = None) -> list[Path]:
    """Contact sheets of every built-in cell at each of its situations, under ``out/<cell>/<situation>/``.

    Returns the contact-sheet paths.
    """
    from depthguard.cli.scenes import render_cell
    from depthguard.progress import log, track
    from depthguard.sim import list_cells, load_cell

    names = cells or list_cells()
    jobs = []
    for name in names:
        cell = load_cell(name)
        for sit in cell.situations.values():
            jobs.append((cell, sit))
    sheets = []
    for cell, sit in track(jobs, "demo: rendering the built-in cells"):
        res = render_cell(cell, sit.time, Path(out) / cell.name / sit.name, noiseless=noiseless, seed=seed,
                          title=f"{cell.name}  [{sit.name}]  t = {sit.time:g} s — {sit.description}", quiet=True)
        sheets.append(res["sheet"])
    log(f"demo: wrote {len(sheets)} contact sheets under {out}")
    return sheets


def _fmt_cm(x):
    return "n/a" if x is None else f"{x * 100:.1f}"


def summary_table(summaries: list[dict], fusion: str = "grid"):
    """The demo's rich table from the scenarios' summaries (as in OUT/summary.json)."""
    from rich.table import Table

    table = Table(title=f"depthguard demo: closed loop on flacco-cell (LWR, hexagon at 0.4 m/s, "
                        f"{'principal Kinect' if fusion == 'single' else 'two Kinects, depth grid'}, 500 Hz)")
    for col in ("scenario", "min dist\n(cm)", "collision", "EE RMS\nclear (mm)", "EE RMS\nall (mm)",
                "max rep.\n(m/s)", "min task\nscale", "safe\nstops", "avoidance\n(Hz)", "RTF\nall", "RTF\nmonitor"):
        table.add_column(col, overflow="fold")
    for s in summaries:
        rms = s["ee_tracking_rms_m"]
        table.add_row(s["scenario"], _fmt_cm(s["min_true_distance_dynamic_m"] if "min_true_distance_dynamic_m" in s
                                            else s["min_true_distance_m"]),
                      "YES" if s["collision"] else "no",
                      "n/a" if rms is None else f"{rms * 1000:.2f}", f"{s['ee_tracking_rms_all_m'] * 1000:.1f}",
                      f"{s['ee_max_repulsion_m_s']:.2f}", f"{s['min_task_scale']:.2f}",
                      str(len(s["safe_stops"])), f"{s['avoidance_rate_hz']:.0f}",
                      f"{s['real_time_factor']:.2f}", f"{s['real_time_factor_system']:.2f}")
    table.caption = ("min dist: true distance robot <-> people and props; EE RMS clear: tracking error while "
                     "nothing is within rho; RTF all: real-time factor (simulated s per wall s) of "
                     "the simulator (cameras, noise, people) and the monitor together in one process; RTF "
                     "monitor: of the monitor's own share (distances, robot removal, reaction)")
    return table


@app.command()
def demo(
    out: Path = typer.Option(Path("out/demo"), "--out", help="Output directory."),
    seed: int = typer.Option(0, "--seed", help="Seed of the simulated sensor noise."),
    noiseless: bool = typer.Option(False, "--noiseless", help="Exact rendered depth, no sensor noise."),
    cameras: str = typer.Option("all", "--cameras", help="all: both Kinects through the depth grid map (R12, Flacco 2015); principal: the principal Kinect only (Flacco 2014)."),
    sheets: bool = typer.Option(True, "--sheets/--no-sheets", help="Also write flacco-cell's contact sheets."),
) -> None:
    """The closed-loop human-robot cell: scenarios reach and elbow on flacco-cell, a summary table, reports.

    About 1 min on a 2-core machine (2 min the first time: numba compiles the kernels). Each scenario writes
    OUT/<scenario>/summary.json and plots (end-effector path, distances of
    every control point, repulsive velocity); OUT/summary.json holds both.
    """
    from rich.console import Console

    from depthguard.evaluation.closed_loop.loop import LoopConfig
    from depthguard.evaluation.closed_loop.scenarios import run_scenario
    from depthguard.progress import track

    if cameras not in ("all", "principal"):
        raise typer.BadParameter(f"must be 'all' or 'principal' (got {cameras!r})", param_hint="--cameras")
    fusion = "grid" if cameras == "all" else "single"
    out = Path(out)
    cfg = LoopConfig(fusion=fusion, noise=not noiseless)
    # compile every kernel of the loop (numba caches them on disk) before any clock starts: the
    # table's real-time factors never include compilation, on a fresh clone either
    run_scenario(next(iter(DEMO_SCENARIOS)), duration=0.1, seed=seed, config=cfg, write=False)
    summaries = []
    for name, dur in DEMO_SCENARIOS.items():
        def progress(it, total, name=name):
            return track(it, f"demo: closed loop, scenario {name} ({dur:g} s simulated)", total=total)
        s, _ = run_scenario(name, out=out / name, duration=dur, seed=seed, config=cfg, progress=progress)
        summaries.append(s)
    (out / "summary.json").write_text(json.dumps(summaries, indent=2))

    Console(width=120).print(summary_table(summaries, fusion))
    if sheets:
        render_contact_sheets(out / "cells", seed=seed, noiseless=noiseless, cells=["flacco-cell"])
    typer.echo(f"wrote {out}/<scenario>/summary.json, ee_path.png, distances.png, repulsion.png, snapshots.png")
