"""Bench group ``availability``: how long a real-time monitor stops the robot for late frames (R27, R36).

``depthguard monitor`` runs a built-in cell in real time, the simulator rendering every camera
in the same process (``--source sim:<cell>``), for a few seconds. A camera whose newest frame in
use is older than ``camera_stale_limit`` (three periods) stops the robot (R27): on a machine
that cannot render the cameras and run the monitor at once, that is the monitor's right answer,
and the time it happens is what this group measures — the robot stopped for nothing else than
the machine's speed.

* ``availability.stale_s.<cell>`` — seconds of the run in which a ``stale:`` reason held
  (the control cycles' log, ``log.jsonl``), median over alternated runs; peer: the same run
  with ``monitor.fusion_duty: 1`` (the fusion building after every frame, as before it had a
  duty; the cell's own setting otherwise). Where the cell's own duty is 1 (every built-in
  cell today) the peer runs the same settings, and the gap between the two medians is the
  machine's spread (2026-11-27: 0.54 against 0.04 s on ``ur3-cell``, 5 runs each).
* ``availability.stale_s.<cell>.busy`` — the same with one other process keeping a core busy.

Each row's note gives every run's stale seconds and how many met the goal (on a 2-core machine
a run is ~0 s or seconds, by the moment it runs in: :data:`RUNS` runs per version), and the
slowest camera's frame age (p99) when the simulator delivered it — the source's part of a late
frame (``summary.json`` ``frame_lag_at_push_ms``).

Each run is its own process (``python -m depthguard monitor``, a rig file written from the
built-in cell's with the ``monitor:`` setting changed), so that the runs do not share threads or
a warm cache beyond numba's on-disk one. The first stamps of a run are excluded up to the
monitor's first frame of every camera (a reason saying ``no frame yet``, a wait, not a late frame).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from depthguard.evaluation.bench import BenchContext, BenchRow, group

#: (cell, with a busy core too)
CASES = (("flacco-cell", True), ("ur3-cell", False))
#: runs per case and version (full bench): on a 2-core machine a run is ~0 s or seconds stale by
#: the moment it runs in, so each run is given in the note beside the median
RUNS = 5
#: the issue's goal: stale seconds of an 8 s run
GOAL_S = 0.3


def stale_seconds(log_path: Path) -> float:
    """Seconds of a run's control cycles (``log.jsonl``) in which some ``stale:`` reason held:
    each cycle counts the time to the next one (R27). The cycles before the first one in which
    every camera has had a frame (a reason saying ``no frame yet``: the start's wait, a stop but
    not a late frame) are not counted; a run in which that never happens counts every cycle."""
    ts, stale, waiting = [], [], []
    with open(log_path) as fh:
        for line in fh:
            rec = json.loads(line)
            reasons = rec.get("reasons", {})
            ts.append(float(rec["t"]))
            stale.append(any(k.startswith("stale:") for k in reasons))
            waiting.append(any(k.startswith("stale:") and "no frame yet" in str(m) for k, m in reasons.items()))
    if len(ts) < 2:
        return float("nan")
    start = next((i for i, w in enumerate(waiting) if not w), 0)
    dt = np.diff(np.asarray(ts))
    counted = np.asarray(stale[:-1]) & (np.arange(len(dt)) >= start)
    return float(dt[counted].sum())


def _rig_file(cell: str, folder: Path, **monitor) -> Path:
    """The built-in cell's rig file with ``monitor`` settings added, written into ``folder``
    (its meshes linked beside it)."""
    import yaml

    from depthguard.sim.cells import cell_rig_path

    src = cell_rig_path(cell)
    data = yaml.safe_load(src.read_text())
    data.setdefault("monitor", {}).update(monitor)
    meshes = src.parent / "meshes"
    if meshes.exists() and not (folder / "meshes").exists():
        (folder / "meshes").symlink_to(meshes)
    out = folder / f"{cell}-{'-'.join(f'{k}{v}' for k, v in monitor.items())}.yaml"
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    return out


def run_once(cell: str, seconds: float, busy: bool, folder: Path, **monitor) -> tuple[float, float | None]:
    """``(stale seconds, the slowest camera's frame age p99 at delivery, ms)`` of one real-time
    run (module docstring; the second from the run's ``summary.json`` ``frame_lag_at_push_ms``,
    None where it has none)."""
    rig = _rig_file(cell, folder, **monitor)
    out = Path(tempfile.mkdtemp(dir=folder))
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if busy else None
    try:
        res = subprocess.run([sys.executable, "-m", "depthguard", "monitor", "--rig", str(rig),
                              "--source", f"sim:{cell}", "--duration", str(seconds), "--out", str(out / "run"),
                              "--quiet"], capture_output=True, text=True, timeout=120 + 4 * seconds)
    finally:
        if hog is not None:
            hog.kill()
            hog.wait()
    if res.returncode != 0:
        raise RuntimeError(f"monitor on {cell} failed ({res.returncode}): {res.stderr.strip()[-400:]}")
    summary = json.loads((out / "run" / "summary.json").read_text())
    lags = [v["p99"] for v in summary.get("frame_lag_at_push_ms", {}).values() if v.get("p99") is not None]
    return stale_seconds(out / "run" / "log.jsonl"), (max(lags) if lags else None)


def _runs_text(values: list) -> str:
    """The runs' stale seconds, in order, and how many met the goal (a run here is either ~0 s or
    seconds: a median alone hides which)."""
    met = sum(1 for v in values if v <= GOAL_S)
    return f"runs {', '.join(f'{v:.2f}' for v in values)} s ({met} of {len(values)} <= {GOAL_S:g} s)"


@group("availability")
def bench_availability(ctx: BenchContext) -> list[BenchRow]:
    from depthguard.sim.cells import load_cell

    seconds = 3.0 if ctx.quick else 8.0
    runs = 1 if ctx.quick else RUNS
    rows: list[BenchRow] = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for cell, with_busy in CASES:
            duty = load_cell(cell).rig.monitor.fusion_duty
            for busy in ((False, True) if with_busy else (False,)):
                ours, peer, lags = [], [], []
                for _ in range(runs):                  # alternated: the machine's load hits both
                    ctx.log(f"availability: {cell}{' busy' if busy else ''} fusion_duty {duty}")
                    stale, lag = run_once(cell, seconds, busy, folder, fusion_duty=duty)
                    ours.append(stale)
                    lags += [] if lag is None else [lag]
                    peer.append(run_once(cell, seconds, busy, folder, fusion_duty=1.0)[0])
                lag_text = (f"; the slowest camera's frames were {np.median(lags):.0f} ms old (p99, median of the "
                            f"runs) when the simulator delivered them" if lags else "")
                # with the cell's own duty 1 the peer runs the same settings: the gap between the two
                # medians is then the machine's spread, not a difference of settings
                same = duty >= 1.0
                rows.append(BenchRow(f"availability.stale_s.{cell}{'.busy' if busy else ''}", float(np.median(ours)),
                                     "s", peer=("the same run again (the cell's fusion_duty is 1): the spread of two "
                                                "identical medians" if same else
                                                "the fusion building after every frame (fusion_duty 1)"),
                                     peer_value=float(np.median(peer)),
                                     note=f"depthguard monitor, real time {seconds:g} s, the simulator rendering "
                                          f"every camera in the process{', one other process busy' if busy else ''}; "
                                          f"seconds with a stale: reason, median of {runs}: {_runs_text(ours)}; "
                                          f"peer {_runs_text(peer)}{lag_text}; goal <= {GOAL_S:g} s"))
    return rows
