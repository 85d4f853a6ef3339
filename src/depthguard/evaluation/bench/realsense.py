"""Bench group ``realsense``: the cost of taking a RealSense frame in (R29).

* ``realsense.ingest_ms`` — median wall time from an SDK depth frame (z16,
  848x480, as a D400 delivers it) to the depth in metres (H, W) float32 and
  its capture stamp in seconds, on the SDK's thread, as the source does it
  (:class:`depthguard.sources.realsense_device.DepthStream`, its
  ``ingest_s``). The frames come from the SDK itself: a ``software_device``
  streams 848x480 z16 frames of a ramp into a ``DepthStream``; a consumer
  takes each frame as the monitor's camera worker does. Goal <= 1 ms. Peer: a
  new float32 image per frame (``np.multiply(z16, units, dtype=float32)``
  on the same thread: the conversion without the stream's reuse of images
  that no consumer holds any more — a new 1.6 MB image costs its page faults).

Without the SDK (or libusb) the row is NaN with a note saying what to install.
"""

from __future__ import annotations

import math
import time

import numpy as np

from depthguard.evaluation.bench import BenchContext, BenchRow, group

WIDTH, HEIGHT, FPS = 848, 480, 30


def _measure(rs, n: int) -> tuple[np.ndarray, np.ndarray]:
    from depthguard.sources.realsense_device import DepthStream

    dev = rs.software_device()
    sensor = dev.add_sensor("Depth")
    intr = rs.intrinsics()
    intr.width, intr.height, intr.fx, intr.fy, intr.ppx, intr.ppy = WIDTH, HEIGHT, 420.0, 420.0, 423.5, 239.5
    intr.model, intr.coeffs = rs.distortion.brown_conrady, [0.0] * 5
    vs = rs.video_stream()
    vs.type, vs.index, vs.uid = rs.stream.depth, 0, 0
    vs.width, vs.height, vs.fps, vs.bpp, vs.fmt, vs.intrinsics = WIDTH, HEIGHT, FPS, 2, rs.format.z16, intr
    profile = sensor.add_video_stream(vs)
    sensor.add_read_only_option(rs.option.depth_units, 0.001)
    peer = []

    class _Stream(DepthStream):
        def _on_frame(self, frame):
            z16 = np.asanyarray(frame.get_data())
            t0 = time.perf_counter()
            np.multiply(z16, np.float32(0.001), dtype=np.float32)
            peer.append(time.perf_counter() - t0)
            super()._on_frame(frame)

    stream = _Stream(rs, sensor, profile, capacity=4, name="bench")
    ramp = (np.arange(WIDTH * HEIGHT, dtype=np.uint32) % 6000 + 300).astype(np.uint16).reshape(HEIGHT, WIDTH)
    kept = []
    try:
        for i in range(n):
            img = ramp.copy()
            kept.append(img)                      # the SDK reads the buffer later
            f = rs.software_video_frame()
            f.pixels, f.bpp, f.stride = img, 2, WIDTH * 2
            f.timestamp, f.domain, f.frame_number = time.time() * 1e3, rs.timestamp_domain.global_time, i + 1
            f.profile, f.depth_units = profile.as_video_stream_profile(), 0.001
            sensor.on_video_frame(f)
            stream.peek_stamp(1.0)
            for depth, _stamp, _number in stream.take_until(math.inf):
                np.array(depth, copy=True)        # the consumer copies and lets go, as the monitor does
            time.sleep(0.004)
    finally:
        stream.stop()
    return np.asarray(stream.ingest_s), np.asarray(peer)


@group("realsense")
def bench_realsense(ctx: BenchContext) -> list[BenchRow]:
    from depthguard.sources.realsense_device import RealSenseUnavailable, import_sdk

    try:
        rs = import_sdk()
    except RealSenseUnavailable as exc:
        return [BenchRow("realsense.ingest_ms", math.nan, "ms", note=f"not measured: {exc}")]
    n = 40 if ctx.quick else 300
    ingest, peer = _measure(rs, n)
    if ingest.size < 3:
        return [BenchRow("realsense.ingest_ms", math.nan, "ms", note="not measured: the SDK delivered no frames")]
    ingest, peer = ingest[2:], peer[2:]                  # the first frames fill the pool
    med = float(np.median(ingest)) * 1e3
    return [BenchRow("realsense.ingest_ms", round(med, 4), "ms", peer="new image per frame",
                     peer_value=round(float(np.median(peer)) * 1e3, 4),
                     note=f"SDK frame (z16 {WIDTH}x{HEIGHT}) to float32 metres + stamp s on the SDK's thread, "
                          f"median of {ingest.size} (p99 {np.percentile(ingest, 99) * 1e3:.3f} ms); goal <= 1 ms")]
