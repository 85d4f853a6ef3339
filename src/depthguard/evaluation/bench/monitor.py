"""Bench group ``monitor``: the runtime (:class:`depthguard.runtime.Monitor`) in real time (R29).

On the ``flacco-cell`` (two Kinect v1 640x480, noisy simulated frames with
the person of situation ``reach``), frames are rendered **before** the clock
starts (a real camera's driver costs nothing here): the scripted robot path
over scene time 10-11 s (the robot swinging off from where it stood, by the
person's hand; the per-cell row ``monitor.build_p50_ms.flacco-cell`` takes the
same second) is played forth and back (a continuous path), each camera's
frames at its capture times along it; the robot moves between any two
frames, so every frame's robot is rendered and its capsules move (until
2026-11-27 the second ended at 9.5 s, where the robot stands still: the
workers rendered its image once, 0.3 ms a frame less than a moving robot
costs them). Then, for ``N`` seconds (quick 1 s, full 10 s):

* one thread per camera pushes a frame every 1/30 s, ``CAPTURE_LATENCY`` after
  its capture stamp (cameras not synchronised: every other camera half a
  period later);
* a joint thread pushes the joint state (the path at its stamp) every 1/500 s;
* the control thread, paced by ``time.sleep`` at 500 Hz, calls ``step(t)``
  (``t`` the cycle's scheduled time; the joints are the newest received).
  It runs under the rig's ``monitor: control_priority`` (SCHED_FIFO 50 where
  the system permits it, as ros2_control runs its loop; the row's note says
  which), with the heap frozen as a real-time run has it
  (:func:`~depthguard.runtime.realtime.frozen_heap`), and so does today's code.

Rows:

* ``monitor.step_p99_ms`` — 99th percentile of ``step`` (after the first
  0.25 s); paper: Flacco 2015's whole cycle, 3.3 ms (two cameras, 9 points,
  Core i7-2600). Peer: **today's code** — the depth grid on the control path
  as the closed loop (:mod:`depthguard.evaluation.closed_loop.loop`) runs it: a cycle with a
  new frame loads it (``set_frames`` with the changed cameras) and makes the
  first query (which classifies the cells, R10–R12), the other cycles query
  the frame loaded; same frames, same arrival times, same 500 Hz pacing, same
  grid options, robot depths rendered off the path (as the loop's camera
  thread does). Goal <= 1 ms.
* ``monitor.frame_to_reaction_p99_ms`` — from ``push_frame`` to the first
  reaction that uses the frame (``monitor.frame_to_reaction_s``); peer: the
  same for today's code (delivery to the end of the cycle that loads it).
  Goal <= 15 ms.
* ``monitor.fusion_build_p50_ms`` — the fusion worker's build of the back grid
  per frame (``monitor.fusion.build_seconds``); peer: today's load + first query.
* ``monitor.cameras_at_30hz`` — the most 640x480 cameras at 30 Hz the monitor
  ingests on this machine with no frame dropped or refused, the step p99
  <= 1 ms **and** frame-to-reaction p99 <= one camera period (33.3 ms). The
  extra cameras are copies of ``cam1`` (same pose, ids ``cam2``, ``cam3`` ...)
  fed ``cam1``'s frames. Counts tried: quick 2 and 4; full 2, 3, 4, 6, 8, 10,
  12, 14, 16, stopping at the first count that fails (a larger count costs
  more per frame and per second; a count held counts only if every smaller
  count tried held too). Peer: the same count for today's code, tried until its
  own first failure (0 = not even 2 cameras).

* ``monitor.step_p99_ms.map_on`` — the step's p99, map on, a path watched (``monitor_map_step``).
* ``monitor.cpu_per_camera`` — the cores the monitor's own threads use per
  640x480 camera at 30 Hz, robot removal included: CPU time (user + system,
  Linux ``/proc/self/task/<tid>/stat``) over the 2-camera session of the
  threads named ``depthguard-*`` (camera workers: checks and the robot's
  rendering; fusion; distances) and of the process's native threads that
  Python does not know (numba's worker pool, which the fusion's parallel
  kernels run on), divided by the session's wall time and by the cameras. Not
  counted: the bench's feeder threads (they stand for the camera drivers and
  the robot's controller) and the control thread (the caller's; the note gives
  its cores, the step and the bench's pacing). The note also gives the figure
  at each count of ``cameras_at_30hz``. Peer: today's control thread (its CPU
  time, the robot depths rendered before the clock and not counted) per
  camera. Goal <= 0.1. NaN where ``/proc`` is missing.

The grid options are the rig's ``monitor:`` section: the product's defaults
(invalid pixels unknown, R28, with the silhouette and small-gap rules, R32).
"""

