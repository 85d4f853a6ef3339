"""The benchmark harness behind ``depthguard bench``.

Each area has a module here that registers a *group* of rows with
:func:`group`. A group is a function ``(ctx: BenchContext) -> list[BenchRow]``.
Rows carry the figure, the paper's figure where there is one, and a peer
(Embree, k-d tree, OctoMap ...) measured in the same run. Timing is by
median / worst over repetitions after a warm-up (numba compiles first).
"""

from __future__ import annotations

import importlib
import time
from dataclasses import asdict, dataclass, field
from typing import Callable

import numpy as np

__all__ = ["BenchRow", "BenchContext", "group", "GROUPS", "run", "time_call"]

# Modules that register groups; each area adds its module name here.
_MODULES = [
    "depthguard.evaluation.bench.render",
    "depthguard.evaluation.bench.distance",
    "depthguard.evaluation.bench.depthgrid",
    "depthguard.evaluation.bench.camera_share",
    "depthguard.evaluation.bench.loop",
    "depthguard.evaluation.bench.freespace",
    "depthguard.evaluation.bench.robot",
    "depthguard.evaluation.bench.control",
    "depthguard.evaluation.bench.stalls",
    "depthguard.evaluation.bench.voxels",
    "depthguard.evaluation.bench.sim",
    "depthguard.evaluation.bench.monitor",
    "depthguard.evaluation.bench.monitor_paths",
    "depthguard.evaluation.bench.fusion_cells",
    "depthguard.evaluation.bench.view",
    "depthguard.evaluation.bench.realsense",
    "depthguard.evaluation.bench.bag",
    "depthguard.evaluation.bench.soak",
    "depthguard.evaluation.bench.calibrate",
    "depthguard.evaluation.bench.units",
    "depthguard.evaluation.bench.availability",
]


@dataclass
class BenchRow:
    name: str
    value: float
    unit: str
    paper: float | None = None
    peer: str | None = None
    peer_value: float | None = None
    note: str = ""

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class BenchContext:
    quick: bool = False          # fewer repetitions (used by the tests)
    repeats: int = 30
    seed: int = 0
    log: Callable[[str], None] = field(default=lambda msg: None)


GROUPS: dict[str, Callable[[BenchContext], list[BenchRow]]] = {}


def group(name: str):
    """Register a bench group under ``name`` (a prefix of its row names)."""
    def deco(fn):
        GROUPS[name] = fn
        return fn
    return deco


def load_groups() -> dict[str, Callable[[BenchContext], list[BenchRow]]]:
    for mod in _MODULES:
        importlib.import_module(mod)
    return GROUPS


def owning_group(prefix: str, names) -> str | None:
    """The group whose rows a row-name prefix ``prefix`` names (``monitor.step_p99_ms`` →
    ``monitor``): the longest group name that ``prefix`` starts with at a dot or equals,
    so that ``monitor.build`` is its own group, not also ``monitor``'s rows."""
    best = None
    for name in names:
        if (prefix == name or prefix.startswith(name + ".")) and (best is None or len(name) > len(best)):
            best = name
    return best


def selected_groups(only: list[str] | None, names) -> list[str]:
    """The groups ``--only`` runs: every group whose name starts with one of ``only``, and for a
    prefix inside a group's rows the group that owns them (:func:`owning_group`)."""
    names = list(names)
    if not only:
        return names
    owners = {owning_group(o, names) for o in only}
    return [n for n in names if n in owners or any(n.startswith(o) for o in only)]


def run(only: list[str] | None = None, ctx: BenchContext | None = None) -> list[BenchRow]:
    """Run every group (or those :func:`selected_groups` picks for ``only``)."""
    ctx = ctx or BenchContext()
    rows: list[BenchRow] = []
    groups = load_groups()
    chosen = set(selected_groups(only, groups))
    for name, fn in groups.items():
        if name not in chosen:
            continue
        ctx.log(f"bench group {name}")
        got = fn(ctx)
        if only:
            got = [r for r in got if any(r.name.startswith(o) or name.startswith(o) for o in only)]
        rows.extend(got)
    return rows


def time_call(fn: Callable[[], object], repeats: int, warmup: int = 2) -> np.ndarray:
    """Wall-clock seconds of ``repeats`` calls of ``fn`` after ``warmup`` calls."""
    for _ in range(warmup):
        fn()
    out = np.empty(repeats)
    for i in range(repeats):
        t0 = time.perf_counter()
        fn()
        out[i] = time.perf_counter() - t0
    return out


def machine() -> str:
    """The machine the figures were measured on, in one line: the CPU's model name (Linux
    ``/proc/cpuinfo``; the platform's processor elsewhere), the cores this process may use, and
    Python's and numba's versions. The same code's figures move with the machine — the fusion's
    build p50 with 2 cameras was 2.4-2.7 ms on one 2-core VM of this project and 1.3-1.5 ms on
    another (issue 29) — so a figure is quoted with its machine."""
    import os
    import platform

    import numba

    info: dict[str, str] = {}
    try:
        with open("/proc/cpuinfo") as fh:
            for ln in fh:
                if not ln.strip():
                    break                                 # the first processor's block
                key, _, value = ln.partition(":")
                info.setdefault(key.strip(), value.strip())
    except OSError:
        pass
    model = info.get("model name") or platform.processor() or platform.machine() or "unknown CPU"
    if "cpu family" in info and "model" in info:          # a VM's model name is often generic
        model += f" (family {info['cpu family']} model {info['model']}"
        model += f", {info['cpu MHz']} MHz)" if "cpu MHz" in info else ")"
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return f"{model}, {cores} cores, Python {platform.python_version()}, numba {numba.__version__}"
