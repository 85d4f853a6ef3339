"""The Intel RealSense SDK (``pyrealsense2``) glue of the RealSense sources (R1, R29, R31).

Everything here that touches the SDK takes the module from :func:`import_sdk`,
which imports ``pyrealsense2`` when a RealSense source, command or bench is
used — never when this module is imported. A missing SDK, or its missing
system library (libusb), becomes one :class:`RealSenseUnavailable` sentence
that names what to install.

- :func:`convert_frame`: one SDK depth frame → ``(depth (H, W) float32 m,
  stamp s, frame number)``: ``z16 × depth units`` (0 stays 0 = no
  measurement); the stamp is the SDK's global time (host clock, ms) in
  seconds, so that a frame is on the clock of the joint states (R30).
- :func:`choose_profile`, :func:`intrinsics_of`, :func:`check_intrinsics`:
  the depth mode of a rig camera, and the SDK's intrinsics against the rig's.
- :func:`make_filters`: the SDK's own spatial and temporal filters, set so that
  "no measurement" stays so (hole filling refused, temporal persistence off).
- :class:`DepthStream`: one depth sensor started with a callback that filters, converts
  each frame at once and keeps it in a bounded buffer (a recording played as
  fast as possible waits for room — back-pressure; a live camera drops its
  oldest frame instead, counted in ``overflow``). Gaps in the frame numbers
  are counted in ``dropped`` (frames the camera or the USB link lost).
- :func:`record_depth`: frames written as an SDK recording by the SDK's own
  recorder from a ``software_device`` (raw ``mono16``; SDK >= 2.58 writes ROS 2
  ``.db3``) — simulated cells as recordings, and the tests without hardware.
"""

from __future__ import annotations

import atexit
import math
import sys
import threading
import time
import weakref
from collections import deque

import numpy as np

__all__ = ["RealSenseUnavailable", "SDK_HINT", "import_sdk", "convert_frame", "intrinsics_of",
           "choose_profile", "check_intrinsics", "DepthStream", "record_depth", "INTRINSICS_TOLERANCE_PX",
           "FILTERS", "make_filters"]

#: what to install, said once wherever the SDK is missing
SDK_HINT = ("install the Intel RealSense SDK with pip install 'depthguard[realsense]' "
            "(and on Debian/Ubuntu its USB library: apt install libusb-1.0-0)")

#: the largest difference (pixels) between the SDK's fx, fy, cx, cy and the rig's that is accepted
INTRINSICS_TOLERANCE_PX = 1.0


class RealSenseUnavailable(ValueError):
    """The RealSense SDK cannot be imported here (the message says what to install)."""


def import_sdk():
    """The ``pyrealsense2`` module, or :class:`RealSenseUnavailable` with one sentence."""
    try:
        import pyrealsense2
    except ImportError as exc:
        text = str(exc)
        if "libusb" in text:
            raise RealSenseUnavailable(
                f"the RealSense SDK (pyrealsense2) is installed but its USB library is missing ({text}): "
                "on Debian/Ubuntu apt install libusb-1.0-0") from None
        raise RealSenseUnavailable(f"RealSense sources need the SDK, which is not installed: {SDK_HINT}") from None
    except OSError as exc:                                  # a broken shared library
        raise RealSenseUnavailable(f"the RealSense SDK (pyrealsense2) cannot load ({exc}): {SDK_HINT}") from None
    return pyrealsense2


