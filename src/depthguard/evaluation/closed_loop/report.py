"""Summary and plots of a closed-loop run (like Flacco 2014 figs. 14–16, 2015 fig. 15).

``summarize(result, ...)`` -> the ``summary.json`` dict; ``write_report(out,
result, summary)`` writes ``summary.json`` and the figures:

* ``ee_path.png``: the end-effector path in the hexagon's plane (Y–Z) with
  the desired hexagon;
* ``distances.png``: sensed distance of every control point over time
  (``inf`` = nothing within ρ is left blank) and the ground-truth
  robot-to-obstacle distance;
* ``repulsion.png``: the components of the EE repulsive velocity, the SNS
  task scale and the safety override;
* ``snapshots.png``: the principal camera's depth frames at a few instants.
"""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np

__all__ = ["summarize", "write_report"]


def _rms(x: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(x ** 2))) if x.size else None


def _avoidance_rate(tm: dict, cycles: int) -> float:
    """(distance + reaction) cycles per wall second: 1 / (mean distance time per distance
    cycle + mean reaction time per control cycle)."""
    nd = max(int(tm.get("distance_cycles", cycles)), 1)
    per = tm["distance"] / nd + tm["reaction"] / max(cycles, 1)
    return float(1.0 / max(per, 1e-12))


def summarize(res, scenario: str, description: str, config, hexagon, extra: dict | None = None) -> dict:
    """The ``summary.json`` dict of a run (units in the key names).

    ``ee_tracking_rms_m``: RMS of ``‖x_ee − p_d(τ)‖`` over the cycles where
    the ground truth has no obstacle within ρ of any control point and the
    safety override is 1. ``avoidance_rate_hz``: control cycles (distance +
    reaction) per wall-clock second spent in them. ``real_time_factor``:
    simulated / wall time of the whole simulation (camera simulation and
    ground truth included); ``real_time_factor_system``: without the camera
    simulation and ground truth, i.e. what a real cell would run
    (self-removal render + distances + reaction).
    """
    t = res.t
    duration = float(t[-1] + (t[1] - t[0])) if len(t) > 1 else 0.0
    err = np.linalg.norm(res.ee - res.ee_des, axis=1)
    clear = np.all(res.gt_cp > config.rho, axis=1) & (res.override >= 1.0)
    path_err = hexagon.path_distance(res.ee)
    tm = res.timing
    system = tm["self_removal"] + tm["distance"] + tm["reaction"]
    stops = []
    for ep in res.episodes:
        stops.append({k: ep[k] for k in ("reason", "t_start", "t_stopped", "t_end")})
    qd_end = float(np.abs(res.qd[-1]).max()) if len(res.qd) else 0.0
    D_fin = np.where(np.isfinite(res.D), res.D, np.nan)
    summary = {
        "scenario": scenario,
        "description": description,
        "duration_s": duration,
        "min_true_distance_m": float(np.min(res.gt_robot)),
        "collision": bool(np.min(res.gt_robot) <= 0.0),
        "min_true_distance_dynamic_m": (None if not np.isfinite(np.min(res.gt_robot_dyn))
                                        else float(np.min(res.gt_robot_dyn))),
        "min_true_distance_control_points_m": float(np.min(res.gt_cp)),
        "ee_tracking_rms_m": _rms(err[clear]),
        "ee_tracking_clear_share": float(np.mean(clear)),
        "ee_tracking_rms_all_m": _rms(err),
        "ee_tracking_max_clear_m": float(err[clear].max()) if clear.any() else None,
        "ee_path_rms_clear_m": _rms(path_err[clear]),
        "ee_max_repulsion_m_s": float(np.linalg.norm(res.rep, axis=1).max()),
        "min_sensed_distance_m": {n: (None if np.all(np.isnan(D_fin[:, j])) else float(np.nanmin(D_fin[:, j])))
                                  for j, n in enumerate(res.control_point_names)},
        "min_task_scale": float(res.scale.min()),
        "avoidance_rate_hz": _avoidance_rate(tm, len(t)),
        "distance_rate_sim_hz": float(tm.get("distance_cycles", len(t)) / max(duration, 1e-12)),
        "real_time_factor": float(duration / max(tm["total"], 1e-12)),
        "real_time_factor_system": float(duration / max(system, 1e-12)),
        "timing_s": {k: round(float(v), 4) for k, v in tm.items()},
        "frames": res.n_frames,
        "cameras": res.camera_ids,
        "fusion": config.fusion,
        "safe_stops": stops,
        "stopped_at_end": bool(res.override[-1] == 0.0 and qd_end < 1e-9),
        "final_override": float(res.override[-1]),
        "final_max_joint_speed_rad_s": qd_end,
        "ground_truth_excludes_capsules": res.excluded_capsules,
        "params": {"rho_m": config.rho, "v_max_m_s": config.v_max, "alpha": config.alpha,
                   "control_hz": config.control_hz, "camera_hz": config.camera_hz,
                   "camera_latency_s": config.latency,
                   "stale_limit_s": config.stale_periods / config.camera_hz,
                   "noise": config.noise, "method": config.method,
                   "hexagon_center_m": list(hexagon.center), "hexagon_radius_m": hexagon.radius,
                   "ee_speed_m_s": hexagon.speed},
    }
    if extra:
        summary.update(extra)
    return summary


