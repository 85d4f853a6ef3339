"""``depthguard server``, ``depthguard node``, ``depthguard status``: the distributed
camera subsystem over zenoh (Oščádal 2022, R20). Every service binds 127.0.0.1
unless given other endpoints; multicast scouting is off unless ``--multicast``.

``--keys DIR`` (R35, ``docs/THREAT_MODEL.md``): Zenoh's TLS with mutual certificates of
the cell's authority and signed messages; the default endpoint is then
``tls/localhost:7447``. Without keys a service refuses to listen beyond loopback
unless ``--insecure``."""

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
_DEFAULT_TLS = "tls/localhost:7447"
_KEYS_HELP = ("Key directory (R35): the CA dir of `depthguard keys init` for the server, a node's "
              "(`keys node`) or an admin's (`keys admin`) for the others. Endpoints are then tls/HOST:PORT.")


def _identity(keys: Optional[Path]):
    if keys is None:
        return None
    from depthguard.transport.keys import load_identity
    return load_identity(keys)


def _endpoints(given: list[str], identity) -> list[str]:
    return list(given) if given else [_DEFAULT_TLS if identity is not None else _DEFAULT]


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
    listen: list[str] = typer.Option([], "--listen", help="Zenoh endpoint(s) to listen on [default: "
                                     f"{_DEFAULT}, with --keys {_DEFAULT_TLS}]."),
    connect: list[str] = typer.Option([], "--connect", help="Zenoh endpoint(s) to connect to."),
    keys: Optional[Path] = typer.Option(None, "--keys", help=_KEYS_HELP),
    insecure: bool = typer.Option(False, "--insecure", help="Allow listening beyond loopback without "
                                  "certificates (anyone who reaches the port can feed the system)."),
    registry: Optional[Path] = typer.Option(None, "--registry", help="File keeping camera -> unit id across "
                                            "restarts (JSON, written atomically)."),
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
    from depthguard.distributed.server import FusionServer
    from depthguard.progress import log
    from depthguard.transport import wire

    identity = _identity(keys)
    listen = _endpoints(listen, identity)
    from depthguard.transport.settings import check_exposure

    check_exposure(listen, connect, identity, insecure)
    r, c = _load_rig(rig, cell)
    joints = ()
    if r.robot is not None:
        q = c.scene.robot_q(sim_time) if (c is not None and sim_time is not None) else r.robot_q0
        joints = tuple(float(x) for x in (q if q is not None else []))
    from depthguard.distributed.unit_state import state_settings_of

    settings = wire.Settings(voxel_size=voxel_size, threshold=threshold, stale_s=stale, joints=joints,
                             state=state_settings_of(r))      # what units with --states make (issue 29)
    try:
        settings.check()
    except wire.WireError as exc:
        raise ValueError(str(exc)) from None
    stop = _stop_event()
    if identity is not None:                 # TLS handshake failures are logged by Zenoh itself
        import zenoh
        zenoh.init_log_from_env_or("error,zenoh_link_tls=warn,zenoh_link_tcp=warn")
    srv = FusionServer(r.camera_ids, settings, listen=listen, connect=connect, prefix=prefix,
                       multicast=multicast, log=log, identity=identity, insecure=insecure, registry=registry)
    srv.start()
    from depthguard.distributed.state_relay import StateRelay

    relay = StateRelay(srv, log=log).start()          # units' states on to the monitor (issue 29)
    if identity is not None:
        log(f"mutual TLS with the authority of {identity.ca_path}; signed messages required (R35)")
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
                                   threshold=threshold, static_meshes=r.static_meshes(), robot=r.robot,
                                   learned={cid: r.learned_depth(cid) for cid in r.camera_ids})

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
        relay.close()
        srv.close()


