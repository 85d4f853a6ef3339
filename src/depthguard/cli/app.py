"""The ``depthguard`` typer application; command modules attach to :data:`app`.

``depthguard --version`` prints the installed version. :class:`DepthguardGroup` shapes
every ``--help``, wherever the commands are registered:

- ``depthguard --help`` lists the commands by what they are for (:data:`OVERVIEW`:
  your cell, the distributed mode, the simulated cells and the papers, development),
  each with one line; a command's own ``--help`` keeps its whole text;
- the paragraphs of a command's text are reflowed (typer keeps the docstring's line
  breaks, which a terminal of another width shows as ragged lines); a paragraph with
  indented or bulleted lines is left as written;
- an on/off flag (``--json``, ``--help``) shows no value placeholder: typer writes
  ``<bool>`` beside every flag, which reads as if the flag took a value.
"""

from __future__ import annotations

import inspect
from typing import Optional

import typer
from typer.core import TyperGroup

__all__ = ["app", "rig_app", "DepthguardGroup", "OVERVIEW", "version_text"]


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


_CELL, _DIST, _SIM, _DEV = ("Your cell", "Distributed mode (R20, R35)", "Simulated cells and the papers",
                             "Development")

#: ``depthguard --help``: per top-level command its panel and one line, in the order listed
OVERVIEW: dict[str, tuple[str, str]] = {
    "monitor": (_CELL, "Frames and joints in, the robot's reaction out (R29)."),
    "check-path": (_CELL, "Is a planned path free? Verdict per segment (R22)."),
    "view": (_CELL, "A run or a recording in the browser, with a time slider."),
    "record": (_CELL, "Record what the sources deliver as a ROS 2 bag (R31)."),
    "rig": (_CELL, "Draft a rig file from a ROS 2 bag or a RealSense camera."),
    "calibrate": (_CELL, "Check and refine the camera poses on the scene (R34)."),
    "placement": (_CELL, "Camera placement; what no camera sees near the robot."),
    "distance": (_CELL, "Distances from points to what each camera sees (R3-R9)."),
    "server": (_DIST, "Run the fusion server of the camera units (R20)."),
    "node": (_DIST, "Run a camera unit: filter, send voxels to the server."),
    "status": (_DIST, "The server's view of every camera of the rig."),
    "keys": (_DIST, "Certificates: the cell's authority, nodes, admins."),
    "demo": (_SIM, "The closed-loop human-robot cell: reach and elbow."),
    "run": (_SIM, "One closed-loop run of a scenario, any cell or rig."),
    "safe-defaults": (_SIM, "The robot alone runs on; a dark person stops it (R32)."),
    "scenes": (_SIM, "The simulated cells: list them, render their cameras."),
    "reproduce": (_SIM, "Reproduce a paper's experiment: plots, a table, checks."),
    "calibration-study": (_SIM, "Random camera pose errors, refined back (R34)."),
    "bench": (_DEV, "Speed beside the papers' figures and a peer's."),
    "fuzz": (_DEV, "Fuzz every decoder and loader of outside input (R35)."),
    "soak": (_DEV, "Soak the distributed mode on loopback (R35)."),
    "warm-up": (_DEV, "Compile the kernels into numba's cache, in parallel."),
}


def _reflow(text: str | None) -> str | None:
    """``text`` with the line breaks inside each paragraph replaced by spaces, except in a
    paragraph with an indented or bulleted line (a list, an example) or typer's ``\\b``."""
    if not text:
        return text
    out = []
    for par in inspect.cleandoc(text).split("\n\n"):
        lines = par.split("\n")
        keep = par.startswith("\b") or any(ln[:1].isspace() or ln.lstrip()[:2] in ("- ", "* ")
                                              for ln in lines[1:])
        out.append(par if keep else " ".join(ln.strip() for ln in lines))
    return "\n\n".join(out)


def _shape_help(command) -> None:
    """Reflow the text of ``command`` and of its sub-commands (once)."""
    if getattr(command, "_depthguard_reflowed", False):
        return
    command.help = _reflow(command.help)
    command._depthguard_reflowed = True
    for sub in getattr(command, "commands", {}).values():
        _shape_help(sub)


class DepthguardGroup(TyperGroup):
    """The top-level group (module docstring): panels and one-line summaries in the overview,
    reflowed texts, flags without ``<bool>``."""

    def list_commands(self, ctx) -> list[str]:
        names = super().list_commands(ctx)
        order = list(OVERVIEW)
        return sorted(names, key=lambda n: order.index(n) if n in order else len(order))

    def get_command(self, ctx, cmd_name):
        command = super().get_command(ctx, cmd_name)
        if command is not None:
            _plain_flags(command, ctx)
            _shape_help(command)
            if cmd_name in OVERVIEW:
                command.rich_help_panel, command.short_help = OVERVIEW[cmd_name]
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
