"""Drive a monitor from its sources: in real time, or as fast as possible (R29, R31).

:func:`run` pulls joint states and frames from the sources and calls
``monitor.step`` at the control rate until the duration is over, every
source is done, or the caller stops it (Ctrl-C, ``stop`` event).

- **Real time** (default): one thread per source polls it on the run's clock
  (from 0, from a recording's first stamp, or the wall clock ``time.time()``
  when a source is live; a source with ``start_clock(t0)``, the simulator, is
  told where that clock starts) and pushes what it returns; the calling
  thread steps the monitor every ``1 / control_hz`` s. A source with
  ``camera_streams()`` (the simulator) has a thread per camera instead, asleep
  until that camera's next capture: a frame never waits for another camera's
  render. The control thread never waits for a frame. For the run's length the objects made before it are
  left out of the cyclic garbage collector (:func:`frozen_heap`): a full
  collection then walks only what the run made.
- **Fast** (``fast=True``): one thread; at each control cycle ``t = k dt``
  the joint states and frames due by ``t`` are pushed (a frame once a joint
  state at or after its capture has been), the frames are processed to the
  end (``monitor.flush``), then the monitor steps. The run is a pure function
  of its inputs: two fast runs give the same log.

Returns the run's summary (:func:`summarise`), which ``--out DIR`` writes to
``DIR/summary.json`` beside ``DIR/log.jsonl``.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Callable

import numpy as np

from depthguard.runtime.realtime import TIMING_KEEP, frozen_heap
from depthguard.runtime.thread_cpu import cpu_by_part, thread_cpu_seconds

__all__ = ["run", "summarise", "RunStats", "reaction_subscribers", "open_run_sinks", "frozen_heap"]


def reaction_subscribers(*sources) -> list:
    """The sources that obey the reaction (a simulated robot: its ``on_reaction``), each once: the
    runner calls them on the control thread with every reaction."""
    out: list = []
    for s in sources:
        f = getattr(s, "on_reaction", None)
        if f is not None and f not in out:
            out.append(f)
    return out


def open_run_sinks(specs, rig, context: dict, fast: bool):
    """``(direct, queued)``: the sinks of ``specs`` (:mod:`depthguard.runtime.sink_specs`), those
    called on the control thread and those for the fan-out thread; every spec is checked before
    any opens, and what opened is closed when a later one fails. A ``live`` sink (a real robot)
    refuses a run as fast as possible (``ValueError``)."""
    from depthguard.runtime.sink_specs import check_sink_spec, open_sink

    for s in specs:
        check_sink_spec(s)
    opened: list = []
    try:
        for s in specs:
            sink = open_sink(s, rig, context)
            opened.append(sink)
            if fast and getattr(sink, "live", False):
                raise ValueError(f"--sink {s}: drives a robot, which is live: run in real time, without --fast")
    except BaseException:
        for sink in opened:
            close = getattr(sink, "close", None)
            if close is not None:
                close()
        raise
    direct = [s for s in opened if getattr(s, "direct", False)]
    return direct, [s for s in opened if not getattr(s, "direct", False)]


class RunStats:
    """What a run accumulates beside the log: a sink called with every reaction."""

    def __init__(self):
        self.cycles = 0
        self.t_first = math.nan
        self.t_last = math.nan
        self.override_min = 1.0
        self.stopped_s = 0.0
        self.slowed_s = 0.0
        self.nearest = math.inf
        self.nearest_at = None
        self.unobserved_cycles = 0        # cycles in which some control or watch point could not be judged
        self.unobserved_points: dict[str, int] = {}   # point name -> cycles it could not be judged
        self._t_prev = None
        self.last = None
        self.interrupted = False          # stopped by Ctrl-C (the summary is still written)
        self.source_errors: list[str] = []  # sources that failed during a real-time run
        self.control_scheduling = "not paced (fast run)"   # real time: runtime.realtime's status
        self.cpu_since = (thread_cpu_seconds(), time.process_time())   # the run's CPU from here
        self.cpu: dict[str, float] = {}   # CPU s per part of the run (runtime.thread_cpu), at its end
        # real time: per camera, each frame's age when its source handed it over (run clock - stamp, s)
        self.lag_at_push: dict[str, list[float]] = {}

    def note_cpu(self) -> None:
        """CPU seconds per part since the run started (:func:`~depthguard.runtime.thread_cpu.cpu_by_part`),
        read while the run's threads are alive."""
        self.cpu = cpu_by_part(*self.cpu_since)

    def __call__(self, r) -> None:
        if self.cycles == 0:
            self.t_first = r.t
        dt = 0.0 if self._t_prev is None else r.t - self._t_prev
        self._t_prev = r.t
        self.t_last = r.t
        self.cycles += 1
        self.override_min = min(self.override_min, r.override)
        if r.override <= 0.0:
            self.stopped_s += dt
        elif r.override < 1.0:
            self.slowed_s += dt
        name, d = r.nearest()
        if d < self.nearest:
            self.nearest, self.nearest_at = d, (name, r.t)
        obs = r.observed
        if not (obs.all() if obs.dtype != np.bool_ else False not in obs.tolist()):   # watch points too: one no
            # camera judges is reported (a bool array's list: ~0.3 us against all()'s ~2 us a cycle)
            self.unobserved_cycles += 1
            for i in np.flatnonzero(~r.observed):
                self.unobserved_points[r.names[i]] = self.unobserved_points.get(r.names[i], 0) + 1
        self.last = r


