"""``depthguard server``, ``depthguard node``, ``depthguard status``: the distributed
camera subsystem over zenoh (Oščádal 2022, R20). Every service binds 127.0.0.1
unless given other endpoints; multicast scouting is off unless ``--multicast``."""

from __future__ import annotations

import json
import signal
import threading
import time
from pathlib import Path
from typing import Optional

import typer

from depthguard.cli.app import app

_DEFAULT = "tcp/127.0.0.1:7447"


def _load_rig(rig: Optional[Path], cell: Optional[str]):
    """``(Rig, built-in Cell or None)``: :func:`depthguard.cli.common.load_rig_or_cell`, no default cell."""
    from depthguard.cli.common import load_rig_or_cell
    return load_rig_or_cell(rig, cell, default=None)


def _stop_event() -> threading.Event:
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    return stop


@app.command("server")
def server_cmd(
    rig: Optional[Path] = typer.Option(None, "--rig", help="Rig YAML: the camera ids allowed to join."),
    cell: Optional[str] = typer.Option(None, "--cell", help="A built-in cell instead of --rig (e.g. ur3-cell)."),
    listen: list[str] = typer.Option([_DEFAULT], "--listen", help="Zenoh endpoint(s) to listen on."),
    connect: list[str] = typer.Option([], "--connect", help="Zenoh endpoint(s) to connect to."),
    prefix: str = typer.Option("depthguard", "--prefix", help="Key prefix of the services."),
    voxel_size: float = typer.Option(0.02, "--voxel-size", help="Voxel size in metres (0.01-0.1)."),
    threshold: float = typer.Option(0.55, "--threshold", help="Voxel density threshold (R19)."),
    stale: float = typer.Option(0.5, "--stale", help="A unit whose last update is older than this (s) is stale."),
    sim_time: Optional[float] = typer.Option(None, "--sim-time", help="With --cell: robot joints from the scene at "
                                             "this time (the fixed pose at which nodes without --joints remove "
                                             "the robot)."),
    multicast: bool = typer.Option(False, "--multicast", help="Enable zenoh multicast scouting."),
    every: float = typer.Option(5.0, "--every", help="Log the status every this many seconds (0 = never)."),
    duration: float = typer.Option(0.0, "--duration", help="Stop after this many seconds (0 = run until Ctrl-C)."),
    centralised: bool = typer.Option(False, "--centralised", help="With --cell: filter every simulated camera in "
                                     "this process (the centralised mode, for comparison) instead of waiting for nodes."),
    fps: float = typer.Option(15.0, "--fps", help="Centralised mode: scene refreshes per second."),
) -> None:
    """Run the fusion server (main unit): registry, freshness, global voxel map (R20).

    With --centralised the same pipeline runs for every camera in this one process
    (all images into one place), and the status reports it the same way."""
    from depthguard.distributed import wire as W
    from depthguard.distributed.server import FusionServer
    from depthguard.progress import log

    r, c = _load_rig(rig, cell)
    joints = ()
    if r.robot is not None:
        q = c.scene.robot_q(sim_time) if (c is not None and sim_time is not None) else r.robot_q0
        joints = tuple(float(x) for x in (q if q is not None else []))
    settings = W.Settings(voxel_size=voxel_size, threshold=threshold, stale_s=stale, joints=joints)
    try:
        settings.check()
    except W.WireError as exc:
        raise ValueError(str(exc)) from None
    stop = _stop_event()
    srv = FusionServer(r.camera_ids, settings, listen=listen, connect=connect, prefix=prefix,
                       multicast=multicast, log=log)
    srv.start()
    log(f"server on {', '.join(listen)} for cameras {', '.join(r.camera_ids)}")
    t0 = time.monotonic()
    central = None
    if centralised:
        if c is None:
            raise typer.BadParameter("--centralised needs --cell (simulated cameras)", param_hint="--centralised")
        from depthguard.distributed.central import CentralisedPipeline
        from depthguard.sources import SimSource

        t_sim = sim_time if sim_time is not None else 0.0
        frames = {cid: f.depth for cid, f in SimSource(c, seed=0).frames(t_sim).items()}
        pipe = CentralisedPipeline(r.cameras, (r.workspace.lo, r.workspace.hi), voxel_size=voxel_size,
                                   threshold=threshold, static_meshes=r.static_meshes(), robot=r.robot)

        def central_loop():
            period = 1.0 / fps if fps > 0 else 0.0
            while not stop.is_set():
                t1 = time.monotonic()
                st = srv.settings
                pipe.configure(voxel_size=st.voxel_size, threshold=st.threshold)
                q = st.joints if (st.joints and r.robot is not None) else None
                for cid, vs in pipe.per_camera(frames, q=q).items():
                    srv.local_update(cid, vs.keys, vs.counts, vs.voxel_size, time.time(),
                                     invalid_frac=vs.n_invalid / frames[cid].size)
                stop.wait(max(0.0, period - (time.monotonic() - t1)))
        central = threading.Thread(target=central_loop, daemon=True)
        central.start()
        log(f"centralised mode: {len(frames)} cameras filtered in this process")
    try:
        while not stop.is_set():
            stop.wait(every if every > 0 else 0.5)
            if every > 0:
                st = srv.status()
                nodes = " ".join(f"{n['camera']}#{n['id']}:{n['state']}" for n in st["nodes"]) or "no nodes"
                log(f"{nodes} | voxels {st['voxels_total']} | {st['bytes_per_s'] / 1000:.1f} kB/s "
                    f"| rejected {st['rejected']} refused {st['refused']}")
            if duration and time.monotonic() - t0 >= duration:
                break
    finally:
        stop.set()
        if central is not None:
            central.join(5)
        srv.close()


