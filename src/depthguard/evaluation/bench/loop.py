"""Bench group ``loop``: the closed loop of scenario ``reach`` on flacco-cell (R15).

``loop.avoidance_rate_hz``: control cycles (distances of the 9 control points
from the depth grid of both cameras + repulsion + R14 limits + SNS) per
wall-clock second spent in them. Paper (Flacco 2015 §VIII): about 300 Hz,
ten times the camera rate. Peer: the same cycle with the principal camera
alone (one-camera depth-space distance, R3–R9).

``loop.real_time_factor``: simulated seconds per wall second of the whole
simulation (camera rendering + noise, self-removal renders, distances,
reaction, ground truth); goal >= 1. ``loop.real_time_factor_system``: the
same without the camera simulation and the ground truth — what would run
on a real cell. Simulated time: quick 0.5 s, full 4 s (both set-ups). The
depth grid classifies its cells lazily (on first use within a frame, only
where the 9 points' queries look), so a new frame costs a few ms. The
cameras' frames arrive one camera period after capture (the loop's default
``camera_latency``) and are simulated meanwhile on a camera thread that takes
one of the cores; the control cycles run on the others.
"""

from __future__ import annotations

from depthguard.evaluation.bench import BenchContext, BenchRow, group


@group("loop")
def bench_loop(ctx: BenchContext) -> list[BenchRow]:
    from depthguard.evaluation.closed_loop.loop import LoopConfig
    from depthguard.evaluation.closed_loop.scenarios import run_scenario

    dur2 = 0.5 if ctx.quick else 4.0
    dur1 = dur2
    # warm-up: compile every kernel, build / load the depth grid map
    run_scenario("reach", duration=0.01, seed=ctx.seed, write=False)
    run_scenario("reach", duration=0.01, seed=ctx.seed, config=LoopConfig(fusion="single"), write=False)
    s2, _ = run_scenario("reach", duration=dur2, seed=ctx.seed, write=False)
    s1, _ = run_scenario("reach", duration=dur1, seed=ctx.seed, config=LoopConfig(fusion="single"), write=False)
    note2 = (f"scenario reach, {dur2:g} s simulated, 500 Hz control, 2 Kinect 640x480 at 30 Hz "
             f"(frames one period late, simulated on a camera thread), depth grid")
    return [
        BenchRow("loop.avoidance_rate_hz", s2["avoidance_rate_hz"], "Hz", paper=300.0,
                 peer="principal camera only", peer_value=s1["avoidance_rate_hz"], note=note2),
        BenchRow("loop.real_time_factor", s2["real_time_factor"], "x", paper=None,
                 peer="principal camera only", peer_value=s1["real_time_factor"],
                 note="whole simulation incl. camera rendering + noise and ground truth; goal >= 1"),
        BenchRow("loop.real_time_factor_system", s2["real_time_factor_system"], "x", paper=None,
                 peer="principal camera only", peer_value=s1["real_time_factor_system"],
                 note="self-removal renders + distances + reaction only (what a real cell runs)"),
    ]
