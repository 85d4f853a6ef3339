"""Reproduction of Hamersma 2011 on the built-in ``c-arm-room`` cell (R21-R24).

For the six setups of the cell (the paper's appendix A): the 21 simulated ToF
cameras' frames, the free-space reconstruction (R21) at each voxel size, the
accuracy against the scene's ground-truth occupancy (R24, tables 1-2), the
intended C-arm motions judged in the reconstruction and in the ground truth
(R22, table 4), the calibration study (cameras' rotations disturbed by up to
±1°, translations by up to ±1 cm; and the rotated ones after R34's calibration
against the static scene, :mod:`depthguard.calibration`), the placement check (R23, fig. 4) and
pictures coloured by case (fig. 9).

Choices (the paper does not give them):

- ground truth: a voxel is occupied when its centre lies in an obstacle
  (``scene.occupancy(..., mode="centre")``); the C-arm is not an obstacle;
- the machine's own volume: voxels the C-arm touches, padded by
  ``self_padding`` (half a voxel), are freed (R21) and left out of the accuracy
  counts (they are free in both by construction);
- reconstructions per setup: ``shell`` — **the product's**
  (:class:`~depthguard.fusion.free_space_product.FreeSpaceProduct`, assembled
  there): ``STILL_FRAMES`` (3) consecutive ToF frames per camera of the still
  scene fused per pixel (:class:`~depthguard.fusion.temporal.StillFusion`: the
  median where they agree, else the nearest), centre pixel, margin 2 sigma of
  the fused depth (1.34 cm), and the known room shell — floor, walls, ceiling
  — as each camera's background (:meth:`FreeSpaceMap.set_background`,
  tolerance margin + 3 sigma); ``single`` (the same from one frame: margin 2 cm = 2 sigma,
  tolerance ``SHELL_TOLERANCE`` = 5 cm); ``noiseless`` (the product's map on
  noiseless images: what its rule and margin allow); ``paper``
  (the paper's own method: one frame, margin 2 cm, no background); ``full``
  (one frame, every pixel of the voxel's projection, no background); ``bound``
  (noiseless, every pixel, margin 0 — what the cameras' resolution allows at
  best: the objects it misses are smaller than the pixel rays' spacing). The
  motion verdicts and the calibration study are judged on ``shell``, with the
  ``paper`` method alongside;
- braking distances ``S = v t_r + v^2 / (2 a)`` from the C-arm's top speeds
  (:data:`depthguard.sim.carm.CARM_SPEEDS`), reaction time 0.2 s and a
  deceleration numerically equal to the top speed per second (stop in 1 s);
- motions: every axis ± and four combinations (longitudinal with propeller
  or L-arm) at each setup's pose, and "k x" approach series as in the paper's
  table 4 (the C-arm advanced by ``k - 1`` braking distances along the motion
  whose true contact is farthest within L, re-rendered and re-reconstructed
  each time, until the truth says S).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from depthguard.control.motion_check import check_motion, compare_verdicts
from depthguard.evaluation.accuracy import Confusion, cases, confusion, plot_case_slices
from depthguard.evaluation.hamersma2011_paper import GOALS, MARGIN_SWEEP, PAPER, PRODUCT, SHELL_TOLERANCE
from depthguard.evaluation.hamersma2011_placement import placement_check
from depthguard.evaluation.hamersma2011_report import jsonable, report_markdown
from depthguard.evaluation.hamersma2011_room import (  # noqa: F401 (re-exported: the reproduction's API)
    Room, braking_distances, carm_pose, clamped_motion, ideal_frames, load_room, measured_frames, motion_specs,
    object_masks, perturbed_cameras, product_map, product_margins, reconstruct, setup_frames, shell_backgrounds,
    shell_map, shell_primitives, still_frame_list, still_frames, still_fusion)
from depthguard.fusion.free_space import FreeSpaceMap
from depthguard.fusion.free_space_product import STILL_FRAMES
from depthguard.transforms import pose

__all__ = ["Room", "load_room", "setup_frames", "braking_distances", "run", "PAPER",
           "perturbed_cameras", "GOALS", "shell_primitives", "shell_backgrounds"]


# ----------------------------------------------------------------------- run
def run(out_dir, voxels=(0.05, 0.10), seed: int = 0, quick: bool = False, log=print,
        placement: bool = True, calibration: bool = True, approach: bool = True,
        improved_rig: bool = True) -> dict:
    """Run the whole reproduction; write ``report.md``, ``results.json`` and pictures to ``out_dir``.

    With ``placement`` and ``improved_rig`` the accuracy and the verdicts are also
    measured with the camera set the placement improver found (rig ``improved``).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    voxels = [float(v) for v in voxels]
    for v in voxels:
        if not (0.01 <= v <= 0.5):
            raise ValueError(f"voxel size {v} m outside [0.01, 0.5]")
    t_start = time.perf_counter()
    room = load_room()
    setups = room.setups[:2] if quick else room.setups
    res: dict = {"voxels": voxels, "setups": setups, "seed": seed, "quick": quick,
                 "braking": braking_distances(), "rigs": {}, "placement": None, "pictures": []}
    fusion = still_fusion(room)
    p_margin, p_tol = product_margins(room)
    res["product"] = {"frames": STILL_FRAMES, "margin_m": p_margin, "tolerance_m": p_tol,
                      "fused_sigma_m": fusion.sigma(0.0), "agree_k": fusion.k}
    log(f"hamersma2011: {len(room.cameras)} cameras, box {room.lo.tolist()} .. {room.hi.tolist()}, "
        f"setups {setups}")
    rigs = {"cell": room.cameras}
    if placement:
        res["placement"] = placement_check(room, vs=0.10 if not quick else 0.20, out=out, log=log)
        if improved_rig:
            rigs["improved"] = res["placement"]["regions"]["interior"].pop("improver")
        else:
            res["placement"]["regions"]["interior"].pop("improver")
        res["placement"]["regions"]["box"].pop("improver")
    for label, cams in rigs.items():
        res["rigs"][label] = _evaluate(room, cams, label, voxels, setups, seed, quick, out, log,
                                       calibration=calibration and label == "cell",
                                       approach=approach and label == "cell",
                                       variants=(PRODUCT, "single", "paper", "full", "bound", "noiseless") if label == "cell" else (PRODUCT, "single", "paper"),
                                       pictures=res["pictures"])
    res["seconds"] = time.perf_counter() - t_start
    (out / "results.json").write_text(json.dumps(jsonable(res), indent=2))
    (out / "report.md").write_text(report_markdown(res))
    log(f"hamersma2011: wrote {out / 'report.md'} ({res['seconds']:.0f} s)")
    return res