# ------------------------------------------------------------------ frames
def convert_frame(rs, frame, units: float | None = None, out=None, clock=None) -> tuple[np.ndarray, float, int]:
    """``(depth (H, W) float32 m, stamp s, frame number)`` of an SDK depth frame.

    ``depth = z16 × units`` (``units``: the frame's own depth units when None),
    written into ``out`` ((H, W) float32) when given and of the frame's size;
    the stamp is the frame's timestamp, ms of the host clock (``global_time``
    or ``system_time`` domain) / 1000. ``ValueError`` for a frame stamped by
    the device's own clock (``hardware_clock``): it is not on the host's clock.
    ``clock``: a callable ``frame -> stamp s`` used instead (a recording's
    :class:`~depthguard.sources.realsense_clock.RecordingClock`).
    """
    if clock is not None:
        stamp = clock(frame)
    elif frame.get_frame_timestamp_domain() == rs.timestamp_domain.hardware_clock:
        raise ValueError("frames are stamped by the camera's own clock, not the host's: turn the sensor "
                         "option global_time_enabled on (the SDK's global time)")
    else:
        stamp = frame.get_timestamp() * 1e-3
    if units is None:
        units = frame.as_depth_frame().get_units()
    z16 = np.asanyarray(frame.get_data())
    if out is not None and out.shape == z16.shape and out.dtype == np.float32:
        depth = np.multiply(z16, np.float32(units), out=out)
    else:
        depth = np.multiply(z16, np.float32(units), dtype=np.float32)
    return depth, stamp, int(frame.get_frame_number())


def intrinsics_of(profile) -> dict:
    """``width, height, fx, fy, cx, cy, fps, model, coeffs`` of an SDK depth stream profile."""
    vp = profile.as_video_stream_profile()
    i = vp.get_intrinsics()
    return {"width": int(i.width), "height": int(i.height), "fx": float(i.fx), "fy": float(i.fy),
            "cx": float(i.ppx), "cy": float(i.ppy), "fps": int(vp.fps()), "model": str(i.model),
            "coeffs": [float(c) for c in i.coeffs]}


def depth_profiles(rs, sensor) -> list:
    """The sensor's z16 depth profiles."""
    return [p for p in sensor.get_stream_profiles()
            if p.stream_type() == rs.stream.depth and p.format() == rs.format.z16 and p.is_video_stream_profile()]


def choose_profile(rs, sensor, width: int, height: int, fps: float, where: str):
    """The z16 depth profile of ``width`` x ``height`` whose rate is nearest ``fps`` (Hz);
    ``ValueError`` naming the modes the sensor offers when it has no such size."""
    profiles = depth_profiles(rs, sensor)
    fitting = [p for p in profiles if (p.as_video_stream_profile().width(), p.as_video_stream_profile().height())
               == (width, height)]
    if not fitting:
        modes = sorted({(p.as_video_stream_profile().width(), p.as_video_stream_profile().height(), p.fps())
                        for p in profiles})
        raise ValueError(f"{where}: no {width}x{height} depth mode; the device offers "
                         + (", ".join(f"{w}x{h}@{f}" for w, h, f in modes) or "no depth stream")
                         + " (write the rig's camera with depthguard rig from-realsense)")
    return min(fitting, key=lambda p: (abs(p.fps() - fps), -p.fps()))


def check_intrinsics(camera, intr: dict, where: str, tol_px: float = INTRINSICS_TOLERANCE_PX) -> None:
    """``ValueError`` with both sets of numbers when the SDK's intrinsics ``intr``
    (:func:`intrinsics_of`) are not the rig camera's within ``tol_px`` pixels, or the
    stream is distorted (the monitor's cameras are pinholes, R1)."""
    rig = {"width": camera.width, "height": camera.height, "fx": camera.fx, "fy": camera.fy, "cx": camera.cx,
           "cy": camera.cy}
    size_ok = (intr["width"], intr["height"]) == (camera.width, camera.height)
    if not size_ok or any(abs(intr[k] - rig[k]) > tol_px for k in ("fx", "fy", "cx", "cy")):
        def fmt(d):
            return (f"{d['width']}x{d['height']} fx={d['fx']:.3f} fy={d['fy']:.3f} cx={d['cx']:.3f} "
                    f"cy={d['cy']:.3f}")
        raise ValueError(f"{where}: the SDK's intrinsics {fmt(intr)} are not the rig's camera {camera.id!r} "
                         f"{fmt(rig)} (tolerance {tol_px:g} px); write the camera with depthguard rig "
                         "from-realsense, or check which device serves which camera")
    if any(abs(c) > 1e-9 for c in intr["coeffs"]):
        raise ValueError(f"{where}: the depth stream has lens distortion {intr['model']} {intr['coeffs']}; "
                         "the monitor needs a rectified (pinhole) depth stream")