from __future__ import annotations

import dataclasses
import math
import sys
import threading
import time

import numpy as np

from depthguard.evaluation.bench import BenchContext, BenchRow, group
from depthguard.evaluation.bench.monitor_cores import cpu_shares, parts_text, per_camera, thread_cpu
from depthguard.runtime.realtime import frozen_heap, realtime_control

CAMERA_HZ = 30.0
CONTROL_HZ = 500.0
CAPTURE_LATENCY = 0.005          # s from capture stamp to push
PATH_FRAMES = 31                 # frames per camera along the path (one second), forth and back
PATH_END = 11.0                  # scene time of the path's end (the robot moves all along it)
SKIP_S = 0.25                    # the first cycles (no frame yet) are not counted in the step figures
STEP_GOAL_MS = 1.0
COUNTS_QUICK = (2, 4)
COUNTS_FULL = (2, 3, 4, 6, 8, 10, 12, 14, 16)
LAG_LIMIT_MS = 1e3 / CAMERA_HZ    # frame-to-reaction p99 limit of a count held: one camera period
#: measure with invalid="free" instead of the rig's default (kept for comparisons; the default is usable now)
FORCE_INVALID_FREE = False


# ---------------------------------------------------------------- the scripted input
class _Script:
    """Pre-rendered frames of the cell's cameras and the joint table, along a path played forth and back."""

    def __init__(self, cell, n_frames: int, seed: int):
        from depthguard.sources.sim_source import SimFrames, SimWorld

        self.cell = cell
        self.rig = cell.rig
        n = int(n_frames)
        if (n - 1) % 3:
            raise ValueError("n_frames - 1 must be a multiple of 3 (whole joint samples per period)")
        self.length = (n - 1) / CAMERA_HZ                 # s, one way
        self.t_start = PATH_END - self.length
        self.period = 2.0 * self.length                   # s, forth and back
        m = int(round(self.period * CONTROL_HZ))
        self.q_table = np.array([self.q_at(i / CONTROL_HZ) for i in range(m)])
        world = SimWorld("flacco-cell", seed=seed)
        self._sim = SimFrames(world)
        self._frames: dict[tuple[str, int], np.ndarray] = {}
        self.phases = (0.0, 0.5)                          # in camera periods
        for cid in self.rig.camera_ids:
            for ph in self.phases:
                for k in range(2 * (n - 1)):
                    s = (k + ph) / CAMERA_HZ
                    key = (cid, self._key(s))
                    if key not in self._frames:
                        tau = self.tau(s)
                        # writable, as a driver's frame (read-only = another signature compiled in the clock)
                        self._frames[key] = self._sim.render(cid, tau, self.cell.scene.robot_q(tau))

    def tau(self, t: float) -> float:
        """Scene time at run time ``t``: forth and back over the path."""
        u = t % self.period
        return self.t_start + (u if u <= self.length else self.period - u)

    def _key(self, s: float) -> int:
        return int(round((self.tau(s) - self.t_start) * CAMERA_HZ * 2))

    def q_at(self, t: float) -> np.ndarray:
        return np.asarray(self.cell.scene.robot_q(self.tau(t)), dtype=np.float64)

    def q_cycle(self, i: int) -> np.ndarray:
        return self.q_table[i % len(self.q_table)]

    def frame(self, source_id: str, s: float) -> np.ndarray:
        """The depth of camera ``source_id`` captured at run time ``s`` (a capture time of its phase)."""
        return self._frames[(source_id, self._key(s))]

    @property
    def n_renders(self) -> int:
        return len(self._frames)


def _rig_with(rig, n: int):
    """The rig with ``n`` cameras: its own, then copies of its last camera (``cam2``, ``cam3`` ...)
    at the same pose; and per camera (id, the rig camera whose frames it gets, phase)."""
    base = list(rig.cameras)
    src = base[-1]
    cams = base[:n] + [dataclasses.replace(src, id=f"cam{i}") for i in range(len(base), n)]
    feeds = [(c.id, c.id if i < len(base) else src.id, (0.0, 0.5)[i % 2]) for i, c in enumerate(cams)]
    return dataclasses.replace(rig, cameras=cams), feeds


