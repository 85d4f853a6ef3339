"""Bench group ``voxels``: the per-camera filter and the distributed subsystem (Oščádal 2022).

Rows (all on the ``ur3-cell`` scene with a person in it, noisy RealSense D435 model):

* ``voxels.filter.<W>x<H>_ms`` — one camera's whole step at 20 mm: expected depth
  (robot rendered at its joints over the cached static CAD, R16) + R17–R19 kernel;
  peer: the plain-numpy twin. Goals 10 ms (640×480), 25 ms (1280×720).
* ``voxels.kernel.<W>x<H>_ms`` — the R17–R19 kernel alone; peer: OctoMap
  (``pyoctomap``) inserting the same kept cloud (``insertPointCloud``, rays as MoveIt
  does) at the same resolution. Goal ≥ 20× faster.
* ``voxels.filter.640x480.<s>mm_ms`` — voxel sizes 10–100 mm.
* ``voxels.refresh.<n>cam.<W>x<H>_ms`` — scene refresh, distributed: the server in
  this process, ``n`` node processes (trigger → last update received); peer: the
  centralised pipeline (all images in one process). Paper: 50 / 104 / 287 ms
  distributed, 67 / 166 / 495 ms centralised (3 cameras). Goal 3×1280×720 ≤ 50 ms.
  This machine has 2 cores: the node processes share them.
* ``voxels.bytes.<W>x<H>`` — bytes of one update message vs the raw float32 image.
* ``voxels.vote.false_removed`` — false voxels removed by multi-camera voting.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import replace

import numpy as np

from depthguard.evaluation.bench import BenchContext, BenchRow, group, time_call

RESOLUTIONS = ((424, 240), (640, 480), (1280, 720))
PAPER_REFRESH_DIST = {(424, 240): 50.0, (640, 480): 104.0, (1280, 720): 287.0}
PAPER_REFRESH_CENT = {(424, 240): 67.0, (640, 480): 166.0, (1280, 720): 495.0}
CELL = "ur3-cell"


def person_time(cell) -> float:
    """The scene time at which a person's arm reaches into the UR3 cell."""
    return cell.time_of("arm_reaching")


def rig_at(rig, w: int, h: int):
    from depthguard.distributed.node import with_resolution

    return replace(rig, cameras=[with_resolution(c, w, h) for c in rig.cameras])


def score(keys, voxel_size, lo, hi, truth_any, visible_keys, tol: int = 1):
    """Precision and recall of kept voxels (world keys at ``voxel_size``).

    truth_any : (nx, ny, nz) bool ground-truth occupancy ("any" mode) of the unknown
        objects over ``lo + [i, i+1)·s``; a kept voxel is true when a truth voxel lies
        within ``tol`` voxels (sensor noise). visible_keys : (M, 3) keys of the unknown
        objects' visible surface (noiseless render + labels); recall is the share of
        them with a kept voxel within ``tol``.
    Returns (precision, recall, n_kept, n_false).
    """
    from scipy.ndimage import binary_dilation

    s = voxel_size
    off = np.round(np.asarray(lo) / s).astype(np.int64)
    dil = binary_dilation(truth_any, iterations=tol) if tol else truth_any
    k = np.asarray(keys, dtype=np.int64) - off
    inside = np.all((k >= 0) & (k < np.array(dil.shape)), axis=1)
    ok = np.zeros(len(k), bool)
    ok[inside] = dil[tuple(k[inside].T)]
    prec = float(ok.mean()) if len(k) else 1.0
    kept = np.zeros(dil.shape, bool)
    kept[tuple(k[inside].T)] = True
    kept_d = binary_dilation(kept, iterations=tol) if tol else kept
    v = np.asarray(visible_keys, dtype=np.int64) - off
    vin = np.all((v >= 0) & (v < np.array(dil.shape)), axis=1)
    rec = float(kept_d[tuple(v[vin].T)].mean()) if vin.any() else float("nan")
    return prec, rec, int(len(k)), int((~ok).sum())


def visible_truth(cell, rig, t, voxel_size):
    """(M, 3) keys of the dynamic objects' surface seen by the rig's cameras (noiseless)."""
    from depthguard.sources import SimSource

    src = SimSource(rig=rig, scene=cell.scene, noiseless=True)
    meshes, names = cell.scene.meshes_at(t)
    dyn_names = {p.name for p in cell.scene.dynamic_at(t)}
    dyn_idx = np.array([i for i, n in enumerate(names) if n in dyn_names], dtype=np.int64)
    lo, hi = rig.workspace.lo, rig.workspace.hi
    out = []
    for cid, fr in src.frames(t, labels=True).items():
        cam = rig.camera(cid)
        mask = np.isin(fr.labels, dyn_idx)
        p = cam.depth_to_points(fr.depth, mask=mask)
        p = p[np.all((p >= lo) & (p < hi), axis=1)]
        out.append(np.floor(p / voxel_size).astype(np.int64))
    return np.unique(np.concatenate(out), axis=0) if out else np.zeros((0, 3), np.int64)


