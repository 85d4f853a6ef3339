"""A monitor's run, with the depth of the bag it read, in the view with a time slider (``depthguard view``, R29, R31).

``depthguard view DIR`` shows the output folder of ``depthguard monitor --out DIR``
(``log.jsonl`` + ``summary.json``, :func:`depthguard.viz.playback.load_run`) in the
live view (:class:`~depthguard.viz.live.LiveView`, the same scene code): the
robot at each record's joints ``q``, the control and watch points coloured by
distance with their vectors (magenta: cannot judge), the frustums by camera
state, the panel with the override and its reasons. The log holds no depth:
when the run read a ROS 2 bag (the summary's ``sources.frames`` names
``bag:PATH``) and that bag is here — or ``--bag BAG`` names it — each camera's
points are drawn too, from the very frame the monitor used at the slider's
time (:class:`~depthguard.viz.replay_index.BagDepth`: indexed by time,
decoded on demand), with the pixels removed as the robot (at the frame's
capture joints) or the known scene in their colours.

A bag alone (``depthguard view BAG``) is first replayed by the monitor as fast
as possible (``depthguard monitor --source bag:BAG --fast``, in ``cli/view.py``)
and then shown like its output folder: the view is for seeing what the monitor
decided and why, and only the monitor can say that — a view of the raw depth
with no reactions would show a robot and points but no answer, and nothing
could tell "no obstacle" from "never judged".

:class:`Replay` adds to :class:`~depthguard.viz.playback.Playback` (time slider,
play switch) a speed box and the frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from depthguard.viz.live_scene import snapshot_of_record
from depthguard.viz.playback import Playback, Recording, load_run, rig_of_run

__all__ = ["ReplayInput", "Replay", "open_run", "bag_of_run", "is_bag", "MIN_COVERAGE"]

#: a bag given for a run must hold at least this share of the frames the run's log says it used
MIN_COVERAGE = 0.99


def is_bag(path: str | Path) -> bool:
    """True for a rosbag2 directory (``metadata.yaml``) or an ``.mcap`` / ``.db3`` file."""
    p = Path(path)
    return (p.is_dir() and (p / "metadata.yaml").is_file()) or (p.is_file() and p.suffix.lower() in (".mcap", ".db3"))


def bag_of_run(recording: Recording) -> tuple[Path | None, str]:
    """``(bag path or None, sentence)``: the bag the run read, from its summary's ``sources.frames``
    (a relative path is tried from here, then from the folder's parent)."""
    sources = recording.summary.get("sources") or {}
    frames = sources.get("frames") if isinstance(sources, dict) else None
    specs = [s for s in frames if isinstance(s, str)] if isinstance(frames, list) else []
    bags = [s.partition(":")[2] for s in specs if s.startswith("bag:")]
    if not bags:
        what = ", ".join(specs) or "sources the summary does not name"
        return None, (f"This run's frames came from {what}, not from a bag: the log holds no depth, so no "
                      f"camera points are drawn.")
    for candidate in (Path(bags[0]), recording.folder.parent / bags[0]):
        if is_bag(candidate):
            return candidate, f"Depth from {candidate} (the bag this run read)."
    return None, (f"This run read bag:{bags[0]}, which is not here: give it with --bag BAG to draw each "
                  f"camera's points.")


@dataclass
class ReplayInput:
    """What ``depthguard view`` shows: the run's records, its rig, the depth (or None) and a note for the panel."""
    recording: Recording
    rig: object
    depth: object = None             # depthguard.viz.replay_index.BagDepth or None
    note: str = ""
    cleanup: list = field(default_factory=list)

    def close(self) -> None:
        if self.depth is not None:
            self.depth.close()
        for fn in self.cleanup:
            fn()


def open_run(folder: str | Path, *, bag: str | Path | None = None, rig_path: Path | None = None,
             keep_hz: float = 50.0) -> ReplayInput:
    """The output folder ``folder`` of a monitor run, with the depth of ``bag`` (default: the bag the
    summary names, when it is here). Errors, each one sentence: not an output folder (no
    ``log.jsonl``), a bad log line (its number), a rig that is not built in (``--rig``), a bag that
    is not a bag, lacks a camera, CameraInfo or joint states, or does not hold the frames the log used."""
    from depthguard.sources.bag import BagError
    from depthguard.viz.replay_index import BagDepth

    folder = Path(folder)
    if folder.is_dir() and not (folder / "log.jsonl").is_file() and is_bag(folder):
        raise ValueError(f"{folder} is a ROS 2 bag, not a monitor's output folder (depthguard view BAG replays it)")
    recording = load_run(folder, keep_hz=keep_hz)
    rig = rig_of_run(recording, rig_path)
    if bag is not None:
        if not Path(bag).exists():
            raise FileNotFoundError(f"--bag {bag}: no such bag")
        bag_path, note = Path(bag), f"Depth from {bag}."
    else:
        bag_path, note = bag_of_run(recording)
    depth = None
    if bag_path is not None:
        depth = BagDepth(bag_path, rig)
        try:
            found, asked = depth.coverage(recording)
            if asked and found < MIN_COVERAGE * asked:
                raise BagError(f"bag {bag_path} does not hold the frames this run used: {asked - found} of the "
                               f"{asked} frames in use in {folder}/log.jsonl are not in it (another run's bag?)")
        except Exception:
            depth.close()
            raise
    return ReplayInput(recording, rig, depth, note)


class Replay(Playback):
    """Time slider, play switch and speed over ``source`` in ``view`` (module docstring).

    ``shown``: the :class:`~depthguard.viz.live_scene.Snapshot` last handed to the view.
    """

    def __init__(self, view, source: ReplayInput, speed: float = 1.0):
        self.depth = source.depth
        self.shown = None
        super().__init__(view, source.recording, speed=speed)
        view.note = " ".join(x for x in (source.note, view.note) if x)
        self.speed_box = view.server.gui.add_number("speed (x real time)", initial_value=float(speed), min=0.01,
                                                    max=100.0, step=0.01, order=-0.5)

        @self.speed_box.on_update
        def _(_event) -> None:
            value = float(self.speed_box.value)
            if value > 0:
                self.speed = value

    def show(self, t: float) -> None:
        """Show the record at ``t`` (s, the log's clock) with the frames its cameras used."""
        snap = snapshot_of_record(self.rec.at(t), f"record at t={t}")
        depth = getattr(self, "depth", None)
        if depth is not None:
            errors: list = []
            snap.extra["frames"] = depth.products_of_record(snap, errors)
            for msg in errors:                    # an image that cannot be read: said, the rest is drawn
                if msg not in self.view.errors:
                    self.view.errors.append(msg)
                    from depthguard.progress import log
                    log(f"view: {msg}")
        self.shown = snap
        self.view.show(snap)

    def seek(self, t: float) -> None:
        """Move the time slider to ``t`` (as a browser does); the view shows that record."""
        t = min(max(float(t), float(self.slider.min)), float(self.slider.max))
        self.slider.value = t
        if self.shown is None or not math.isclose(self.shown.t, self.rec.at(t)["t"]):
            self.show(t)
