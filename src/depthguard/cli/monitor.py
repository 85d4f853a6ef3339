"""``depthguard monitor``: run the runtime on a cell, from its sources, to its sinks (R29, R31).

With no argument it runs the built-in ``flacco-cell`` with its people, in
real time, until Ctrl-C, with a live status line.
"""

from __future__ import annotations

import json
import os
import re
import signal
import threading
from pathlib import Path
from typing import List, Optional

import typer

from depthguard.cli.app import app
from depthguard.cli.common import in_range, load_rig_or_cell


def check_out_dir(out: Path, files=("log.jsonl", "summary.json")) -> None:
    """Refuse, before any work, an output folder that cannot be written or already holds a run."""
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"--out {out}: cannot create the folder ({exc.strerror or exc})") from None
    if not os.access(out, os.W_OK):
        raise ValueError(f"--out {out}: the folder is not writable")
    for f in files:
        if (out / f).exists():
            raise ValueError(f"--out {out}: {f} exists already (a run never overwrites one); choose a new folder")


def _skipped_behind(sources) -> int:
    """Frames the simulated sources did not render because they were behind real time."""
    return sum(s.counters().get("skipped_behind_real_time", 0) for s in sources if hasattr(s, "counters"))


def _status_line(r) -> str:
    name, d = r.nearest()
    unobs = [n for n, o, w in zip(r.names, r.observed, r.is_watch) if not o and not w]
    n_cp = int((~r.is_watch).sum())
    if name is None and len(unobs) == n_cp:
        near = "cannot judge any point"             # never "nothing within rho" when nothing was seen
    else:
        near = "nothing within rho" if name is None else f"nearest {name} {d * 100:.1f} cm"
        if unobs:
            near += f", cannot judge {len(unobs)} point(s)"
    cams = " ".join(f"{c}:{'-' if s.age_s == float('inf') else f'{s.age_s * 1e3:.0f}ms'}" + ("!" if s.state == "stale" else "")
                    for c, s in r.cameras.items())
    why = ("  STOP: " if r.override <= 0 else "  slowing: ") + "; ".join(_short_reasons(r.reasons)) if r.reasons else ""
    return f"t={r.t:7.2f}s override {r.override:4.2f}  {near}  cameras {cams}{why}"


_REFUSED = "; its frames are refused"


_NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


class RefusalTeller:
    """Called with every cycle's reaction: a camera's refused frames (R27, R30), logged through
    ``log`` in full once when they start and again only when their cause changes kind — the
    cause with its numbers (a frame's stamp, a share of pixels) left out. Each refusal naming its
    frame's stamp ('frame at 1795686387.497 s refused: no joint state received yet') was a line
    per frame, 60 a second with two cameras (issue 33's first-contact check)."""

    def __init__(self, log):
        self.log = log
        self.told: dict[str, str] = {}

    def __call__(self, r) -> None:
        refusing = set()
        for k, m in r.reasons.items():
            if k.startswith("stale:") and _REFUSED in m:
                refusing.add(k)
                why = m.split(_REFUSED, 1)[1].split(": ", 1)[-1]
                kind = _NUMBER.sub("#", why)
                if self.told.get(k) != kind:
                    self.told[k] = kind
                    self.log(f"monitor: camera {k.split(':', 1)[1]} refuses its frames: {why}")
        for k in [k for k in self.told if k not in refusing]:     # accepted again: a new refusal is told
            del self.told[k]


def _short_reasons(reasons: dict) -> list[str]:
    """The reasons for the status line, a stale camera's refused frames first and alone (their
    cause is what the user must read: runtime.refusals), the others as they are."""
    refused = [f"camera {k.split(':', 1)[1]} refuses its frames{m.split(_REFUSED, 1)[1]}"
               for k, m in reasons.items() if k.startswith("stale:") and _REFUSED in m]
    return refused + [m for k, m in reasons.items() if not (k.startswith("stale:") and _REFUSED in m)]


