"""The cores a monitor bench session's threads used (``monitor.cpu_per_camera``, issue 29).

Per thread of the process (Linux ``/proc/self/task``, read by
:mod:`depthguard.runtime.thread_cpu`), Python's threads by name and the native ones (numba's
pool) apart: the monitor's (``depthguard-*`` and native), the control thread's and the bench's
feeders'.
"""

from __future__ import annotations

import math
import os
import threading

from depthguard.runtime.thread_cpu import task_seconds

__all__ = ["thread_cpu", "cpu_shares", "parts_text", "per_camera"]


def thread_cpu() -> dict[int, tuple[str | None, float]]:
    """Per thread (Linux ``/proc/self/task``): id -> (Python thread name, None for a native thread
    such as numba's pool; CPU s user + system). Empty where ``/proc`` is missing."""
    names = {t.native_id: t.name for t in threading.enumerate()}
    out = {}
    try:
        tids = os.listdir("/proc/self/task")
    except OSError:
        return out
    for tid in tids:
        s = task_seconds(int(tid))
        if s is not None:                          # (None: the thread ended meanwhile)
            out[int(tid)] = (names.get(int(tid)), s)
    return out


def cpu_shares(before: dict, after: dict, wall: float, control_tid: int) -> dict:
    """Cores used over ``wall`` s between two :func:`thread_cpu` snapshots: ``monitor`` (threads
    named ``depthguard-*`` and native threads), ``control`` (the control thread), ``bench`` (the
    other Python threads: feeders). NaN each when ``/proc`` was missing."""
    if not after or wall <= 0:
        return {"monitor": math.nan, "control": math.nan, "bench": math.nan, "parts": {}}
    used = {"monitor": 0.0, "control": 0.0, "bench": 0.0}
    parts: dict[str, float] = {}      # the monitor's by thread kind: camera workers, fusion, numba's pool ...
    for tid, (name, cpu) in after.items():
        d = cpu - before.get(tid, (None, 0.0))[1]
        if tid == control_tid:
            used["control"] += d
        elif name is None or name.startswith("depthguard-"):
            used["monitor"] += d
            kind = "numba's pool" if name is None else name.split("-")[1]
            parts[kind] = parts.get(kind, 0.0) + d / wall
        else:
            used["bench"] += d
    return {**{k: v / wall for k, v in used.items()}, "parts": parts}


def parts_text(cpu: dict) -> str:
    """The monitor's cores by thread kind (:func:`cpu_shares`' ``parts``), largest first."""
    parts = sorted(cpu.get("parts", {}).items(), key=lambda kv: -kv[1])
    return ", ".join(f"{k} {v:.3g}" for k, v in parts) or "not measured"


def per_camera(r: dict) -> float:
    """Cores of the monitor's threads per camera in the run ``r`` (a :func:`depthguard.evaluation.bench.monitor` session)."""
    return r["cpu"]["monitor"] / r["cameras"]