@app.command("node")
def node_cmd(
    camera: str = typer.Option(..., "--camera", help="Camera id in the rig."),
    rig: Optional[Path] = typer.Option(None, "--rig", help="Rig YAML (needed with --source pattern)."),
    source: str = typer.Option("sim", "--source", help="'sim' (simulated camera of --cell) or 'pattern' (test patch)."),
    cell: Optional[str] = typer.Option(None, "--cell", help="Built-in cell for --source sim (e.g. ur3-cell)."),
    sim_time: float = typer.Option(0.0, "--sim-time", help="Scene time of the simulated frame (s)."),
    resolution: Optional[str] = typer.Option(None, "--resolution", help="Another mode of the camera's sensor, e.g. 1280x720."),
    connect: list[str] = typer.Option([], "--connect", help=f"Server endpoint(s) [default: {_DEFAULT}, "
                                      f"with --keys {_DEFAULT_TLS}]."),
    listen: list[str] = typer.Option([], "--listen", help="Own zenoh endpoint(s) [default: tcp/127.0.0.1:0; "
                                     "with --keys none]."),
    keys: Optional[Path] = typer.Option(None, "--keys", help=_KEYS_HELP),
    insecure: bool = typer.Option(False, "--insecure", help="Allow listening beyond loopback without certificates."),
    wait: float = typer.Option(30.0, "--wait", help="Seconds to wait for the server at start before giving up."),
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
    states: bool = typer.Option(False, "--states", help="Send each frame's depth grid state (the robot removed, "
                                "made with the monitor's options from the server) instead of voxels: the monitor "
                                "lists the camera in monitor: state_cameras (issue 29, docs/DISTRIBUTED.md)."),
) -> None:
    """Run one camera node: filter locally (R16-R19), send voxels to the server (R20).

    With --joints the robot is removed at the joints of each frame's capture (R30); without it, at the fixed pose
    of the server's settings (a moving robot then leaves voxels)."""
    from depthguard.distributed.node import _resolution, build_node
    from depthguard.progress import log
    from depthguard.transport.client import ServerRefused, ServerUnavailable

    if source not in ("sim", "pattern"):
        raise typer.BadParameter(f"unknown source {source!r}; use 'sim' or 'pattern'", param_hint="--source")
    identity = _identity(keys)
    node = build_node(None if rig is None else str(rig), camera, source, cell, sim_time,
                      resolution=_resolution(resolution), connect=_endpoints(connect, identity),
                      listen=list(listen) or None, identity=identity, insecure=insecure, init_timeout_s=wait,
                      prefix=prefix, fps=fps, trigger=trigger, multicast=multicast, log=log,
                      joints=joints, joints_connect=joints_connect, states=states)
    stop = _stop_event()
    try:
        node.run(stop)
    except (ServerRefused, ServerUnavailable) as exc:
        raise ValueError(str(exc)) from None
    finally:
        node.close()


def _parse_settings(items: list[str]) -> dict:
    """``["voxel_size=0.05", "joints=[0,1]"]`` → ``{"voxel_size": 0.05, "joints": [0, 1]}`` (JSON values)."""
    out = {}
    for it in items:
        name, sep, value = it.partition("=")
        if not sep or not name:
            raise ValueError(f"--set {it!r}: use NAME=VALUE, e.g. --set voxel_size=0.05")
        try:
            out[name.strip()] = json.loads(value)
        except ValueError:
            raise ValueError(f"--set {it!r}: the value must be a number or a JSON list") from None
    return out


@app.command("status")
def status_cmd(
    connect: list[str] = typer.Option([], "--connect", help=f"Server endpoint(s) [default: {_DEFAULT}, "
                                      f"with --keys {_DEFAULT_TLS}]."),
    prefix: str = typer.Option("depthguard", "--prefix", help="Key prefix of the services."),
    keys: Optional[Path] = typer.Option(None, "--keys", help=_KEYS_HELP + " Status needs an admin certificate."),
    as_json: bool = typer.Option(False, "--json", help="Print the raw JSON."),
    set_: list[str] = typer.Option([], "--set", help="Change a server setting first, NAME=VALUE (voxel_size, "
                                   "threshold, stale_s, offset_const, offset_k; joints=[q1,...]); with --keys an "
                                   "admin certificate is needed."),
    timeout: float = typer.Option(2.0, "--timeout", help="Seconds to wait for the server."),
) -> None:
    """Print the server's view: every camera of the rig (fresh / stale / left, or missing: never
    joined), voxels, bytes per second."""
    from depthguard.transport.client import ServerClient, ServerRefused, ServerUnavailable

    identity = _identity(keys)
    connect = _endpoints(connect, identity)
    from depthguard.transport.settings import check_exposure

    check_exposure([], connect, identity)
    with ServerClient(connect, prefix=prefix, identity=identity) as c:
        try:
            st = c.wait_for_server(timeout)
            if set_:
                st = c.set_settings(timeout=timeout, **_parse_settings(set_))
        except ServerRefused as exc:
            raise ValueError(str(exc)) from None
        except ServerUnavailable as exc:
            why = f" ({exc})" if "refused" in str(exc) else ""
            raise ValueError(f"no server answered on {', '.join(connect)} within {timeout:g} s: is "
                             f"`depthguard server` running there{' with the same authority' if identity else ''}?"
                             f"{why}") from None
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
    joined = {n["camera"] for n in st["nodes"]}
    for cam in st.get("cameras", []):
        if cam not in joined:
            t.add_row(cam, "-", "[bold red]missing[/]", "-", "0", "-", "never joined")
    Console().print(t)


