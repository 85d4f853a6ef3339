"""``depthguard check-path``: is my next motion free? A planned path against the runtime's free-space map (R22, R37).

Exit status: 0 every segment safe; :data:`EXIT_MAYBE` (3) some segment touches unknown space and
none occupied space; :data:`EXIT_UNSAFE` (4) some segment meets occupied space; 2 a usage error
or bad input (one line on stderr) — never mistaken for a verdict.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import List, Optional

import numpy as np
import typer

from depthguard.cli.app import app

__all__ = ["EXIT_MAYBE", "EXIT_UNSAFE", "read_path_csv", "check_path_cmd"]

EXIT_MAYBE = 3
EXIT_UNSAFE = 4


def read_path_csv(path: Path, robot) -> tuple[np.ndarray, np.ndarray]:
    """A path file: header ``stamp,<joint 1>,...,<joint dof>`` (names free, like the joints CSV),
    then one waypoint per row, stamps in s, joints in rad. Returns ``(stamps (n,), q (n, dof))``;
    ``ValueError`` naming the file and line, or the waypoint (0-based) for a bad path."""
    from depthguard.control.path_check import validate_path

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"path file {p} does not exist")
    rows_t, rows_q = [], []
    with p.open(newline="") as fh:
        rows = csv.reader(fh)
        header = [h.strip() for h in next(rows, [])]
        if not header or header[0] != "stamp" or len(header) != robot.dof + 1:
            raise ValueError(f"{p}:1: the header must be stamp and {robot.dof} joint names for {robot.name} "
                             f"(got {header})")
        for line, row in enumerate(rows, start=2):
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) != robot.dof + 1:
                raise ValueError(f"{p}:{line}: waypoint {len(rows_t)}: {len(row) - 1} joints, "
                                 f"the robot {robot.name} has {robot.dof}")
            try:
                vals = [float(c) for c in row]
            except ValueError:
                raise ValueError(f"{p}:{line}: waypoint {len(rows_t)}: not a number in {row}") from None
            rows_t.append(vals[0])
            rows_q.append(vals[1:])
    if len(rows_t) < 2:
        raise ValueError(f"{p}: a path needs at least 2 waypoints, got {len(rows_t)}")
    try:
        return validate_path(np.array(rows_t), np.array(rows_q), robot)
    except ValueError as exc:
        raise ValueError(f"{p}: {exc}") from None


def feed(mon, sources, joint_source, settle: float, flush_timeout: float = 300.0) -> None:
    """Push ``settle`` s of joints and frames into ``mon`` at the camera rate, as fast as the monitor
    takes them (a frame once a joint state at or after its stamp is in, R30); no control steps."""
    dt = 1.0 / mon.config.camera_hz
    newest = -math.inf
    waiting: list = []
    k = 0
    while True:
        t = k * dt
        if t > settle + 1e-12:
            break
        for ts, qq in joint_source.states_until(t):
            if mon.push_joints(ts, qq):
                newest = max(newest, float(ts))
        for src in sources:
            waiting.extend(src.frames_until(t))
        due = [f for f in waiting if f.stamp <= newest or joint_source.done]
        waiting = [f for f in waiting if not (f.stamp <= newest or joint_source.done)]
        for f in due:
            mon.push_frame(f)
        if due:
            mon.flush(timeout=flush_timeout)
        k += 1


def _table(v) -> str:
    lines = [f"path: {v.verdict}" + ("" if v.first_not_safe is None else
                                      f" (first segment not safe: {v.first_not_safe})")
             + f"; {len(v.segments)} segments, {v.samples} samples, map at {v.map_stamp:.3f} s"]
    lines += ["  " + r for r in v.reasons()[:20]]
    if len(v.reasons()) > 20:
        lines.append(f"  ... {len(v.reasons()) - 20} more segments not safe")
    return "\n".join(lines)


@app.command("check-path")
def check_path_cmd(
    path: Path = typer.Option(..., "--path", help="The planned path: CSV stamp,q1..qn (s, rad), one waypoint a row, like the joints CSV."),
    rig: Optional[Path] = typer.Option(None, "--rig", help="Your rig file (YAML)."),
    cell: Optional[str] = typer.Option(None, "--cell", help="A built-in cell (default flacco-cell when no --rig)."),
    source: List[str] = typer.Option([], "--source", help="Frame source SCHEME:ARG as for `depthguard monitor`, repeatable (default: the cell's simulator)."),
    joints: Optional[str] = typer.Option(None, "--joints", help="Joint source as for `depthguard monitor` (default: sim with a sim source)."),
    settle: float = typer.Option(0.5, "--settle", help="Seconds of the sources run before the map is built (s, > 0)."),
    padding: Optional[float] = typer.Option(None, "--padding", help="Padding (m) on the robot's capsules (default: the rig's monitor robot_padding)."),
    voxel: Optional[float] = typer.Option(None, "--voxel", help="Voxel size (m) of the map (default: the rig's monitor free_space_voxel, 0.05)."),
    as_json: bool = typer.Option(False, "--json", help="Print the verdict as one JSON object."),
) -> None:
    """Is my next motion free? Run the sources for --settle seconds (as fast as they allow),
    build the free-space map of the workspace from their newest frames (robot removed at each
    frame's capture joints, the known scene as background, unknown kept unknown, R21), and judge
    the path's every segment (R22): safe (every voxel the swept padded robot touches is free),
    maybe (it touches unknown space) or unsafe (occupied space).

    Exit status: 0 when every segment is safe, 3 when the worst is maybe, 4 when a segment is
    unsafe; 2 is a usage error or bad input (a bad path names its waypoint).
    """
    from depthguard.cli.common import load_rig_or_cell
    from depthguard.progress import log
    from depthguard.runtime.monitor import Monitor, warm_up
    from depthguard.sources.base import check_source_spec, open_joints, open_source

    if not (math.isfinite(settle) and settle > 0):
        raise typer.BadParameter("must be > 0 seconds", param_hint="--settle")
    if padding is not None and not (math.isfinite(padding) and padding >= 0):
        raise typer.BadParameter("must be >= 0 m", param_hint="--padding")
    the_rig, the_cell = load_rig_or_cell(rig, cell)
    if the_rig.robot is None:
        raise ValueError(f"rig {the_rig.name!r} has no robot: a path needs one")
    stamps, q = read_path_csv(path, the_rig.robot)
    specs = list(source) or [f"sim:{the_cell.name}" if the_cell is not None else "sim"]
    schemes = [check_source_spec(s)[0] for s in specs]
    joint_spec = joints or ("sim" if "sim" in schemes else None) or next((s for s in specs if s.startswith("bag:")), None)
    if joint_spec is None:
        raise typer.BadParameter("a non-simulated source needs --joints (csv:FILE or zenoh:KEY)", param_hint="--joints")
    cfg = the_rig.monitor
    if voxel is not None:
        cfg = cfg.with_changes(free_space_voxel=voxel)
    context: dict = {"zenoh_listen": (cfg.zenoh_listen,), "zenoh_connect": ()}
    sources: list = []
    joint_source = mon = None
    try:
        for s in specs:
            sources.append(open_source(s, the_rig, context))
        joint_source = open_joints(joint_spec, the_rig, context)
        log("check-path: compiling kernels (once; cached on disk) ...")
        warm_up(the_rig, cfg)
        mon = Monitor(the_rig, cfg)
        feed(mon, sources, joint_source, settle)
        verdict = mon.check_path(stamps, q, padding=padding, fresh=True)
    finally:
        for s in sources:
            s.close()
        if joint_source is not None:
            joint_source.close()
        if mon is not None:
            mon.close()
    if as_json:
        print(json.dumps(verdict.as_dict()))
    else:
        print(_table(verdict))
    code = {"safe": 0, "maybe": EXIT_MAYBE, "unsafe": EXIT_UNSAFE}[verdict.verdict]
    raise typer.Exit(code)