def write_report(out: Path, res, summary: dict, hexagon, rho: float, snapshots=None) -> list[Path]:
    """Write ``summary.json`` and the figures into ``out``; returns the written paths."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    p = out / "summary.json"
    p.write_text(json.dumps(summary, indent=2))
    written.append(p)
    t = res.t
    # wrapped to the figures' 8-inch width at 9 pt (a long scenario description was cut at the edge)
    title = textwrap.fill(f"{summary['scenario']}: {summary['description']}", width=110)

    # EE path in the hexagon plane
    fig, ax = plt.subplots(figsize=(5.5, 5))
    C = np.vstack([hexagon.corners, hexagon.corners[:1]])
    ax.plot(C[:, 1], C[:, 2], "k--", lw=1, label="desired hexagon")
    sc = ax.scatter(res.ee[:, 1], res.ee[:, 2], c=t, s=2, cmap="autumn", label="end effector")
    fig.colorbar(sc, ax=ax, label="t [s]")
    ax.set_xlabel("y [m]")
    ax.set_ylabel("z [m]")
    ax.set_aspect("equal")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(f"EE path (plane x = {hexagon.center[0]:g} m)", fontsize=9)
    fig.tight_layout()
    p = out / "ee_path.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    written.append(p)

    # distances
    fig, axs = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    D = np.where(np.isfinite(res.D), res.D, np.nan)
    axs[0].plot(t, D[:, 0], color="tab:blue", label=f"{res.control_point_names[0]} (sensed)")
    axs[0].plot(t, res.gt_cp[:, 0].clip(max=1.0), color="tab:blue", ls=":", label="EE point, true")
    if np.isfinite(res.gt_robot_dyn).any():
        axs[0].plot(t, res.gt_robot_dyn.clip(max=1.0), color="k", lw=1, label="robot <-> moving obstacles, true")
    axs[0].axhline(rho, color="gray", ls="--", lw=0.8)
    axs[0].set_ylabel("distance [m]")
    axs[0].set_ylim(0, max(rho * 1.5, 0.1))
    axs[0].legend(fontsize=7, loc="lower right")
    axs[0].set_title(title, fontsize=9)
    for j in range(1, D.shape[1]):
        axs[1].plot(t, D[:, j], lw=1, label=res.control_point_names[j])
    axs[1].axhline(rho, color="gray", ls="--", lw=0.8)
    axs[1].set_ylim(0, rho * 1.05)
    axs[1].set_ylabel("other control points [m]")
    axs[1].set_xlabel("t [s]")
    axs[1].legend(fontsize=6, ncol=4, loc="lower right")
    fig.tight_layout()
    p = out / "distances.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    written.append(p)

    # repulsion, scale, override
    fig, axs = plt.subplots(2, 1, figsize=(8, 5), sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    for i, c in enumerate("xyz"):
        axs[0].plot(t, res.rep[:, i], label=f"$\\dot x_{{rep,{c}}}$")
    axs[0].plot(t, np.linalg.norm(res.rep, axis=1), "k", lw=0.8, label="|.|")
    axs[0].set_ylabel("EE repulsive velocity [m/s]")
    axs[0].legend(fontsize=7, ncol=4)
    axs[0].set_title(title, fontsize=9)
    axs[1].plot(t, res.scale, label="SNS task scale s")
    axs[1].plot(t, res.override, label="safety override k")
    axs[1].set_ylim(-0.05, 1.05)
    axs[1].set_xlabel("t [s]")
    axs[1].legend(fontsize=7)
    fig.tight_layout()
    p = out / "repulsion.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    written.append(p)

    if snapshots:
        # one colour scale for every snapshot, with its bar in metres; no return: white
        valid = [d[d > 0] for _, _, d in snapshots]
        lo = min((float(v.min()) for v in valid if v.size), default=0.0)
        hi = max((float(v.max()) for v in valid if v.size), default=1.0)
        cmap = matplotlib.colormaps["viridis"].with_extremes(bad="white")
        fig, axs = plt.subplots(1, len(snapshots), figsize=(3.2 * len(snapshots) + 0.8, 2.8), squeeze=False,
                                layout="constrained")
        axs = axs[0]
        im = None
        for ax, (ts, cid, depth) in zip(axs, snapshots):
            im = ax.imshow(np.where(depth > 0, depth, np.nan), cmap=cmap, vmin=lo, vmax=max(hi, lo + 1e-3))
            ax.set_title(f"{cid}, t = {ts:.1f} s", fontsize=8)
            ax.axis("off")
        fig.colorbar(im, ax=list(axs), label="depth [m] (white: no return)", shrink=0.9)
        p = out / "snapshots.png"
        fig.savefig(p, dpi=100)
        plt.close(fig)
        written.append(p)
    return written
