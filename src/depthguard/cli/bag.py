"""``depthguard record`` (sources -> a ROS 2 bag) and ``depthguard rig from-bag`` (R31).

Formats and topics: ``docs/BAGS.md``.
"""

from __future__ import annotations

import signal
import threading
from pathlib import Path
from typing import List, Optional

import typer

from depthguard.cli.app import app, rig_app
from depthguard.cli.common import load_rig_or_cell


@app.command("record")
def record(
    out: Path = typer.Option(..., "--out", "-o", help="The new bag directory (must not exist): metadata.yaml + one .mcap with zstd chunks."),
    source: List[str] = typer.Option([], "--source", help="Frame source SCHEME:ARG, repeatable (sim:CELL[:...], images:DIR, bag:PATH). Default: the simulator of the cell."),
    joints: Optional[str] = typer.Option(None, "--joints", help="Joint source (sim, csv:FILE, zenoh:KEY, bag:PATH). Default: sim with a sim source, the bag with a bag: source."),
    rig: Optional[Path] = typer.Option(None, "--rig", help="Rig file (YAML) of your cell."),
    cell: Optional[str] = typer.Option(None, "--cell", help="A built-in cell (default flacco-cell when no --rig)."),
    duration: Optional[float] = typer.Option(None, "--duration", help="Seconds to record (needed for a source that never ends, such as the simulator)."),
    encoding: str = typer.Option("16UC1", "--encoding", help="Depth encoding: 16UC1 (millimetres, as ROS drivers publish) or 32FC1 (metres)."),
) -> None:
    """Record what the sources deliver as a ROS 2 bag (MCAP, zstd): per camera Image and CameraInfo,
    JointState, the camera poses on /tf_static (R31)."""
    from depthguard.progress import log
    from depthguard.sources.bag_record import BagRecorder, record_sources
    from depthguard.sources.base import open_joints, open_source

    if duration is not None and not duration > 0:
        raise typer.BadParameter("must be > 0 seconds", param_hint="--duration")
    if out.exists():
        raise ValueError(f"--out {out} exists already; a recording never overwrites one (choose a new name)")
    the_rig, the_cell = load_rig_or_cell(rig, cell)
    specs = list(source) or [f"sim:{the_cell.name}" if the_cell is not None else "sim"]
    if duration is None and any(s.split(":", 1)[0] == "sim" for s in specs):
        raise typer.BadParameter("the simulator never ends: give --duration S", param_hint="--duration")
    context: dict = {}
    sources = [open_source(s, the_rig, context) for s in specs]
    from depthguard.sources.sim_source import sim_world

    joint_spec = joints or ("sim" if sim_world(context) is not None else None) \
        or next((s for s in specs if s.startswith("bag:")), None)      # a bag holds its joint states too
    joint_source = open_joints(joint_spec, the_rig, context) if joint_spec else None
    stop = threading.Event()
    previous = signal.signal(signal.SIGINT, lambda *_: stop.set())
    try:
        with BagRecorder(out, the_rig, encoding=encoding) as rec:
            seconds = record_sources(rec, sources, joint_source, duration, dt=the_rig.monitor.dt, stop=stop,
                                     progress=lambda t: log(f"record: {t:.1f} s ..."))
            raw, frames, states, clipped = rec.raw_bytes, rec.frames, rec.states, rec.clipped
    finally:
        signal.signal(signal.SIGINT, previous)
        for s in sources:
            s.close()
        if joint_source is not None:
            joint_source.close()
    size = sum(f.stat().st_size for f in out.glob("*.mcap"))
    log(f"record: {seconds:.2f} s, {frames} frames, {states} joint states")
    if clipped:
        typer.echo(f"record: warning: {clipped} pixels beyond 65535 depth units (65.535 m in millimetres; "
                   f"less with a camera's smaller depth_scale) cannot be stored as 16UC1 and were written as 0 "
                   f"(no measurement); record with --encoding 32FC1 to keep them", err=True)
    typer.echo(f"record: wrote {out} ({size / 1e6:.1f} MB; the depth images raw would be {raw / 1e6:.1f} MB): "
               f"{frames} frames of {', '.join(the_rig.camera_ids)}, {states} joint states, camera poses on /tf_static")


@rig_app.command("from-bag")
def rig_from_bag(
    bag: Path = typer.Argument(..., help="A rosbag2 directory or an .mcap file."),
    out: Path = typer.Option(..., "--out", "-o", help="The rig file to write (must not exist)."),
    urdf: Optional[Path] = typer.Option(None, "--urdf", help="The robot's URDF (default: /robot_description of the bag)."),
    base_frame: Optional[str] = typer.Option(None, "--base-frame", help="The TF frame that is the rig's world (default: the root of the TF tree)."),
) -> None:
    """Draft a rig from a bag: cameras from CameraInfo and TF, the robot from /robot_description or
    --urdf; what cannot be decided is left as a commented field (R31)."""
    from depthguard.sources.rig_draft import draft_rig

    text, notes = draft_rig(bag, out, urdf=urdf, base_frame=base_frame)
    for n in notes:
        typer.echo(f"rig from-bag: {n}", err=True)
    typer.echo(f"rig from-bag: wrote {out}")
