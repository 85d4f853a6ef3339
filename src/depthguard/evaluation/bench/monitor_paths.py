"""Bench rows of the runtime's free-space map and path checks (R36, R37; issue 30).

``monitor.freespace_update_ms.{2,4}cam``: one :meth:`RuntimeFreeSpace.build` (robot removal at the
frame's joints, the map's update, the state and the robot's current volume) from ``ur3-cell``'s
cameras, 640 x 480, 5 cm voxels, its workspace (goal <= 5 ms), numba on one thread as in the
monitor's worker; peer: the reproduction's own assembly (:class:`FreeSpaceProduct`: three still
frames fused per camera, then the same map update) on the same frames. The note gives the CPU
seconds of the calling thread too (``time.thread_time``: what the build costs on a loaded machine).
``.flat_buffer``: the same build the way it was before issue 30's change (every image copied into
one flat buffer, a robot mask made and the robot pixels negated there, the pairs read in voxel
order by :func:`free_space_update`) beside the pixel-order update of the row above, same run and
frames; both give the same map (``tests/test_free_space_centre.py``).

``monitor.check_path_ms``: :meth:`Monitor.check_path`'s work (:func:`check_path_states`) for a
5 s path of 100 waypoints in that map (goal <= 2 ms), and ``.free_map`` the same path in a map free
everywhere (no segment's sweep ends early: the most work); peer: the reproduction's sweep
(:func:`~depthguard.control.motion_check.check_motion`, the same path as one motion, its own
step control and :meth:`VoxelGrid.touched_by`).
"""

from __future__ import annotations

import numpy as np

from depthguard.evaluation.bench import BenchRow, group, time_call

__all__ = ["monitor_paths"]


def _setup(n_cams: int):
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.runtime.free_space_map import RuntimeFreeSpace
    from depthguard.sim import load_cell
    from depthguard.sources.simulated import SimSource

    cell = load_cell("ur3-cell")
    rig = cell.rig
    t = cell.time_of("arm_reaching")
    q = cell.scene.robot_q(t)
    ids = [c.id for c in rig.cameras][:n_cams]
    frames = SimSource(cell, seed=0, cameras=ids).frames(t)
    depths = {k: f.depth for k, f in frames.items()}
    rdepth = {c: np.asarray(ExpectedDepth(rig.camera(c), rig.robot, []).robot(q)) for c in ids}
    space = RuntimeFreeSpace(rig, ids, 0.05, rig.monitor.robot_offset, rig.monitor.robot_padding)
    return cell, rig, q, ids, depths, rdepth, space


def _flat_buffer_build(space, depths: dict, rdepth: dict, q):
    """:meth:`RuntimeFreeSpace.build`'s work the way it was before issue 30's change (module
    docstring): returns the state (nx, ny, nz) uint8 and the body mask."""
    from depthguard.control.path_check import FREE, OCCUPIED, UNKNOWN, body_mask
    from depthguard.fusion.free_space_kernels import free_space_update, negate_where, robot_pixels

    m = space.map
    if not hasattr(space, "_bench_flat"):
        space._bench_flat = (np.zeros(int((m.widths * m.heights).sum()), np.float32),
                             {c.id: np.zeros(c.shape, bool) for c in m.cameras})
    buf, masks = space._bench_flat
    for ci, cam in enumerate(m.cameras):
        seg = buf[m.offs[ci]: m.offs[ci] + cam.width * cam.height].reshape(cam.shape)
        np.maximum(depths[cam.id], np.float32(0.0), out=seg, casting="unsafe")
        negate_where(seg, robot_pixels(depths[cam.id], rdepth[cam.id], space.robot_offset, masks[cam.id]))
    free_space_update(buf, m.offs, m.widths, m.heights, m.rmin, m.rmax, m.vstart, m.chunk, m.vox, m.pix, m.zc, m.ru,
                      m.rv, m.half, m.far, m._bg, m.background_tolerance, m._use_bg, m.margin, m.grow,
                      m.min_free_views, False, False, m._nf, m._ns, m._free, m._occ)
    nf, ns = m.counts()
    state = np.where(m.occupied, np.where(ns > 0, OCCUPIED, UNKNOWN), FREE).astype(np.uint8)
    g = space.grid
    return state, body_mask(g.shape, g.lo, g.voxel_size, space.robot, q)


def _cpu_ms(fn, reps: int) -> float:
    """Median CPU milliseconds of the calling thread per call (after one warm-up call)."""
    import time

    fn()
    out = []
    for _ in range(reps):
        c0 = time.thread_time()
        fn()
        out.append(time.thread_time() - c0)
    return float(np.median(out) * 1e3)


