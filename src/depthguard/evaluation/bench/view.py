"""Bench group ``view``: the monitor's step with the live view on and a browser connected (R29).

The same input as the ``monitor`` group (:mod:`depthguard.evaluation.bench.monitor`):
``flacco-cell``, two 640x480 cameras at 30 Hz from their own threads with
pre-rendered frames, joint states at 500 Hz, ``step`` at 500 Hz, the same run
(its ``_run_monitor``: the control thread under the rig's ``control_priority``) —
twice on this machine, one after the other:

* **view off**: the monitor alone;
* **view on**: a :class:`~depthguard.viz.live.LiveView` is one of the
  monitor's sinks (called on the control thread: one lock, one assignment)
  and updates the scene at 15 Hz on its own thread, with one headless
  Chromium connected to it and drawing (WebGL in software: SwiftShader, on
  the same cores, at niceness ``BROWSER_NICE``: it stands for the operator's
  browser, usually on another machine).

Quick: one pair of 2 s runs; full: three pairs of 10 s, off and on
alternating, so that a change in the machine's load hits both alike.

Rows:

* ``view.step_p99_ms`` — 99th percentile of ``step`` with the view on and
  the browser connected; peer: the same with the view off. Goal <= 1 ms.
* ``view.update_hz`` — scene updates per second the view achieved during
  that run; goal >= 10.

Skipped (no rows, a log line) where no Chromium is installed.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from depthguard.evaluation.bench import BenchContext, BenchRow, group
from depthguard.evaluation.bench.monitor import _pct, _rig_with, _run_monitor, _Script

STEP_GOAL_MS = 1.0
UPDATE_GOAL_HZ = 10.0
#: the browser's niceness: it stands for the operator's browser, usually on another machine
BROWSER_NICE = 10


def _run(script: _Script, rig, feeds, cfg, duration: float, view: bool) -> dict:
    """The monitor bench's real-time run (:func:`~depthguard.evaluation.bench.monitor._run_monitor`,
    control thread under the rig's ``control_priority``), with or without the view and a browser."""
    if not view:
        return {**_run_monitor(script, rig, feeds, cfg, duration), "updates": 0, "update_s": [], "browser": False}
    held: dict = {}

    def attach(mon):
        from depthguard.viz.browser import HeadlessBrowser, wait_for_client
        from depthguard.viz.live import LiveView

        live = held["live"] = LiveView(rig, port=0, monitor=mon)
        mon.sinks.append(live)
        browser = held["browser"] = HeadlessBrowser(live.url, size=(1024, 768), nice=BROWSER_NICE)
        wait_for_client(live.server, 60.0)
        mon.push_joints(-0.002, script.q_cycle(0))
        mon.step(-0.001)                       # the browser draws the scene once before the clock starts
        time.sleep(3.0)
        n0, cpu0 = live.updates, (live.cpu_s, _thread_cpu(live))

        def finish(wall: float) -> dict:
            return {"updates": live.updates - n0, "wall": wall,
                    "cpu": ((live.cpu_s - cpu0[0]) / wall, (_thread_cpu(live) - cpu0[1]) / wall),
                    "update_s": list(live.update_s), "errors": list(live.errors),
                    "browser": browser.proc.poll() is None and bool(live.server.get_clients())}
        return finish

    try:
        return _run_monitor(script, rig, feeds, cfg, duration, attach=attach)
    finally:
        if "browser" in held:
            held["browser"].close()


def _thread_cpu(live) -> float:
    """CPU seconds of viser's event-loop thread (Linux ``/proc``; 0 elsewhere)."""
    import os

    th = getattr(getattr(live.server, "_websock_server", None), "_server_thread", None)
    try:
        with open(f"/proc/self/task/{th.native_id}/stat") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (AttributeError, OSError, ValueError, IndexError):
        return 0.0


@group("view")
def bench_view(ctx: BenchContext) -> list[BenchRow]:
    from depthguard.runtime.monitor import warm_up
    from depthguard.runtime.runner import REAL_TIME_SWITCH_INTERVAL_S
    from depthguard.sim import load_cell
    from depthguard.viz.browser import find_browser

    if find_browser() is None:
        ctx.log("bench view: skipped - no Chromium (install the Debian package `chromium`)")
        return []
    cell = load_cell("flacco-cell")
    duration = 2.0 if ctx.quick else 10.0
    script = _Script(cell, 10 if ctx.quick else 31, ctx.seed)
    rig, feeds = _rig_with(cell.rig, 2)
    cfg = rig.monitor
    warm_up(rig, cfg)
    old = sys.getswitchinterval()
    sys.setswitchinterval(REAL_TIME_SWITCH_INTERVAL_S)
    pairs = 1 if ctx.quick else 3                    # off, on, off, on ...: the machine's load drifts alike
    off: dict = {"step_s": []}
    on: dict = {"step_s": [], "update_s": [], "updates": 0, "wall": 0.0, "browser": True, "errors": []}
    try:
        for _ in range(pairs):
            a = _run(script, rig, feeds, cfg, duration, view=False)
            b = _run(script, rig, feeds, cfg, duration, view=True)
            off["step_s"] += a["step_s"]
            on["step_s"] += b["step_s"]
            on["update_s"] += b["update_s"]
            on["updates"] += b["updates"]
            on["wall"] += b["wall"]
            on["browser"] = on["browser"] and b["browser"]
            on["errors"] += b["errors"]
            on["cpu"] = [x + y / pairs for x, y in zip(on.get("cpu", (0.0, 0.0)), b["cpu"])]
    finally:
        sys.setswitchinterval(old)
    on["update_hz"] = on["updates"] / on["wall"] if on["wall"] > 0 else 0.0
    upd = np.asarray(on["update_s"]) * 1e3
    ctx.log(f"  view off: step p50 {_pct(off['step_s'], 50):.3f} p99 {_pct(off['step_s'], 99):.3f} ms; view on + "
            f"browser: p50 {_pct(on['step_s'], 50):.3f} p99 {_pct(on['step_s'], 99):.3f} ms, "
            f"{on['update_hz']:.1f} updates/s")
    common = (f"flacco-cell, 2 Kinect 640x480 at 30 Hz, step at 500 Hz, {pairs} x ({duration:g} s view off, "
              f"{duration:g} s view on); one headless Chromium connected throughout: {on['browser']} (WebGL in "
              f"software on the same cores, at niceness {BROWSER_NICE})")
    return [
        BenchRow("view.step_p99_ms", _pct(on["step_s"], 99), "ms", peer="view off (same run, same input)",
                 peer_value=_pct(off["step_s"], 99),
                 note=(f"{common}; p50 {_pct(on['step_s'], 50):.3g} ms (off {_pct(off['step_s'], 50):.3g}), "
                       f"{len(on['step_s'])} cycles; goal <= {STEP_GOAL_MS:g} ms")),
        BenchRow("view.update_hz", float(on["update_hz"]), "Hz",
                 note=(f"scene updates per second on the view's thread (rate 15 Hz); update p50 "
                       f"{np.percentile(upd, 50) if len(upd) else float('nan'):.3g} ms, p99 "
                       f"{np.percentile(upd, 99) if len(upd) else float('nan'):.3g} ms; CPU: view thread "
                       f"{on['cpu'][0] * 100:.1f} %, viser's event loop {on['cpu'][1] * 100:.1f} % of a core; view errors "
                       f"{on.get('errors') or 'none'}; goal >= {UPDATE_GOAL_HZ:g} Hz")),
    ]