def _sleep_until(t_wall: float, stop: threading.Event | None = None) -> None:
    while True:
        dt = t_wall - time.perf_counter()
        if dt <= 0 or (stop is not None and stop.is_set()):
            return
        time.sleep(dt)


def _pct(xs, q, empty: float = math.nan) -> float:
    """The ``q``-th percentile of ``xs`` (s) in ms; ``empty`` when there is none."""
    return float(np.percentile(np.asarray(xs, dtype=np.float64) * 1e3, q)) if len(xs) else empty


# ---------------------------------------------------------------- the monitor in real time
def _run_monitor(script: _Script, rig, feeds, cfg, duration: float, attach=None) -> dict:
    """The real-time run (module docstring). ``attach(monitor) -> finish`` (optional) is called
    before the clock starts (the ``view`` group adds its live view and a browser there);
    ``finish(wall seconds) -> dict`` after the run, its items added to the result."""
    from depthguard.runtime.monitor import Monitor
    from depthguard.sources.frame import Frame

    dt = 1.0 / CONTROL_HZ
    stop = threading.Event()
    # the heap frozen before the clock starts, as runtime.runner.run has it (real_time() then nests)
    with Monitor(rig, cfg) as mon, frozen_heap():
        finish = attach(mon) if attach is not None else None
        step0 = len(mon.step_s)                # steps taken by ``attach`` are not the run's
        t0 = time.perf_counter() + 0.05

        def camera(cid, source, phase):
            k = 0
            while not stop.is_set():
                s = (k + phase) / CAMERA_HZ
                if s + CAPTURE_LATENCY > duration:
                    return
                _sleep_until(t0 + s + CAPTURE_LATENCY, stop)
                if stop.is_set():
                    return
                mon.push_frame(Frame(cid, script.frame(source, s), s))
                k += 1

        def joints():
            # the robot's controller: a joint state every 1/500 s on the wall clock (never late
            # because the control thread is)
            i = 0
            while not stop.is_set() and i * dt <= duration + 0.1:
                _sleep_until(t0 + i * dt, stop)
                mon.push_joints(i * dt, script.q_cycle(i))
                i += 1

        threads = [threading.Thread(target=camera, args=f, name=f"bench-camera-{f[0]}", daemon=True)
                   for f in feeds]
        threads.append(threading.Thread(target=joints, name="bench-joints", daemon=True))
        for th in threads:
            th.start()
        late, n_cycles = 0, int(duration * CONTROL_HZ)
        try:
            with realtime_control(cfg.control_priority) as rt, mon.real_time():
                cpu0, w0 = thread_cpu(), time.perf_counter()
                for i in range(n_cycles):
                    t = i * dt
                    _sleep_until(t0 + t)
                    if time.perf_counter() - (t0 + t) > dt:
                        late += 1
                    mon.step(t)
                cpu = cpu_shares(cpu0, thread_cpu(), time.perf_counter() - w0, threading.get_native_id())
        finally:
            stop.set()
            for th in threads:
                th.join(2.0)
        wall = time.perf_counter() - t0
        skip = step0 + int(SKIP_S * CONTROL_HZ)
        st = mon.stats()
        extra = finish(wall) if finish is not None else {}
        return {**extra, "step_s": list(mon.step_s[skip:]), "f2r_s": list(mon.frame_to_reaction_s),
                "build_s": list(mon.fusion.build_seconds), "late": late, "cycles": n_cycles,
                "scheduling": rt.status, "dropped": sum(c["dropped"] for c in st["cameras"].values()),
                "refused": sum(sum(c["refused"].values()) for c in st["cameras"].values()),
                "frames": sum(c["frames"] for c in st["cameras"].values()),
                "refusals": {k: v for c in st["cameras"].values() for k, v in c["refused"].items()},
                "fusion_errors": st["fusion_errors"], "last_error": st["fusion_last_error"],
                "distance_fallbacks": mon.distance_fallbacks, "distance_queries": mon.distance_queries,
                "distance_offers": mon.distance_answers_from_builds,
                "override_min": None, "cpu": cpu, "cameras": len(feeds)}


