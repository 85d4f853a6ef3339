"""Bench group ``control``: the CPU of one control cycle and of its log line (R29, R31; issue 29).

A monitor of ``ur3-cell`` (four 640x480 cameras, eight control points) is fed one simulated frame
per camera and run as a real-time run runs it (``Monitor.real_time``: the distance worker on);
the calling thread then does a control cycle's work, numba on one thread so that all of it is
on the calling thread, and ``time.thread_time`` measures it:

- ``control.cycle_cpu_us`` — ``step`` (joints, kinematics, the distance worker's answer bounded
  at the cycle's points, supervision, the reaction policies, the reaction) plus the runner's own
  statistics sink, per cycle, median over the cycles (p99 in the note). The robot moves along its
  path a joint-state period every 50 cycles; the note gives the distance worker's queries and
  reused answers over the run. (No peer: the code before issue 29 is not in the package; its
  figure measured in the same session is in the commit that added this row.)
- ``control.log_line_us`` — the ``log.jsonl`` line of one of those reactions
  (:func:`depthguard.runtime.reaction_json.reaction_json`), the peer the reference encoding
  ``json.dumps(reaction.to_dict(), allow_nan=False)`` of the same reactions, alternated.
- ``control.sinks_cpu_us`` — what ``depthguard monitor``'s own sinks cost per control cycle: 500
  of those reactions a second, in real time, through a :class:`~depthguard.runtime.sinks.SinkFanout`
  to ``log.jsonl`` and ``results.mcap`` (markers at 30 Hz), the CPU of the sink thread per reaction
  (it holds the GIL for most of it); the peer is the way before issue 29's sink work, in the same
  run, alternated: the thread woken for every reaction and the markers serialised by ``rosbags``
  from their message objects.
"""

from __future__ import annotations

import time

import numpy as np

from depthguard.evaluation.bench import BenchContext, BenchRow, group

CELL = "ur3-cell"


@group("control")
def bench_control(ctx: BenchContext) -> list[BenchRow]:
    import numba

    from depthguard.runtime.monitor import Monitor, warm_up
    from depthguard.runtime.reaction_json import reaction_json, reaction_json_reference
    from depthguard.runtime.runner import RunStats
    from depthguard.sim import load_cell
    from depthguard.sources.frame import Frame
    from depthguard.sources.sim_source import SimFrames, SimWorld

    cycles = 400 if ctx.quick else 3000
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        rig = load_cell(CELL).rig
        warm_up(rig, rig.monitor)
        sim = SimFrames(SimWorld(CELL, seed=ctx.seed))
        qs = [np.asarray(sim.world._path_q(0.5 + k * 0.002), dtype=np.float64) for k in range(400)]
        stats = RunStats()
        cpu, line, ref, reactions = [], [], [], []
        with Monitor(rig, rig.monitor) as mon:
            for k in range(400):
                mon.push_joints(k * 0.002, qs[k])
            for cid in rig.camera_ids:
                mon.push_frame(Frame(cid, sim.render(cid, 0.7, qs[350]).copy(), 0.7))
            mon.flush(120.0)
            with mon.real_time():
                worker = mon._dist_worker
                deadline = time.perf_counter() + 10.0
                while (worker is not None and worker.newest() is None and time.perf_counter() < deadline):
                    mon.step(0.79, qs[350])
                    time.sleep(0.002)
                for k in range(cycles + 100):
                    q = qs[350 + (k // 50) % 40]
                    c0 = time.thread_time()
                    r = mon.step(0.79 + k * 1e-6, q)
                    stats(r)
                    c1 = time.thread_time()
                    if k >= 100:
                        cpu.append(c1 - c0)
                        reactions.append(r)
                    time.sleep(0.001)
                queries = (worker.queries, worker.reused) if worker is not None else (0, 0)
        for r in reactions:
            c0 = time.thread_time()
            reaction_json(r)
            c1 = time.thread_time()
            reaction_json_reference(r)
            c2 = time.thread_time()
            line.append(c1 - c0)
            ref.append(c2 - c1)
    finally:
        numba.set_num_threads(threads)
    sinks, sinks_old = _sinks_cpu(rig, reactions[:1500], 0.6 if ctx.quick else 2.0)
    us = 1e6
    return [
        BenchRow("control.cycle_cpu_us", float(np.median(cpu)) * us, "us", None, None, None,
                 f"{CELL}, {len(rig.robot.control_points)} control points, {len(rig.camera_ids)} cameras; step + "
                 f"run statistics per cycle, thread CPU, numba 1 thread, {len(cpu)} cycles; p99 "
                 f"{np.percentile(cpu, 99) * us:.0f} us; distance worker {queries[0]} queries, {queries[1]} "
                 f"answers reused; goal <= 100 us (issue 29)"),
        BenchRow("control.log_line_us", float(np.median(line)) * us, "us", None,
                 "json.dumps(reaction.to_dict()), the same reactions", float(np.median(ref)) * us,
                 f"the log.jsonl line of {len(line)} of those reactions, thread CPU, byte-identical to the peer's"),
        BenchRow("control.sinks_cpu_us", sinks * us, "us", None,
                 "the thread woken per reaction, markers through rosbags (before issue 29)", sinks_old * us,
                 f"{CELL}: log.jsonl + results.mcap (markers 30 Hz) through the sink fan-out at 500 reactions/s, "
                 f"the sink thread's CPU per reaction, median of 3 alternated runs each"),
    ]


def _sinks_cpu(rig, reactions, seconds: float) -> tuple[float, float]:
    """Sink-thread CPU s per reaction, ``(now, before)`` (module docstring), medians of 3 alternated runs."""
    import tempfile
    from dataclasses import replace
    from pathlib import Path

    from depthguard.runtime.mcap_results import McapResults
    from depthguard.runtime.sinks import JsonlLog, SinkFanout
    from depthguard.transport import ros_messages as rosmsg

    class OldMcap(McapResults):
        def markers_cdr(self, r):
            return rosmsg.serialize(self.markers_msg(r))

    class PerReaction(SinkFanout):
        def __call__(self, reaction):
            super().__call__(reaction)
            with self._cond:
                self._urgent = True
                self._cond.notify()

    n = max(2, min(len(reactions), int(seconds * 500)))
    rs = [replace(reactions[k % len(reactions)], t=k * 0.002) for k in range(n)]
    watch = [(w.name, w.position) for w in rig.monitor.watch_points]
    out: dict = {True: [], False: []}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(6):
            new = i % 2 == 0
            d = Path(tmp) / str(i)
            d.mkdir()
            clock = []
            fan = (SinkFanout if new else PerReaction)(
                [lambda r: clock.append(time.thread_time()), JsonlLog(d / "log.jsonl"),
                 (McapResults if new else OldMcap)(d / "results.mcap", rig.robot, watch)], block=False)
            t0 = time.perf_counter()
            for k, r in enumerate(rs):
                wait = t0 + k * 0.002 - time.perf_counter()
                if wait > 0:
                    time.sleep(wait)
                fan(r)
            fan(replace(rs[-1], t=n * 0.002))           # its clock reading ends the last one's work
            fan.close()
            out[new].append((clock[-1] - clock[0]) / max(fan.delivered - 1, 1))
    return float(np.median(out[True])), float(np.median(out[False]))
