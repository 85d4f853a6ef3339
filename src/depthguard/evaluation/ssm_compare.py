"""Repulsion vs speed and separation monitoring on every built-in scenario (R33, issue 17).

:func:`compare` runs each closed-loop scenario of
:mod:`depthguard.evaluation.closed_loop.scenarios` once per reaction mode
(``repulsion``, ``ssm``, ``both``) and :func:`table` writes the markdown table:

* **progress**: the task's own time at the end over the run's duration (1.00 =
  never slowed; the productivity; the task completion time is the duration
  over it);
* **min true separation**: the robot's capsules to the moving obstacles, from
  the ground truth (m);
* **protective stops** and **time stopped** (s): SSM stops (entries into the
  protective stop) and the time the protective stop or the supervisor's
  override held the robot at zero;
* **SSM violations**: cycles where the ground truth's separation fell below
  ``S_p`` computed with the true human speed while the robot was neither
  stopping nor standing (:mod:`depthguard.evaluation.closed_loop.ssm_truth`); ``—``
  in repulsion mode (no ``S_p``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

__all__ = ["MODES", "compare", "row_of", "table"]

MODES = ("repulsion", "ssm", "both")


def row_of(summary: dict, res, mode: str) -> dict:
    """One table row from a run's summary and :class:`~depthguard.evaluation.closed_loop.loop.LoopResult`."""
    dt = float(res.t[1] - res.t[0]) if len(res.t) > 1 else 0.0
    duration = float(summary["duration_s"])
    pstop = res.protective_stop if res.protective_stop is not None else np.zeros(len(res.t), dtype=bool)
    held = pstop | (res.override <= 0.0)
    stops = int(np.count_nonzero(pstop[1:] & ~pstop[:-1]) + (1 if len(pstop) and pstop[0] else 0))
    on = mode != "repulsion"
    return {
        "scenario": summary["scenario"], "reaction": mode,
        "progress": float((res.tau[-1] + dt) / duration) if res.tau is not None and duration > 0 else None,
        "min_true_separation_m": summary["min_true_distance_dynamic_m"],
        "collision": bool(summary["collision"]),
        "protective_stops": stops if on else None,
        "supervisor_stops": len(summary["safe_stops"]),
        "time_stopped_s": float(np.count_nonzero(held) * dt),
        "ssm_violations": int(np.count_nonzero(res.ssm_violation)) if on else None,
        "ssm_violations_with_Z_d": int(np.count_nonzero(res.ssm_violation_zd)) if on else None,
        "min_ssm_margin_m": (float(np.min(res.ssm_margin)) if on and np.isfinite(np.min(res.ssm_margin))
                             else None),
    }


def compare(scenarios=None, modes=MODES, cell: str = "flacco-cell", seed: int = 0, ssm=None,
            progress=None, out: Path | None = None) -> list[dict]:
    """Run every scenario × mode; ``ssm`` an :class:`~depthguard.control.ssm_config.SSMConfig`
    (None: defaults); ``progress(iterable, total, label)`` wraps each run's cycles. With ``out``,
    each run's ``summary.json`` goes to ``out/<scenario>-<mode>/`` and the rows to
    ``out/ssm_compare.json``. Returns the rows."""
    from depthguard.evaluation.closed_loop.loop import LoopConfig
    from depthguard.evaluation.closed_loop.scenarios import SCENARIOS, run_scenario

    names = list(SCENARIOS) if scenarios is None else list(scenarios)
    for n in names:
        if n not in SCENARIOS:
            raise ValueError(f"unknown scenario {n!r}; choose among {', '.join(SCENARIOS)}")
    for md in modes:
        if md not in MODES:
            raise ValueError(f"unknown reaction {md!r}; choose among {', '.join(MODES)}")
    rows = []
    for name in names:
        for md in modes:
            cfg = LoopConfig(reaction=md, ssm=ssm)
            prog = None if progress is None else (lambda it, total, _l=f"{name} / {md}": progress(it, total, _l))
            run_out = None if out is None else Path(out) / f"{name}-{md}"
            summary, res = run_scenario(name, out=run_out, seed=seed, config=cfg, cell=cell, progress=prog,
                                        write=False)
            row = row_of(summary, res, md)
            rows.append(row)
            if run_out is not None:
                run_out.mkdir(parents=True, exist_ok=True)
                summary = dict(summary, ssm_compare=row)
                (run_out / "summary.json").write_text(json.dumps(summary, indent=2))
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        (Path(out) / "ssm_compare.json").write_text(json.dumps(rows, indent=2))
    return rows


def _f(v, fmt):
    return "—" if v is None else format(v, fmt)


def table(rows: list[dict]) -> str:
    """The markdown table of :func:`compare`'s rows."""
    head = ("| scenario | reaction | progress | min true separation (m) | collision | protective stops "
            "| supervisor stops | time stopped (s) | SSM violations | min SSM margin (m) |\n"
            "|---|---|---:|---:|---|---:|---:|---:|---:|---:|\n")
    lines = [f"| {r['scenario']} | {r['reaction']} | {_f(r['progress'], '.2f')} | "
             f"{_f(r['min_true_separation_m'], '.3f')} | {'yes' if r['collision'] else 'no'} | "
             f"{_f(r['protective_stops'], 'd')} | {r['supervisor_stops']} | {r['time_stopped_s']:.2f} | "
             f"{_f(r['ssm_violations'], 'd')} | {_f(r['min_ssm_margin_m'], '.3f')} |" for r in rows]
    return head + "\n".join(lines) + "\n"
