"""Intel RealSense cameras and SDK recordings as frame sources (R1, R27, R29, R30, R31).

Two schemes; ``pyrealsense2`` is imported when one of them is opened, never
when this module is imported (:func:`depthguard.sources.realsense_device.import_sdk`:
a missing SDK or libusb is one sentence saying what to install):

- ``realsense[:DEVICES]`` — live devices. ``DEVICES`` is a comma list of
  serial numbers, each for the rig's cameras in order (``realsense:123,456``),
  or of ``CAMERA=SERIAL`` (``realsense:left=123,right=456``). Empty: the one
  connected device serves the rig's first camera (several connected: name
  them). Each device streams z16 depth in its camera's size, at the rate
  nearest the rig's ``monitor.camera_hz``.
- ``realsense-file:PATHS`` — SDK recordings (``.db3``, or an older ``.bag``),
  one per device, as ``PATH[,PATH]`` (the rig's cameras in order) or
  ``CAMERA=PATH``. Played through the SDK as fast as the monitor takes the
  frames (no frame dropped; each recording is read past ``t`` before the
  frames due by ``t`` are given, so several recordings come out in stamp
  order), at the mode recorded, other streams beside depth left unread. Stamps
  on the host clock: as recorded, or, for a recording in the device's
  ``hardware_clock``, derived from its metadata
  (:class:`~depthguard.sources.realsense_clock.RecordingClock`); the runner
  paces them in real time from the first stamp, or runs them ``--fast``.

Options after either spec, as ``:WORD``: the SDK's own post-processing
filters (:func:`~depthguard.sources.realsense_device.make_filters`, not
rewritten), ``:spatial`` and ``:temporal``, set so that "no measurement" stays
so; ``:hole_filling`` and ``:decimation`` are refused with the reason. After
``realsense-file:`` only, ``:device_clock``: the recording's own clock
(:mod:`~depthguard.sources.realsense_clock`); :meth:`RealSenseFileSource.stamp_span`
lets the monitor refuse joints on another clock.

Frames (:class:`~depthguard.sources.Frame`): depth (H, W) float32 metres =
z16 × the device's depth units (0 = no measurement); stamp = the SDK's
global time (the host clock, ms → s: the clock of ``time.time()``, so joint
states stamped on the same clock are interpolated at capture, R30). On open,
every stream's intrinsics are checked against its rig camera
(:func:`~depthguard.sources.realsense_device.check_intrinsics`: a mismatch is
an error with both sets of numbers).

``stats()`` per camera: frames ``received``, ``dropped`` (gaps in the frame
numbers: frames the device or the USB link lost), ``overflow`` (dropped here
because the monitor did not take them in time), ``reconnects``.

Unplugging (live): the devices are listed again every ``recheck_s``; a camera
whose device is no longer listed stops delivering, ``lost`` says which (the
monitor holds its last frame, which goes stale: the robot stops, R27), and it
is opened again, intrinsics checked, when the device comes back — no restart.
A device still listed that sends nothing for ``silent_s`` (1 s) is named in
``lost`` too. ``lost`` is None again once every camera delivers.

Context keys: ``realsense_devices`` a callable ``() -> {serial: rs.device}``
(default: the devices an SDK ``context`` lists), ``realsense_recheck_s``
(default 0.5), ``realsense_buffer`` frames buffered per camera (default 4).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

from depthguard.sources.base import register_source
from depthguard.sources.frame import Frame

__all__ = ["RealSenseSource", "RealSenseFileSource", "parse_device_list"]


def parse_device_list(argument: str, rig, what: str) -> list[tuple[str, str]]:
    """``"A,B"`` or ``"cam1=A,cam2=B"`` → ``[(camera id, A), ...]`` (bare items take the rig's
    cameras in order); ``ValueError`` naming the problem."""
    items = [a.strip() for a in argument.split(",")] if argument.strip() else []
    if any(not a for a in items):
        raise ValueError(f"{what}: empty item in {argument!r} (a comma list of {what} or CAMERA={what})")
    out, ids = [], list(rig.camera_ids)
    for i, item in enumerate(items):
        cam, sep, value = item.partition("=")
        if sep:
            cam, value = cam.strip(), value.strip()
            if cam not in ids:
                raise ValueError(f"{what} {item!r}: the rig {rig.name!r} has no camera {cam!r}; cameras: "
                                 f"{', '.join(ids)}")
        else:
            if i >= len(ids):
                raise ValueError(f"{what}: {len(items)} given but the rig {rig.name!r} has {len(ids)} camera(s) "
                                 f"({', '.join(ids)})")
            cam, value = ids[i], item
        if not value:
            raise ValueError(f"{what} {item!r}: nothing after '='")
        out.append((cam, value))
    cams = [c for c, _ in out]
    if len(set(cams)) != len(cams):
        raise ValueError(f"{what}: a camera is named twice in {argument!r}")
    return out


class _Camera:
    """One rig camera served by one device: its stream and counters."""

    def __init__(self, camera, key: str):
        self.camera = camera
        self.key = key                      # serial or path
        self.stream = None
        self.received = self.dropped = self.overflow = 0
        self.reconnects = 0
        self.problem: str | None = None
        self.clock = None                   # a recording's RecordingClock (None: live, the host clock)

    def close_stream(self) -> None:
        if self.stream is not None:
            s = self.stream
            self.received += s.received
            self.dropped += s.dropped
            self.overflow += s.overflow
            s.stop()
            self.stream = None

    def counters(self) -> dict:
        s = self.stream
        extra = (s.received, s.dropped, s.overflow) if s is not None else (0, 0, 0)
        return {"device": self.key, "received": self.received + extra[0], "dropped": self.dropped + extra[1],
                "overflow": self.overflow + extra[2], "reconnects": self.reconnects, "problem": self.problem,
                **({"clock": self.clock.describe()} if self.clock is not None else {})}


def describe_streams(rs, device) -> str:
    """What a device or recording streams, for messages: ``"color 640x480 rgb8 30 Hz (RGB Camera), ..."``
    (``"no stream at all"`` when it has none)."""
    items = []
    for sensor in device.query_sensors():
        try:
            name = sensor.get_info(rs.camera_info.name)
        except RuntimeError:
            name = "a sensor"
        for p in sensor.get_stream_profiles():
            kind = str(p.stream_type()).split(".")[-1]
            fmt = str(p.format()).split(".")[-1]
            size = ""
            if p.is_video_stream_profile():
                v = p.as_video_stream_profile()
                size = f" {v.width()}x{v.height()}"
            items.append(f"{kind}{size} {fmt} {p.fps()} Hz ({name})")
    return ", ".join(dict.fromkeys(items)) or "no stream at all"


class _Frames:
    """What both sources share: per camera a started stream, frames converted to :class:`Frame`."""

    def __init__(self, rs, rig, filters=()):
        from depthguard.sources.realsense_device import make_filters

        self.rs = rs
        self.rig = rig
        self.filter_names = tuple(filters)
        make_filters(rs, self.filter_names)          # refuses a bad name before any device opens
        self._cams: list[_Camera] = []
        self._closed = False

    @property
    def camera_ids(self) -> list[str]:
        return [c.camera.id for c in self._cams]

    def _open_stream(self, cam: _Camera, device, *, blocking: bool, capacity: int, where: str, clock=None):
        from depthguard.sources.realsense_device import (DepthStream, check_intrinsics, choose_profile,
                                                          intrinsics_of, make_filters)

        rs = self.rs
        try:
            sensor = device.first_depth_sensor()
        except RuntimeError:
            what = "the recording" if device.is_playback() else "the device"
            raise ValueError(f"{where}: {what} holds no depth stream; it holds {describe_streams(rs, device)}") \
                from None
        if not device.is_playback() and sensor.supports(rs.option.global_time_enabled) and \
                not sensor.is_option_read_only(rs.option.global_time_enabled):
            sensor.set_option(rs.option.global_time_enabled, 1)       # stamps on the host clock
        c = cam.camera
        profile = choose_profile(rs, sensor, c.width, c.height, self.rig.monitor.camera_hz, where)
        check_intrinsics(c, intrinsics_of(profile), where)
        cam.stream = DepthStream(rs, sensor, profile, capacity=capacity, blocking=blocking, name=where,
                                 filters=make_filters(rs, self.filter_names), clock=clock)   # filters: per camera

    def frames_until(self, t: float) -> list[Frame]:
        """The frames captured at or before ``t`` (s) not returned yet, in stamp order."""
        out = []
        for cam in self._cams:
            s = cam.stream
            if s is None:
                continue
            if s.error is not None and cam.problem is None:
                cam.problem = s.error
            for depth, stamp, _number in s.take_until(t):
                out.append(Frame(cam.camera.id, depth, stamp))
        out.sort(key=lambda f: f.stamp)
        return out

    def stats(self) -> dict:
        """Per camera: device, received, dropped (frame-number gaps), overflow, reconnects, problem."""
        return {c.camera.id: c.counters() for c in self._cams}

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for cam in self._cams:
            cam.close_stream()


class RealSenseFileSource(_Frames):
    """``realsense-file:`` — SDK recordings played through the SDK (module docstring).

    ``first_stamp``: the earliest first frame's stamp (s); ``done`` once every
    recording has played to its end and its frames are taken.
    """

    live = False

    def __init__(self, paths: list[tuple[str, str]], rig, *, buffer: int = 4, first_frame_timeout_s: float = 10.0,
                 filters=(), device_clock: bool = False):
        from depthguard.sources.realsense_clock import RecordingClock
        from depthguard.sources.realsense_device import import_sdk

        super().__init__(import_sdk(), rig, filters)
        rs = self.rs
        self.stall_s = float(first_frame_timeout_s)
        self._ctx = rs.context()
        self._devices = []
        try:
            for cid, p in paths:
                path = Path(p)
                if path.is_dir():
                    raise ValueError(f"realsense-file: {path} is a folder, not a recording (give its .db3 or .bag "
                                     "file)")
                if not path.is_file():
                    raise FileNotFoundError(f"realsense-file: recording {path} not found")
                where = f"realsense-file {path} (camera {cid})"
                try:
                    device = self._ctx.load_device(str(path))
                except RuntimeError as exc:
                    raise ValueError(f"{where}: the SDK cannot read it as a recording ({exc}; truncated or "
                                     "damaged? a recorder stopped before it closed the file leaves it "
                                     "unreadable)") from None
                playback = device.as_playback()
                playback.set_real_time(False)         # as fast as taken: the callback waits for room
                self._devices.append(playback)
                cam = _Camera(rig.camera(cid), str(path))
                cam.clock = RecordingClock(rs, device_clock=device_clock)
                self._cams.append(cam)
                self._open_stream(cam, device, blocking=True, capacity=buffer, where=where, clock=cam.clock)
            firsts = []
            for cam in self._cams:
                s = cam.stream.peek_stamp(first_frame_timeout_s)
                if s is None and cam.stream.error is not None:
                    raise ValueError(cam.stream.error)     # e.g. a clock that cannot be related (realsense_clock)
                if s is None:
                    raise ValueError(f"realsense-file {cam.key}: no depth frame within {first_frame_timeout_s:g} s "
                                     f"(an empty recording?)")
                firsts.append(s)
        except BaseException:
            self.close()
            raise
        self.first_stamp = min(firsts)
        self._firsts = firsts
        self._durations = [p.get_duration().total_seconds() for p in self._devices]

    def stamp_span(self) -> list[tuple[str, float, float, str]]:
        """Per recording ``(what, first stamp s, last stamp s (first + the recording's duration), its
        clock)``: what :func:`~depthguard.sources.realsense_clock.check_joint_clock` compares."""
        out = []
        for cam, first, duration in zip(self._cams, self._firsts, self._durations):
            out.append((f"realsense-file {cam.key} (camera {cam.camera.id})", first, first + duration, cam.clock))
        return out

    def frames_until(self, t: float) -> list[Frame]:
        """The frames stamped at or before ``t`` (s) not returned yet, in stamp order across the
        recordings: each recording is first read past ``t`` (or to its end)."""
        if not self._closed:
            stopped = self.rs.playback_status.stopped
            for d, c in zip(self._devices, self._cams):
                if not c.stream.wait_beyond(t, lambda d=d: d.current_status() == stopped, self.stall_s):
                    c.problem = c.problem or (f"realsense-file {c.key}: the SDK delivered no frame for "
                                              f"{self.stall_s:g} s before the end of the recording")
        return super().frames_until(t)

    @property
    def done(self) -> bool:
        if self._closed:
            return True
        stopped = self.rs.playback_status.stopped
        return all(d.current_status() == stopped and c.stream.pending() == 0
                   for d, c in zip(self._devices, self._cams))

    @property
    def lost(self) -> str | None:
        return next((c.problem for c in self._cams if c.problem), None)

    def close(self) -> None:
        super().close()
        self._devices = []
        for cam in self._cams:
            try:
                self._ctx.unload_device(cam.key)
            except Exception:  # noqa: BLE001 - not loaded (it failed to open) or already gone
                pass


class RealSenseSource(_Frames):
    """``realsense:`` — live devices, picked up again after an unplug (module docstring)."""

    live = True
    first_stamp = None

    def __init__(self, serials: list[tuple[str, str]] | None, rig, *, devices=None, recheck_s: float = 0.5,
                 buffer: int = 4, filters=(), silent_s: float = 1.0):
        from depthguard.sources.realsense_device import import_sdk

        super().__init__(import_sdk(), rig, filters)
        if devices is None:
            ctx = self.rs.context()
            self._ctx = ctx

            def devices():
                found = {}
                for d in ctx.query_devices():
                    try:
                        found[d.get_info(self.rs.camera_info.serial_number)] = d
                    except RuntimeError:
                        pass              # a device going away while listed
                return found
        self._list = devices
        self.recheck_s = float(recheck_s)
        self.silent_s = float(silent_s)
        self.buffer = int(buffer)
        present = self._list()
        if not serials:
            if len(present) != 1:
                raise ValueError("realsense: " + ("no RealSense device is connected" if not present else
                                                  f"{len(present)} devices are connected ({', '.join(sorted(present))}): "
                                                  "name them, realsense:SERIAL[,SERIAL] or CAMERA=SERIAL"))
            serials = [(rig.camera_ids[0], next(iter(present)))]
        missing = [s for _, s in serials if s not in present]
        if missing:
            raise ValueError(f"realsense: device(s) {', '.join(missing)} not connected; connected: "
                             f"{', '.join(sorted(present)) or 'none'}")
        try:
            for cid, serial in serials:
                cam = _Camera(rig.camera(cid), serial)
                self._cams.append(cam)
                self._open_stream(cam, present[serial], blocking=False, capacity=self.buffer,
                                  where=self._where(cam))
        except BaseException:
            self.close()
            raise
        self._next_check = time.monotonic() + self.recheck_s

    @staticmethod
    def _where(cam: _Camera) -> str:
        return f"realsense {cam.key} (camera {cam.camera.id})"

    def check_devices(self) -> None:
        """List the devices: close the streams of those gone, reopen those back (module docstring)."""
        self._next_check = time.monotonic() + self.recheck_s
        try:
            present = self._list()
        except Exception as exc:  # noqa: BLE001 - the SDK failed to list: every camera is in doubt
            for cam in self._cams:
                cam.problem = f"{self._where(cam)}: listing the devices failed ({exc})"
            return
        for cam in self._cams:
            if cam.key not in present:
                if cam.stream is not None:
                    cam.close_stream()
                    cam.problem = (f"{self._where(cam)} was unplugged at {time.strftime('%H:%M:%S')}: "
                                   "its camera goes stale; waiting for it to come back")
            elif cam.stream is not None:
                quiet = cam.stream.silent_s()
                silent = f"{self._where(cam)}: no frame for"
                if quiet > self.silent_s:
                    cam.problem = f"{silent} {quiet:.1f} s (the device is still listed)"
                elif cam.problem is not None and cam.problem.startswith(silent):
                    cam.problem = None
            else:
                try:
                    self._open_stream(cam, present[cam.key], blocking=False, capacity=self.buffer,
                                      where=self._where(cam))
                except (ValueError, RuntimeError) as exc:
                    cam.problem = f"{self._where(cam)} is back but cannot stream: {exc}"
                    cam.close_stream()
                    continue
                cam.reconnects += 1
                cam.problem = None

    def frames_until(self, t: float) -> list[Frame]:
        if not self._closed and time.monotonic() >= self._next_check:
            self.check_devices()
        return super().frames_until(t)

    @property
    def done(self) -> bool:
        return self._closed

    @property
    def lost(self) -> str | None:
        """None while every camera's device is present; else a sentence per missing camera."""
        problems = [c.problem for c in self._cams if c.problem]
        return "; ".join(problems) if problems else None


_OPTIONS = ("spatial", "temporal", "hole_filling", "decimation", "device_clock")


def split_options(argument: str) -> tuple[str, list[str]]:
    """``"a.db3:temporal:spatial"`` → ``("a.db3", ["temporal", "spatial"])``: the trailing
    ``:OPTION`` words (module docstring); anything else stays in the argument."""
    opts: list[str] = []
    while True:
        head, sep, last = argument.rpartition(":")
        if not sep or last.strip() not in _OPTIONS:
            return argument, opts[::-1]
        opts.append(last.strip())
        argument = head


@register_source("realsense-file")
def open_realsense_file(argument: str, rig, context: dict) -> RealSenseFileSource:
    """``realsense-file:PATH[,PATH][:FILTER...]`` or ``CAMERA=PATH,...`` (module docstring)."""
    arg, opts = split_options(argument)
    if not arg.strip():
        raise ValueError("realsense-file needs a recording: realsense-file:PATH (.db3 or .bag)")
    paths = parse_device_list(arg, rig, "recordings")
    device_clock = "device_clock" in opts           # the recording's own clock (realsense_clock)
    return RealSenseFileSource(paths, rig, buffer=int(context.get("realsense_buffer", 4)),
                               filters=[o for o in opts if o != "device_clock"], device_clock=device_clock)


@register_source("realsense")
def open_realsense(argument: str, rig, context: dict) -> RealSenseSource:
    """``realsense[:SERIAL[,SERIAL]][:FILTER...]`` or ``CAMERA=SERIAL,...`` (module docstring)."""
    argument, opts = split_options(argument)
    if "device_clock" in opts:
        raise ValueError("the option :device_clock is for recordings (realsense-file:); a live camera is stamped "
                         "on the host clock (the SDK's global time)")
    serials = parse_device_list(argument, rig, "serials") if argument.strip() else None
    recheck = float(context.get("realsense_recheck_s", 0.5))
    if not (math.isfinite(recheck) and recheck > 0):
        raise ValueError(f"realsense_recheck_s must be > 0 s (got {recheck!r})")
    return RealSenseSource(serials, rig, devices=context.get("realsense_devices"), recheck_s=recheck,
                           buffer=int(context.get("realsense_buffer", 4)), filters=opts)