def never_accepted(stats: dict) -> str | None:
    """One line naming every camera that refused frames and never accepted one (``Monitor.stats()``),
    with its last refusal; None when there is none."""
    bad = [f"camera {c} never had a frame accepted ({sum(s['refused'].values())} refused; last: "
           f"{(s['last_refusal'] or '?').removeprefix(f'camera {c}: ').removeprefix(f'camera {c}: ')})"
           for c, s in stats["cameras"].items() if s["frames"] == 0 and s["refused"]]
    return "; ".join(bad) or None


def frame_age_split(summary: dict, stale_limit_s: float) -> str | None:
    """Whose lateness a real-time run's stale-camera stops were (R27), from its summary: the
    slowest camera's frame age when its source delivered (``frame_lag_at_push_ms``, p99) beside
    the monitor's own part, delivery to reaction (``frame_to_reaction_ms``, p99), against the
    stale limit; None without those figures (a fast run, no frame)."""
    lags = {c: v["p99"] for c, v in summary.get("frame_lag_at_push_ms", {}).items() if v.get("p99") is not None}
    f2r = summary.get("frame_to_reaction_ms", {}).get("p99")
    if not lags or f2r is None:
        return None
    slow = max(lags, key=lags.get)
    return (f"frames' age p99 against the stale limit of {stale_limit_s * 1e3:.0f} ms: {lags[slow]:.0f} ms when the "
            f"source delivered them (camera {slow}, the slowest), then {f2r:.0f} ms in the monitor to a reaction "
            f"(summary.json frame_lag_at_push_ms, frame_to_reaction_ms)")


def late_frame_stop(summary: dict) -> bool:
    """A camera's frames went stale during the run (R27): an episode of a ``stale:<camera>`` reason
    other than the start's wait for a camera's first frame ("no frame yet", a stop but not a late
    frame). What :func:`frame_age_split`'s line explains."""
    cams = set(summary.get("cameras") or ())
    return any(str(e.get("key", "")).startswith("stale:") and str(e["key"])[len("stale:"):] in cams
               and "no frame yet" not in str(e.get("reason", "")) for e in summary.get("episodes") or ())


def never_delivered(stats: dict) -> str | None:
    """One line naming every monitored camera that delivered no frame at all in the run (none
    accepted, none refused): the robot was stopped for it throughout (R27); None when there is none."""
    silent = [c for c, s in stats["cameras"].items() if s["frames"] == 0 and not s["refused"]]
    if not silent:
        return None
    return (f"camera{'s' if len(silent) > 1 else ''} {', '.join(silent)} delivered no frame in this run: the robot "
            f"was stopped for {'them' if len(silent) > 1 else 'it'} throughout (R27); a camera the cell does not "
            f"have leaves the rig's monitor: cameras list")