# ---------------------------------------------------------------- today's code: the grid on the control path
def _run_today(script: _Script, rig, feeds, cfg, duration: float) -> dict:
    """The closed loop's way (module docstring): set_frames + first query on the control path."""
    from depthguard.control.repulsion_limits import repulsion_and_limits
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.fusion.depth_grid import DepthGridMap

    robot = rig.robot
    cams = list(rig.cameras)
    d_min, d_max = rig.workspace.depth_span(cams[0])
    grid = DepthGridMap(cams, principal=cams[0].id, d_min=d_min, d_max=d_max, delta_d=cfg.delta_d)
    # robot depth of every frame at its capture joints: rendered off the path (the loop's camera thread)
    dt = 1.0 / CONTROL_HZ
    experts = {c.id: ExpectedDepth(c, robot, rig.static_meshes()) for c in cams}
    deliveries = []                                  # (push time, camera, depth, robot depth, q at capture)
    for cid, source, phase in feeds:
        k = 0
        while True:
            s = (k + phase) / CAMERA_HZ
            if s + CAPTURE_LATENCY > duration:
                break
            q = script.q_at(s)
            deliveries.append((s + CAPTURE_LATENCY, cid, script.frame(source, s),
                               np.array(experts[cid].robot(q), copy=True), q))
            k += 1
    deliveries.sort(key=lambda d: d[0])
    data = robot.create_data()
    q_min, q_max, qd_max = (np.ascontiguousarray(a, dtype=np.float64) for a in (robot.q_min, robot.q_max,
                                                                                   robot.qd_max))
    buf = (np.empty(3), np.empty(robot.dof), np.empty(robot.dof))
    depths, rdepths, q_caps = {}, {}, {}
    pending: set[str] = set()
    pushed: dict[str, float] = {}
    n_cycles = int(duration * CONTROL_HZ)
    cycle_s, f2r_s, load_s = [], [], []
    j = 0
    rt = realtime_control(cfg.control_priority)
    with frozen_heap(), rt:                          # as the monitor's run (_run_monitor)
        t0 = time.perf_counter() + 0.05
        cpu0, w0 = time.thread_time(), time.perf_counter()
        for i in range(n_cycles):
            t = i * dt
            _sleep_until(t0 + t)
            # frames due by the cycle's scheduled time: a loop that falls behind still loads every
            # frame at its cycle (and its frame-to-reaction grows with the lag)
            while j < len(deliveries) and deliveries[j][0] <= t:
                _, cid, d, rd, qc = deliveries[j]
                depths[cid], rdepths[cid], q_caps[cid] = d, rd, qc
                pending.add(cid)
                pushed[cid] = t0 + deliveries[j][0]
                j += 1
            c0 = time.perf_counter()
            q = script.q_cycle(i)
            robot.forward(q, data)
            loaded = False
            if pending and cams[0].id in depths:
                segs, rads = [], []
                for qf in q_caps.values():
                    ab, r = robot.collision_segments(qf, cfg.robot_padding)
                    segs.append(ab)
                    rads.append(r)
                grid.set_frames(depths, rdepths, robot_offset=cfg.robot_offset,
                                robot_capsules=(np.concatenate(segs), np.concatenate(rads)), invalid=cfg.invalid,
                                robot_in_others=cfg.robot_in_others, changed=set(pending),
                                silhouette_px=cfg.silhouette_px)
                loaded = True
            if grid.has_frames:
                res = grid.query(data.cp_positions, rho=cfg.rho, method=cfg.method, threads=1)
                D, V = np.asarray(res.distance, dtype=np.float64), np.asarray(res.direction, dtype=np.float64)
            else:
                D, V = np.full(len(data.cp_positions), np.inf), np.zeros((len(data.cp_positions), 3))
            repulsion_and_limits(D, V, data.cp_jacobians, q, q_min, q_max, qd_max, cfg.dt, cfg.rho, cfg.v_max, cfg.alpha,
                        1.0, out=buf)
            c1 = time.perf_counter()
            if t >= SKIP_S:
                cycle_s.append(c1 - c0)
            if loaded:
                load_s.append(c1 - c0)
                for cid in pending:
                    f2r_s.append(c1 - pushed[cid])
                pending = set()
        cores = (time.thread_time() - cpu0) / (time.perf_counter() - w0)
    return {"step_s": cycle_s, "f2r_s": f2r_s, "build_s": load_s, "dropped": 0, "refused": 0,
            "late_s": time.perf_counter() - (t0 + n_cycles * dt), "cores": cores, "cameras": len(feeds)}