# ------------------------------------------------------------------ the SDK's post-processing
#: the SDK's filters a source may apply, in the order applied
FILTERS = ("spatial", "temporal")
_REFUSED_FILTERS = {
    "hole_filling": "it replaces 'no measurement' by a neighbour's depth: unknown space would read as a "
                    "surface with free space in front of it (R28)",
    "decimation": "it changes the image size, so the rig camera's intrinsics would no longer apply "
                  "(not supported yet)",
}


def make_filters(rs, names) -> list:
    """The SDK's own processing blocks for ``names`` (of :data:`FILTERS`), in that order.

    ``spatial``: edge-preserving smoothing, the SDK's defaults, hole filling off.
    ``temporal``: smoothing over time, the SDK's defaults but **persistence off**
    (its option ``holes_fill`` = 0): the default would show an older depth where the
    newest frame has none (a person arriving in dark clothes would stay background).
    ``ValueError`` for the others, saying why (``hole_filling``, ``decimation``).
    """
    out = []
    for n in names:
        if n in _REFUSED_FILTERS:
            raise ValueError(f"the RealSense filter {n!r} is refused: {_REFUSED_FILTERS[n]}")
        if n not in FILTERS:
            raise ValueError(f"unknown RealSense filter {n!r}; known: {', '.join(FILTERS)}")
    for n in FILTERS:
        if n in names:
            f = rs.spatial_filter() if n == "spatial" else rs.temporal_filter()
            f.set_option(rs.option.holes_fill, 0)
            out.append(f)
    return out


# ------------------------------------------------------------------ a started sensor
def _unreferenced(pool: list, shape, free_refs: int):
    """The first image of ``pool`` of ``shape`` that only the pool references, or None."""
    for a in pool:
        if a.shape == shape and sys.getrefcount(a) == free_refs:
            return a
    return None


def _calibrate_free_refs() -> int:
    """The reference count :func:`_unreferenced` sees for an image that only its pool holds
    (measured, not assumed: the interpreter's counting of borrowed references varies)."""
    probe = [np.empty((1, 1), dtype=np.float32)]
    for r in range(1, 16):
        if _unreferenced(probe, (1, 1), r) is not None:
            probe.append(probe[0])                             # one more reference: must not match
            return r if _unreferenced(probe[:1], (1, 1), r) is None else -1
    return -1                                                  # never matches: no reuse


_FREE_REFS = _calibrate_free_refs()


#: the streams started and not stopped yet: stopped at exit (``_stop_open_streams``)
_OPEN_STREAMS: "weakref.WeakSet[DepthStream]" = weakref.WeakSet()


@atexit.register
def _stop_open_streams() -> None:
    """Stop every stream still running when the interpreter exits, before it finalizes: an SDK
    thread still in a stream's Python callback then (a recording's blocking callback waiting for
    room, say) is torn down by the interpreter's shutdown inside C++, and the SDK aborts the
    process (``FATAL: exception not rethrown``, exit 134, or a segmentation fault) — as a
    command that raised a usage error after opening a recording did."""
    for stream in list(_OPEN_STREAMS):
        stream.stop()


