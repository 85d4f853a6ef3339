"""The ``depthguard`` typer application; command modules attach to :data:`app`.

``depthguard --version`` prints the installed version. In ``--help`` an on/off flag
(``--json``, ``--help``) shows no value placeholder: typer writes ``<bool>`` beside
every flag, which reads as if the flag took a value; :class:`DepthguardGroup`
blanks it for every command and sub-command, wherever they are registered.
"""

from __future__ import annotations

from typing import Optional

import typer
from typer.core import TyperGroup

__all__ = ["app", "rig_app", "DepthguardGroup", "version_text"]


def _plain_flags(command, ctx) -> None:
    """Give the on/off flags of ``command`` (and of its sub-commands) an empty metavar."""
    params = list(getattr(command, "params", []))
    if hasattr(command, "get_help_option"):
        help_option = command.get_help_option(ctx)
        if help_option is not None:
            params.append(help_option)
    for param in params:
        if getattr(param, "is_flag", False) and param.metavar is None:
            param.metavar = ""
    for sub in getattr(command, "commands", {}).values():
        _plain_flags(sub, ctx)


class DepthguardGroup(TyperGroup):
    """The top-level group: every command it hands out lists its flags without ``<bool>``."""

    def get_command(self, ctx, cmd_name):
        command = super().get_command(ctx, cmd_name)
        if command is not None:
            _plain_flags(command, ctx)
        return command

    def format_help(self, ctx, formatter) -> None:
        _plain_flags(self, ctx)
        super().format_help(ctx, formatter)


def version_text() -> str:
    """``"depthguard X.Y.Z"``: the installed distribution's version (the package's own if not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        v = version("depthguard")
    except PackageNotFoundError:
        from depthguard import __version__ as v
    return f"depthguard {v}"


app = typer.Typer(
    name="depthguard",
    cls=DepthguardGroup,
    help="Depth cameras watching a robot cell: distances, fusion, free space, reactions.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _print_version(value: bool) -> None:
    if value:
        typer.echo(version_text())
        raise typer.Exit()


#: ``depthguard rig ...``: rig files drafted from recordings and devices (``from-bag``, ``from-realsense``)
rig_app = typer.Typer(help="Rig files drafted from recordings and devices: ROS 2 bags, RealSense.",
                      no_args_is_help=True)
app.add_typer(rig_app, name="rig")


@app.callback()
def _root(
    version: Optional[bool] = typer.Option(None, "--version", is_eager=True, callback=_print_version,
                                           help="Print the version and exit."),
) -> None:
    """Depth cameras watching a robot cell: distances, fusion, free space, reactions."""