# ---------------------------------------------------------------- the group
def _held(r: dict) -> bool:
    return (_pct(r["step_s"], 99) <= STEP_GOAL_MS and r.get("dropped", 0) == 0 and r.get("refused", 0) == 0
            and _pct(r["f2r_s"], 99) <= LAG_LIMIT_MS and len(r["f2r_s"]) > 0)


def _session(ctx, script, rig, cfg, n_cams, duration, monitor=True, today=True):
    """The monitor's real-time run with ``n_cams`` cameras and today's code's (each only if asked):
    ``(monitor result or None, today's result or None)``."""
    from depthguard.runtime.monitor import warm_up

    r2, feeds = _rig_with(rig, n_cams)
    mon = peer = None
    if monitor:
        warm_up(r2, cfg)
        mon = _run_monitor(script, r2, feeds, cfg, duration)
        ctx.log(f"  monitor {n_cams} cams: step p50 {_pct(mon['step_s'], 50):.3f} p99 {_pct(mon['step_s'], 99):.3f} "
                f"ms, f2r p50 {_pct(mon['f2r_s'], 50):.2f} p99 {_pct(mon['f2r_s'], 99):.2f} ms, build p50 "
                f"{_pct(mon['build_s'], 50):.2f} ms, dropped {mon['dropped']}, refused {mon['refusals']}, "
                f"late {mon['late']}")
    if today:
        peer = _run_today(script, r2, feeds, cfg, duration)
        ctx.log(f"  today {n_cams} cams: step p99 {_pct(peer['step_s'], 99):.3f} ms, "
                f"f2r p99 {_pct(peer['f2r_s'], 99):.2f} ms")
    return mon, peer


@group("monitor")
def bench_monitor(ctx: BenchContext) -> list[BenchRow]:
    """The group, with the thread switch interval of a real-time run (``runtime.runner``) for
    the monitor and today's code alike."""
    from depthguard.runtime.runner import REAL_TIME_SWITCH_INTERVAL_S

    old = sys.getswitchinterval()
    sys.setswitchinterval(REAL_TIME_SWITCH_INTERVAL_S)
    try:
        return _bench_monitor(ctx)
    finally:
        sys.setswitchinterval(old)