def summarise(monitor, stats: RunStats, wall_s: float, sources: dict, extra: dict | None = None) -> dict:
    """The summary of a run: what was monitored, the reaction's extremes, every stop episode,
    per-camera counters, and the monitor's timing (medians and 99th percentiles, ms)."""
    def pct(xs, q):
        return None if not xs else round(float(np.percentile(np.asarray(xs) * 1e3, q)), 4)
    st = monitor.stats()
    sim_s = 0.0 if stats.cycles < 2 else stats.t_last - stats.t_first
    out = {
        "rig": monitor.rig.name, "cameras": list(monitor.camera_ids), "sources": sources,
        "cycles": stats.cycles, "run_time_s": round(sim_s, 6), "wall_s": round(wall_s, 4),
        "real_time_factor": round(sim_s / wall_s, 4) if wall_s > 0 else None,
        "override_min": round(stats.override_min, 6), "stopped_s": round(stats.stopped_s, 4),
        "slowed_s": round(stats.slowed_s, 4),
        "nearest_distance_m": None if not math.isfinite(stats.nearest) else round(stats.nearest, 6),
        "nearest_point": None if stats.nearest_at is None else stats.nearest_at[0],
        "nearest_t": None if stats.nearest_at is None else round(stats.nearest_at[1], 4),
        "unobserved_cycles": stats.unobserved_cycles,
        "unobserved_points": dict(stats.unobserved_points),
        "source_errors": list(stats.source_errors),
        "control_scheduling": stats.control_scheduling,
        "cpu_s": stats.cpu,
        "distance_thread": {"queries": monitor.distance_queries,
                            "answers_from_builds": monitor.distance_answers_from_builds,
                            "cycles_that_queried_themselves": dict(monitor.distance_fallbacks)},
        "episodes": monitor.episodes,
        "step_ms": {"p50": pct(monitor.step_s, 50), "p99": pct(monitor.step_s, 99), "max": pct(monitor.step_s, 100)},
        "frame_to_reaction_ms": {"p50": pct(monitor.frame_to_reaction_s, 50),
                                 "p99": pct(monitor.frame_to_reaction_s, 99)},
        "fusion_build_ms": {"p50": pct(monitor.fusion.build_seconds, 50),
                            "p99": pct(monitor.fusion.build_seconds, 99)},
        # real time: how old each camera's frames were when their source delivered them (the
        # source's part of a frame's age; the monitor's is frame_to_reaction_ms), so that a stop
        # for stale frames (R27) says whose lateness it was; {} in a fast run
        "frame_lag_at_push_ms": {cid: {"p50": pct(lags, 50), "p99": pct(lags, 99), "max": pct(lags, 100),
                                       "frames": len(lags)}
                                 for cid, lags in sorted(stats.lag_at_push.items())},
        "stats": st,
        "config": monitor.config.model_dump(mode="json"),
    }
    if extra:
        out.update(extra)
    return out


