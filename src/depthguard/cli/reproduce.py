"""``depthguard reproduce NAME``: the papers' experiments on the built-in cells.

Each reproduction registers itself on :data:`reproduce_app` from its own
command module (``cli/distance.py`` for flacco2014, ...).
"""

from __future__ import annotations

import typer

from depthguard.cli.app import app

reproduce_app = typer.Typer(
    help="Reproduce a paper's experiment on a built-in simulated cell: plots, a table, and checks.",
    no_args_is_help=True,
)
app.add_typer(reproduce_app, name="reproduce")