def _bench_monitor(ctx: BenchContext) -> list[BenchRow]:
    from depthguard.sim import load_cell

    cell = load_cell("flacco-cell")
    rig = cell.rig
    duration = 1.0 if ctx.quick else 10.0
    script = _Script(cell, 10 if ctx.quick else PATH_FRAMES, ctx.seed)
    default = rig.monitor
    cfg = default.with_changes(invalid="free") if FORCE_INVALID_FREE else default
    cfg_note = ('invalid="free" (the default "unknown" is pathological on the wall-less flacco-cell '
                'today)' if cfg is not default else f'rig default (invalid="{cfg.invalid}")')
    swi = sys.getswitchinterval()

    mon, peer = _session(ctx, script, rig, cfg, 2, duration)
    extra = ""
    if cfg is not default and not ctx.quick:
        dmon, dpeer = _session(ctx, script, rig, default, 2, duration)
        extra = (f"; with the rig default (invalid={default.invalid!r}): p99 {_pct(dmon['step_s'], 99):.3g} ms, "
                 f"frame-to-reaction p99 {_pct(dmon['f2r_s'], 99):.3g} ms, build p50 "
                 f"{_pct(dmon['build_s'], 50):.3g} ms, dropped {dmon['dropped']}; today "
                 f"{_pct(dpeer['step_s'], 99):.3g} ms")
    common = (f"flacco-cell, 2 Kinect 640x480 at 30 Hz from their own threads, step at 500 Hz, "
              f"{duration:g} s, {cfg_note}")
    rows = [
        BenchRow("monitor.step_p99_ms", _pct(mon["step_s"], 99), "ms", paper=3.3,
                 peer="today: depth grid on the control path (set_frames + first query)",
                 peer_value=_pct(peer["step_s"], 99),
                 note=(f"{common}; p50 {_pct(mon['step_s'], 50):.3g} ms (today {_pct(peer['step_s'], 50):.3g}), "
                       f"{len(mon['step_s'])} cycles, {mon['late']} started > 1 cycle late, control thread "
                       f"{mon['scheduling']}, switch interval "
                       f"{swi * 1e3:g} ms; distances on their own thread at {cfg.distance_hz:g} Hz "
                       f"({mon['distance_queries']} queries and {mon['distance_offers']} answers of the fusion builds' "
                       f"own queries, {mon['distance_fallbacks']} cycles queried "
                       f"the grid themselves, distance_margin {cfg.distance_margin:g} m); goal <= 1 ms{extra}")),
        BenchRow("monitor.frame_to_reaction_p99_ms", _pct(mon["f2r_s"], 99, math.inf), "ms",   # inf: no frame used
                 peer="today: delivery -> end of the cycle that loads it", peer_value=_pct(peer["f2r_s"], 99, math.inf),
                 note=(f"push_frame -> first reaction using it; p50 {_pct(mon['f2r_s'], 50):.3g} ms, "
                       f"{len(mon['f2r_s'])} frames used of {mon['frames']} processed (the others replaced by a newer "
                       f"frame before a fusion build), dropped {mon['dropped']}, refused {mon['refused']}; "
                       f"goal <= 15 ms")),
        BenchRow("monitor.fusion_build_p50_ms", _pct(mon["build_s"], 50), "ms",
                 peer="today: set_frames + first query on the control path", peer_value=_pct(peer["build_s"], 50),
                 note=(f"fusion worker per frame (R10-R12 + cells classified ahead); p99 "
                       f"{_pct(mon['build_s'], 99):.3g} ms, {len(mon['build_s'])} builds")),
    ]
    from depthguard.evaluation.bench.monitor_map_step import map_on_row    # the map on, same run (issue 30)
    rows.append(map_on_row(ctx, script, rig, cfg, duration, mon))

    counts = COUNTS_QUICK if ctx.quick else COUNTS_FULL
    best = best_today = 0             # the largest count held with every smaller count tried held too
    trying = trying_today = True      # stop at the first count that fails (more cameras only cost more)
    seen, per_cam = [], []
    for n in counts:
        if not (trying or trying_today):
            break
        if n == 2:
            m, p = mon, peer
        else:
            m, p = _session(ctx, script, rig, cfg, n, duration, monitor=trying, today=trying_today)
        if m is not None:
            ok = _held(m)
            seen.append(f"{n}: step p99 {_pct(m['step_s'], 99):.2f} ms, f2r p99 {_pct(m['f2r_s'], 99):.1f} ms, "
                        f"dropped {m['dropped']}, refused {m['refused']}, used {len(m['f2r_s'])}/{m['frames']}"
                        f"{'' if ok else ' (failed)'}")
            best, trying = (n, True) if ok else (best, False)
            per_cam.append(f"{n}: {per_camera(m):.3g}")
        if p is not None:
            ok_today = _held(p)
            best_today, trying_today = (n, True) if ok_today else (best_today, False)
    rows.append(BenchRow("monitor.cameras_at_30hz", float(best), "cameras",
                         peer="today: depth grid on the control path", peer_value=float(best_today),
                         note=(f"most 640x480 cameras at 30 Hz with nothing dropped or refused, step p99 <= "
                               f"{STEP_GOAL_MS:g} ms and frame-to-reaction p99 <= {LAG_LIMIT_MS:.1f} ms (one camera "
                               f"period); tried {', '.join(map(str, counts))} up to the first failure (extra "
                               f"cameras = copies of cam1); {'; '.join(seen)}; {cfg_note}; goal >= 10")))
    cpu = mon["cpu"]
    rows.append(BenchRow("monitor.cpu_per_camera", per_camera(mon), "cores",
                         peer="today: its control thread's CPU per camera (robot depths rendered before the clock)",
                         peer_value=peer["cores"] / peer["cameras"],
                         note=(f"CPU time of the monitor's threads (depthguard-*: camera workers with the robot's "
                               f"rendering, fusion, distances; and numba's pool) / wall / cameras, "
                               f"{duration:g} s with 2 cameras at 30 Hz: {cpu['monitor']:.3g} cores in all; not "
                               f"counted: the control thread (step at {CONTROL_HZ:g} Hz and the bench's pacing) "
                               f"{cpu['control']:.3g} cores, the bench's feeder threads {cpu['bench']:.3g}; the "
                               f"monitor's by threads: {parts_text(cpu)}; per "
                               f"camera at each count tried: {', '.join(per_cam)}; goal <= 0.1")))
    return rows
