"""``depthguard reproduce flacco2015``: the depth grid map on the flacco-cell (SPEC §3, R10–R12)."""

from __future__ import annotations

from pathlib import Path

import typer

from depthguard.cli.reproduce import reproduce_app
from depthguard.evaluation.flacco2015 import PAPER_DELTA_D, PAPER_RHO


@reproduce_app.command("flacco2015")
def flacco2015_cmd(
    out: Path = typer.Option(Path("out/flacco2015"), "--out", help="Output directory for the plots and table.md."),
    rho: float = typer.Option(PAPER_RHO, "--rho", help="Radius of surveillance, metres (paper: 0.4)."),
    padding: float = typer.Option(0.05, "--padding", help="Padding of the robot's capsules (self volume), metres."),
    delta_d: float = typer.Option(PAPER_DELTA_D, "--delta-d", help="Depth slice of the grid, metres (paper: 0.01)."),
) -> None:
    """Flacco & De Luca 2015 figs. 8/12 and 9/13 on the flacco-cell: shadow, hidden hand, robot alone.

    Compares one camera (the paper's one-camera method) with the depth grid of
    two cameras for the LWR's 9 control points, against the exact ground
    truth; writes one plot per situation (cam0 view with distance lines, and
    distances per control point) and table.md.
    """
    import numpy as np

    from depthguard.evaluation.flacco2015 import run_flacco2015, table, write_outputs

    if not (0 < rho <= 2.0):
        raise typer.BadParameter(f"rho must lie in (0, 2] m, got {rho}", param_hint="--rho")
    if not (0 <= padding <= 0.3):
        raise typer.BadParameter(f"padding must lie in [0, 0.3] m, got {padding}", param_hint="--padding")
    if not (0.001 <= delta_d <= 0.2):
        raise typer.BadParameter(f"delta-d must lie in [0.001, 0.2] m, got {delta_d}", param_hint="--delta-d")
    from depthguard.cli.common import check_output_dir

    check_output_dir(out)      # before any work is done
    res = run_flacco2015(rho=rho, padding=padding, delta_d=delta_d, quiet=False)
    files = write_outputs(res, out)
    typer.echo(table(res, rho))
    s, h, a = res["shadow"], res["hidden_hand"], res["robot_alone"]
    lines = [
        f"shadow: 1 camera min {np.min(s.one):.3f} m (truth min {np.min(s.truth):.3f}); "
        f"2 cameras (paper) phantom-free: {bool(np.all(s.two_paper >= s.truth - s.eps))}; "
        f"2 cameras (R9) min {np.min(s.two):.3f} m",
        f"hidden hand: 1 camera min {np.min(h.one):.3f} m, 2 cameras min {np.min(h.two):.3f} m, "
        f"truth min {np.min(h.truth):.3f} m",
        f"robot alone: phantom-free (reported >= truth - eps): 2 cameras {bool(np.all(a.two >= a.truth - a.eps))}",
    ]
    for ln in lines:
        typer.echo(ln)
    typer.echo(f"wrote {len(files)} files to {out}")