def _none(_t):
    return ()


def _push_frames(monitor, frames) -> int:
    for f in frames:
        monitor.push_frame(f)
    return len(frames)


def run(monitor, frame_sources: list, joint_source, *, duration: float | None = None, fast: bool = False,
        stop: threading.Event | None = None, on_reaction: Callable | None = None,
        status: Callable | None = None, status_hz: float = 4.0) -> tuple[RunStats, float]:
    """Run until ``duration`` s of run time, all sources done, or ``stop`` is set; returns
    ``(stats, wall seconds)``. ``on_reaction(r)`` is called with every reaction (after the
    monitor's own sinks); ``status(r)`` at ``status_hz`` for a live status line."""
    if duration is not None and not (math.isfinite(duration) and duration > 0):
        raise ValueError(f"duration must be > 0 s (got {duration!r})")
    stop = stop or threading.Event()
    stats = RunStats()
    wall0 = time.perf_counter()

    def all_done() -> bool:
        return bool(frame_sources) and all(s.done for s in frame_sources) and \
            (joint_source is None or joint_source.done)

    def emit(r, next_status):
        stats(r)
        if on_reaction is not None:
            on_reaction(r)
        if status is not None and r.t >= next_status:
            status(r)
            return r.t + 1.0 / status_hz
        return next_status

    firsts = [getattr(src, "first_stamp", None) for src in [*frame_sources, joint_source] if src is not None]
    firsts = [float(f) for f in firsts if f is not None and math.isfinite(f)]
    t0 = min(firsts) if firsts else 0.0           # a recording's clock starts at its first stamp
    if not fast and any(getattr(src, "live", False) for src in [*frame_sources, joint_source] if src is not None):
        t0 = time.time()                          # live sources stamp with the wall clock: so does the run
    for src in {id(s): s for s in [*frame_sources, joint_source] if s is not None}.values():
        if hasattr(src, "start_clock"):
            src.start_clock(t0)                   # the simulator's time 0 is the run's start, on its clock
    try:
        if fast:
            with monitor.replay():                # one grid: each cycle follows a flush
                return _run_fast(monitor, frame_sources, joint_source, duration, stop, emit, all_done, stats,
                                 wall0, t0)
        return _run_real_time(monitor, frame_sources, joint_source, duration, stop, emit, all_done, stats, wall0, t0)
    except KeyboardInterrupt:
        stats.interrupted = True
        stop.set()
        return stats, time.perf_counter() - wall0


def _run_fast(monitor, frame_sources, joint_source, duration, stop, emit, all_done, stats, wall0, t0=0.0):
    """Fast mode (module docstring): joints, then frames due by ``t``, processed to the end, then a step.

    A frame is handed to the monitor once a joint state at or after its capture stamp has
    been (R30: its joints are interpolated, never extrapolated), as it would arrive in
    real time with any latency longer than one joint period; until then it waits here, so
    that a camera worker never waits for joints that a fast run has not pushed yet. Once
    the joint source is done, the frames still waiting go to the monitor (which refuses
    those stamped after the last joint state)."""
    dt = monitor.config.dt
    next_status = 0.0
    k = 0
    newest_joint = -math.inf
    waiting: list = []
    while not stop.is_set():
        t = t0 + k * dt
        if duration is not None and t - t0 > duration + 1e-12:
            break
        if joint_source is not None:
            for ts, q in joint_source.states_until(t):
                if monitor.push_joints(ts, q):
                    newest_joint = max(newest_joint, float(ts))
        for s in frame_sources:
            waiting.extend(s.frames_until(t))
        if joint_source is None or joint_source.done:
            due, waiting = waiting, []
        else:
            due = [f for f in waiting if f.stamp <= newest_joint]
            waiting = [f for f in waiting if f.stamp > newest_joint]
        n = _push_frames(monitor, due)
        for src in frame_sources:
            for cid, centres, size, stamp in getattr(src, "voxels_until", _none)(t):
                monitor.push_voxels(cid, centres, size, stamp)
            for st in getattr(src, "states_until", _none)(t):      # units' states (issue 29)
                n += monitor.push_state(st)
        if n:
            monitor.flush()
        next_status = emit(monitor.step(t), next_status)
        if all_done():
            break
        k += 1
    stats.note_cpu()
    return stats, time.perf_counter() - wall0


