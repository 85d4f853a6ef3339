"""The clock of an SDK recording's frames: stamps on the joints' clock (R30, issue 31).

A RealSense frame is stamped in one of the SDK's timestamp domains:

- ``global_time`` — the device's clock mapped by the SDK onto the host clock
  (``time.time()``, ms); ``system_time`` — the host clock when the frame
  arrived (a device without metadata). Both are the host's clock: used as they are.
- ``hardware_clock`` — the device's own clock (ms since it powered up), what a
  recording made with the sensor option ``global_time_enabled`` off holds. It
  cannot be compared with joint states stamped on the host clock as it is.

:class:`RecordingClock` gives every frame of one recording a stamp in seconds:

- host domains: ``timestamp / 1000``;
- ``hardware_clock``, by default **derived from the recording's own metadata**:
  the first depth frame's host arrival time (metadata ``backend_timestamp``, the
  host clock when the USB transfer ended, else ``time_of_arrival``, when the SDK
  received it; ms) minus its device stamp is the offset from the device's clock to
  the host's, fixed for the recording; every frame's stamp is then
  ``(device stamp + offset) / 1000``. The device's spacing of the frames is kept
  exactly; the whole recording sits late by the first frame's transfer latency
  (a few ms over USB 3) and drifts by the device clock's rate error (tens of ppm:
  a few ms per minute);
- ``device_clock=True`` (the source option ``:device_clock``): the recording's
  own clock, ``timestamp / 1000`` whatever the domain — the joint states must be
  stamped on that clock too.

A ``hardware_clock`` frame without either arrival time, and without
``device_clock``, is a :class:`ClockError`: its clock cannot be related to the
joints' (never guessed).

**Wrap-around.** A D400's hardware stamps are a 32-bit microsecond counter
(:data:`HW_WRAP_MS`: it wraps every 71.6 min), so a recording of a camera that
has been on for a while can jump back by 4294967.296 ms in its middle. A
``hardware_clock`` stamp more than half that period behind the previous one is
taken as one more turn of the counter and unwrapped (counted in ``wraps``), in
both the derived and the device clock: the stamps keep rising, each frame keeps
its place (a frame 71 minutes in the past would be refused as stale, and every
frame after it with it). With ``:device_clock`` the joints must be on that
unwrapped clock.
"""

from __future__ import annotations

__all__ = ["ClockError", "RecordingClock", "DEVICE_CLOCK_HINT", "HW_WRAP_MS"]

#: one turn of a D400's 32-bit microsecond hardware clock (ms): 2**32 us, 71.6 min
HW_WRAP_MS = 2.0 ** 32 * 1e-3

#: what to do about a clock that cannot be related to the host's
DEVICE_CLOCK_HINT = ("give the joint states on the camera's clock and add the option :device_clock "
                     "(realsense-file:PATH:device_clock), or record with the sensor option global_time_enabled on")


class ClockError(ValueError):
    """A recording's frames are on a clock that cannot be related to the host's (one sentence)."""


class RecordingClock:
    """Stamps (s) of one recording's frames (module docstring). ``mode``: None before the first
    frame, then ``"host"``, ``"derived"`` or ``"device"``; ``offset_ms`` the device → host offset
    of a derived clock; ``wraps`` the turns of the hardware counter unwrapped (module docstring). The
    stream that uses it names the recording in messages."""

    def __init__(self, rs, *, device_clock: bool = False):
        self.rs = rs
        self.device_clock = bool(device_clock)
        self.mode: str | None = "device" if device_clock else None
        self.offset_ms: float | None = None
        self.wraps = 0
        self._last_hw_ms: float | None = None
        self._arrival_keys = (rs.frame_metadata_value.backend_timestamp, rs.frame_metadata_value.time_of_arrival)

    def _arrival_ms(self, frame) -> float | None:
        for key in self._arrival_keys:
            if frame.supports_frame_metadata(key):
                value = float(frame.get_frame_metadata(key))
                if value > 0:
                    return value
        return None

    def _unwrapped(self, ms: float) -> float:
        """A hardware-clock stamp (ms) with the counter's turns so far added (module docstring)."""
        if self._last_hw_ms is not None and ms < self._last_hw_ms - HW_WRAP_MS / 2:
            self.wraps += 1
        self._last_hw_ms = ms
        return ms + self.wraps * HW_WRAP_MS

    def __call__(self, frame) -> float:
        """The frame's stamp in seconds; :class:`ClockError` when its clock cannot be related."""
        ms = float(frame.get_timestamp())
        hardware = frame.get_frame_timestamp_domain() == self.rs.timestamp_domain.hardware_clock
        if hardware:
            ms = self._unwrapped(ms)
        if self.device_clock:
            return ms * 1e-3
        if not hardware:
            self.mode = self.mode or "host"
            return ms * 1e-3
        if self.offset_ms is None:
            arrival = self._arrival_ms(frame)
            if arrival is None:
                raise ClockError("its frames are stamped by the camera's own clock (hardware_clock) "
                                 "and carry no host arrival time (metadata backend_timestamp or time_of_arrival) "
                                 f"to relate that clock to the joints' host clock; {DEVICE_CLOCK_HINT}")
            self.offset_ms = arrival - ms
            self.mode = "derived"
        return (ms + self.offset_ms) * 1e-3

    def describe(self) -> str:
        """One phrase for logs and stats: which clock the stamps are on."""
        turns = f", its 32-bit counter unwrapped {self.wraps} time(s)" if self.wraps else ""
        if self.mode == "derived":
            return f"the camera's clock + {self.offset_ms:.1f} ms (from the first frame's arrival{turns})"
        if self.mode == "device" and turns:
            return f"the recording's own clock{turns}"
        return {"host": "the host clock (global or system time)", "device": "the recording's own clock",
                None: "not known yet"}[self.mode]


def check_joint_clock(sources, joint_source, joint_spec: str, slack_s: float = 1.0) -> None:
    """``ValueError`` (one sentence) when a recording's frames and the joint states are on clocks that
    cannot be the same one: their stamp spans (s) are more than ``slack_s`` apart. Looks at the
    sources with ``stamp_span()`` (``realsense-file:``) and a joint source with ``first_stamp`` and
    ``last_stamp`` (a recording: ``csv:``); a live one is not judged. Without it, such a run would
    remove the robot at joints of another moment, or at none (R30)."""
    j0, j1 = getattr(joint_source, "first_stamp", None), getattr(joint_source, "last_stamp", None)
    if j0 is None or j1 is None:
        return
    for src in sources:
        for what, f0, f1, clock in getattr(src, "stamp_span", lambda: [])():
            gap = max(f0 - j1, j0 - f1)
            if gap <= slack_s:
                continue
            on = clock.describe() if clock is not None else "the host clock"
            if clock is not None and clock.mode == "device":
                hint = "stamp the joints on the camera's clock, or leave out :device_clock if they are on the host's"
            elif clock is not None and clock.mode == "derived":
                hint = ("its hardware clock was related to the host clock through its metadata; if the joints "
                        "are on the camera's clock add :device_clock")
            else:
                hint = "stamp the joints on the host clock the recording was made on (NTP or PTP)"
            raise ValueError(f"{what}: its frames are stamped {f0:.3f} to {f1:.3f} s ({on}) but the joints "
                             f"{joint_spec} {j0:.3f} to {j1:.3f} s: the two clocks are {gap:.3f} s apart, so the "
                             f"robot could not be removed at each frame's joints (R30); {hint}")