def blob_artefacts(frames: dict, seed: int = 3, n: int = 40) -> dict:
    """Copies of ``frames`` with ``n`` 5x5-pixel blobs per image pulled towards the camera
    (depth × U(0.4, 0.8)), the way stereo mismatches look."""
    rng = np.random.default_rng(seed)
    out = {}
    for cid, d in frames.items():
        d = d.copy()
        H, W = d.shape
        for _ in range(n):
            v, u = rng.integers(2, H - 2), rng.integers(2, W - 2)
            d[v - 2:v + 3, u - 2:u + 3] *= np.float32(rng.uniform(0.4, 0.8))
        out[cid] = d
    return out


def truth_any(cell, t, voxel_size):
    from depthguard.sim.ground_truth import occupancy

    lo, hi = cell.rig.workspace.lo, cell.rig.workspace.hi
    return occupancy(cell.scene.dynamic_at(t), lo, hi, voxel_size, mode="any")


def cpu_ms(fn, n: int) -> float:
    """Mean process CPU time of ``fn`` in ms (load-independent on a shared machine)."""
    fn()
    c0 = time.process_time()
    for _ in range(n):
        fn()
    return (time.process_time() - c0) / n * 1e3


# ------------------------------------------------------------------ distributed
class _Refresh:
    """Server in this process + node processes in trigger mode; times trigger → last update."""

    def __init__(self, cam_ids, w, h, t, qs=None, cell_name=CELL):
        from depthguard.distributed.server import FusionServer
        from depthguard.transport import wire

        import socket
        with socket.socket() as so:
            so.bind(("127.0.0.1", 0))
            port = so.getsockname()[1]
        self.ep = f"tcp/127.0.0.1:{port}"
        self.cam_ids = list(cam_ids)
        self.server = FusionServer(self.cam_ids, wire.Settings(stale_s=5.0), listen=[self.ep]).start()
        self._cv = threading.Condition()
        self._seen: dict[str, int] = {}
        self.server.on_update = self._on_update
        self.procs = [subprocess.Popen(
            [sys.executable, "-m", "depthguard.distributed.node", "--source", "sim", "--cell", cell_name,
             "--camera", c, "--sim-time", repr(t), "--resolution", f"{w}x{h}", "--connect", self.ep,
             "--trigger", "--quiet"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            for c in self.cam_ids]
        self.qs = qs

    def _on_update(self, u):
        with self._cv:
            self._seen[u.camera] = u.seq
            self._cv.notify_all()

    def wait_ready(self, timeout=300.0):
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            if all(c in self.server.units and self.server.units[c].alive for c in self.cam_ids):
                return
            if any(p.poll() is not None for p in self.procs):
                raise RuntimeError("a node process exited during start-up")
            time.sleep(0.05)
        raise TimeoutError("nodes did not join in time")

    def once(self, k: int, timeout=10.0) -> float | None:
        if self.qs is not None:          # the robot "moves": every node re-renders it each frame
            self.server.set_settings(joints=self.qs[k % 2])
        t0 = time.perf_counter()
        self.server.session.put(self.server.keys.trigger, int(k).to_bytes(4, "little"))
        with self._cv:
            ok = self._cv.wait_for(lambda: all(self._seen.get(c) == k for c in self.cam_ids), timeout)
        return time.perf_counter() - t0 if ok else None

    def cpu_s(self) -> np.ndarray:
        """(n,) CPU seconds (user + system) used so far by each node process (Linux /proc)."""
        tick = os.sysconf("SC_CLK_TCK")
        out = []
        for p in self.procs:
            with open(f"/proc/{p.pid}/stat") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
            out.append((int(fields[11]) + int(fields[12])) / tick)
        return np.asarray(out)

    def close(self):
        for p in self.procs:
            if p.poll() is None:
                p.send_signal(signal.SIGKILL)
            p.wait(10)
        self.server.close()


def distributed_refresh(cam_ids, w, h, t, repeats: int, qs=None, cpu: dict | None = None) -> np.ndarray:
    """Wall-clock seconds of ``repeats`` scene refreshes (trigger → every node's update in).
    ``cpu``, if given, receives ``per_node_ms``: the nodes' mean CPU time per refresh."""
    r = _Refresh(cam_ids, w, h, t, qs)
    try:
        r.wait_ready()
        k = 0
        warm = 0
        while warm < 3:                      # first triggers may precede the subscriptions
            k += 1
            if r.once(k, timeout=3.0) is not None:
                warm += 1
        warm_k = k
        out = []
        c0 = r.cpu_s()
        while len(out) < repeats:
            k += 1
            dt = r.once(k)
            if dt is not None:
                out.append(dt)
        if cpu is not None:
            cpu["per_node_ms"] = (r.cpu_s() - c0) / max(1, k - warm_k) * 1e3
        return np.asarray(out)
    finally:
        r.close()


# ------------------------------------------------------------------ the group
@group("voxels")
def bench_voxels(ctx: BenchContext) -> list[BenchRow]:
    import pyoctomap

    from depthguard.distributed.central import CentralisedPipeline
    from depthguard.fusion import voxel_kernels
    from depthguard.fusion.voxels import VoxelFilter, vote
    from depthguard.sim import load_cell
    from depthguard.sources import SimSource
    from depthguard.transport import wire

    rows: list[BenchRow] = []
    cell = load_cell(CELL)
    t = person_time(cell)
    q = cell.scene.robot_q(t)
    base = cell.rig
    ws = (base.workspace.lo, base.workspace.hi)
    statics = base.static_meshes()
    rep = max(3, ctx.repeats // 3) if ctx.quick else ctx.repeats
    # the robot moves a little between frames, so the expected depth is re-rendered every
    # frame (the filter caches it while the joints stay put)
    qs = (q, q + 1e-4)
    tick = iter(range(1 << 60))

    def q_next():
        return qs[next(tick) % 2]
    goals = {(640, 480): 10.0, (1280, 720): 25.0}
    frames_by_res = {}
    for (w, h) in RESOLUTIONS:
        tag = f"{w}x{h}"
        rig = rig_at(base, w, h)
        src = SimSource(rig=rig, scene=cell.scene, seed=ctx.seed)
        frames = {cid: f.depth for cid, f in src.frames(t).items()}
        frames_by_res[(w, h)] = (rig, frames)
        cam = rig.cameras[0]
        f = VoxelFilter(cam, ws, voxel_size=0.02, static_meshes=statics, robot=rig.robot)
        depth = frames[cam.id]
        ctx.log(f"voxels: filter {tag}")
        full = time_call(lambda: f.filter(depth, q=q_next()), rep)
        exp = np.array(f.expected_depth(q))
        kern = time_call(lambda: f.filter(depth, expected=exp), rep)
        off = f.offset
        twin = time_call(lambda: voxel_kernels.filter_voxelize_numpy(cam, depth, exp, off.const, off.k, ws[0], ws[1],
                                                          0.02, f.threshold), 1 if ctx.quick else 3, warmup=0)
        goal = goals.get((w, h))
        cpu = cpu_ms(lambda: f.filter(depth, q=q_next()), rep)
        rows.append(BenchRow(f"voxels.filter.{tag}_ms", float(np.median(full) * 1e3), "ms", None,
                             "numpy twin (same step, expected given)", float(np.median(twin) * 1e3),
                             (f"goal <= {goal:g} ms; " if goal else "")
                             + f"expected depth (robot render) + R17-R19, 20 mm, worst {full.max() * 1e3:.1f} ms, "
                             f"CPU {cpu:.1f} ms, load avg {os.getloadavg()[0]:.1f}"))
        # OctoMap inserting the same kept cloud
        keep = voxel_kernels.keep_mask_numpy(cam, depth, exp, off.const, off.k)
        pts = cam.depth_to_points(depth, mask=keep)
        pts = np.ascontiguousarray(pts[np.all((pts >= ws[0]) & (pts < ws[1]), axis=1)])
        origin = np.asarray(cam.position, dtype=np.float64)
        tree = pyoctomap.OcTree(0.02)
        octo = time_call(lambda: tree.insertPointCloud(pts, origin), 1 if ctx.quick else 5, warmup=1)
        speed = float(np.median(octo) / np.median(kern))
        rows.append(BenchRow(f"voxels.kernel.{tag}_ms", float(np.median(kern) * 1e3), "ms", None,
                             "OctoMap insertPointCloud (same kept cloud, 20 mm)", float(np.median(octo) * 1e3),
                             f"{speed:.0f}x faster than OctoMap (goal >= 20x); {len(pts)} kept points"))
        vs = f.filter(depth, expected=exp)
        msg = wire.update_request(1, 1, 0.0, vs.voxel_size, vs.keys, vs.counts)
        rows.append(BenchRow(f"voxels.bytes.{tag}", float(len(msg)), "bytes",
                             1162.5 if (w, h) == (640, 480) else None, "raw float32 image", float(w * h * 4),
                             f"{len(vs)} voxels, {wire.BYTES_PER_VOXEL} B/voxel; paper: ~100 voxels x 96 bit"))
    # voxel-size sweep at 640x480
    rig, frames = frames_by_res[(640, 480)]
    cam = rig.cameras[0]
    f = VoxelFilter(cam, ws, static_meshes=statics, robot=rig.robot)
    sizes = (10, 20, 50, 100) if ctx.quick else tuple(range(10, 101, 10))
    for mm in sizes:
        f.configure(voxel_size=mm / 1000)
        tt = time_call(lambda: f.filter(frames[cam.id], q=q_next()), rep)
        rows.append(BenchRow(f"voxels.filter.640x480.{mm}mm_ms", float(np.median(tt) * 1e3), "ms",
                             None, None, None, f"{len(f.filter(frames[cam.id], q=q))} voxels"))
    # scene refresh: centralised (one process) and distributed (node processes)
    configs = ([(3, (1280, 720))] if ctx.quick else
               [(n, (1280, 720)) for n in (1, 2, 3, 4)] + [(3, (424, 240)), (3, (640, 480))])
    for n, (w, h) in configs:
        tag = f"{n}cam.{w}x{h}"
        rig, frames = frames_by_res[(w, h)]
        ids = rig.camera_ids[:n]
        pipe = CentralisedPipeline([rig.camera(c) for c in ids], ws, static_meshes=statics, robot=rig.robot)
        sub = {c: frames[c] for c in ids}
        cen = time_call(lambda: pipe.refresh(sub, q=q_next()), rep)
        cen_cpu = cpu_ms(lambda: pipe.refresh(sub, q=q_next()), rep)
        if ctx.quick:          # node processes take seconds to start: not in quick mode
            dval, note = float("nan"), "distributed not run in quick mode (node processes)"
        else:
            ctx.log(f"voxels: distributed refresh {tag}")
            try:
                cpu: dict = {}
                dist = distributed_refresh(ids, w, h, t, rep, qs, cpu)
                dval = float(np.median(dist) * 1e3)
                note = (f"worst {dist.max() * 1e3:.1f} ms; {n} node processes + server share "
                        f"{os.cpu_count()} cores (load avg {os.getloadavg()[0]:.1f}); node CPU per refresh "
                        f"max {cpu['per_node_ms'].max():.1f} ms, sum {cpu['per_node_ms'].sum():.1f} ms")
            except (RuntimeError, TimeoutError) as exc:
                dval, note = float("nan"), f"distributed run failed: {exc}"
        note += f"; centralised CPU {cen_cpu:.1f} ms"
        if n == 3:
            note += (f"; paper centralised {PAPER_REFRESH_CENT[(w, h)]:g} ms"
                     + ("; goal <= 50 ms" if (w, h) == (1280, 720) else ""))
        rows.append(BenchRow(f"voxels.refresh.{tag}_ms", dval, "ms",
                             PAPER_REFRESH_DIST[(w, h)] if n == 3 else None,
                             "centralised (same pipeline, one process)", float(np.median(cen) * 1e3), note))
    # multi-camera voting on the noisy simulator (640x480, 20 mm): as is, and with blob artefacts
    from depthguard.fusion.voxels import union
    rig, frames = frames_by_res[(640, 480)]
    truth = truth_any(cell, t, 0.02)
    vis = visible_truth(cell, rig, t, 0.02)
    variants = [("noisy", 0.55, frames), ("noisy_t0.1", 0.1, frames), ("blobs_t0.1", 0.1, blob_artefacts(frames))]
    for name, thr, fr in (variants[2:] if ctx.quick else variants):
        pipe = CentralisedPipeline(rig.cameras, ws, threshold=thr, static_meshes=statics, robot=rig.robot)
        sets = pipe.per_camera(fr, q=q)
        tv = time_call(lambda: vote(sets, rig.cameras, fr), 1 if ctx.quick else 5, warmup=1)
        voted = vote(sets, rig.cameras, fr)
        before = score(union(list(sets.values()), 0.02), 0.02, ws[0], ws[1], truth, vis)
        after = score(union(list(voted.values()), 0.02), 0.02, ws[0], ws[1], truth, vis)
        true_lost = (before[2] - before[3]) - (after[2] - after[3])
        rows.append(BenchRow(f"voxels.vote.{name}.false_removed", float(before[3] - after[3]), "voxels", None,
                             "false voxels without voting", float(before[3]),
                             f"threshold {thr}; true voxels lost {true_lost}; precision {before[0]:.3f} -> "
                             f"{after[0]:.3f}, recall {before[1]:.3f} -> {after[1]:.3f}; "
                             f"vote {np.median(tv) * 1e3:.1f} ms (4 cameras)"))
    return rows