#: the interpreter's thread switch interval during a real-time run (s): a worker thread in Python
#: code holds the GIL at most this long before the control thread gets it (default 5 ms)
REAL_TIME_SWITCH_INTERVAL_S = 0.0005


def _run_real_time(monitor, frame_sources, joint_source, duration, stop, emit, all_done, stats, wall0, t0=0.0):
    import sys

    old = sys.getswitchinterval()
    sys.setswitchinterval(REAL_TIME_SWITCH_INTERVAL_S)
    try:
        return _run_paced(monitor, frame_sources, joint_source, duration, stop, emit, all_done, stats, wall0, t0)
    finally:
        sys.setswitchinterval(old)


def _run_paced(monitor, frame_sources, joint_source, duration, stop, emit, all_done, stats, wall0, t0=0.0):
    dt = monitor.config.dt
    for src in frame_sources:
        if hasattr(src, "skip_behind"):
            src.skip_behind = True          # a simulated camera drops what it cannot render in time
        if hasattr(src, "use_noise_bank"):
            src.use_noise_bank()            # and draws its noise from a pre-drawn bank (sources/noise.py)
        if hasattr(src, "warm_up"):
            src.warm_up()                   # its first frame's one-off costs paid before the clock starts
    with frozen_heap():
        return _run_threads(monitor, frame_sources, joint_source, duration, stop, emit, all_done, stats, wall0, t0)


