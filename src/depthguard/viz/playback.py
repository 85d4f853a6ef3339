"""A monitor's output folder in the live view, with a time slider (``depthguard view DIR``, R31).

``depthguard monitor --out DIR`` writes ``DIR/log.jsonl`` (one record per
control cycle, ``docs/MONITOR.md``) and ``DIR/summary.json``. :func:`load_run`
reads both (every line is checked; a bad one is named by its line number)
and keeps the records at most ``keep_hz`` per second plus every record where
the set of reasons, or running / slowing / stopped, changed, so that an hour
at 500 Hz stays small.
:class:`Playback` adds a time slider and a play switch to a
:class:`~depthguard.viz.live.LiveView` and shows the record at the slider's time.

The log has no joint states: the robot and its points cannot be placed,
so a playback shows the cameras' states, the override, its reasons and the
distances in the panel, and says so. A record that carries ``q`` (dof,) rad
is drawn with the robot.
"""

from __future__ import annotations

import bisect
import json
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from depthguard.viz.live_scene import snapshot_of_record

__all__ = ["Recording", "load_run", "Playback", "rig_of_run"]


@dataclass
class Recording:
    """The records kept from a run: ``times`` (n,) s ascending, ``records`` (n,) dicts, the summary."""
    folder: Path
    times: list
    records: list
    summary: dict
    lines: int

    def at(self, t: float) -> dict:
        """The last record at or before ``t`` (the first one before the start)."""
        i = max(0, bisect.bisect_right(self.times, t) - 1)
        return self.records[i]


def load_run(folder: str | Path, keep_hz: float = 50.0) -> Recording:
    """Read ``folder``'s ``log.jsonl`` and ``summary.json`` (module docstring). ``FileNotFoundError``
    when one is missing; ``ValueError`` naming the file and line of a record that is not a monitor's."""
    from depthguard.progress import stage

    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such folder (give the --out folder of `depthguard monitor`)")
    log_path, summary_path = folder / "log.jsonl", folder / "summary.json"
    for p in (log_path, summary_path):
        if not p.is_file():
            raise FileNotFoundError(f"{p}: missing - {folder} is not the output folder of `depthguard monitor`")
    try:
        summary = json.loads(summary_path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{summary_path}: not JSON ({exc})") from None
    if not isinstance(summary, dict):
        raise ValueError(f"{summary_path}: not a monitor summary (a JSON object is expected)")
    period = 1.0 / float(keep_hz)
    times, records = [], []
    last_t, last_state = -float("inf"), None
    n = 0
    with stage(f"view: reading {log_path}"), open(log_path, encoding="utf-8", errors="strict") as fh:
        for n, line in enumerate(fh, start=1):
            where = f"{log_path} line {n}"
            try:
                rec = json.loads(line)
            except json.JSONDecodeError as exc:
                raise ValueError(f"{where}: not JSON ({exc.msg})") from None
            if not isinstance(rec, dict):
                raise ValueError(f"{where}: not a monitor record (a JSON object is expected)")
            snap = snapshot_of_record(rec, where)          # checks every field the view reads
            if times and snap.t < times[-1]:
                raise ValueError(f"{where}: t = {snap.t} goes back in time (previous {times[-1]})")
            state = (snap.override <= 0.0, snap.override < 1.0, tuple(sorted(snap.reasons)))
            if snap.t - last_t >= period - 1e-9 or state != last_state:
                times.append(snap.t)
                records.append(rec)
                last_t, last_state = snap.t, state
    if not records:
        raise ValueError(f"{log_path}: no record (the run wrote no control cycle)")
    return Recording(folder, times, records, summary, n)


def rig_of_run(recording: Recording, rig_path: Path | None = None):
    """The rig to draw the run in: ``rig_path`` if given, else the built-in cell named by the
    summary's ``rig``; ``ValueError`` saying to give ``--rig`` otherwise."""
    if rig_path is not None:
        from depthguard.rig import Rig

        return Rig.load(rig_path)
    from depthguard.sim.cells import list_cells, load_cell

    name = recording.summary.get("rig")
    if name in list_cells():
        return load_cell(name).rig
    raise ValueError(f"{recording.folder}/summary.json: rig {name!r} is not a built-in cell; "
                     f"give its rig file with --rig FILE")


class Playback:
    """A time slider and a play switch on ``view`` over ``recording`` (module docstring)."""

    def __init__(self, view, recording: Recording, speed: float = 1.0):
        self.view = view
        self.rec = recording
        self.speed = float(speed)
        t0, t1 = recording.times[0], recording.times[-1]
        gui = view.server.gui
        step = max(0.002, round((t1 - t0) / 2000.0, 3))
        self.slider = gui.add_slider("t (s)", min=round(t0, 3), max=round(max(t1, t0 + step), 3), step=step,
                                     initial_value=round(t0, 3), order=-2)
        self.play = gui.add_checkbox("play", False, order=-1)
        has_q = "q" in recording.records[0]
        view.note = ("" if has_q else "This log has no joint states: the robot and its points are not drawn; "
                     "their distances are listed above.")
        if not has_q:
            for name in ("robot", "control points", "vectors"):
                view.set_layer(name, False)
        self.slider.on_update(lambda _e: self.show(float(self.slider.value)))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="depthguard-playback", daemon=True)
        self._thread.start()
        self.show(t0)

    def show(self, t: float) -> None:
        rec = self.rec.at(t)
        self.view.show(snapshot_of_record(rec, f"record at t={t}"))

    def _run(self) -> None:
        last = time.monotonic()
        while not self._stop.wait(0.05):
            now = time.monotonic()
            if self.play.value:
                t = float(self.slider.value) + (now - last) * self.speed
                if t > self.rec.times[-1]:
                    t = self.rec.times[0]
                self.slider.value = min(t, self.slider.max)
                self.show(t)
            last = now

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
