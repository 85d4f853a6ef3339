"""What every command that works on a cell shares: ``--rig FILE`` or ``--cell NAME`` (R2).

A user simulates and checks their own cell, not only the built-in ones: each
such command takes a rig file (``--rig``, format in ``docs/ARCHITECTURE.md``)
or a built-in cell (``--cell``, :func:`depthguard.sim.list_cells`), never both.
:func:`load_rig_or_cell` is the one place that turns the two options into a
rig and, where a command simulates, a :class:`~depthguard.sim.cells.Cell`.

Errors are ``ValueError`` s (a :class:`~depthguard.rig.RigError` for a missing
or invalid rig file), which ``depthguard.cli.main`` prints as one line and
exit status 2.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

__all__ = ["load_rig_or_cell", "parse_vector3", "check_output_dir", "in_range"]


def load_rig_or_cell(rig: Optional[Path], cell: Optional[str], default: Optional[str] = "flacco-cell",
                     simulate: bool = False):
    """``(Rig, Cell or None)`` from ``--rig FILE`` or ``--cell NAME`` (R2).

    - ``--rig`` and ``--cell`` together: ``ValueError`` (one line, exit 2 from the CLI);
    - ``--rig FILE``: the validated rig (``RigError``, a ``ValueError``, names the file and the
      field). The cell is ``None``, or with ``simulate`` the rig's own scene
      (:func:`depthguard.sim.cells.cell_from_rig`: its static objects, the robot at its rig
      joints, no people);
    - ``--cell NAME``: the built-in cell and its rig (``ValueError`` listing the cells if unknown);
    - neither: the built-in ``default`` cell, or ``ValueError`` when ``default`` is None.
    """
    if rig is not None and cell is not None:
        raise ValueError(f"give --rig FILE or --cell NAME, not both (got --rig {rig} and --cell {cell})")
    if rig is not None:
        from depthguard.rig import Rig

        the_rig = Rig.load(rig)
        if not simulate:
            return the_rig, None
        from depthguard.sim.cells import cell_from_rig
        return the_rig, cell_from_rig(the_rig)
    name = cell or default
    if name is None:
        raise ValueError("give --rig FILE (your cell) or --cell NAME (a built-in cell, see `depthguard scenes list`)")
    from depthguard.sim import load_cell

    the_cell = load_cell(name)
    return the_cell.rig, the_cell


def parse_vector3(text: str, option: str) -> tuple[float, float, float]:
    """``"X,Y,Z"`` (metres) as three finite floats; ``ValueError`` naming ``option`` otherwise."""
    import math

    parts = [p.strip() for p in str(text).split(",")]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise ValueError(f"{option}: expected three numbers X,Y,Z in metres (got {text!r})")
    return values


def check_output_dir(out: Path, option: str = "--out") -> Path:
    """``out`` as a folder the command can write, checked before any work is done.

    Creates the folder (and its parents) if needed and writes and removes one
    uniquely named probe file in it, so that nothing already stored there is touched.
    ``ValueError`` naming ``option`` and the folder when it is a file, lies under a
    file (``/dev/null/x``), or cannot be created or written.
    """
    import os
    import tempfile

    p = Path(out)
    if p.exists() and not p.is_dir():
        raise ValueError(f"{option} {p}: is a file, not a folder (give a folder for the results)")
    try:
        p.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".depthguard-write-check-", dir=p)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise ValueError(f"{option} {p}: cannot write results there ({reason})") from None
    return p


def in_range(lo: int, hi: int):
    """A typer callback: the option's integer within ``lo..hi`` (None passes), else a usage
    error naming the option. The option's help says the range: typer's own ``min=`` /
    ``max=`` print it beside the type (``<int range> [0<=x<=65535]``), which widened the
    type column of a whole ``--help`` and cut the other options' texts short at 80 columns."""

    def check(param: typer.CallbackParam, value: Optional[int]) -> Optional[int]:
        if value is not None and not lo <= value <= hi:
            raise typer.BadParameter(f"must be {lo} to {hi}, got {value}", param_hint=param.opts[0])
        return value

    return check
