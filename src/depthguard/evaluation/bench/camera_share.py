"""Bench group ``share``: a fusion build's CPU with each camera's share made on its own thread (R36).

On ``flacco-cell`` and ``ur3-cell`` (the product's ``monitor:`` settings: invalid pixels
unknown, silhouette and small-gap rules, padded robot), noisy simulated frames of every camera
along one second of the robot's path are rendered before any clock, the cameras taking turns as
unsynchronised cameras do. Each build loads the one camera that changed (the robot's volume at
the capture joints of the frames in use, ``set_frames`` with ``changed=``) and classifies the
cells around the control points ahead (``query`` at ``rho + distance_margin``), as the
monitor's fusion worker does.

* ``share.build_cpu_ms.<cell>`` — CPU seconds of that build (``time.thread_time``, one numba
  thread: robust to other load on the machine), median over the frames, with each frame's state
  and pyramids made beforehand by :class:`~depthguard.fusion.depth_grid_state.StateMaker` (what
  the camera's worker does) and copied in (the monitor's split). Peer: the same builds working the states out
  themselves (the build before the camera's share moved out), alternated run by run; the
  figures are the least median of five runs each.
* ``share.rebuild_cpu_ms.<cell>`` — the same build done again with no camera changed (every
  other camera's clearing memoised): what the design pays per build whatever its frame changed,
  beside the build after a new frame.
* ``share.state_cpu_ms.<cell>`` — what the camera's worker pays per frame for its share (the
  state; the pyramids stay with the build, as in the monitor: made into fresh memory per frame
  they cost the worker several ms of page faults). Peer: the same state made by the unfused
  passes (:func:`~depthguard.fusion.depth_grid_state.state_into_unfused`), frame by frame
  alternated with it.
* ``share.worker_cpu_ms.<cell>`` — the whole camera worker per frame
  (:class:`~depthguard.runtime.ingest.CameraWorker` on its own thread, as in the monitor: the
  checks, the drift statistic, the joints at capture, the robot rendered, the state), CPU of that
  thread (its ``pthread`` clock), median over every camera's frames. Peer: the worker before
  issue 29's pool — new arrays per frame and the frame's depth copied (on a thread of its own,
  5 MB allocated and freed per frame: glibc gives the heap back and faults it in again, about
  620 pages per frame of a camera other than the principal) —, frame by frame alternated with
  it, each first every other frame. Linux (a thread's CPU clock); absent elsewhere.
"""

from __future__ import annotations

import time

import numpy as np

from depthguard.evaluation.bench import BenchContext, BenchRow, group

CELLS = (("flacco-cell", 10.0), ("ur3-cell", 2.0))     # (cell, scene time of the first frame; the robot moving)


def _frames(cell_name: str, t0: float, n: int):
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.fusion.depth_grid_state import StateMaker, StateOptions
    from depthguard.sim.cells import load_cell
    from depthguard.sources.sim_source import SimFrames, SimWorld

    cell = load_cell(cell_name)
    rig, cfg = cell.rig, cell.rig.monitor
    sim = SimFrames(SimWorld(cell_name, seed=0))
    cams = list(rig.cameras)
    expected = {c.id: ExpectedDepth(c, rig.robot, rig.static_meshes()) for c in cams}
    makers = {c.id: StateMaker(c) for c in cams}
    options = StateOptions.of(cfg)
    out, state_s, stamps = [], [], []
    for k in range(n):
        cam = cams[k % len(cams)]
        t = t0 + k / (30.0 * len(cams))
        q = np.asarray(cell.scene.robot_q(t), dtype=np.float64)
        depth = sim.render(cam.id, t, q).copy()
        rd = np.array(expected[cam.id].robot(q), copy=True)
        other = cam.id != cams[0].id
        out.append((cam.id, depth, rd, q, (options, cfg.robot_in_others == "free" and other, False,
                                           1 if other else cfg.principal_bin)))
        stamps.append(t)
    worker_frames = [(t, cid, depth, role) for t, (cid, depth, _rd, _q, role) in zip(stamps, out)]
    for cid, depth, rd, _q, role in out:                 # compiled and buffers touched: not timed
        makers[cid].make(depth, rd, *role)
    unfused_s = []
    for cid, depth, rd, _q, role in out:
        _make_unfused(makers[cid], depth, rd, *role)
    for i, (cid, depth, rd, q, role) in enumerate(out):
        c0 = time.thread_time()                          # today's fused pass and the unfused one, alternated
        st = makers[cid].make(depth, rd, *role)
        state_s.append(time.thread_time() - c0)
        c0 = time.thread_time()
        _make_unfused(makers[cid], depth, rd, *role)
        unfused_s.append(time.thread_time() - c0)
        out[i] = (cid, depth, rd, q, st)
    return cell, out, (state_s, unfused_s), worker_frames