def _run_threads(monitor, frame_sources, joint_source, duration, stop, emit, all_done, stats, wall0, t0):
    dt = monitor.config.dt
    next_status = 0.0
    start = time.monotonic() - t0
    clock = lambda: time.monotonic() - start          # noqa: E731 - the run's clock, from t0
    lags = stats.lag_at_push

    def push_frame(frame) -> None:
        """``monitor.push_frame``, the frame's age at hand-over noted first (run clock - stamp:
        the stamps of every real-time source are on the run's clock, module docstring)."""
        try:
            age = clock() - float(frame.stamp)
        except (TypeError, ValueError, AttributeError):
            age = math.nan               # the monitor's worker refuses the frame, with its reason
        if math.isfinite(age):
            lag = lags.get(frame.camera_id)
            if lag is None:
                lag = lags[frame.camera_id] = []
            lag.append(age)
            if len(lag) > TIMING_KEEP:           # a long run keeps its newest ages, not all of them
                del lag[:TIMING_KEEP // 2]
        monitor.push_frame(frame)

    def pump(fn, push, stamped: bool = False):
        from depthguard.runtime.ingest import background_thread

        background_thread()              # one core, lower priority than the control thread
        pace = _Pace() if stamped else None
        while not stop.is_set():
            n = 0
            try:
                items = fn(clock())
                for x in items:                        # a generator (frames_each): each pushed as it comes
                    push(x)
                    n += 1
            except Exception as exc:                   # a failing source: reported, the monitor goes stale
                stats.source_errors.append(f"{type(exc).__name__}: {exc}")
                from depthguard.progress import log
                log(f"source failed, its cameras go stale (R27): {type(exc).__name__}: {exc}")
                return
            if pace is not None:
                pace.seen(items)
                time.sleep(pace.wait(clock()))
            elif not n:
                time.sleep(POLL_S)
    def camera_pump(stream, push):
        """One simulated camera (``stream``, :class:`~depthguard.sources.sim_source.CameraStream`):
        asleep until its next frame can be rendered (``wake_at``), then rendered and pushed."""
        from depthguard.runtime.ingest import background_thread

        background_thread()
        while not stop.is_set():
            wait = stream.wake_at() - clock()
            if wait > 0:
                time.sleep(min(wait, STREAM_WAIT_MAX_S))        # woken for stop at least that often
                continue
            n = 0
            try:
                for f in stream.frames_each(clock()):
                    push(f)
                    n += 1
            except Exception as exc:                   # a failing camera: reported, it goes stale
                stats.source_errors.append(f"{type(exc).__name__}: {exc}")
                from depthguard.progress import log
                log(f"source failed, its cameras go stale (R27): {type(exc).__name__}: {exc}")
                return
            if not n:
                time.sleep(POLL_S)                     # due but not renderable yet (a followed robot's state)

    # a source that renders each camera on its own thread (the simulator: camera_streams, issue 29)
    # has one thread per camera, woken at its capture times; one that renders its frames one at a
    # time (frames_each) hands each on as soon as it is made, not when every camera due is
    threads = []
    for i, s in enumerate(frame_sources):
        streams = s.camera_streams() if hasattr(s, "camera_streams") else None
        if streams:
            threads += [threading.Thread(target=camera_pump, args=(st, push_frame), daemon=True,
                                         name=f"depthguard-source-{i}-{st.camera_id}") for st in streams]
        else:
            threads.append(threading.Thread(target=pump, args=(getattr(s, "frames_each", s.frames_until),
                                                               push_frame),
                                            daemon=True, name=f"depthguard-source-{i}"))
    threads += [threading.Thread(target=pump, args=(s.voxels_until, lambda v: monitor.push_voxels(*v)),
                                 daemon=True, name=f"depthguard-units-{i}")
                for i, s in enumerate(frame_sources) if hasattr(s, "voxels_until")]
    threads += [threading.Thread(target=pump, args=(s.states_until, monitor.push_state), daemon=True,
                                 name=f"depthguard-unit-states-{i}")
                for i, s in enumerate(frame_sources) if hasattr(s, "states_until")]
    if joint_source is not None:
        # a source on the run's clock (the simulator, a recording) is polled when its next state is
        # due; a live one's stamps are on its own clock: polled every POLL_S as they may come
        threads.append(threading.Thread(target=pump, args=(joint_source.states_until,
                                                           lambda s: monitor.push_joints(*s),
                                                           not getattr(joint_source, "live", False)),
                                        daemon=True, name="depthguard-joints"))
    for th in threads:
        th.start()
    from depthguard.runtime.realtime import realtime_control

    try:
        with realtime_control(monitor.config.control_priority) as rt, monitor.real_time():
            stats.control_scheduling = rt.status
            _paced_loop(monitor, stop, emit, all_done, clock, dt, t0, duration, next_status)
            stats.note_cpu()
    finally:
        stop.set()
        for th in threads:
            th.join(2.0)
    return stats, time.perf_counter() - wall0


#: the source threads' polling period when nothing came (s)
POLL_S = 0.0005

#: the longest sleep of a simulated camera's thread before its next capture (s): it sees ``stop``
STREAM_WAIT_MAX_S = 0.05


class _Pace:
    """When to poll a joint source whose stamps are on the run's clock again (issue 29): at the
    newest stamp plus the shortest interval seen between two states, never later than that
    interval from now (a source that stamps ahead of the clock is still polled once a period)
    and never sooner than :data:`POLL_S`; until two states have come, and while a state is
    overdue, every :data:`POLL_S` as before. A 500 Hz stream is then polled about 500 times a
    second instead of 2000, each empty poll of the simulator's stream ~25 us of CPU with its
    sleep (measured 2026-11-26)."""

    def __init__(self):
        self.last = -math.inf
        self.gap = math.inf

    def seen(self, items) -> None:
        for it in items:
            s = float(it[0])
            if s > self.last:
                if math.isfinite(self.last):
                    self.gap = min(self.gap, s - self.last)
                self.last = s

    def wait(self, now: float) -> float:
        if not math.isfinite(self.gap):
            return POLL_S
        return min(max(self.last + self.gap - now, POLL_S), max(self.gap, POLL_S))


def _paced_loop(monitor, stop, emit, all_done, clock, dt, t0, duration, next_status) -> None:
    """The control thread: ``step`` every ``dt`` of the run's clock; a late cycle is skipped, never queued."""
    k = 0
    while not stop.is_set():
        t_next = t0 + k * dt
        now = clock()
        if now < t_next:
            time.sleep(t_next - now)
        t = clock()
        if duration is not None and t - t0 > duration + 1e-12:
            break
        next_status = emit(monitor.step(t), next_status)
        if all_done():
            break
        k = max(k + 1, int((t - t0) / dt) + 1)