@app.command("node")
def node_cmd(
    camera: str = typer.Option(..., "--camera", help="Camera id in the rig."),
    rig: Optional[Path] = typer.Option(None, "--rig", help="Rig YAML (needed with --source pattern)."),
    source: str = typer.Option("sim", "--source", help="'sim' (simulated camera of --cell) or 'pattern' (test patch)."),
    cell: Optional[str] = typer.Option(None, "--cell", help="Built-in cell for --source sim (e.g. ur3-cell)."),
    sim_time: float = typer.Option(0.0, "--sim-time", help="Scene time of the simulated frame (s)."),
    resolution: Optional[str] = typer.Option(None, "--resolution", help="Another mode of the camera's sensor, e.g. 1280x720."),
    connect: list[str] = typer.Option([_DEFAULT], "--connect", help="Server endpoint(s)."),
    listen: list[str] = typer.Option(["tcp/127.0.0.1:0"], "--listen", help="Own zenoh endpoint(s)."),
    prefix: str = typer.Option("depthguard", "--prefix", help="Key prefix of the services."),
    fps: float = typer.Option(15.0, "--fps", help="Frames per second (0 = as fast as possible)."),
    trigger: bool = typer.Option(False, "--trigger", help="Process a frame per message on <prefix>/trigger."),
    multicast: bool = typer.Option(False, "--multicast", help="Enable zenoh multicast scouting."),
    joints: Optional[str] = typer.Option(None, "--joints", help="Joint stream, e.g. zenoh:KEY (payload as in "
                                         "docs/MONITOR.md): the robot is removed at each frame's capture joints; "
                                         "a frame outside the joint history is skipped. Without it: the fixed "
                                         "joints of the server's settings."),
    joints_connect: list[str] = typer.Option([], "--joints-connect", help="Zenoh endpoint(s) of the joint "
                                             "publisher (default: the node's own session)."),
) -> None:
    """Run one camera node: filter locally (R16-R19), send voxels to the server (R20).

    With --joints the robot is removed at the joints of each frame's capture (R30); without it, at the fixed pose
    of the server's settings (a moving robot then leaves voxels)."""
    from depthguard.distributed.client import ServerRefused
    from depthguard.distributed.node import _resolution, build_node
    from depthguard.progress import log

    if source not in ("sim", "pattern"):
        raise typer.BadParameter(f"unknown source {source!r}; use 'sim' or 'pattern'", param_hint="--source")
    node = build_node(None if rig is None else str(rig), camera, source, cell, sim_time,
                      resolution=_resolution(resolution), connect=connect,
                      listen=listen, prefix=prefix, fps=fps, trigger=trigger, multicast=multicast, log=log,
                      joints=joints, joints_connect=joints_connect)
    stop = _stop_event()
    try:
        node.run(stop)
    except ServerRefused as exc:
        raise ValueError(str(exc)) from None
    finally:
        node.close()


@app.command("status")
def status_cmd(
    connect: list[str] = typer.Option([_DEFAULT], "--connect", help="Server endpoint(s)."),
    prefix: str = typer.Option("depthguard", "--prefix", help="Key prefix of the services."),
    as_json: bool = typer.Option(False, "--json", help="Print the raw JSON."),
    timeout: float = typer.Option(2.0, "--timeout", help="Seconds to wait for the server."),
) -> None:
    """Print the server's view: nodes (fresh / stale / left), voxels, bytes per second."""
    from depthguard.distributed.client import ServerClient, ServerUnavailable

    with ServerClient(connect, prefix=prefix) as c:
        try:
            st = c.wait_for_server(timeout)
        except ServerUnavailable:
            raise ValueError(f"no server answered on {', '.join(connect)} within {timeout:g} s") from None
    if as_json:
        typer.echo(json.dumps(st, indent=2))
        return
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"depthguard server: {st['voxels_total']} voxels of {st['voxel_size'] * 1000:g} mm, "
                    f"{st['bytes_per_s'] / 1000:.1f} kB/s, rejected {st['rejected']}, refused {st['refused']}")
    for col in ("camera", "id", "state", "age_s", "voxels", "invalid px", "address"):
        t.add_column(col)
    for n in st["nodes"]:
        age = "-" if n["age_s"] is None else f"{n['age_s']:.3f}"
        inv = "-" if n.get("invalid_frac") is None else f"{100 * n['invalid_frac']:.0f} %"
        t.add_row(n["camera"], str(n["id"]), n["state"], age, str(n["voxels"]), inv, n.get("address", ""))
    Console().print(t)