def _evaluate(room: Room, cams, label, voxels, setups, seed, quick, out, log, calibration, approach,
              variants, pictures) -> dict:
    from depthguard.progress import track

    S = braking_distances()
    r: dict = {"cameras": len(cams), "accuracy": {}, "objects": {}, "verdicts": {}, "calibration": {}}
    ideal = {s: ideal_frames(room, s, cameras=cams) for s in track(setups, f"render setups ({label} rig)")}
    noisy = {s: measured_frames(room, s, ideal[s], seed, cameras=cams) for s in setups}
    still = {s: still_frame_list(room, s, ideal[s], seed, cameras=cams, first=noisy[s]) for s in setups}
    p_margin, _ = product_margins(room, cams)
    for vs in voxels:
        self_pad = 0.5 * vs
        make = {PRODUCT: lambda: product_map(room, cams, vs),
                "single": lambda: shell_map(room, cams, vs),
                "paper": lambda: FreeSpaceMap(cams, (room.lo, room.hi), vs, margin=room.margin),
                "full": lambda: FreeSpaceMap(cams, (room.lo, room.hi), vs, margin=room.margin, footprint="full"),
                "bound": lambda: FreeSpaceMap(cams, (room.lo, room.hi), vs, margin=0.0, footprint="full"),
                "noiseless": lambda: product_map(room, cams, vs).map}
        maps = {k: make[k]() for k in variants}
        # the margin trade-off of the product (same frames, same background), cell rig only
        sweep = {}
        if "bound" in variants:
            bg = shell_backgrounds(room, cams)
            for mg in MARGIN_SWEEP:
                sweep[mg] = FreeSpaceMap(cams, (room.lo, room.hi), vs, margin=mg)
                sweep[mg].set_background(bg, tolerance=SHELL_TOLERANCE)
        sweep_acc = {mg: Confusion(0, 0, 0, 0) for mg in sweep}
        sweep_occ: dict = {mg: {} for mg in sweep}
        sweep_verdicts: dict = {mg: {} for mg in sweep}
        seer = FreeSpaceMap(cams, (room.lo, room.hi), vs, margin=0.0)   # noiseless, centre, no margin
        grid = maps[PRODUCT].map.grid
        acc = {k: {} for k in maps}
        objs = {}
        recon = {}
        recon_paper = {}
        for setup in track(setups, f"reconstruct at {vs * 100:.0f} cm ({label} rig)"):
            t = room.times[setup]
            truth = room.scene.occupancy(room.lo, room.hi, vs, t, robot=False, mode="centre")
            if truth.shape != grid.shape:
                raise ValueError(f"ground truth grid {truth.shape} differs from the map {grid.shape}")
            machine = room.carm.primitives(carm_pose(room, setup))
            for k, fs in maps.items():
                depths = (ideal[setup] if k in ("bound", "noiseless") else still[setup] if k == PRODUCT
                          else noisy[setup])
                occ, mach = reconstruct(fs, depths, machine, self_pad)
                acc[k][setup] = confusion(occ, truth, mask=~mach)
                if k == PRODUCT:
                    recon[setup] = (occ, truth, mach)
                elif k == "paper":
                    recon_paper[setup] = occ
            occ, truth_, mach = recon[setup]
            views = maps[PRODUCT].map.view_counts()
            unseen = views == 0
            acc.setdefault("unseen_free", {})[setup] = int((unseen & ~truth_ & ~mach).sum())
            # truly free voxels no camera sees free even in noiseless images (out of view or
            # in the shadow of something for every camera): no reconstruction can free them
            seer.update(ideal[setup])
            nf, _ = seer.counts()
            acc.setdefault("hidden_free", {})[setup] = int(((nf == 0) & ~truth_ & ~mach).sum())
            # free seen as object (product) with the voxel's centre within half a voxel plus the
            # margin of a surface: the depth behind the centre is at most that, so ToF noise
            # against the margin decides (a property of the depth test, not of the camera layout)
            miss = occ & ~truth_ & ~mach
            near = 0
            if miss.any():
                from depthguard.geometry import sdf_union
                prims = list(room.scene.obstacles_at(t)) + list(machine)
                near = int((sdf_union(prims, grid.centres().reshape(-1, 3)[miss.ravel()])
                            <= 0.5 * vs + p_margin + 1e-9).sum())
            acc.setdefault("near_surface_missed", {})[setup] = near
            miss_p = recon_paper[setup] & ~truth_ & ~mach
            near_p = 0
            if miss_p.any():
                from depthguard.geometry import sdf_union
                near_p = int((sdf_union(list(room.scene.obstacles_at(t)) + list(machine),
                                        grid.centres().reshape(-1, 3)[miss_p.ravel()])
                              <= 0.5 * vs + room.margin + 1e-9).sum())
            acc.setdefault("near_surface_missed_paper", {})[setup] = near_p
            for mg, fs_m in sweep.items():
                occ_m, mach_m = reconstruct(fs_m, noisy[setup], machine, self_pad)
                sweep_acc[mg] = sweep_acc[mg] + confusion(occ_m, truth_, mask=~mach)
                sweep_occ[mg][setup] = (occ_m, mach_m)
            per = {}
            for name, (m, thin) in object_masks(room, setup, room.lo, room.hi, vs).items():
                n = int((m & ~mach).sum())
                if n:
                    per[name] = {"voxels": n, "seen_as_free": int((m & ~mach & ~occ).sum()), "smallest_extent_m": thin}
            objs[setup] = per
            if vs == min(voxels):
                p = plot_case_slices(cases(occ, truth_, mask=~mach), grid.lo, vs,
                                     out / f"fig9_{label}_{setup}_{int(round(vs * 100))}cm.png",
                                     title=f"{setup} ({label} rig, {len(cams)} cameras): reconstruction vs truth, "
                                           f"{vs * 100:.0f} cm voxels",
                                     z_levels=[int(0.3 / vs), int(1.1 / vs), int(2.1 / vs)])
                pictures.append(str(p))
        r["accuracy"][vs] = {k: ({s: c.as_dict() for s, c in v.items()}
                                 if k not in ("unseen_free", "hidden_free", "near_surface_missed",
                                              "near_surface_missed_paper")
                                 else v) for k, v in acc.items()}
        r["objects"][vs] = objs
        if sweep_acc:
            r.setdefault("margin_sweep", {})[vs] = {mg: c.as_dict() for mg, c in sweep_acc.items()}

        # ------------------------------------------------ motion verdicts (R22)
        verdicts = []
        fs, fs_paper = maps[PRODUCT], maps["paper"]
        for setup in track(setups, f"motion verdicts at {vs * 100:.0f} cm ({label} rig)"):
            occ, truth, mach = recon[setup]
            q0 = carm_pose(room, setup)
            rows = []
            for name, axes in motion_specs():
                m, _ = clamped_motion(room, q0, axes, S, name)
                rows.append(_verdict_row(setup, m, occ, truth, grid, mach, recon_paper[setup]))
                for mg, per in sweep_occ.items():       # the margin trade-off: base motions only
                    occ_m, mach_m = per[setup]
                    v = _verdict_row(setup, m, occ_m, truth, grid, mach_m)["verdict"]
                    sweep_verdicts[mg][v] = sweep_verdicts[mg].get(v, 0) + 1
            verdicts += rows
            if approach and not quick:
                # approach a contact in steps of S (the paper's "k x" rows): the motion whose true
                # contact is farthest within L, so that the series runs L -> M -> S
                cand = [x for x in rows if 1.0 < (x["u_truth"] or math.inf) <= 5.0]
                if cand:
                    best = max(cand, key=lambda x: x["u_truth"])
                    axes = dict(motion_specs())[best["motion"]]
                    for k in range(2, 7):
                        m, q_at = clamped_motion(room, q0, axes, S, f"{k} x {best['motion']}", offset=float(k - 1))
                        qk = q_at(0.0)
                        ideal_k = ideal_frames(room, setup, carm_q=qk, cameras=cams)
                        one_k = measured_frames(room, setup, ideal_k, seed, cameras=cams)
                        still_k = still_frame_list(room, setup, ideal_k, seed, cameras=cams, first=one_k)
                        occ_k, mach_k = reconstruct(fs, still_k, room.carm.primitives(qk), self_pad)
                        occ_kp, _ = reconstruct(fs_paper, one_k, room.carm.primitives(qk), self_pad)
                        row = _verdict_row(setup, m, occ_k, truth, grid, mach_k, occ_kp)
                        verdicts.append(row)
                        if row["truth"] == "S":
                            break
        r["verdicts"][vs] = verdicts
        for mg, counts in sweep_verdicts.items():
            r["margin_sweep"][vs][mg]["verdicts"] = counts

        # ------------------------------------------------ calibration study
        if calibration:
            cal_cache: dict = {}
            rng = np.random.default_rng(seed + 1)
            cal = {}
            for lab, rot, tr in (("rotation ±1°", 1.0, 0.0), ("translation ±1 cm", 0.0, 0.01), ("both", 1.0, 0.01)):
                pcams = perturbed_cameras(cams, rng, rot, tr)
                rows = [(lab, pcams)]
                if lab == "rotation ±1°":
                    # R34: the disturbed cameras calibrated against the room's static scene first
                    rows.append(("rotation ±1°, calibrated", _calibrated(room, pcams, cams, still[setups[0]],
                                                                         cal_cache, r, log)))
                for lab_k, cams_k in rows:
                    cal[lab_k] = _accuracy_with(room, cams_k, vs, setups, recon, still, noisy, self_pad)
            cal["none"] = {}
            for k in (PRODUCT, "paper"):
                base = Confusion(0, 0, 0, 0)
                for c in acc[k].values():
                    base = base + c
                cal["none"][k] = base.as_dict()
            r["calibration"][vs] = cal
    return r


