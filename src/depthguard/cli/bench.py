"""``depthguard bench``: the benchmark table beside the papers' numbers and peers."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer

from depthguard.cli.app import app


@app.command()
def bench(
    json_out: Optional[Path] = typer.Option(None, "--json", help="Also write the rows as a JSON list to this file."),
    only: Optional[list[str]] = typer.Option(None, "--only", help="Run only rows whose name starts with this (repeatable), e.g. render."),
    quick: bool = typer.Option(False, "--quick", help="Fewer repetitions: a smoke run, not figures to quote."),
    list_groups: bool = typer.Option(False, "--list", help="List the benchmark groups and exit."),
) -> None:
    """Measure speed: each figure beside the paper's number and a peer measured in the same run.

    Timings are medians (and worst cycles where the paper quotes worst cycles)
    after a warm-up that compiles every numba kernel.
    """
    from rich.console import Console
    from rich.table import Table

    from depthguard.evaluation import bench as bench_harness
    from depthguard.progress import log

    if list_groups:
        for name in bench_harness.load_groups():
            typer.echo(name)
        raise typer.Exit()
    ctx = bench_harness.BenchContext(quick=quick, repeats=5 if quick else 30, log=log)
    known = list(bench_harness.load_groups())
    for o in only or []:
        if not bench_harness.selected_groups([o], known):
            raise typer.BadParameter(f"no benchmark group matches {o!r}; groups: {', '.join(known)}", param_hint="--only")
    rows = bench_harness.run(only=only, ctx=ctx)
    table = Table(title="depthguard bench", caption=f"measured on {bench_harness.machine()}")
    for col in ("name", "value", "unit", "paper", "peer", "peer value", "note"):
        table.add_column(col, overflow="fold")

    def fmt(x):
        return "" if x is None else (f"{x:.4g}" if isinstance(x, float) else str(x))

    for r in rows:
        table.add_row(r.name, fmt(r.value), r.unit, fmt(r.paper), r.peer or "", fmt(r.peer_value), r.note)
    Console(width=160).print(table)
    if json_out is not None:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps([r.as_dict() for r in rows], indent=2))
        typer.echo(f"wrote {json_out}")