@app.command("monitor")
def monitor(
    rig: Optional[Path] = typer.Option(None, "--rig", help="Rig file (YAML) of your cell; its monitor: section sets the runtime."),
    cell: Optional[str] = typer.Option(None, "--cell", help="A built-in cell (default flacco-cell when no --rig)."),
    source: List[str] = typer.Option([], "--source", help="Frame source SCHEME:ARG, repeatable: sim[:CELL[:SITUATION]] (then any of :alone :dark :noiseless), images:DIR, bag:PATH (a ROS 2 bag, docs/BAGS.md), realsense[:CAM=SERIAL,...] and realsense-file:PATH (docs/REALSENSE.md), ros2: (live ROS 2 topics through rmw_zenoh, docs/ROS2.md), units:ENDPOINT (the camera units of a fusion server; list their cameras in the rig's monitor: remote_cameras). Default: the simulator of the cell (or of the rig's own scene)."),
    joints: Optional[str] = typer.Option(None, "--joints", help="Joint source: sim (the simulated robot, which obeys the reaction), csv:FILE, zenoh:KEY, bag:PATH, ros2:[TOPIC] (default /joint_states), ur-rtde:HOST, franky:HOST (beside a sim: source its cameras render that robot where it is: the closed loop of docs/ROBOTS.md). Default: sim with a sim source, the bag with a bag: source, ros2: with a ros2: source."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Folder for log.jsonl (one line per control cycle) and summary.json (default: out/monitor/<UTC time>)."),
    duration: Optional[float] = typer.Option(None, "--duration", help="Seconds of run time (default: until Ctrl-C or the end of the sources)."),
    fast: bool = typer.Option(False, "--fast", help="As fast as possible and deterministic (recordings, simulation), not in real time."),
    zenoh: bool = typer.Option(False, "--zenoh", help="Shorthand of --sink zenoh: (publish reactions, distances and health under depthguard/<cell>/..., loopback unless --zenoh-listen)."),
    zenoh_listen: Optional[str] = typer.Option(None, "--zenoh-listen", help="Zenoh endpoint the monitor listens on (default: the rig's monitor: zenoh_listen, loopback)."),
    zenoh_connect: List[str] = typer.Option([], "--zenoh-connect", help="Zenoh endpoints to connect to (repeatable)."),
    ros2: bool = typer.Option(False, "--ros2", help="Shorthand of --sink ros2: (the reaction as ROS 2 topics through rmw_zenoh: /depthguard/override (std_msgs/Float64), reaction, markers, and the speed scaling of a joint_trajectory_controller on --ros2-scaling-topic; docs/ROS2.md)."),
    ros2_domain: Optional[int] = typer.Option(None, "--ros2-domain", callback=in_range(0, 232), help="ROS 2 domain id (0 to 232) of ros2: sources and --ros2 (default: ROS_DOMAIN_ID, else 0)."),
    ros2_router: Optional[str] = typer.Option(None, "--ros2-router", help="Zenoh router of the ROS 2 cell (default tcp/127.0.0.1:7447, where rmw_zenohd listens)."),
    ros2_scaling_topic: str = typer.Option("/joint_trajectory_controller/speed_scaling_input", "--ros2-scaling-topic", show_default=False, help="Where --ros2 publishes control_msgs/SpeedScalingFactor (transient local) for a ros2_control joint_trajectory_controller: its ~/speed_scaling_input (by default the one of the controller named joint_trajectory_controller); 'none' for no scaling topic (docs/ROS2.md)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No status line."),
    units_keys: Optional[Path] = typer.Option(None, "--units-keys", help="Certificate directory (depthguard keys admin) for a units:tls/HOST:PORT source of a server started with --keys (docs/THREAT_MODEL.md)."),
    view: bool = typer.Option(False, "--view", help="Shorthand of --sink view: (a live 3-D view in the browser at 127.0.0.1:8080; docs/VIEW.md)."),
    sink: List[str] = typer.Option([], "--sink", help="Where the reaction goes besides OUT/log.jsonl and OUT/results.mcap, SCHEME:ARG, repeatable: zenoh:[CELL], ros2:[NAMESPACE] (default /depthguard; docs/ROS2.md), view:[[HOST:]PORT] (the live view, default 127.0.0.1:8080, anyone who reaches it can change rho; docs/VIEW.md), ur-rtde:HOST (a Universal Robots arm's speed slider through RTDE; needs depthguard[ur]), franky:HOST,path=FILE (a Franka FR3 runs the joint path of FILE through franky, slowed and stopped by the reaction; path=fr3-cell: that cell's path; needs depthguard[franka]) (docs/ROBOTS.md), jsonl:FILE, mcap:FILE, or a registered plug-in's scheme (docs/ARCHITECTURE.md)."),
) -> None:
    """Run the monitor: frames and joint states in, the robot's reaction out (R29).

    Every source feeds one runtime: per camera the robot is removed with the
    joints of the frame's capture (R30), the frames are fused in the depth grid
    off the control path, and every control cycle (500 Hz by default) reports
    the distances of the control and watch points, the speed override and its
    reasons. Stale frames or joints and points no camera can judge stop the
    robot (R26, R27).
    """
    from depthguard.progress import is_terminal, log
    from depthguard.runtime.monitor import Monitor, warm_up
    from depthguard.runtime.runner import open_run_sinks, reaction_subscribers, run, summarise
    from depthguard.runtime.sink_specs import check_sink_spec, shorthand_specs
    import depthguard.viz.sinks  # noqa: F401  (the rooms above the runtime register their sinks: view:)
    from depthguard.runtime.sinks import SinkFanout
    from depthguard.sources.base import check_source_spec, open_joints, open_source

    if duration is not None and not duration > 0:
        raise typer.BadParameter("must be > 0 seconds", param_hint="--duration")
    the_rig, the_cell = load_rig_or_cell(rig, cell)
    cell_name = None if the_cell is None else the_cell.name
    if out is None:
        import datetime

        out = Path("out") / "monitor" / datetime.datetime.now(datetime.timezone.utc).strftime("%Y%m%d-%H%M%S")
    check_out_dir(out, ("log.jsonl", "summary.json", "results.mcap"))
    specs = list(source) or [f"sim:{cell_name}" if cell_name else "sim"]
    zenoh_listen = zenoh_listen or the_rig.monitor.zenoh_listen
    context: dict = {"zenoh_listen": (zenoh_listen,), "zenoh_connect": tuple(zenoh_connect)}
    if units_keys is not None:
        context["units_keys"] = units_keys
    context.update(ros2_domain=ros2_domain, ros2_router=ros2_router)     # ros2: sources and sinks (docs/ROS2.md)
    context.update(out=out, fast=fast, ros2_scaling_topic=ros2_scaling_topic)
    sink_specs = ["jsonl:", "mcap:"] + shorthand_specs(zenoh=zenoh, ros2=ros2, view=view) + list(sink)
    for x in sink_specs:
        try:
            check_sink_spec(x)
        except ValueError as exc:
            raise typer.BadParameter(str(exc), param_hint="--sink") from None
    if fast and any(s.startswith("ros2:") for s in [*specs, joints or ""]):
        raise typer.BadParameter("ros2: sources are live (stamped on the wall clock): run in real time, without --fast",
                                 param_hint="--fast")
    schemes = [check_source_spec(s)[0] for s in specs]      # every argument checked before a source opens
    joint_spec = joints or ("sim" if "sim" in schemes else None) \
        or next((s for s in specs if s.startswith("bag:")), None) \
        or ("ros2:" if any(s.startswith("ros2:") for s in specs) else None)   # a bag / a ROS cell has joints too
    if fast and any(x.startswith(("ur-rtde:", "franky:")) for x in sink):
        raise typer.BadParameter("a robot sink is live: run in real time, without --fast", param_hint="--sink")
    if joint_spec is None:
        raise typer.BadParameter("a non-simulated source needs --joints (csv:FILE or zenoh:KEY)", param_hint="--joints")
    sources: list = []                  # every source opened is closed, whatever fails next: an SDK
    joint_source = mon = None           # recording left playing at exit aborted the process (exit 134)
    direct: list = []
    queued: list = []
    try:
        for s in specs:
            sources.append(open_source(s, the_rig, context))
        joint_source = open_joints(joint_spec, the_rig, context)
        from depthguard.sources.realsense_clock import check_joint_clock      # one clock for frames and joints (R30)
        check_joint_clock(sources, joint_source, joint_spec)
        cfg = the_rig.monitor
        log("monitor: compiling kernels (once; cached on disk) ...")
        seconds = warm_up(the_rig, cfg)
        log(f"monitor: ready in {seconds:.1f} s; cameras {', '.join(c.id for c in the_rig.cameras)}; "
            f"sources {', '.join(specs)}; joints {joint_spec}; {'as fast as possible' if fast else 'real time'}"
            + ("" if duration else "; Ctrl-C stops"))
        if the_rig.principal_bin_why:
            log(f"monitor: grid {the_rig.principal_bin_why}")
        direct, queued = open_run_sinks(sink_specs, the_rig, context, fast)     # runtime.sink_specs
        fanout = SinkFanout(queued, block=fast)
        # called by the control thread: the robot that obeys, and sinks that only keep the newest reaction
        mon = Monitor(the_rig, cfg, sinks=reaction_subscribers(*sources, joint_source) + direct + [fanout])
        if hasattr(joint_source, "attach"):       # ur-rtde: the program's speed at scale 1 for SSM (R33)
            joint_source.attach(mon)
        for x in [*direct, *queued]:              # after it: the sink that runs the program knows better
            if hasattr(x, "attach"):
                x.attach(mon)
            if getattr(x, "describe", None):
                log(f"monitor: {x.describe}")
        tty = is_terminal() and not quiet

        tell_refusals = RefusalTeller(log)

        changes_told: set = set()

        def tell_changes():
            """A changed cell (issue 31): each region that newly changed, once, as a log line."""
            from depthguard.runtime.scene_change import SceneChangeWatch
            now = mon.scene_changes() if mon is not None else []
            for ch in now:
                key = (ch["camera"], ch["kind"], ch["region"])
                if key not in changes_told:
                    changes_told.add(key)
                    log("monitor: " + SceneChangeWatch.sentence(ch))
            changes_told.intersection_update({(c["camera"], c["kind"], c["region"]) for c in now})

        def status(r):
            tell_changes()
            line = _status_line(r)
            behind = _skipped_behind(sources)
            if behind:                      # so that stale-camera stops are not read as the monitor's fault
                line += f"  (simulator behind real time: {behind} frames skipped)"
            if tty:
                typer.echo("\r" + line[:200].ljust(200), nl=False, err=True)
            elif not quiet:
                log(line)

    except BaseException:
        if mon is not None:
            mon.close()                 # its sinks too
        else:
            for x in [*direct, *queued]:
                if hasattr(x, "close"):
                    x.close()
        for s in [*sources, joint_source]:
            if s is not None:
                s.close()
        raise

    stop = threading.Event()
    interrupted = []

    def on_signal(signum, _frame):
        # Ctrl-C or SIGTERM ends the run at the next cycle boundary (the summary is written);
        # a second one interrupts at once
        interrupted.append(signum)
        stop.set()
        signal.signal(signum, signal.default_int_handler if signum == signal.SIGINT else signal.SIG_DFL)

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        stats, wall = run(mon, sources, joint_source, duration=duration, fast=fast, stop=stop,
                          on_reaction=tell_refusals, status=status, status_hz=4.0 if tty else 1.0)
        stats.interrupted = stats.interrupted or bool(interrupted)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        mon.close()                     # closes the fan-out: the log is complete
        for s in sources:
            s.close()
        joint_source.close()
    if tty:
        typer.echo("", err=True)
    summary = summarise(mon, stats, wall, {"frames": specs, "joints": joint_spec},
                        {"interrupted": stats.interrupted, "fast": fast,
                         "sinks_dropped": fanout.dropped, "sink_errors": fanout.errors,
                         "source_counts": {sp: s.counters() for sp, s in zip(specs, sources) if hasattr(s, "counters")}})
    summary["scene_changes"] = mon.scene_changes()       # issue 31: where the cell no longer matches its learned scene
    (out / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=False) + "\n")
    near = summary["nearest_distance_m"]
    blind = (f" ({summary['unobserved_cycles']} of {summary['cycles']} cycles could not judge every point)"
             if summary["unobserved_cycles"] else "")               # "no obstacle" is not "cannot judge" (R26)
    near_text = (f"{near * 100:.1f} cm" if near is not None else "none within rho") + \
        (" where it could judge" + blind if blind else "")
    f2r = summary["frame_to_reaction_ms"]["p99"]
    typer.echo(f"monitor: {summary['cycles']} cycles over {summary['run_time_s']:.2f} s "
               f"({'interrupted' if stats.interrupted else 'done'}); override min {summary['override_min']:.2f}, "
               f"stopped {summary['stopped_s']:.2f} s; nearest {near_text}; "
               f"step p99 {summary['step_ms']['p99']} ms; frame to reaction p99 "
               f"{'n/a (no frame used)' if f2r is None else f'{f2r} ms'}"
               + f"; wrote {out}/log.jsonl, summary.json and results.mcap")
    silent = never_delivered(summary["stats"])
    if silent:
        typer.echo(f"monitor: {silent}", err=True)
    refused = never_accepted(summary["stats"]) if fast else None
    if refused:                         # a recording none of whose frames could be used: bad input
        typer.echo(f"depthguard: error: {refused}", err=True)
        raise typer.Exit(2)
    behind = _skipped_behind(sources)
    if behind:
        typer.echo(f"monitor: the simulated cameras fell behind real time and skipped {behind} frames: this machine "
                   f"cannot render them and run the monitor at once at full rate; the stale-camera stops are the "
                   f"monitor's answer to late frames (R27), --fast runs the same cell without the clock")
    if not fast and summary["stopped_s"] > 0 and summary.get("cpu_s"):
        from depthguard.runtime.thread_cpu import top_parts

        typer.echo(f"monitor: cores used ({summary['cpu_s']['process'] / max(summary['wall_s'], 1e-9):.2f} in all, "
                   f"summary.json cpu_s): {top_parts(summary['cpu_s'], summary['wall_s'])}")
    ages = frame_age_split(summary, mon.config.camera_stale_limit) if not fast and late_frame_stop(summary) else None
    if ages:
        typer.echo(f"monitor: {ages}")