def _accuracy_with(room: Room, cams, vs, setups, recon, still, noisy, self_pad) -> dict:
    """Pooled confusion (``shell`` and ``paper``) of every setup reconstructed with the map's
    cameras ``cams`` (the images are the true cameras')."""
    # the product renders its background with the cameras it believes in
    fss = {PRODUCT: product_map(room, cams, vs),
           "paper": FreeSpaceMap(cams, (room.lo, room.hi), vs, margin=room.margin)}
    out = {}
    for k, fsp in fss.items():
        tot = Confusion(0, 0, 0, 0)
        for setup in setups:
            _, truth, _ = recon[setup]
            occ, mach = reconstruct(fsp, still[setup] if k == PRODUCT else noisy[setup],
                                     room.carm.primitives(carm_pose(room, setup)), self_pad)
            tot = tot + confusion(occ, truth, mask=~mach)
        out[k] = tot.as_dict()
    return out


def _calibrated(room: Room, pcams, true_cams, frames: list, cache: dict, r: dict, log) -> list:
    """The disturbed cameras ``pcams`` refined against the room's static CAD (R34,
    :func:`depthguard.calibration.calibrate_camera`) from the still frames ``frames`` of the
    first setup (people and the C-arm in view: occluders); the pose errors left are kept in
    ``r["calibration_errors"]``."""
    from depthguard.calibration import StaticScene, calibrate_camera, pose_error

    key = tuple(c.key() for c in pcams)
    if key not in cache:
        scene = StaticScene(room.cell.rig.static_meshes())
        out, errs = [], []
        for pc, tc in zip(pcams, true_cams):
            cal = calibrate_camera(pc, [f[pc.id] for f in frames], scene)
            out.append(cal.refined)
            errs.append(pose_error(cal.refined.world_from_camera, tc.world_from_camera)
                        + pose_error(pc.world_from_camera, tc.world_from_camera))
        e = np.array(errs)
        r["calibration_errors"] = {"cameras": len(out), "before_deg_max": float(e[:, 2].max()),
                                   "after_deg_median": float(np.median(e[:, 0])), "after_deg_max": float(e[:, 0].max()),
                                   "after_mm_median": float(np.median(e[:, 1]) * 1e3),
                                   "after_mm_max": float(e[:, 1].max() * 1e3)}
        log(f"hamersma2011: calibrated the disturbed cameras: {r['calibration_errors']}")
        cache[key] = out
    return cache[key]


def _verdict_row(setup, motion, occ, truth, grid, mach, occ_paper=None) -> dict:
    vr = check_motion(occ, grid, motion, exclude=mach)
    vt = check_motion(truth, grid, motion, exclude=mach)
    row = {"setup": setup, "motion": motion.name, "reconstruction": vr.level, "truth": vt.level,
           "u_recon": vr.u_contact, "u_truth": vt.u_contact, "verdict": compare_verdicts(vr.level, vt.level)}
    if occ_paper is not None:   # the paper's method (no background) on the same frames
        vp = check_motion(occ_paper, grid, motion, exclude=mach)
        row.update(paper_reconstruction=vp.level, paper_verdict=compare_verdicts(vp.level, vt.level))
    return row
