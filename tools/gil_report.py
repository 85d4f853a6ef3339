"""Who holds CPython's GIL, and who waits for it, during a depthguard command (a developer's tool).

Usage (root, Linux ``perf`` with uprobes; CPython with the ``take_gil`` / ``drop_gil`` symbols,
as pyenv and distribution builds keep them)::

    python tools/gil_report.py --skip 5 -- monitor --cell ur3-cell --duration 8 --quiet --out /tmp/gil-run

runs ``depthguard <arguments>`` in this interpreter under ``perf record`` with uprobes on entry
to and return from ``take_gil`` and on ``drop_gil``, and prints per thread (by its Python name;
numbered siblings such as ``depthguard-source-0-camA`` grouped) the time it held the GIL and the
time it waited to take it (a thread that waits is runnable in Python but cannot run). ``--skip``
leaves out the first seconds (the start's imports and kernel loads). The uprobes cost a few
microseconds per event: absolute figures are a little pessimistic, the split between threads is
what to read. (issue 29: it showed that a real-time ur3-cell run holds the GIL ~60 % of the time,
that the simulator's threads waited for it ~2 s each in an 8 s run, and which calls give it away.)
"""

from __future__ import annotations

import argparse
import collections
import os
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

import numpy as np

_CHILD = r"""
import sys, threading
names = open(sys.argv[1], "w")
names.write(f"{threading.get_native_id()} MainThread\n"); names.flush()
_boot = threading.Thread._bootstrap_inner
def _named(self):
    names.write(f"{threading.get_native_id()} {self.name}\n"); names.flush()
    return _boot(self)
threading.Thread._bootstrap_inner = _named
from depthguard.cli import main
sys.argv = ["depthguard"] + sys.argv[2:]
main()
"""


def _libpython() -> str:
    lib = Path(sysconfig.get_config_var("LIBDIR") or "") / (sysconfig.get_config_var("LDLIBRARY") or "")
    return str(lib) if lib.is_file() else os.path.realpath(sys.executable)


def _group(name: str) -> str:
    if name.startswith("depthguard-source"):
        return "depthguard-source (all)"
    if name.startswith("depthguard-camera"):
        return "depthguard-camera (all)"
    return name


def report(events: Path, names: Path, skip: float) -> None:
    tid_name = {}
    for line in names.read_text().splitlines():
        tid, _, name = line.partition(" ")
        tid_name[int(tid)] = name
    asked, held_since = {}, {}
    waits, holds = collections.defaultdict(list), collections.defaultdict(list)
    first = last = None
    with open(events) as fh:
        for line in fh:
            parts = line.split()
            if len(parts) < 4:
                continue
            tid, t, ev = int(parts[1]), float(parts[2].rstrip(":")), parts[3]
            first = t if first is None else first
            last = t
            counted = t - first >= skip
            if ev.endswith("take_gil:"):
                asked[tid] = t
            elif ev.endswith("take_gil__return:"):
                if tid in asked and counted:
                    waits[tid].append(t - asked[tid])
                asked.pop(tid, None)
                held_since[tid] = t
            elif ev.endswith("drop_gil:") and tid in held_since:
                if counted:
                    holds[tid].append(t - held_since[tid])
                held_since.pop(tid)
    if first is None:
        sys.exit("no GIL events recorded (are the uprobes in place?)")
    span = last - first - skip
    by = collections.defaultdict(lambda: ([], []))
    for tid in set(waits) | set(holds):
        g = by[_group(tid_name.get(tid, str(tid)))]
        g[0].extend(holds.get(tid, []))
        g[1].extend(waits.get(tid, []))
    total = sum(sum(h) for h, _ in by.values())
    print(f"{span:.2f} s after the first {skip:g} s; the GIL held {total:.2f} s ({total / span:.0%})")
    print(f"{'thread':28s} {'held s':>7s} {'share':>6s} {'takes':>7s} {'hold p99 ms':>11s} {'hold max ms':>11s} "
          f"{'waited s':>8s} {'wait p99 ms':>11s} {'wait max ms':>11s}")
    for name, (h, w) in sorted(by.items(), key=lambda kv: -sum(kv[1][0])):
        h, w = np.asarray(h or [0.0]), np.asarray(w or [0.0])
        print(f"{name:28s} {h.sum():7.2f} {h.sum() / span:6.0%} {len(w):7d} {np.percentile(h, 99) * 1e3:11.2f} "
              f"{h.max() * 1e3:11.1f} {w.sum():8.2f} {np.percentile(w, 99) * 1e3:11.2f} {w.max() * 1e3:11.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skip", type=float, default=5.0, help="seconds left out at the start (default 5)")
    ap.add_argument("args", nargs=argparse.REMAINDER, help="-- then depthguard's arguments")
    ns = ap.parse_args()
    args = ns.args[1:] if ns.args[:1] == ["--"] else ns.args
    if not args:
        ap.error("give depthguard's arguments after --")
    lib = _libpython()
    for probe in ("take_gil", "take_gil%return", "drop_gil"):
        subprocess.run(["perf", "probe", "-q", "-x", lib, probe], capture_output=True)   # (kept if there)
    group = "probe_" + Path(lib).name.split(".")[0].replace("-", "_")
    with tempfile.TemporaryDirectory() as tmp:
        data, names, events = Path(tmp) / "perf.data", Path(tmp) / "threads.txt", Path(tmp) / "events.txt"
        cmd = ["perf", "record", "-q", "-o", str(data)]
        for ev in ("take_gil", "take_gil__return", "drop_gil"):
            cmd += ["-e", f"{group}:{ev}"]
        cmd += ["--", sys.executable, "-c", _CHILD, str(names), *args]
        rc = subprocess.run(cmd).returncode
        if rc != 0:
            sys.exit(f"perf record exited with {rc} (root and perf with uprobes are needed)")
        with open(events, "w") as out:
            subprocess.run(["perf", "script", "-i", str(data), "-F", "comm,tid,time,event"], stdout=out,
                           stderr=subprocess.DEVNULL, check=True)
        report(events, names, ns.skip)


if __name__ == "__main__":
    main()