@app.command("fuzz")
def fuzz_cmd(
    cases: int = typer.Option(10_000, "--cases", help="Inputs per target."),
    target: list[str] = typer.Option([], "--target", help="wire, envelope, settings, registry, rig, depth "
                                     "(default: all)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the mutations (a run is reproducible)."),
    out: Optional[Path] = typer.Option(None, "--out", help="Directory for the inputs that crashed (none if "
                                       "nothing crashed)."),
) -> None:
    """Fuzz every decoder and loader of outside input (R35): mutated wire messages, signed envelopes,
    settings JSON, registry, rig and depth files. Each input must be accepted or refused with a
    sentence (ValueError) and a refusal must change nothing stored. Exit 1 on any crash."""
    from rich.console import Console
    from rich.table import Table

    from depthguard.distributed.fuzz import run
    from depthguard.progress import log

    results = run(target or None, cases, seed,
                  progress=lambda name, n: log(f"fuzz {name}: {n}/{cases}") if n % 2500 == 0 else None)
    t = Table(title=f"depthguard fuzz: {cases} cases per target, seed {seed}")
    for col in ("target", "cases", "accepted", "refused (clear error)", "crashes", "s", "most common refusals"):
        t.add_column(col)
    crashed = 0
    for r in results:
        common = "; ".join(f"{k} ({n})" for k, n in sorted(r.errors.items(), key=lambda x: -x[1])[:3])
        t.add_row(r.target, str(r.cases), str(r.accepted), str(r.rejected), str(r.crashes), f"{r.seconds:.1f}", common)
        crashed += r.crashes
        if r.crashes and out is not None:
            out.mkdir(parents=True, exist_ok=True)
            for i, (data, tb) in enumerate(r.crash_examples):
                (out / f"{r.target}-{i}.bin").write_bytes(data)
                (out / f"{r.target}-{i}.txt").write_text(tb)
        for data, tb in r.crash_examples[:1]:
            log(f"fuzz {r.target}: crash on {data[:60]!r}...\n{tb}")
    Console().print(t)
    if crashed:
        raise typer.Exit(1)


@app.command("soak")
def soak_cmd(
    units: int = typer.Option(16, "--units", help="Simulated units (threads, each its own Zenoh session)."),
    minutes: float = typer.Option(10.0, "--minutes", help="Duration in minutes."),
    hz: float = typer.Option(30.0, "--hz", help="Updates per second per unit."),
    voxels: int = typer.Option(500, "--voxels", help="Voxels per update (8 bytes each)."),
    as_json: bool = typer.Option(False, "--json", help="Print the figures as JSON."),
) -> None:
    """Soak the distributed mode on loopback (R35): N units at 30 Hz with sequence numbers against a
    server process; lost updates, refresh p50/p99 and the server's memory over time."""
    from depthguard.distributed.soak import run_soak
    from depthguard.progress import log

    r = run_soak(units, minutes, hz, voxels, log=log)
    if as_json:
        typer.echo(json.dumps(r, indent=1))
        return
    rss = r["rss_mb"]
    typer.echo(f"{r['units']} units x {r['hz']:g} Hz for {r['minutes']:g} min on {r['cpu_count']} CPUs, "
               f"{r['voxels']} voxels per update\n"
               f"  sent {r['sent']} of {r['slots']} slots (late slots {r['late_slots']}: the CPU did not keep up)\n"
               f"  lost {r['lost']} ({100 * r['lost'] / max(r['sent'], 1):.3f} %), sequence gaps {r['seq_gaps']}, "
               f"failed requests {r['failed_requests']}\n"
               f"  refresh at the server p50 {r['refresh_ms']['p50']:.1f} ms, p99 {r['refresh_ms']['p99']:.1f} ms, "
               f"max {r['refresh_ms']['max']:.1f} ms (ideal {r['refresh_ms']['ideal']:.1f}); "
               f"round trip p50 {r['rtt_ms']['p50']:.1f} ms, p99 {r['rtt_ms']['p99']:.1f} ms\n"
               f"  server RSS {rss[0][1]:.1f} MB at start, {rss[-1][1]:.1f} MB at the end; growth after "
               f"{r['warmup_s']:.0f} s warm-up {r['rss_growth_pct']:+.2f} %")
