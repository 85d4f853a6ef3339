"""The live view of a monitor running on a simulated cell, in the background (R29, R31).

:func:`live_monitor` is what ``depthguard view --screenshot`` (no folder), the
browser test and the docs' screenshot share: the cell's simulator as the
frame and joint source (``sim:CELL``; the simulated robot obeys the
reaction), the monitor in real time on a background thread with a
:class:`~depthguard.viz.live.LiveView` as one of its sinks, and the caller's
function run meanwhile.
"""

from __future__ import annotations

import threading
from typing import Callable

__all__ = ["live_monitor"]


def live_monitor(during: Callable, cell: str = "flacco-cell", *, source: str | None = None, host: str = "127.0.0.1",
                 port: int = 0, rate_hz: float = 15.0, max_seconds: float = 600.0):
    """Run the monitor on ``cell``'s simulator (``source``: a ``sim:`` spec, default ``sim:CELL``)
    with a live view; call ``during(view, monitor)`` in this thread once the monitor runs; stop
    when it returns (or after ``max_seconds``). Returns ``(during's result, the run's summary dict)``."""
    from depthguard.progress import log
    from depthguard.runtime.monitor import Monitor, warm_up
    from depthguard.runtime.runner import run, summarise
    from depthguard.sim import load_cell
    from depthguard.sources.base import open_joints, open_source
    from depthguard.viz.live import LiveView

    the_cell = load_cell(cell)
    rig = the_cell.rig
    context: dict = {}
    spec = source or f"sim:{cell}"
    sources = [open_source(spec, rig, context)]
    joints = open_joints("sim", rig, context)
    log("view: compiling the monitor's kernels (once; cached on disk) ...")
    warm_up(rig, rig.monitor)
    view = LiveView(rig, host=host, port=port, rate_hz=rate_hz)
    mon = Monitor(rig, rig.monitor, sinks=[joints.on_reaction, view])
    view.attach(mon)
    stop = threading.Event()
    box: dict = {}

    def control() -> None:
        try:
            box["stats"] = run(mon, sources, joints, duration=max_seconds, stop=stop)
        except Exception as exc:  # noqa: BLE001 - reported to the caller
            box["error"] = exc

    th = threading.Thread(target=control, name="depthguard-control", daemon=True)
    th.start()
    try:
        result = during(view, mon)
    finally:
        stop.set()
        th.join(10.0)
        mon.close()                           # closes the view too (a sink)
        for s in sources:
            s.close()
        joints.close()
    if "error" in box:
        raise box["error"]
    stats, wall = box["stats"]
    return result, summarise(mon, stats, wall, {"frames": [spec], "joints": "sim"},
                             {"view_updates": view.updates, "view_errors": list(view.errors)})
