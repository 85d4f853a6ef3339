"""Reproduction of Hamersma 2011 on the built-in ``c-arm-room`` cell (R21-R24).

For the six setups of the cell (the paper's appendix A): the 21 simulated ToF
cameras' frames, the free-space reconstruction (R21) at each voxel size, the
accuracy against the scene's ground-truth occupancy (R24, tables 1-2), the
intended C-arm motions judged in the reconstruction and in the ground truth
(R22, table 4), the calibration study (cameras' rotations disturbed by up to
±1°, translations by up to ±1 cm), the placement check (R23, fig. 4) and
pictures coloured by case (fig. 9).

Choices (the paper does not give them):

- ground truth: a voxel is occupied when its centre lies in an obstacle
  (``scene.occupancy(..., mode="centre")``); the C-arm is not an obstacle;
- the machine's own volume: voxels the C-arm touches, padded by
  ``self_padding`` (half a voxel), are freed (R21) and left out of the accuracy
  counts (they are free in both by construction);
- three reconstructions per setup: ``paper`` (ToF noise, centre pixel,
  margin 2 cm), ``full`` (ToF noise, every pixel of the voxel's projection),
  ``bound`` (noiseless, every pixel, margin 0 — what the cameras' resolution
  allows at best: the objects it misses are smaller than the pixel rays'
  spacing);
- braking distances ``S = v t_r + v^2 / (2 a)`` from the C-arm's top speeds
  (:data:`depthguard.sim.carm.CARM_SPEEDS`), reaction time 0.2 s and a
  deceleration numerically equal to the top speed per second (stop in 1 s);
- motions: every axis ± and four combinations (longitudinal with propeller
  or L-arm) at each setup's pose, and "k x" approach series as in the paper's
  table 4 (the C-arm advanced by ``k - 1`` braking distances along the motion
  whose true contact is nearest, re-rendered and re-reconstructed each time).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from depthguard.camera import Camera
from depthguard.control.motion_check import (LEVELS, Motion, braking_distance, check_motion,
                                             compare_verdicts)
from depthguard.evaluation.accuracy import Confusion, cases, confusion, plot_case_slices
from depthguard.fusion.free_space import FreeSpaceMap
from depthguard.transforms import pose, rot_x, rot_y, rot_z

__all__ = ["Room", "load_room", "setup_frames", "braking_distances", "run", "PAPER",
           "perturbed_cameras", "GOALS"]

PAPER = {"free": 98.9, "object": 91.1, "unsafe": 2, "motions": 35,
         "table2": {1: (99.1, 89.1), 2: (98.7, 94.0), 3: (98.7, 93.0), 4: (98.6, 89.0),
                    5: (99.2, 90.2), 6: (99.0, 87.3)}}
GOALS = {"free": 99.5, "object": 97.0, "unsafe": 0}
REACTION_TIME = 0.2
MARGIN = 0.02
AXES = ("larm", "propeller", "carc", "longitudinal")
AXIS_LABEL = {"larm": "Larm", "propeller": "Prop", "carc": "Carc", "longitudinal": "Long"}


def braking_distances() -> dict[str, float]:
    """S per C-arm axis (rad or m): top speed, reaction 0.2 s, stop from top speed in 1 s."""
    from depthguard.sim.carm import CARM_SPEEDS
    return {a: braking_distance(CARM_SPEEDS[a], CARM_SPEEDS[a], REACTION_TIME) for a in AXES}


@dataclass
class Room:
    cell: object
    cameras: list[Camera]
    lo: np.ndarray
    hi: np.ndarray
    scene: object
    carm: object
    setups: list[str]
    times: dict[str, float]
    margin: float = MARGIN
    _sims: dict = field(default_factory=dict)


def _situation_time(v) -> float:
    if isinstance(v, (int, float)):
        return float(v)
    for attr in ("t", "time"):
        if hasattr(v, attr):
            return float(getattr(v, attr))
    raise ValueError(f"c-arm-room situation {v!r} has no time")


def load_room() -> Room:
    """The ``c-arm-room`` cell as used here: cameras, box, scene, C-arm, setups (in order)."""
    from depthguard.sim import load_cell

    cell = load_cell("c-arm-room")
    rig, scene = cell.rig, cell.scene
    times = {name: _situation_time(v) for name, v in cell.situations.items()}
    setups = list(times)
    carm = scene.robot
    if carm is None or not hasattr(carm, "primitives"):
        raise ValueError("c-arm-room: the scene's machine is not a C-arm")
    return Room(cell, list(rig.cameras), np.asarray(rig.workspace.lo, float),
                np.asarray(rig.workspace.hi, float), scene, carm, setups, times)


def carm_pose(room: Room, setup: str):
    from depthguard.sim.carm import CArmPose
    return CArmPose.from_array(room.scene.robot_q(room.times[setup]))


def _sim(room: Room, cam: Camera, seed: int, noiseless: bool):
    from depthguard.sources import SimulatedCamera
    key = (cam.id, seed, noiseless)
    if key not in room._sims:
        room._sims[key] = SimulatedCamera(cam, seed=seed, noiseless=noiseless)
    return room._sims[key]


def scene_meshes(room: Room, setup: str, carm_q=None) -> list:
    """World meshes of a setup with the C-arm at ``carm_q`` (default: the setup's pose)."""
    t = room.times[setup]
    meshes, _ = room.scene.meshes_at(t, robot=False)
    q = carm_pose(room, setup) if carm_q is None else carm_q
    return list(meshes) + list(room.carm.link_meshes(q))


def ideal_frames(room: Room, setup: str, carm_q=None) -> dict[str, np.ndarray]:
    """Noiseless rendered depth per camera (float32, 0 = nothing)."""
    meshes = scene_meshes(room, setup, carm_q)
    out = {}
    for cam in room.cameras:
        depth, _ = _sim(room, cam, 0, True).renderer.render(meshes)
        out[cam.id] = np.array(depth, copy=True)
    return out


def measured_frames(room: Room, setup: str, ideal: dict, seed: int = 0, noiseless: bool = False):
    """Measured frames from ideal ones through each camera's sensor model (deterministic)."""
    t = room.times[setup]
    return {cid: np.array(_sim(room, room.cell.rig.camera(cid), seed, noiseless).measure(img, stamp=t), copy=True)
            for cid, img in ideal.items()}


def setup_frames(room: Room, setup: str, seed: int = 0, carm_q=None, noiseless: bool = False):
    """Measured depth images (dict id -> (H, W) float32) of a setup."""
    return measured_frames(room, setup, ideal_frames(room, setup, carm_q), seed, noiseless)


def perturbed_cameras(cameras, rng: np.random.Generator, rot_deg: float = 0.0, trans_m: float = 0.0):
    """Cameras whose poses are disturbed: each of three rotation angles (about the camera's
    own axes) uniform in ±``rot_deg``, each translation component uniform in ±``trans_m``."""
    out = []
    for c in cameras:
        a, b, g = np.deg2rad(rng.uniform(-rot_deg, rot_deg, 3)) if rot_deg else (0.0, 0.0, 0.0)
        T = c.world_from_camera @ pose(rot_z(g) @ rot_y(b) @ rot_x(a))
        if trans_m:
            T = T.copy()
            T[:3, 3] += rng.uniform(-trans_m, trans_m, 3)
        out.append(c.with_pose(T))
    return out


# ------------------------------------------------------------------- pieces
def _reconstruct(fs: FreeSpaceMap, depths, machine, self_padding):
    occ = fs.update(depths).copy()
    fs.add_free_volume(machine, padding=self_padding)
    return fs.occupied.copy(), fs.machine.copy()


def _object_masks(room: Room, setup: str, lo, hi, s):
    from depthguard.sim.ground_truth import occupancy
    t = room.times[setup]
    out = {}
    for prim in room.scene.obstacles_at(t):
        m = occupancy([prim], lo, hi, s, mode="centre")
        if m.any():
            ext = np.asarray(prim.bounds())
            out[prim.name or type(prim).__name__] = (m, float(np.min(ext[1] - ext[0])))
    return out


def _clamped_motion(room: Room, q0, axes: dict[str, float], S: dict[str, float], name: str, offset: float = 0.0):
    """A C-arm motion clamped at the axis limits; ``offset`` (in S) advances the start pose."""
    from depthguard.sim.carm import CARM_LIMITS

    def q_at(u):
        kw = {}
        for f, m in axes.items():
            lo, hi = CARM_LIMITS[f]
            kw[f] = float(np.clip(getattr(q0, f) + (u + offset) * m * S[f], lo, hi))
        return dataclasses.replace(q0, **kw)

    return Motion(name, lambda u: room.carm.primitives(q_at(u)),
                  ", ".join(f"{f} {m:+g} x S={S[f]:.4g}" for f, m in axes.items())), q_at


def _motion_specs():
    specs = []
    for a in AXES:
        for sgn in (+1, -1):
            specs.append((f"{AXIS_LABEL[a]} {'+' if sgn > 0 else '-'}", {a: float(sgn)}))
    for sl in (+1, -1):
        for b in ("propeller", "larm"):
            specs.append((f"Long{'+' if sl > 0 else '-'} & {AXIS_LABEL[b]}+", {"longitudinal": float(sl), b: 1.0}))
    return specs


# ----------------------------------------------------------------------- run
def run(out_dir, voxels=(0.05, 0.10), seed: int = 0, quick: bool = False, log=print,
        placement: bool = True, calibration: bool = True, approach: bool = True) -> dict:
    """Run the whole reproduction; write ``report.md``, ``results.json`` and pictures to ``out_dir``."""
    from depthguard.progress import track

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    voxels = [float(v) for v in voxels]
    for v in voxels:
        if not (0.01 <= v <= 0.5):
            raise ValueError(f"voxel size {v} m outside [0.01, 0.5]")
    t_start = time.perf_counter()
    room = load_room()
    setups = room.setups[:2] if quick else room.setups
    S = braking_distances()
    res: dict = {"voxels": voxels, "setups": setups, "seed": seed, "quick": quick,
                 "braking": S, "accuracy": {}, "objects": {}, "verdicts": {}, "calibration": {},
                 "placement": None, "pictures": []}

    log(f"hamersma2011: {len(room.cameras)} cameras, box {room.lo.tolist()} .. {room.hi.tolist()}, "
        f"setups {setups}")
    ideal = {s: ideal_frames(room, s) for s in track(setups, "render setups")}
    noisy = {s: measured_frames(room, s, ideal[s], seed) for s in setups}

    for vs in voxels:
        self_pad = 0.5 * vs
        maps = {"paper": FreeSpaceMap(room.cameras, (room.lo, room.hi), vs, margin=room.margin),
                "full": FreeSpaceMap(room.cameras, (room.lo, room.hi), vs, margin=room.margin, footprint="full"),
                "bound": FreeSpaceMap(room.cameras, (room.lo, room.hi), vs, margin=0.0, footprint="full")}
        grid = maps["paper"].grid
        acc = {k: {} for k in maps}
        objs = {}
        recon_paper = {}
        for setup in track(setups, f"reconstruct at {vs * 100:.0f} cm"):
            t = room.times[setup]
            truth = room.scene.occupancy(room.lo, room.hi, vs, t, robot=False, mode="centre")
            if truth.shape != grid.shape:
                raise ValueError(f"ground truth grid {truth.shape} differs from the map {grid.shape}")
            machine = room.carm.primitives(carm_pose(room, setup))
            for k, fs in maps.items():
                depths = ideal[setup] if k == "bound" else noisy[setup]
                occ, mach = _reconstruct(fs, depths, machine, self_pad)
                acc[k][setup] = confusion(occ, truth, mask=~mach)
                if k == "paper":
                    recon_paper[setup] = (occ, truth, mach)
            occ, truth_, mach = recon_paper[setup]
            # which objects are seen as free (paper variant)
            per = {}
            for name, (m, thin) in _object_masks(room, setup, room.lo, room.hi, vs).items():
                n = int((m & ~mach).sum())
                miss = int((m & ~mach & ~occ).sum())
                if n:
                    per[name] = {"voxels": n, "seen_as_free": miss, "smallest_extent_m": thin}
            objs[setup] = per
            if vs == min(voxels):
                p = plot_case_slices(cases(occ, truth_, mask=~mach), grid.lo, vs,
                                     out / f"fig9_{setup}_{int(round(vs * 100))}cm.png",
                                     title=f"{setup}: reconstruction vs truth, {vs * 100:.0f} cm voxels "
                                           "(white 1, blue 2, green 3, red 4)",
                                     z_levels=[int(0.3 / vs), int(0.9 / vs), int(1.5 / vs)])
                res["pictures"].append(str(p))
        res["accuracy"][vs] = {k: {s: c.as_dict() for s, c in v.items()} for k, v in acc.items()}
        res["objects"][vs] = objs

        # ------------------------------------------------ motion verdicts (R22)
        verdicts = []
        fs = maps["paper"]
        for setup in track(setups, f"motion verdicts at {vs * 100:.0f} cm"):
            occ, truth, mach = recon_paper[setup]
            q0 = carm_pose(room, setup)
            rows = []
            for name, axes in _motion_specs():
                m, _ = _clamped_motion(room, q0, axes, S, name)
                vr = check_motion(occ, grid, m, exclude=mach)
                vt = check_motion(truth, grid, m, exclude=mach)
                rows.append({"setup": setup, "motion": name, "reconstruction": vr.level, "truth": vt.level,
                             "u_recon": vr.u_contact, "u_truth": vt.u_contact,
                             "verdict": compare_verdicts(vr.level, vt.level)})
            verdicts += rows
            if approach and not quick:
                # the motion whose true contact is nearest but not immediate: approach it in steps
                cand = [r for r in rows if 1.0 < r["u_truth"] < math.inf]
                if cand:
                    best = min(cand, key=lambda r: r["u_truth"])
                    axes = dict(_motion_specs())[best["motion"]]
                    k = 2
                    while k <= 5:
                        m, q_at = _clamped_motion(room, q0, axes, S, f"{k} x {best['motion']}", offset=float(k - 1))
                        qk = q_at(0.0)
                        prims_k = room.carm.primitives(qk)
                        t = room.times[setup]
                        depths_k = measured_frames(room, setup, ideal_frames(room, setup, qk), seed)
                        occ_k, mach_k = _reconstruct(fs, depths_k, prims_k, self_pad)
                        vr = check_motion(occ_k, grid, m, exclude=mach_k)
                        vt = check_motion(truth, grid, m, exclude=mach_k)
                        verdicts.append({"setup": setup, "motion": m.name, "reconstruction": vr.level,
                                         "truth": vt.level, "u_recon": vr.u_contact, "u_truth": vt.u_contact,
                                         "verdict": compare_verdicts(vr.level, vt.level)})
                        if vt.level == "S":
                            break
                        k += 1
        res["verdicts"][vs] = verdicts

        # ------------------------------------------------ calibration study
        if calibration:
            rng = np.random.default_rng(seed + 1)
            cal = {}
            for label, rot, tr in (("rotation ±1°", 1.0, 0.0), ("translation ±1 cm", 0.0, 0.01),
                                   ("both", 1.0, 0.01)):
                cams = perturbed_cameras(room.cameras, rng, rot, tr)
                fsp = FreeSpaceMap(cams, (room.lo, room.hi), vs, margin=room.margin)
                tot = Confusion(0, 0, 0, 0)
                for setup in setups:
                    _, truth, _ = recon_paper[setup]
                    occ, mach = _reconstruct(fsp, noisy[setup], room.carm.primitives(carm_pose(room, setup)),
                                             self_pad)
                    tot = tot + confusion(occ, truth, mask=~mach)
                cal[label] = tot.as_dict()
            base = Confusion(0, 0, 0, 0)
            for c in acc["paper"].values():
                base = base + c
            cal["none"] = base.as_dict()
            res["calibration"][vs] = cal

    # ------------------------------------------------------ placement (R23)
    if placement:
        res["placement"] = _placement(room, vs=0.10 if not quick else 0.20, out=out, log=log)

    res["seconds"] = time.perf_counter() - t_start
    (out / "results.json").write_text(json.dumps(_jsonable(res), indent=2))
    (out / "report.md").write_text(report_markdown(res))
    log(f"hamersma2011: wrote {out / 'report.md'} ({res['seconds']:.0f} s)")
    return res


def _placement(room: Room, vs: float, out: Path, log=print) -> dict:
    from depthguard.evaluation.placement import (azimuths, candidate_cameras, greedy_placement,
                                                 passes_criterion, share_vs_cameras, visibility)
    from depthguard.fusion.free_space import VoxelGrid

    grid = VoxelGrid(room.lo, room.hi, vs)
    pts = grid.centres()
    # the empty room: only the shell (static objects outside the box's interior)
    shell = [p for p in room.scene.static if _outside_box(p, room.lo, room.hi)]
    meshes = [p.mesh() for p in shell]
    seen = visibility(room.cameras, pts, meshes)
    az = azimuths(room.cameras, pts)
    ok = passes_criterion(seen, az)
    # fig. 4: share vs number of cameras, adding the rig's cameras greedily (best first)
    g_rig = greedy_placement(seen, az, room.cameras, target_share=1.0, max_cameras=len(room.cameras), prune=False)
    curve_rig = share_vs_cameras(seen, az, g_rig.chosen)
    # improver from candidates on the walls and the ceiling
    cands = candidate_cameras(room.lo, room.hi, target=(0.0, 0.0, 0.9), template=room.cameras[0], spacing=0.5,
                              wall_height=room.hi[2] - 0.2)
    seen_c = visibility(cands, pts, meshes)
    az_c = azimuths(cands, pts)
    reachable = float(passes_criterion(seen_c, az_c).mean())
    target = min(1.0, reachable)
    g = greedy_placement(seen_c, az_c, cands, target_share=target, max_cameras=40)
    curve = share_vs_cameras(seen_c, az_c, g.chosen)
    _plot_fig4(out / "fig4_placement.png", curve_rig, curve, len(room.cameras))
    return {"voxel": vs, "rig_share": float(ok.mean()), "rig_cameras": len(room.cameras),
            "rig_curve": curve_rig.tolist(), "rig_order": [room.cameras[i].id for i in g_rig.chosen],
            "candidates": len(cands), "candidates_all_share": reachable, "improver_target": target,
            "improver_cameras": len(g.chosen), "improver_share": g.final_share, "improver_curve": curve.tolist(),
            "improver_positions": [c.position.round(3).tolist() for c in g.cameras],
            "shell": [p.name for p in shell]}


def _outside_box(prim, lo, hi, tol=0.01) -> bool:
    b = np.asarray(prim.bounds())
    return bool(np.any(b[1] <= lo + tol) or np.any(b[0] >= hi - tol))


def _plot_fig4(path, curve_rig, curve_imp, n_rig):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(np.arange(1, len(curve_rig) + 1), 100 * np.asarray(curve_rig), "o-", label=f"the cell's {n_rig} cameras, best first")
    ax.plot(np.arange(1, len(curve_imp) + 1), 100 * np.asarray(curve_imp), "s-", label="greedy improver (walls + ceiling)")
    ax.axvline(21, color="gray", ls=":", label="paper: 21 cameras")
    ax.set_xlabel("number of cameras"); ax.set_ylabel("voxels passing [%]")
    ax.set_title("R23: >= 3 views pairwise >= 100° apart (empty room)")
    ax.grid(alpha=0.3); ax.legend(fontsize=8)
    fig.tight_layout(); fig.savefig(path, dpi=110); plt.close(fig)


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return None if not math.isfinite(float(x)) else float(x)
    if isinstance(x, np.integer):
        return int(x)
    return x


# ------------------------------------------------------------------- report
def _pct(x):
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{100 * x:.1f}"


def report_markdown(res: dict) -> str:
    L = ["# Hamersma 2011 on `c-arm-room`", ""]
    L.append(f"Setups: {', '.join(res['setups'])}; seed {res['seed']}; voxel sizes "
             f"{', '.join(f'{v * 100:.0f} cm' for v in res['voxels'])}."
             + (" QUICK run (two setups, no approach series): not figures to quote." if res["quick"] else ""))
    L.append("")
    L.append("Braking distances S (top speed, 0.2 s reaction, stop in 1 s): "
             + ", ".join(f"{AXIS_LABEL[a]} {math.degrees(v):.1f}°" if a != "longitudinal" else f"{AXIS_LABEL[a]} {v * 100:.1f} cm"
                         for a, v in res["braking"].items()) + "; M = 2 S, L = 5 S.")
    L.append("")
    summary = {}
    for vs in res["voxels"]:
        acc = res["accuracy"][vs]
        L.append(f"## Accuracy at {vs * 100:.0f} cm (tables 1-2)")
        L.append("")
        L.append("Free = correct free / truly free; object = correct object / truly occupied; the C-arm's own "
                 "(freed) voxels are left out. `paper`: ToF noise, centre pixel; `full`: ToF noise, every pixel "
                 "of the voxel's projection; `bound`: noiseless, every pixel (what the resolution allows).")
        L.append("")
        L.append("| setup | free % paper | object % paper | free % full | object % full | object % bound | "
                 "n1 | n2 | n3 | n4 | paper (2011) free / object |")
        L.append("|---|---|---|---|---|---|---|---|---|---|---|")
        tot = {k: Confusion(0, 0, 0, 0) for k in acc}
        for i, s in enumerate(res["setups"]):
            row = {k: acc[k][s] for k in acc}
            for k in acc:
                d = row[k]
                tot[k] = tot[k] + Confusion(d["correct_free"], d["free_as_object"], d["correct_object"], d["object_as_free"])
            p = row["paper"]
            pp = PAPER["table2"].get(i + 1)
            L.append(f"| {s} | {_pct(p['free_accuracy'])} | {_pct(p['object_accuracy'])} | "
                     f"{_pct(row['full']['free_accuracy'])} | {_pct(row['full']['object_accuracy'])} | "
                     f"{_pct(row['bound']['object_accuracy'])} | {p['correct_free']} | {p['free_as_object']} | "
                     f"{p['correct_object']} | {p['object_as_free']} | "
                     f"{'' if pp is None else f'{pp[0]} / {pp[1]}'} |")
        L.append(f"| **all** | **{_pct(tot['paper'].free_accuracy)}** | **{_pct(tot['paper'].object_accuracy)}** | "
                 f"**{_pct(tot['full'].free_accuracy)}** | **{_pct(tot['full'].object_accuracy)}** | "
                 f"**{_pct(tot['bound'].object_accuracy)}** | {tot['paper'].correct_free} | {tot['paper'].free_as_object} | "
                 f"{tot['paper'].correct_object} | {tot['paper'].object_as_free} | {PAPER['free']} / {PAPER['object']} |")
        L.append("")
        summary[vs] = tot
        # objects seen as free
        agg = {}
        for s, per in res["objects"][vs].items():
            for name, d in per.items():
                key = name.split("/")[0] if "/" in name else name
                a = agg.setdefault(key, [0, 0, d["smallest_extent_m"]])
                a[0] += d["voxels"]; a[1] += d["seen_as_free"]; a[2] = min(a[2], d["smallest_extent_m"])
        worst = sorted(agg.items(), key=lambda kv: -kv[1][1])[:8]
        if worst:
            L.append(f"Objects seen as free (paper variant, all setups): " + "; ".join(
                f"{k} {v[1]}/{v[0]} voxels (thinnest part {v[2] * 100:.0f} cm)" for k, v in worst if v[1]) + ".")
            L.append("")
        # goals
        b = tot["bound"].object_accuracy
        best_obj = max(tot["paper"].object_accuracy, tot["full"].object_accuracy)
        best_free = max(tot["paper"].free_accuracy, tot["full"].free_accuracy)
        L.append(f"Goals at {vs * 100:.0f} cm: free >= {GOALS['free']} %: paper {_pct(tot['paper'].free_accuracy)} %, "
                 f"full {_pct(tot['full'].free_accuracy)} % -> {'met' if 100 * best_free >= GOALS['free'] else 'NOT met'}; "
                 f"objects >= {GOALS['object']} %: paper {_pct(tot['paper'].object_accuracy)} %, full "
                 f"{_pct(tot['full'].object_accuracy)} % -> {'met' if 100 * best_obj >= GOALS['object'] else 'NOT met'}.")
        if 100 * b < GOALS["object"]:
            L.append(f"Even noiseless cameras judging every pixel of each voxel reach only {_pct(b)} % of the objects "
                     f"at {vs * 100:.0f} cm: the goal of {GOALS['object']} % is impossible with these cameras by "
                     f"{GOALS['object'] - 100 * b:.1f} points (objects thinner than the spacing of the pixel rays "
                     "slip between them).")
        L.append("")
    for vs in res["voxels"]:
        rows = res["verdicts"][vs]
        L.append(f"## Motion verdicts at {vs * 100:.0f} cm (table 4)")
        L.append("")
        L.append("Reconstruction vs ground truth (same sweep, same exclusion of the C-arm's own volume); "
                 "s = same, ts = 1-2 levels more severe, tts = stop where the truth is free, u = less severe (unsafe). "
                 "u = first contact in multiples of S.")
        L.append("")
        L.append("| setup | motion | reconstruction | truth | verdict | u recon | u truth |")
        L.append("|---|---|---|---|---|---|---|")
        for r in rows:
            f = lambda u: "–" if u is None or not math.isfinite(u) else f"{u:.2f}"
            L.append(f"| {r['setup']} | {r['motion']} | {r['reconstruction']} | {r['truth']} | "
                     f"{r['verdict']} | {f(r['u_recon'])} | {f(r['u_truth'])} |")
        cnt = {k: sum(r["verdict"] == k for r in rows) for k in ("s", "ts", "tts", "u")}
        L.append("")
        L.append(f"{len(rows)} motions: s {cnt['s']}, ts {cnt['ts']}, tts {cnt['tts']}, **u {cnt['u']}** "
                 f"(paper: 27 s, 6 ts/tts, 2 u of 35; goal: no u).")
        L.append("")
    if res["calibration"]:
        L.append("## Calibration study (paper §6.1.2)")
        L.append("")
        L.append("The map's camera model disturbed, images from the true cameras; all setups pooled.")
        L.append("")
        L.append("| voxel | disturbance | free % | object % |")
        L.append("|---|---|---|---|")
        for vs, cal in res["calibration"].items():
            for label in ("none", "rotation ±1°", "translation ±1 cm", "both"):
                d = cal[label]
                L.append(f"| {float(vs) * 100:.0f} cm | {label} | {_pct(d['free_accuracy'])} | {_pct(d['object_accuracy'])} |")
        L.append("")
    pl = res.get("placement")
    if pl:
        L.append("## Sensor placement (R23, fig. 4)")
        L.append("")
        L.append(f"Empty room (shell: {', '.join(pl['shell'])}), {pl['voxel'] * 100:.0f} cm voxels over the box. "
                 f"The cell's {pl['rig_cameras']} cameras: **{_pct(pl['rig_share'])} %** of the voxels are seen by "
                 f">= 3 cameras pairwise >= 100° apart. Share vs cameras (the rig's cameras added best first): "
                 + ", ".join(f"{i + 1}: {_pct(v)}" for i, v in enumerate(pl["rig_curve"])) + ".")
        L.append("")
        L.append(f"Greedy improver over {pl['candidates']} candidates on the walls (0.2 m below the ceiling) and the "
                 f"ceiling (all candidates together reach {_pct(pl['candidates_all_share'])} %): "
                 f"**{pl['improver_cameras']} cameras** reach {_pct(pl['improver_share'])} % (paper: 21 cameras). "
                 "Curve: " + ", ".join(f"{i + 1}: {_pct(v)}" for i, v in enumerate(pl["improver_curve"])) + ".")
        L.append("")
    L.append("Pictures: " + ", ".join(Path(p).name for p in res["pictures"])
             + (", fig4_placement.png" if pl else "") + ".")
    L.append("")
    return "\n".join(L)
