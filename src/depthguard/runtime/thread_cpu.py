"""Where a run's CPU went: seconds per thread of the process (issue 29, R36).

A monitor that falls behind real time stops the robot for stale frames (R27). Which part
took the machine — the simulated cameras, the camera workers, the fusion, the control loop,
the sinks — is read from the kernel's per-thread counters (``/proc/self/task/<tid>/stat``,
Linux) for every live Python thread, grouped by the thread's name with a camera's id or a
source's index dropped (``depthguard-camera-camA`` and ``-camB`` are one ``depthguard-camera``
line). What no live Python thread accounts for (numba's parallel workers, threads that ended,
start-up) is ``other``. Elsewhere than Linux the counters are absent: ``{}``.
"""

from __future__ import annotations

import os
import re
import threading
import time

__all__ = ["thread_cpu_seconds", "cpu_by_part", "top_parts", "task_seconds"]

_TICKS = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
#: threads of which a run has one per camera or source: grouped under the prefix
_PER_ITEM = re.compile(r"^(depthguard-(?:camera|source|units|unit-states))-.+$")


def task_seconds(tid: int) -> float | None:
    """User + system CPU seconds of thread ``tid`` of this process, None when unreadable."""
    try:
        with open(f"/proc/self/task/{tid}/stat") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    # after "pid (comm)": state is field 3, utime field 14, stime field 15 (proc(5))
    return (int(fields[11]) + int(fields[12])) / _TICKS


def thread_cpu_seconds() -> dict[str, float]:
    """``{thread name: CPU s}`` of every live Python thread (``{}`` where the kernel does not say)."""
    out: dict[str, float] = {}
    for th in threading.enumerate():
        tid = getattr(th, "native_id", None)
        s = None if tid is None else task_seconds(tid)
        if s is not None:
            out[th.name] = out.get(th.name, 0.0) + s
    return out


def cpu_by_part(since: dict[str, float] | None = None, process_since: float = 0.0) -> dict[str, float]:
    """CPU seconds per part of the run (thread names without their camera id or index), plus
    ``other`` (the process's CPU no live Python thread accounts for) and ``process``; ``since``,
    ``process_since``: an earlier :func:`thread_cpu_seconds` and ``time.process_time()``,
    subtracted (the run alone, not the start-up). Rounded to 1 ms."""
    now = thread_cpu_seconds()
    if not now:
        return {}
    total = time.process_time() - process_since
    since = since or {}
    parts: dict[str, float] = {}
    for name, s in now.items():
        part = "control (main thread)" if name == "MainThread" else _PER_ITEM.sub(r"\1", name)
        parts[part] = parts.get(part, 0.0) + max(s - since.get(name, 0.0), 0.0)
    named = sum(parts.values())
    parts["other"] = max(total - named, 0.0)       # numba's parallel workers, ended threads
    out = {k: round(v, 3) for k, v in sorted(parts.items(), key=lambda kv: -kv[1])}
    out["process"] = round(total, 3)
    return out


def top_parts(parts: dict[str, float], seconds: float, n: int = 4) -> str:
    """``"depthguard-fusion 0.98, depthguard-source 0.83, ..."``: the ``n`` largest parts of
    :func:`cpu_by_part` in cores over a run of ``seconds`` (wall)."""
    if not parts or seconds <= 0:
        return ""
    items = [(k, v) for k, v in parts.items() if k != "process"][:n]
    return ", ".join(f"{k} {v / seconds:.2f}" for k, v in items)
