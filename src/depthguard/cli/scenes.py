"""``depthguard scenes``: list the built-in cells and render the cameras of a cell or of a user's
rig file (``--rig``, R2) to depth PNGs."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from depthguard.cli.app import app

scenes_app = typer.Typer(help="The simulated cells: list the built-in ones, render the depth cameras of one or of your rig file.",
                         no_args_is_help=True)
app.add_typer(scenes_app, name="scenes")


def render_cell(cell, t: float, out: Path, noiseless: bool = False, seed: int = 0, title: str = "",
                quiet: bool = False) -> dict:
    """Render every camera of ``cell`` at scene time ``t`` into ``out``.

    Writes ``<camera>.png`` (16-bit millimetres, 0 = no measurement) per camera and
    ``contact_sheet.png``. Returns ``{"depths": {id: (H, W) float32}, "files": [Path], "sheet": Path}``.
    """
    from depthguard.depth_io import write_depth
    from depthguard.progress import track
    from depthguard.sources.simulated import SimulatedCamera
    from depthguard.viz.contact_sheet import contact_sheet

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    meshes, _ = cell.scene.meshes_at(t)
    depths, files = {}, []
    for cam in track(cell.rig.cameras, f"{cell.name}: rendering {len(cell.rig.cameras)} cameras", quiet=quiet):
        d = SimulatedCamera(cam, seed=seed, noiseless=noiseless).capture(meshes, stamp=t)
        depths[cam.id] = d
        files.append(write_depth(out / f"{cam.id}.png", d))
    sheet = contact_sheet(depths, out / "contact_sheet.png",
                          title=title or f"{cell.name}  t = {t:.2f} s" + ("  (noiseless)" if noiseless else ""))
    return {"depths": depths, "files": files, "sheet": sheet}


@scenes_app.command("list")
def list_cmd() -> None:
    """List the built-in cells: name, cameras, robot, situations and description."""
    from rich.console import Console
    from rich.table import Table

    from depthguard.sim import list_cells, load_cell

    table = Table(title="built-in cells")
    for col in ("name", "cameras", "robot", "situations", "description"):
        table.add_column(col, overflow="fold")
    for name in list_cells():
        cell = load_cell(name)
        cams = cell.rig.cameras
        sensors = sorted({c.sensor or "?" for c in cams})
        robot = cell.robot
        rname = "-" if robot is None else getattr(robot, "name", type(robot).__name__)
        sits = ", ".join(f"{s.name}@{s.time:g}s" for s in cell.situations.values())
        table.add_row(name, f"{len(cams)} x {'/'.join(sensors)} {cams[0].width}x{cams[0].height}", rname, sits,
                      cell.description)
    Console(width=160).print(table)


@scenes_app.command("render")
def render_cmd(
    name: Optional[str] = typer.Argument(None, help="Built-in cell (see `depthguard scenes list`); or give --rig."),
    out: Path = typer.Option(..., "--out", help="Directory for <camera>.png and contact_sheet.png."),
    rig: Optional[Path] = typer.Option(None, "--rig", help="Your rig file (YAML): its static objects and its robot at "
                                       "its rig joints, seen by its cameras (instead of a built-in cell)."),
    time: Optional[float] = typer.Option(None, "--time", help="Scene time in seconds (default: 0, or the situation's)."),
    situation: Optional[str] = typer.Option(None, "--situation", help="A named situation of the cell (sets the time)."),
    noiseless: bool = typer.Option(False, "--noiseless", help="Exact rendered depth (only the valid range applies)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the sensor noise."),
) -> None:
    """Render every camera of a cell or rig file (R2): 16-bit millimetre depth PNGs and a colour contact sheet.

    A rig file's scene holds still: its static objects and the robot at its rig
    joints, no people, no situations.
    """
    from depthguard.cli.common import load_rig_or_cell

    if name is None and rig is None:
        raise ValueError("give a built-in cell NAME (see `depthguard scenes list`) or --rig FILE")
    if name is not None and rig is not None:
        raise ValueError(f"give a built-in cell NAME or --rig FILE, not both (got {name} and --rig {rig})")
    _, cell = load_rig_or_cell(rig, name, default=None, simulate=True)
    label = cell.name if rig is None else f"{cell.name} ({rig})"
    if situation is not None:
        _, t_sit = cell.scene_for(situation)
        if time is not None and abs(time - t_sit) > 1e-9:
            raise typer.BadParameter(f"give --time or --situation, not both ({situation} is at t = {t_sit:g} s)",
                                     param_hint="--time")
        t = t_sit
    else:
        t = 0.0 if time is None else time
    if not (t == t) or t < 0:
        raise typer.BadParameter(f"time must be >= 0 (got {t})", param_hint="--time")
    from depthguard.cli.common import check_output_dir

    check_output_dir(out)      # before any work is done
    res = render_cell(cell, t, out, noiseless=noiseless, seed=seed,
                      title=f"{label}  t = {t:.2f} s" + (f"  [{situation}]" if situation else "")
                      + ("  (noiseless)" if noiseless else ""))
    typer.echo(f"wrote {len(res['files'])} depth PNGs and {res['sheet']}")
