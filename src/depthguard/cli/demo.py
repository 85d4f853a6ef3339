"""``depthguard demo``: the ``make demo`` job.

For now: render every built-in cell at its situations and write the contact
sheets (issue 2 §9). Later the closed-loop run joins (issue 5);
:func:`render_contact_sheets` stays callable on its own.
"""

from __future__ import annotations

from pathlib import Path

import typer

from depthguard.cli.app import app


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


@app.command()
def demo(
    out: Path = typer.Option(Path("out/demo"), "--out", help="Output directory."),
    seed: int = typer.Option(0, "--seed", help="Seed of the simulated sensor noise."),
    noiseless: bool = typer.Option(False, "--noiseless", help="Exact rendered depth, no sensor noise."),
) -> None:
    """Render the built-in cells (every situation) and write their contact sheets (the `make demo` job)."""
    sheets = render_contact_sheets(out, seed=seed, noiseless=noiseless)
    typer.echo(f"wrote {len(sheets)} contact sheets under {out}")