@app.command("safe-defaults")
def safe_defaults(
    cell: List[str] = typer.Option(["flacco-cell", "ur3-cell"], "--cell", help="Built-in cells with a robot (repeatable)."),
    duration: float = typer.Option(60.0, "--duration", help="Seconds of the robot alone per cell (run as fast as possible)."),
    dark_duration: float = typer.Option(12.0, "--dark-duration", help="Seconds of flacco-cell's script for the dark-person run (0: skip)."),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Also write the results to this JSON file."),
) -> None:
    """Check the product's safe defaults on the built-in cells (R32): the robot alone must not see
    itself, and a person whose pixels are all invalid must slow and stop the robot like a visible one.

    Runs the monitor with each rig's own monitor: settings and its cameras' noise models, as fast
    as possible, and compares with the simulator's exact geometry.
    """
    from depthguard.evaluation.safe_defaults import dark_person, robot_alone
    from depthguard.progress import log

    if not duration > 0:
        raise typer.BadParameter("must be > 0 seconds", param_hint="--duration")
    results = {"robot_alone": [], "dark_person": None}
    for name in cell:
        log(f"safe-defaults: {name}, the robot alone for {duration:g} s ...")
        r = robot_alone(name, duration=duration)
        results["robot_alone"].append(r)
        typer.echo(f"{name}: robot alone {duration:g} s: override min {r['override_min']:.3f}, speed along "
                   f"its path min {r['robot_speed_min']:.2f} (slowed {r['robot_slowed_s']:.2f} s); {r['false_near']} of {r['readings']} readings more than "
                   f"{r['tolerance_m'] * 100:.0f} cm nearer than the truth (worst {r['worst_m']} m at {r['worst_at']}); "
                   f"{r['missed_within_rho']} fixed objects within rho not reported; repulsion up to "
                   f"{r['repulsion_max_m_s']} m/s")
        if r["blind_spots"]:
            typer.echo(f"{name}: space that no camera sees, within rho of the robot (unknown is an obstacle; "
                       f"the camera layout's fault): {len(r['blind_spots'])} at the false readings' times, e.g.")
            for line in r["blind_spots"][:4]:
                typer.echo(f"  {line}")
        elif r["false_near"]:
            typer.echo(f"{name}: no space unseen by every camera explains the false readings "
                       f"(noise, dropout or the grid's discretisation)")
    if dark_duration > 0:
        log(f"safe-defaults: flacco-cell's person, visible and dark, {dark_duration:g} s each ...")
        d = dark_person("flacco-cell", duration=dark_duration)
        results["dark_person"] = d
        for label in ("visible", "dark"):
            x = d[label]
            typer.echo(f"flacco-cell, {label} person (closest {x['person_to_ee_min_m']} m to the end effector): "
                       f"override min {x['override_min']:.3f}, speed min {x['robot_speed_min']:.2f}, slowed "
                       f"{x['robot_slowed_s']:.2f} s, stopped {x['robot_stopped_s']:.2f} s, end effector reported at {x['ee_reported_min_m']} m, "
                       f"repulsion up to {x['repulsion_max_m_s']} m/s")
    if json_out is not None:
        json_out.write_text(json.dumps(results, indent=1) + "\n")