class DepthStream:
    """One depth sensor started with a converting callback (module docstring).

    ``take_until(t)`` → the buffered ``(depth, stamp, number)`` with stamp <= ``t``
    (s), oldest first. ``blocking``: the callback waits for room (a recording
    played as fast as possible); else the oldest buffered frame is dropped
    (``overflow``). Counters: ``received``, ``dropped`` (gaps in frame numbers),
    ``overflow``; ``error`` holds a sentence when a frame could not be used;
    ``ingest_s`` the wall seconds of the newest conversions. A new frame is written
    into the image of an earlier one only when nothing references that image any
    more (:func:`_unreferenced`): a frame a consumer keeps never changes. ``clock``: the
    stamps' callable for :func:`convert_frame` (None: the host clock, R30).
    """

    def __init__(self, rs, sensor, profile, *, capacity: int = 8, blocking: bool = False, name: str = "camera",
                 filters=(), clock=None):
        self.rs = rs
        self.clock = clock
        self.filters = list(filters)        # SDK processing blocks applied to each frame, in order
        self.sensor = sensor
        self.profile = profile
        self.name = name
        self.capacity = max(1, int(capacity))
        self.blocking = blocking
        self.units = float(sensor.as_depth_sensor().get_depth_scale()) if sensor.is_depth_sensor() else None
        self._buf: deque = deque()
        self._cv = threading.Condition()
        self.received = 0
        self.dropped = 0
        self.overflow = 0
        self.error: str | None = None
        self.last_number: int | None = None
        self.last_arrival = math.nan        # time.monotonic() of the newest frame
        self.ingest_s: deque = deque(maxlen=1000)      # wall seconds of the newest conversions
        self._pool: list[np.ndarray] = []
        self._pool_max = self.capacity + 4
        self.started_at = time.monotonic()
        self._stopped = False
        sensor.open(profile)
        try:
            sensor.start(self._on_frame)
        except Exception:
            sensor.close()
            raise
        _OPEN_STREAMS.add(self)

    def _on_frame(self, frame) -> None:
        try:
            for f in self.filters:
                frame = f.process(frame)
            t0 = time.perf_counter()
            depth, stamp, number = convert_frame(self.rs, frame, out=self._free_buffer(frame), clock=self.clock)
            self.ingest_s.append(time.perf_counter() - t0)
        except Exception as exc:  # noqa: BLE001 - an SDK thread must not raise; reported in error
            with self._cv:
                self.error = f"{self.name}: {exc}"
                self._cv.notify_all()                  # a wait for the first frame ends with the reason
            return
        with self._cv:
            if self.last_number is not None and number > self.last_number + 1:
                self.dropped += number - self.last_number - 1
            self.last_number = number
            self.received += 1
            self.last_arrival = time.monotonic()
            while self.blocking and len(self._buf) >= self.capacity and not self._stopped:
                self._cv.wait(0.05)
            if len(self._buf) >= self.capacity:
                self._buf.popleft()
                self.overflow += 1
            self._buf.append((depth, stamp, number))
            self._cv.notify_all()

    def _free_buffer(self, frame) -> np.ndarray | None:
        """A float32 image of the frame's size that nothing outside the pool references any
        more (every frame given out, and every view of it, is gone), else a new one kept in
        the pool while it has room: a new 1.6 MB image per frame costs its page faults, more
        than the conversion itself. Never an image that a consumer still holds."""
        vf = frame.as_video_frame()
        shape = (vf.get_height(), vf.get_width())
        a = _unreferenced(self._pool, shape, _FREE_REFS)
        if a is not None:
            return a
        if len(self._pool) >= self._pool_max:
            return None
        a = np.empty(shape, dtype=np.float32)
        self._pool.append(a)
        return a

    def silent_s(self) -> float:
        """Seconds since the newest frame arrived (since the start before the first)."""
        with self._cv:
            last = self.last_arrival if self.received else self.started_at
        return time.monotonic() - last

    def peek_stamp(self, timeout: float = 0.0) -> float | None:
        """The stamp (s) of the oldest buffered frame, waiting up to ``timeout`` s for one (None at
        once when a frame could not be used: ``error`` says why)."""
        with self._cv:
            if not self._buf and timeout > 0:
                self._cv.wait_for(lambda: bool(self._buf) or self.error is not None, timeout)
            return self._buf[0][1] if self._buf else None

    def wait_beyond(self, t: float, finished, timeout: float) -> bool:
        """Wait up to ``timeout`` s until a frame stamped after ``t`` (s) is buffered, the buffer
        is full, or ``finished()`` (the recording ended); False on timeout. A recording played as
        fast as possible thus gives every frame due by ``t``, whatever its thread's pace."""
        end = time.monotonic() + timeout
        with self._cv:
            while not ((self._buf and self._buf[-1][1] > t) or len(self._buf) >= self.capacity):
                if finished() or time.monotonic() > end:
                    return finished()
                self._cv.wait(0.005)
        return True

    def pending(self) -> int:
        with self._cv:
            return len(self._buf)

    def take_until(self, t: float) -> list[tuple[np.ndarray, float, int]]:
        out = []
        with self._cv:
            while self._buf and self._buf[0][1] <= t:
                out.append(self._buf.popleft())
            if out:
                self._cv.notify_all()
        return out

    def stop(self) -> None:
        """Stop and close the sensor (quietly: an unplugged device cannot answer)."""
        with self._cv:
            if self._stopped:
                return
            self._stopped = True
            self._cv.notify_all()
        _OPEN_STREAMS.discard(self)
        for call in (self.sensor.stop, self.sensor.close):
            try:
                call()
            except Exception:  # noqa: BLE001 - the device may be gone
                pass


