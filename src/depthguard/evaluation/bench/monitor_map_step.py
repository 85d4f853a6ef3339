"""Bench row ``monitor.step_p99_ms.map_on``: the control step's p99 with the free-space map on
(R21, R37; issue 30: "the control step's p99 unchanged with the map on").

In the ``monitor`` group's run (:mod:`depthguard.evaluation.bench.monitor`: flacco-cell, two Kinect
640x480 at 30 Hz from their own threads, step at 500 Hz, the same pre-rendered frames and joint
script), once more with ``free_space`` on (the map's thread at ``free_space_hz``, 10 Hz, 5 cm
voxels, building from the camera workers' products) and the reaction policies plus ``path_watch``
watching the script's own path (``Monitor.watch_path``: a fresh verdict at every map update, the
policy's part in every step). Peer: ``monitor.step_p99_ms`` of the same run, map off. The note
gives the map's builds and their median, and the p99 with the map on but no path watched.
"""

from __future__ import annotations

import numpy as np

from depthguard.evaluation.bench import BenchRow

__all__ = ["map_on_row"]


def _watch(script, n: int = 21):
    """``attach`` for the bench's run: watch the script's path (``n`` waypoints over one period)."""
    def attach(mon):
        stamps = np.linspace(0.0, script.period, n)
        q = np.stack([script.q_at(float(t)) for t in stamps])
        mon.watch_path(stamps, q)

        def finish(_wall):
            fs = mon.free_space
            return {"map_builds": fs.builds, "map_errors": fs.errors,
                    "map_build_ms": 1e3 * float(fs.snapshot.build_s) if fs.snapshot is not None else float("nan")}
        return finish
    return attach


def _plain(mon):
    def finish(_wall):
        fs = mon.free_space
        return {"map_builds": fs.builds, "map_errors": fs.errors}
    return finish


def map_on_row(ctx, script, rig, cfg, duration: float, off: dict) -> BenchRow:
    """The row (module docstring); ``off``: the group's own run with the map off (its result dict)."""
    from depthguard.evaluation.bench.monitor import _pct, _rig_with, _run_monitor
    from depthguard.runtime.monitor import warm_up

    r2, feeds = _rig_with(rig, 2)
    on = cfg.with_changes(free_space=True)
    watched = on.with_changes(reactions=tuple(on.policies) + ("path_watch",))
    warm_up(r2, watched)
    plain = _run_monitor(script, r2, feeds, on, duration, attach=_plain)
    mon = _run_monitor(script, r2, feeds, watched, duration, attach=_watch(script))
    p_off, p_plain, p_on = _pct(off["step_s"], 99), _pct(plain["step_s"], 99), _pct(mon["step_s"], 99)
    ctx.log(f"  map on: step p99 {p_on:.3f} ms watched, {p_plain:.3f} ms not watched, off {p_off:.3f} ms; "
            f"map builds {mon['map_builds']}")
    return BenchRow("monitor.step_p99_ms.map_on", p_on, "ms", None,
                    "the same run with the map off (monitor.step_p99_ms)", p_off,
                    f"free_space on ({on.free_space_hz:g} Hz, {on.free_space_voxel * 100:g} cm voxels, its own "
                    f"thread) and path_watch watching the script's path: {mon['map_builds']} map builds in "
                    f"{duration:g} s ({mon['map_errors']} failed); p50 {_pct(mon['step_s'], 50):.3g} ms (off "
                    f"{_pct(off['step_s'], 50):.3g}); map on, no path watched: p99 {p_plain:.3g} ms "
                    f"({plain['map_builds']} builds); goal: unchanged (<= 1 ms)")
