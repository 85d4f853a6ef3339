"""Bench group ``bag``: ROS 2 bags in and out (R31, issue 14).

The bag: flacco-cell's two 640x480 cameras at 30 Hz and its robot's joints at 500 Hz,
20 s (quick mode: 3 s), written by :class:`~depthguard.sources.bag_record.BagRecorder`
(16UC1, zstd chunks). Each frame is the cell's known depth at rest through the Kinect v1
noise model with a fresh seed (noise and quantisation are what makes depth compress
badly; a noiseless image would flatter the size).

Rows:

- ``bag.replay_x_realtime``: seconds of bag per wall second of a ``--fast`` replay by the
  ``bag:`` sources alone (their one pass over the bag, every frame decoded to float32 metres
  and every joint state served, pulled at the 500 Hz control rate as the runner does). Goal
  >= 10. Peer: the independent ``mcap`` reader iterating the same file's messages without
  decoding (zstd decompression + record parsing: the floor of any reader).
- ``bag.replay_x_realtime_cpu``: the same per CPU second (a loaded machine lowers the wall figure).
- ``bag.recorded_mb_per_s``: MB of ``.mcap`` per second of recording; peer: the raw
  16-bit images of that second (2 x 30 x 640 x 480 x 2 bytes = 36.9 MB).
- ``bag.record_x_realtime``: seconds of bag written per wall second (encoding + zstd).

No paper quotes a figure for these.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from depthguard.evaluation.bench import BenchContext, BenchRow, group

CAMERA_HZ, JOINT_HZ = 30.0, 500.0


def make_bench_bag(path: Path, seconds: float, seed: int = 0) -> tuple[float, float]:
    """Write the bench bag (module docstring); returns ``(raw image bytes, wall seconds)``."""
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.sensors import sensor_model
    from depthguard.sim import load_cell
    from depthguard.sources.bag_record import BagRecorder
    from depthguard.sources.frame import Frame
    from depthguard.sources.noise import apply_noise

    rig = load_cell("flacco-cell").rig
    q0 = np.asarray(rig.robot_q0, dtype=np.float64)
    ideal = {c.id: np.array(ExpectedDepth(c, rig.robot, rig.static_meshes()).known(q0), copy=True) for c in rig.cameras}
    rng = np.random.default_rng(seed)
    events = [(k / JOINT_HZ, "j", None) for k in range(int(seconds * JOINT_HZ) + 1)]
    for i, c in enumerate(rig.cameras):
        events += [(i * 0.37 / CAMERA_HZ + k / CAMERA_HZ, "f", c) for k in range(int(seconds * CAMERA_HZ))]
    events.sort(key=lambda e: (e[0], e[1]))
    t0 = time.perf_counter()
    with BagRecorder(path, rig) as rec:
        for stamp, kind, cam in events:
            if kind == "j":
                rec.write_joints(stamp, q0 + 0.05 * np.sin(stamp) * (rig.robot.q_max > q0 + 0.1))
            else:
                m = sensor_model(cam.sensor or "kinect_v1")
                d = apply_noise(ideal[cam.id], m, cam.fx, rng, min_range=cam.min_range, max_range=cam.max_range)
                rec.write_frame(Frame(cam.id, d, stamp))
        raw = rec.raw_bytes
    return float(raw), time.perf_counter() - t0


def replay_seconds(path: Path, dt: float = 0.002) -> tuple[float, int, int, float]:
    """A fast replay by the bag sources: ``(wall s, frames, states, CPU s of this process)``."""
    from depthguard.sim import load_cell
    from depthguard.sources.base import open_joints, open_source, source_schemes

    rig = load_cell("flacco-cell").rig            # the rig and the source modules are loaded before the clock
    source_schemes()
    t0, c0 = time.perf_counter(), time.process_time()
    ctx: dict = {}
    frames, joints = open_source(f"bag:{path}", rig, ctx), open_joints(f"bag:{path}", rig, ctx)
    n_f = n_j = 0
    k = 0
    start = min(frames.first_stamp, joints.first_stamp)
    while not (frames.done and joints.done):
        t = start + k * dt
        n_j += len(joints.states_until(t))
        n_f += len(frames.frames_until(t))
        k += 1
    frames.close()
    joints.close()
    return time.perf_counter() - t0, n_f, n_j, time.process_time() - c0


def _mcap_floor(path: Path) -> float:
    from mcap.reader import make_reader

    t0 = time.perf_counter()
    for mcap_file in path.glob("*.mcap"):
        with open(mcap_file, "rb") as fh:
            for _ in make_reader(fh).iter_messages():
                pass
    return time.perf_counter() - t0


@group("bag")
def bag_group(ctx: BenchContext) -> list[BenchRow]:
    seconds = 3.0 if ctx.quick else 20.0
    tmp = Path(tempfile.mkdtemp(prefix="depthguard-bench-bag-"))
    try:
        path = tmp / "bench"
        ctx.log(f"bag: writing a {seconds:g} s bag (2 x 640x480 at 30 Hz, joints at 500 Hz) ...")
        raw, wall_rec = make_bench_bag(path, seconds, ctx.seed)
        size = sum(f.stat().st_size for f in path.glob("*.mcap"))
        walls, cpus = [], []
        for _ in range(1 if ctx.quick else 3):
            wall, n_f, n_j, cpu = replay_seconds(path)
            walls.append(wall)
            cpus.append(cpu)
        wall, cpu = float(np.median(walls)), float(np.median(cpus))
        try:
            floor = _mcap_floor(path)
            peer, peer_value = "mcap reader, messages undecoded (x real time)", seconds / floor
        except ImportError:
            peer, peer_value = None, None
        rows = [
            BenchRow("bag.replay_x_realtime", seconds / wall, "x", None, peer, peer_value,
                     f"{seconds:g} s bag, {n_f} frames + {n_j} joint states decoded by the bag: sources, fast "
                     f"(median of {len(walls)}; goal >= 10)"),
            BenchRow("bag.replay_x_realtime_cpu", seconds / cpu, "x", None, None, None,
                     "the same replay per CPU second of the process (what a machine whose other processes "
                     "leave it a core would reach)"),
            BenchRow("bag.recorded_mb_per_s", size / seconds / 1e6, "MB/s", None, "raw 16-bit images",
                     raw / seconds / 1e6, "16UC1 + CameraInfo + JointState, zstd chunks (Kinect v1 noise)"),
            BenchRow("bag.record_x_realtime", seconds / wall_rec, "x", None, None, None,
                     "BagRecorder: encode + serialise + zstd (the noise model's time included)"),
        ]
        return rows
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