# ------------------------------------------------------------------ recording (software device)
def record_depth(path, frames, camera, *, serial: str = "000000000000", name: str = "depthguard software camera",
                 units: float = 0.001, fps: int = 30, numbers=None, period_s: float | None = None) -> dict:
    """Write ``frames`` [(depth (H, W) float m, stamp s)] of rig camera ``camera`` as an SDK
    recording at ``path`` (the SDK's recorder, raw ``mono16``; ``.db3`` with SDK >= 2.58).

    A ``software_device`` named ``name`` with serial ``serial`` gets a depth sensor of the
    camera's intrinsics (no distortion), depth units ``units`` m and rate ``fps``; each frame is
    quantised to ``round(depth / units)`` (0 = no measurement; beyond 65535 units: 0), stamped
    ``stamp × 1000`` ms in the global-time domain, and numbered ``numbers[i]`` (default 1, 2,
    ...). Frames are injected ``period_s`` apart (default ``1 / fps``: the recorder drops frames
    injected back to back). Refuses an existing ``path``. Returns ``{"z16": [...], "numbers": [...]}``.
    """
    from pathlib import Path

    rs = import_sdk()
    path = Path(path)
    if path.exists():
        raise ValueError(f"{path} exists already; record into a new file")
    numbers = list(range(1, len(frames) + 1)) if numbers is None else [int(n) for n in numbers]
    if len(numbers) != len(frames):
        raise ValueError(f"record_depth: {len(frames)} frames but {len(numbers)} frame numbers")
    W, H = int(camera.width), int(camera.height)
    dev = rs.software_device()
    sensor = dev.add_sensor("Depth")
    intr = rs.intrinsics()
    intr.width, intr.height = W, H
    intr.fx, intr.fy, intr.ppx, intr.ppy = float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy)
    intr.model, intr.coeffs = rs.distortion.brown_conrady, [0.0] * 5
    vs = rs.video_stream()
    vs.type, vs.index, vs.uid = rs.stream.depth, 0, 0
    vs.width, vs.height, vs.fps, vs.bpp, vs.fmt, vs.intrinsics = W, H, int(fps), 2, rs.format.z16, intr
    profile = sensor.add_video_stream(vs)
    sensor.add_read_only_option(rs.option.depth_units, float(units))     # else playback finds no depth sensor
    dev.register_info(rs.camera_info.serial_number, str(serial))
    dev.register_info(rs.camera_info.name, str(name))
    recorder = rs.recorder(str(path), dev, False)                         # False: raw, not compressed
    sink = rs.frame_queue(4)
    sensor.open(profile)
    sensor.start(sink)
    kept, z16s = [], []
    period = (1.0 / fps) if period_s is None else float(period_s)
    try:
        for (depth, stamp), number in zip(frames, numbers):
            d = np.asarray(depth, dtype=np.float64)
            q = np.where(np.isfinite(d) & (d > 0), np.round(d / units), 0.0)
            z16 = np.where(q <= 65535, q, 0).astype(np.uint16)
            kept.append(z16)                                 # the SDK reads the buffer later: keep it alive
            z16s.append(z16)
            f = rs.software_video_frame()
            f.pixels, f.bpp, f.stride = z16, 2, W * 2
            f.timestamp, f.domain, f.frame_number = float(stamp) * 1e3, rs.timestamp_domain.global_time, number
            f.profile, f.depth_units = profile.as_video_stream_profile(), float(units)
            t0 = time.perf_counter()
            sensor.on_video_frame(f)
            while sink.poll_for_frame():                     # keep the queue empty
                pass
            time.sleep(max(0.0, period - (time.perf_counter() - t0)))
        time.sleep(0.1)
    finally:
        sensor.stop()
        sensor.close()
        del recorder                                         # closes the file
    return {"z16": z16s, "numbers": numbers}
