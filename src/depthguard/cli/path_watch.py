"""``depthguard reproduce path-watch``: a person steps onto the path ahead of the moving robot; the
path watch against distances alone, one table (R37; issue 30)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer

from depthguard.cli.reproduce import reproduce_app


@reproduce_app.command("path-watch")
def path_watch_cmd(
    out: Optional[Path] = typer.Option(None, "--out", help="Also write OUT/table.md and OUT/path_watch.json."),
    seed: int = typer.Option(0, "--seed", help="Seed of the cameras' noise."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress output."),
) -> None:
    """The scenario 'a person steps onto the path ahead of the moving robot' on ur3-cell: the UR3
    runs a planned joint path (its shoulder pans 1.6 rad in 5.5 s); a person walks up to the table,
    puts a hand onto a later part of that path, holds it there for 4 s, then leaves. Run twice on
    the simulator (four D435 at 30 Hz, the runtime monitor at 500 Hz, the free-space map at 10 Hz
    of simulated time): with the rig's reactions (distances alone: repulsion, R13, R14), and with
    path_watch added and the path given to Monitor.watch_path.

    Prints one table from the simulator's ground truth (robot capsules to the person's surface):
    the minimum true separation, where the robot stopped, whether it stopped short of the person,
    from when the rest of the path was truly free of the person again, when the robot moved again,
    and how much of the path it did. About 3 min of CPU (10 s simulated per run).
    """
    from depthguard.evaluation.onto_path import compare, table
    from depthguard.progress import track

    if out is not None and out.exists() and not out.is_dir():
        raise typer.BadParameter(f"{out} exists and is not a folder", param_hint="--out")

    def progress(it, total, watch):
        return track(it, f"onto_path, {'path watch' if watch else 'distances alone'}", total=total, quiet=quiet)

    rows = compare(seed=seed, progress=progress)
    md = table(rows)
    typer.echo(md)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / "table.md").write_text(md + "\n")
        (out / "path_watch.json").write_text(json.dumps(rows, indent=2, default=str))
        typer.echo(f"wrote {out}/table.md and {out}/path_watch.json")
