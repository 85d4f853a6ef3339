"""Bench group ``units``: camera units that make their camera's share; the monitor only combines (issue 29).

On ``ur3-cell`` (four D435 640x480, the product's ``monitor:`` settings), noisy simulated frames
of one camera along the robot's path, the robot in view, are rendered before any clock.

* ``units.unit_ms`` — the unit's work per frame (:class:`~depthguard.distributed.unit_state.StateUnit`):
  render the robot at the capture joints, make the frame's state, encode it (codec ``f32``).
* ``units.combine_ms`` — the monitor's work per remote frame: decode the message
  (:func:`~depthguard.transport.state_wire.decode_state`) and hand the state to the fusion
  (:meth:`~depthguard.runtime.unit_states.UnitWorker.accept`). Goal <= 1 ms. Peer, in the same
  run: what a local camera's worker does for the same frame (render the robot, make the state:
  ``ExpectedDepth.robot`` + ``StateMaker.make``) — what the unit saves the monitor.
* ``units.combine_cpu_ms`` — the same in CPU seconds of the thread; ``units.combine_f64_ms`` with
  codec ``f64`` (the decode makes no array: 1.8x the bytes, less CPU).
* ``units.bytes_per_frame`` — one message of a 640x480 frame (codec ``f32``); peer: codec ``f64``.
* ``units.net_mb_s_per_camera`` — at 30 Hz, codec ``f32``.

Times are wall-clock medians over the frames (the machine's other load included).
"""

from __future__ import annotations

import time

import numpy as np

from depthguard.evaluation.bench import BenchContext, BenchRow, group, time_call


@group("units")
def bench_units(ctx: BenchContext) -> list[BenchRow]:
    from depthguard.distributed.unit_state import StateUnit, options_of, state_settings_of
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.fusion.depth_grid_state import StateMaker
    from depthguard.runtime.unit_states import UnitWorker
    from depthguard.sim.cells import load_cell
    from depthguard.sources.sim_source import SimFrames, SimWorld
    from depthguard.transport import state_wire as sw

    cell = load_cell("ur3-cell")
    rig = cell.rig
    cam = rig.cameras[1]
    settings = state_settings_of(rig)
    options, robot_free = options_of(settings, cam.id)
    sim = SimFrames(SimWorld("ur3-cell", seed=ctx.seed))
    n = 4 if ctx.quick else 12
    frames = []
    for k in range(n):
        t = 2.0 + k / 30.0
        q = np.asarray(cell.scene.robot_q(t), dtype=np.float64)
        frames.append((sim.render(cam.id, t, q).copy(), t, q))
    unit = StateUnit(cam, rig.robot)
    local_expected = ExpectedDepth(cam, rig.robot, rig.static_meshes())
    local_maker = StateMaker(cam)
    reps = max(3, (ctx.repeats if not ctx.quick else 3) // 3)
    msgs = [unit.encode(d, t, q, i, settings) for i, (d, t, q) in enumerate(frames)]
    msgs64 = [sw.encode_state(cam.id, 0, t, q, tuple(options), robot_free, *unit.make(d, q, settings)[:2],
                              codec=sw.CODEC_F64) for d, t, q in frames[:1]]
    i = [0]

    def nxt():
        i[0] = (i[0] + 1) % n
        return i[0]

    unit_s = time_call(lambda: unit.encode(*frames[nxt()][:2], frames[i[0]][2], 0, settings), reps * n)

    def local():
        d, _t, q = frames[nxt()]
        rd = np.array(local_expected.robot(q), copy=True)
        local_maker.make(d, rd, options, robot_free, False)
    local_s = time_call(local, reps * n)
    worker = UnitWorker(cam, rig.robot, lambda: (options, robot_free), lambda _cid: None)
    stamp = [0.0]

    def combine():
        st = sw.decode_state(msgs[nxt()])
        stamp[0] += 1.0                       # every state newer than the one in use
        worker.accept(st._replace(stamp=stamp[0]), 0.0)
    combine_s = time_call(combine, reps * n)
    cpu = []
    for _ in range(reps * n):                  # the same, CPU of this thread (robust to other load)
        c0 = time.thread_time()
        combine()
        cpu.append(time.thread_time() - c0)
    msg64 = msgs64[0]

    def combine64():
        st = sw.decode_state(msg64)
        stamp[0] += 1.0
        worker.accept(st._replace(stamp=stamp[0]), 0.0)
    combine64_s = time_call(combine64, reps * n)
    if worker.refused:
        raise RuntimeError(f"units bench: states refused: {worker.last_refusal}")
    nbytes = float(np.median([len(m) for m in msgs]))
    note = f"ur3-cell camera {cam.id} {cam.width}x{cam.height}, {n} frames, robot in view"
    return [
        BenchRow("units.unit_ms", float(np.median(unit_s) * 1e3), "ms",
                 note=f"render robot + state + encode (f32) per frame; {note}"),
        BenchRow("units.combine_ms", float(np.median(combine_s) * 1e3), "ms", peer="local worker: render + state",
                 peer_value=float(np.median(local_s) * 1e3),
                 note=f"decode + hand to the fusion per remote frame (goal <= 1 ms); p90 "
                      f"{np.percentile(combine_s, 90) * 1e3:.2f} ms; {note}"),
        BenchRow("units.combine_cpu_ms", float(np.median(cpu) * 1e3), "ms",
                 note="the same, CPU seconds of the thread (time.thread_time; 1 ms resolution on some kernels: "
                      "a median)"),
        BenchRow("units.combine_f64_ms", float(np.median(combine64_s) * 1e3), "ms",
                 note="decode + hand over with codec f64 (no float64 array made: a view of the message), "
                      "1.8x the bytes"),
        BenchRow("units.bytes_per_frame", nbytes, "B", peer="codec f64", peer_value=float(len(msgs64[0])),
                 note=f"one state message, codec f32 (bit-exact); {note}"),
        BenchRow("units.net_mb_s_per_camera", nbytes * 30 / 1e6, "MB/s", note="codec f32 at 30 Hz"),
    ]