def _make_unfused(maker, depth, rd, options, robot_free, _pyramids, b):
    """``StateMaker.make`` (no pyramids) with the unfused passes
    (:func:`~depthguard.fusion.depth_grid_state.state_into_unfused`): the peer of
    ``share.state_cpu_ms``."""
    from depthguard.fusion.depth_grid_state import state_into_unfused

    cam = maker.camera
    shape = (-(-cam.height // b), -(-cam.width // b))
    free, kind = np.empty(shape), np.empty(shape, dtype=np.int8)
    state_into_unfused(cam, depth, rd, options, robot_free, maker._silhouette, maker._gaps, free, kind, b)
    return free, kind


def _worker_cpu(cell, frames) -> tuple[list[float], list[float]]:
    """CPU seconds per frame of each camera's worker thread with its pool and with new arrays per
    frame (module docstring, ``share.worker_cpu_ms``), alternated frame by frame; ``frames``:
    ``(stamp, camera id, depth, state role)`` in stamp order."""
    from depthguard.robot.joint_history import JointHistory
    from depthguard.frame_pool import BufferPool
    from depthguard.runtime.ingest import CameraWorker
    from depthguard.sources.frame import Frame

    class _Fresh(BufferPool):                 # never reuses a set: new arrays every frame
        @staticmethod
        def _unheld(arrays) -> bool:
            return False

    class _Before(CameraWorker):              # and the frame's depth copied, as before the pool
        def _own_depth(self, depth):
            return np.array(depth, dtype=np.float32, copy=True)

    rig, cfg = cell.rig, cell.rig.monitor
    joints = JointHistory(rig.robot.dof, span_s=10.0)
    for t in np.arange(frames[0][0] - 0.1, frames[-1][0] + 0.01, 0.002):
        joints.push(float(t), np.asarray(cell.scene.robot_q(float(t)), dtype=np.float64))
    drift = dict(k_sigma=cfg.drift_sigma, share=cfg.drift_share, frames=cfg.drift_frames) if cfg.drift_watch else None
    static = rig.static_meshes()
    workers = {}
    for mode in ("pool", "fresh"):
        for cam in rig.cameras:
            w = (CameraWorker if mode == "pool" else _Before)(cam, rig.robot, static, joints, 0.0, lambda _c: None,
                                                              drift=drift, name=f"bench-{mode}-{cam.id}")
            if mode == "fresh":
                w.pool = _Fresh(cap=1)
            workers[mode, cam.id] = w
    out: dict[str, list[float]] = {"pool": [], "fresh": []}
    faults: dict[str, list[int]] = {"pool": [], "fresh": []}
    seen: set = set()
    try:
        for k, (t, cid, depth, role) in enumerate(frames):
            for mode in (("pool", "fresh") if k % 2 else ("fresh", "pool")):   # the second reads a warm frame
                w = workers[mode, cid]
                w.state_options = (lambda r=role: r)
                clock = time.pthread_getcpuclockid(w._thread.ident)
                f0 = _minor_faults(w._thread.native_id)
                c0 = time.clock_gettime(clock)
                w.offer(Frame(cid, depth, t), time.perf_counter())
                while not w.idle():
                    time.sleep(0.0002)
                if (mode, cid) in seen:            # each worker's first frame: compiled, pages touched
                    out[mode].append(time.clock_gettime(clock) - c0)
                    faults[mode].append(_minor_faults(w._thread.native_id) - f0)
                seen.add((mode, cid))
                if w.refused:
                    raise RuntimeError(f"bench share: {w.last_refusal}")
    finally:
        for w in workers.values():
            w.close()
    return out["pool"], out["fresh"], float(np.median(faults["pool"])), float(np.median(faults["fresh"]))


def _minor_faults(tid: int) -> int:
    """Minor page faults of thread ``tid`` so far (Linux ``/proc``; 0 where unreadable)."""
    try:
        with open(f"/proc/self/task/{tid}/stat") as f:
            return int(f.read().rsplit(")", 1)[1].split()[7])
    except (OSError, ValueError, IndexError):
        return 0


def _builds(grid, cell, frames, with_states: bool, unchanged: bool = False) -> float:
    """Median CPU seconds of the builds over ``frames`` (module docstring); ``unchanged``: each
    build is done a second time with no camera changed, and that one is timed."""
    from depthguard.robot.volume import robot_volume

    rig, cfg = cell.rig, cell.rig.monitor
    robot = rig.robot
    data = robot.create_data()
    n_cams = len(rig.cameras)
    depths, rds, qs, states, cpu = {}, {}, {}, {}, []
    for i, (cid, d, rd, q, st) in enumerate(frames):
        depths[cid], rds[cid], qs[cid], states[cid] = d, rd, q, st
        if len(depths) < n_cams:
            continue
        for again in ((False, True) if unchanged else (False,)):
            c0 = time.thread_time()
            caps = robot_volume(robot, list(qs.values()), cfg.robot_padding)
            grid.set_frames(depths, rds, robot_offset=cfg.robot_offset, robot_capsules=caps, invalid=cfg.invalid,
                            robot_in_others=cfg.robot_in_others,
                            changed=set() if again else ({cid} if i >= n_cams else None),
                            silhouette_px=cfg.silhouette_px, gap_px=cfg.gap_px,
                            states=states if with_states else None)
            robot.forward(q, data)
            grid.query(data.cp_positions, rho=cfg.query_rho + cfg.distance_margin, method=cfg.method)
            if again or not unchanged:
                cpu.append(time.thread_time() - c0)
    return float(np.median(cpu))


@group("share")
def bench_share(ctx: BenchContext) -> list[BenchRow]:
    import numba

    from depthguard.fusion.depth_grid import DepthGridMap

    rows: list[BenchRow] = []
    previous = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        for name, t0 in CELLS:
            cell, frames, state_s, worker_frames = _frames(name, t0, 8 if ctx.quick else 24)
            rig = cell.rig
            cams = list(rig.cameras)
            d_min, d_max = rig.workspace.depth_span(cams[0])
            grid = DepthGridMap(cams, principal=cams[0].id, d_min=d_min, d_max=d_max, delta_d=rig.monitor.delta_d,
                                principal_bin=rig.monitor.principal_bin)
            grid.touch()
            seq = frames * (1 if ctx.quick else 3)
            _builds(grid, cell, seq, True)                   # compiled, pages touched
            _builds(grid, cell, seq, False)
            shared, own = [], []
            for _ in range(2 if ctx.quick else 5):
                shared.append(_builds(grid, cell, seq, True))
                own.append(_builds(grid, cell, seq, False))
            rows.append(BenchRow(f"share.build_cpu_ms.{name}", 1e3 * min(shared), "ms",
                                 peer="the build working the states out itself", peer_value=1e3 * min(own),
                                 note=f"{len(cams)} cameras 640x480, one build per frame, one numba thread, CPU "
                                      f"(thread_time); least median of {len(shared)} alternated runs; goal: the "
                                      f"build near 1 ms (R36)"))
            again = min(_builds(grid, cell, seq, True, unchanged=True) for _ in range(2 if ctx.quick else 5))
            rows.append(BenchRow(f"share.rebuild_cpu_ms.{name}", 1e3 * again, "ms",
                                 peer="a build after a new frame (share.build_cpu_ms)", peer_value=1e3 * min(shared),
                                 note="the same build again with no camera changed: what every build pays whatever "
                                      "its frame changed (capsule intervals, finding and re-classifying the cells "
                                      "from the memo, the lookup); one numba thread, CPU, least median"))
            rows.append(BenchRow(f"share.state_cpu_ms.{name}", 1e3 * float(np.median(state_s[0])), "ms",
                                 peer="the unfused passes (dilate + gaps + frame_state, before issue 29)",
                                 peer_value=1e3 * float(np.median(state_s[1])),
                                 note="a frame's state on its camera's worker (the fused pass, new arrays), one "
                                      "numba thread, CPU (thread_time), median over the frames alternated with "
                                      "the peer; goal: the worker's own passes <= 1.5 ms per 640x480 frame"))
            if hasattr(time, "pthread_getcpuclockid"):
                span = worker_frames[-1][0] - worker_frames[0][0] + 1.0 / 30.0
                again = [(t + r * span, *rest) for r in range(1 if ctx.quick else 2) for t, *rest in worker_frames]
                pooled, fresh, f_pool, f_fresh = _worker_cpu(cell, again)
                rows.append(BenchRow(f"share.worker_cpu_ms.{name}", 1e3 * float(np.median(pooled)), "ms",
                                     peer="the worker with new arrays per frame and the depth copied (before its pool)",
                                     peer_value=1e3 * float(np.median(fresh)),
                                     note=f"the whole camera worker per frame on its own thread (checks, drift, "
                                          f"joints, robot rendered, state), CPU of that thread, median over "
                                          f"{len(pooled)} frames of {len(cams)} cameras alternated with the peer; "
                                          f"page faults per frame (median) {f_pool:.0f}, peer {f_fresh:.0f}; "
                                          f"goal: near the sum of its kernels (render + state)"))
    finally:
        numba.set_num_threads(previous)
    return rows
