"""The ``depthguard`` typer application; command modules attach to :data:`app`."""

from __future__ import annotations

import typer

app = typer.Typer(
    name="depthguard",
    help="Depth cameras watching a robot cell: distances, fusion, free space, reactions.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