@group("monitor.paths")
def monitor_paths(ctx) -> list[BenchRow]:
    import numba

    from depthguard.control.motion_check import Motion, check_motion
    from depthguard.control.path_check import check_path_states
    from depthguard.fusion.free_space_product import FreeSpaceProduct
    from depthguard.sensors import sensor_model

    reps = 5 if ctx.quick else ctx.repeats
    rows = []
    threads = numba.get_num_threads()
    numba.set_num_threads(1)                        # as on the monitor's background worker
    try:
        for n in (2, 4):
            cell, rig, q, ids, depths, rdepth, space = _setup(n)
            ts = time_call(lambda: space.build(depths, rdepth, q), reps)
            cams = [rig.camera(c) for c in ids]
            # the product takes depth-independent noise only: the ToF model's (the D435's is refused)
            prod = FreeSpaceProduct(cams, (rig.workspace.lo, rig.workspace.hi), 0.05, sensor_model("tof"),
                                    rig.static_meshes())
            still = [depths] * prod.frames
            tp = time_call(lambda: prod.update(still), reps)
            tf = time_call(lambda: _flat_buffer_build(space, depths, rdepth, q), reps)
            cpu = _cpu_ms(lambda: space.build(depths, rdepth, q), reps)
            cpu_f = _cpu_ms(lambda: _flat_buffer_build(space, depths, rdepth, q), reps)
            snap = space.build(depths, rdepth, q)
            rows.append(BenchRow(f"monitor.freespace_update_ms.{n}cam", float(np.median(ts) * 1e3), "ms", None,
                                 "FreeSpaceProduct.update (the reproduction's assembly)", float(np.median(tp) * 1e3),
                                 f"ur3-cell {n} x 640x480, 5 cm, {snap.grid.shape} voxels, {len(space.map.vox)} "
                                 f"voxel-camera pairs, numba 1 thread; goal <= 5 ms; worst {ts.max() * 1e3:.1f} ms; "
                                 f"thread CPU {cpu:.2f} ms"))
            rows.append(BenchRow(f"monitor.freespace_update_ms.{n}cam.flat_buffer", float(np.median(tf) * 1e3), "ms",
                                 None, "the pixel-order update (row above)", float(np.median(ts) * 1e3),
                                 f"before issue 30's change: images copied, robot mask, pairs in voxel order; "
                                 f"thread CPU {cpu_f:.2f} ms (pixel order {cpu:.2f} ms)"))
        robot = rig.robot
        Q = np.linspace(q, np.clip(q + np.array([0.8, 0.3, -0.4, 0.3, 0.3, 0.0]), robot.q_min, robot.q_max), 100)
        stamps = np.linspace(0.0, 5.0, 100)
        g = snap.grid
        pad = rig.monitor.robot_padding
        tc = time_call(lambda: check_path_states(snap.state, g.lo, g.voxel_size, robot, stamps, Q, padding=pad), reps)

        def at(u):
            f = min(max(u / 5.0, 0.0), 1.0) * (len(Q) - 1)
            i = min(int(f), len(Q) - 2)
            return robot.collision_capsules(Q[i] + (f - i) * (Q[i + 1] - Q[i]), pad)

        motion = Motion("path", at)
        occ = snap.state != 0
        tm = time_call(lambda: check_motion(occ, g, motion), max(2, reps // 5), warmup=1)
        v = check_path_states(snap.state, g.lo, g.voxel_size, robot, stamps, Q, padding=pad)
        rows.append(BenchRow("monitor.check_path_ms", float(np.median(tc) * 1e3), "ms", None,
                             "check_motion (the reproduction's sweep), same path", float(np.median(tm) * 1e3),
                             f"5 s path, 100 waypoints, {v.samples} samples, 5 cm, verdict {v.verdict}; goal <= 2 ms; "
                             f"worst {tc.max() * 1e3:.1f} ms"))
        # the same path in a map that is free everywhere: no segment ends its sweep early (the
        # check's most work; a verdict found unsafe early is the least)
        free = np.zeros_like(snap.state)
        tf = time_call(lambda: check_path_states(free, g.lo, g.voxel_size, robot, stamps, Q, padding=pad), reps)
        tmf = time_call(lambda: check_motion(free != 0, g, motion), max(2, reps // 5), warmup=1)
        vf = check_path_states(free, g.lo, g.voxel_size, robot, stamps, Q, padding=pad)
        rows.append(BenchRow("monitor.check_path_ms.free_map", float(np.median(tf) * 1e3), "ms", None,
                             "check_motion (the reproduction's sweep), same path and map", float(np.median(tmf) * 1e3),
                             f"the path above in an all-free map: every sample swept, verdict {vf.verdict}; "
                             f"goal <= 2 ms; worst {tf.max() * 1e3:.1f} ms"))
    finally:
        numba.set_num_threads(threads)
    return rows
