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

import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from depthguard.camera import Camera
from depthguard.control.motion_check import (Motion, braking_distance, check_motion,
                                             compare_verdicts)
from depthguard.evaluation.accuracy import Confusion, cases, confusion, plot_case_slices
from depthguard.fusion.free_space import FreeSpaceMap
from depthguard.fusion.free_space_product import STILL_FRAMES, FreeSpaceProduct, fuse_still
from depthguard.fusion.free_space_product import product_margins as _fused_margins
from depthguard.fusion.free_space_product import shell_backgrounds as _shell_depths
from depthguard.transforms import pose, rot_x, rot_y, rot_z

__all__ = ["Room", "load_room", "setup_frames", "braking_distances", "run", "PAPER",
           "perturbed_cameras", "GOALS", "shell_primitives", "shell_backgrounds"]

PAPER = {"free": 98.9, "object": 91.1, "unsafe": 2, "motions": 35,
         "table2": {1: (99.1, 89.1), 2: (98.7, 94.0), 3: (98.7, 93.0), 4: (98.6, 89.0),
                    5: (99.2, 90.2), 6: (99.0, 87.3)}}
GOALS = {"free": 99.5, "object": 97.0, "unsafe": 0}
REACTION_TIME = 0.2
MARGIN = 0.02
MARGIN_SWEEP = (0.005, 0.01, 0.015, 0.02)   # the product's margin trade-off, reported beside it
TOF_SIGMA = 0.01                       # the cell's ToF sensor model: sigma about 1 cm
SHELL_TOLERANCE = MARGIN + 3 * TOF_SIGMA   # a measurement this close to the known shell is the shell
PRODUCT = "shell"                      # the reconstruction reported as the product's
FRAME_PERIOD = 1.0 / 30.0              # s between a camera's consecutive frames (30 Hz ToF)
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


def ideal_frames(room: Room, setup: str, carm_q=None, cameras=None) -> dict[str, np.ndarray]:
    """Noiseless rendered depth per camera (float32, 0 = nothing); default: the cell's cameras."""
    meshes = scene_meshes(room, setup, carm_q)
    out = {}
    for cam in (room.cameras if cameras is None else cameras):
        depth, _ = _sim(room, cam, 0, True).renderer.render(meshes)
        out[cam.id] = np.array(depth, copy=True)
    return out


def measured_frames(room: Room, setup: str, ideal: dict, seed: int = 0, noiseless: bool = False, cameras=None,
                    frame: int = 0):
    """Measured frames from ideal ones through each camera's sensor model (deterministic);
    ``frame`` k is the camera's k-th frame of the still setup (its own noise)."""
    t = room.times[setup]
    by_id = {c.id: c for c in (room.cameras if cameras is None else cameras)}
    out = {}
    for cid, img in ideal.items():
        sim = _sim(room, by_id[cid], seed, noiseless)
        out[cid] = np.array(sim.measure(img, stamp=t + frame * FRAME_PERIOD), copy=True)
    return out


def still_fusion(room: Room, cameras=None):
    """The product's fusion of ``STILL_FRAMES`` frames per camera (one sensor model for all)."""
    from depthguard.fusion.temporal import StillFusion
    models = {_sim(room, c, 0, False).model for c in (room.cameras if cameras is None else cameras)}
    if len(models) != 1:
        raise ValueError("the still fusion needs one sensor model for all cameras")
    return StillFusion.for_sensor(models.pop(), STILL_FRAMES)


def still_frame_list(room: Room, setup: str, ideal: dict, seed: int = 0, cameras=None,
                     first: dict | None = None) -> list[dict[str, np.ndarray]]:
    """``STILL_FRAMES`` consecutive measured frames (dicts id -> (H, W) float32) of the still
    setup, frame 0 first, as :meth:`FreeSpaceProduct.update` takes them; ``first``: frame 0 if
    already measured."""
    frames = [first if first is not None else measured_frames(room, setup, ideal, seed, cameras=cameras)]
    frames += [measured_frames(room, setup, ideal, seed, cameras=cameras, frame=k) for k in range(1, STILL_FRAMES)]
    return frames


def still_frames(room: Room, setup: str, ideal: dict, seed: int = 0, cameras=None,
                 first: dict | None = None) -> dict[str, np.ndarray]:
    """``STILL_FRAMES`` consecutive measured frames per camera of the still setup, fused
    (:class:`~depthguard.fusion.temporal.StillFusion`); ``first``: frame 0 if already measured."""
    return fuse_still(still_fusion(room, cameras), still_frame_list(room, setup, ideal, seed, cameras, first),
                      ids=list(ideal))


def setup_frames(room: Room, setup: str, seed: int = 0, carm_q=None, noiseless: bool = False, cameras=None):
    """Measured depth images (dict id -> (H, W) float32) of a setup."""
    return measured_frames(room, setup, ideal_frames(room, setup, carm_q, cameras), seed, noiseless, cameras)


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


def shell_primitives(room: Room) -> list:
    """The room's fixed shell (floor, ceiling, walls): static primitives outside the box."""
    return [p for p in room.scene.static if _outside_box(p, room.lo, room.hi)]


def shell_meshes(room: Room) -> list:
    """World meshes of the room's fixed shell (:func:`shell_primitives`)."""
    return [p.mesh() for p in shell_primitives(room)]


def shell_backgrounds(room: Room, cameras) -> dict[str, np.ndarray]:
    """Expected depth (float32, 0 = nothing) of the room's shell per camera, as the map's
    cameras believe they are placed (:func:`depthguard.fusion.free_space_product.shell_backgrounds`)."""
    return _shell_depths(cameras, shell_meshes(room))


def _shell_map(room: Room, cams, vs) -> FreeSpaceMap:
    """The ``single`` variant: the product's rule on one frame (margin ``room.margin`` = 2 sigma
    of one frame, the shell as background with tolerance ``SHELL_TOLERANCE``)."""
    fs = FreeSpaceMap(cams, (room.lo, room.hi), vs, margin=room.margin)
    fs.set_background(shell_backgrounds(room, cams), tolerance=SHELL_TOLERANCE)
    return fs


def product_margins(room: Room, cams=None) -> tuple[float, float]:
    """``(margin, shell tolerance)`` of the product: 2 and 2 + 3 sigma of the fused depth
    (:func:`depthguard.fusion.free_space_product.product_margins`)."""
    return _fused_margins(still_fusion(room, cams))


def _product(room: Room, cams, vs) -> FreeSpaceProduct:
    """The product's map (:class:`~depthguard.fusion.free_space_product.FreeSpaceProduct`) of
    the room with cameras ``cams`` at voxel size ``vs``."""
    return FreeSpaceProduct(cams, (room.lo, room.hi), vs, still_fusion(room, cams), shell_meshes(room))


# ------------------------------------------------------------------- pieces
def _reconstruct(fs, depths, machine, self_padding):
    """``fs``: a FreeSpaceMap (``depths`` one dict id -> image) or a FreeSpaceProduct
    (``depths`` its list of still frames)."""
    fs.update(depths)
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
        res["placement"] = _placement(room, vs=0.10 if not quick else 0.20, out=out, log=log)
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
    (out / "results.json").write_text(json.dumps(_jsonable(res), indent=2))
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
        make = {PRODUCT: lambda: _product(room, cams, vs),
                "single": lambda: _shell_map(room, cams, vs),
                "paper": lambda: FreeSpaceMap(cams, (room.lo, room.hi), vs, margin=room.margin),
                "full": lambda: FreeSpaceMap(cams, (room.lo, room.hi), vs, margin=room.margin, footprint="full"),
                "bound": lambda: FreeSpaceMap(cams, (room.lo, room.hi), vs, margin=0.0, footprint="full"),
                "noiseless": lambda: _product(room, cams, vs).map}
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
                occ, mach = _reconstruct(fs, depths, machine, self_pad)
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
                occ_m, mach_m = _reconstruct(fs_m, noisy[setup], machine, self_pad)
                sweep_acc[mg] = sweep_acc[mg] + confusion(occ_m, truth_, mask=~mach)
                sweep_occ[mg][setup] = (occ_m, mach_m)
            per = {}
            for name, (m, thin) in _object_masks(room, setup, room.lo, room.hi, vs).items():
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
            for name, axes in _motion_specs():
                m, _ = _clamped_motion(room, q0, axes, S, name)
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
                    axes = dict(_motion_specs())[best["motion"]]
                    for k in range(2, 7):
                        m, q_at = _clamped_motion(room, q0, axes, S, f"{k} x {best['motion']}", offset=float(k - 1))
                        qk = q_at(0.0)
                        ideal_k = ideal_frames(room, setup, carm_q=qk, cameras=cams)
                        one_k = measured_frames(room, setup, ideal_k, seed, cameras=cams)
                        still_k = still_frame_list(room, setup, ideal_k, seed, cameras=cams, first=one_k)
                        occ_k, mach_k = _reconstruct(fs, still_k, room.carm.primitives(qk), self_pad)
                        occ_kp, _ = _reconstruct(fs_paper, one_k, room.carm.primitives(qk), self_pad)
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
    fss = {PRODUCT: _product(room, cams, vs),
           "paper": FreeSpaceMap(cams, (room.lo, room.hi), vs, margin=room.margin)}
    out = {}
    for k, fsp in fss.items():
        tot = Confusion(0, 0, 0, 0)
        for setup in setups:
            _, truth, _ = recon[setup]
            occ, mach = _reconstruct(fsp, still[setup] if k == PRODUCT else noisy[setup],
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


PLACEMENT_RINGS = [(2.35, (0.0, 0.0, 0.6)), (0.6, (0.0, 0.0, 1.8))]   # wall rings: height, target
WALL_CLEARANCE = 0.8            # interior (working volume): 0.8 m from the walls ...
INTERIOR_Z = (0.3, 2.2)         # ... from 0.3 m above the floor to 0.3 m below the ceiling


def _placement(room: Room, vs: float, out: Path, log=print) -> dict:
    """R23 on the empty room: the criterion over the whole box and over its interior
    (``WALL_CLEARANCE`` from the walls, heights ``INTERIOR_Z``); the greedy improver over
    wall rings + ceiling, aiming at 99.5 % of what all candidates together reach."""
    from depthguard.evaluation.placement import (azimuths, candidate_cameras, greedy_placement,
                                                 passes_criterion, share_vs_cameras, visibility)
    from depthguard.fusion.free_space import VoxelGrid

    shell = shell_primitives(room)
    meshes = [p.mesh() for p in shell]
    cands = candidate_cameras(room.lo, room.hi, target=(0.0, 0.0, 0.9), template=room.cameras[0],
                              spacing=0.5, rings=PLACEMENT_RINGS)
    # a camera cannot hang inside (or right against) the room's fixed furniture (cabinets ...)
    furniture = [p for p in room.scene.static if not _outside_box(p, room.lo, room.hi)]
    if furniture:
        from depthguard.geometry import sdf_union
        free = sdf_union(furniture, np.stack([c.position for c in cands])) > 0.10
        cands = [c for c, ok in zip(cands, free) if ok]
    res = {"voxel": vs, "rig_cameras": len(room.cameras), "candidates": len(cands),
           "shell": [p.name for p in shell], "rings": PLACEMENT_RINGS, "regions": {}}
    clear = np.array([WALL_CLEARANCE, WALL_CLEARANCE, 0.0])
    ilo = room.lo + clear
    ihi = room.hi - clear
    ilo[2], ihi[2] = INTERIOR_Z
    for region, (lo, hi) in (("box", (room.lo, room.hi)), ("interior", (ilo, ihi))):
        grid = VoxelGrid(lo, hi, vs)
        pts = grid.centres()
        seen, az = visibility(room.cameras, pts, meshes), azimuths(room.cameras, pts)
        ok = passes_criterion(seen, az)
        g_rig = greedy_placement(seen, az, room.cameras, target_share=1.0, max_cameras=len(room.cameras), prune=False)
        curve_rig = share_vs_cameras(seen, az, g_rig.chosen)
        sc, ac = visibility(cands, pts, meshes), azimuths(cands, pts)
        reach = float(passes_criterion(sc, ac).mean())
        g = greedy_placement(sc, ac, cands, target_share=0.995 * reach, max_cameras=40)
        curve = share_vs_cameras(sc, ac, g.chosen)
        by_z = ok.reshape(grid.shape).mean(axis=(0, 1))
        res["regions"][region] = {
            "lo": np.asarray(lo).tolist(), "hi": np.asarray(hi).tolist(), "rig_share": float(ok.mean()),
            "rig_share_by_z": by_z.tolist(), "rig_curve": curve_rig.tolist(),
            "candidates_all_share": reach, "improver_cameras": len(g.chosen), "improver_share": g.final_share,
            "improver_curve": curve.tolist(), "improver_positions": [c.position.round(3).tolist() for c in g.cameras],
            "improver": g.cameras}
        log(f"placement {region}: rig {100 * ok.mean():.1f} %, improver {len(g.chosen)} cameras -> "
            f"{100 * g.final_share:.1f} % (all candidates {100 * reach:.1f} %)")
    r = res["regions"]
    _plot_fig4(out / "fig4_placement.png", r["interior"]["rig_curve"], r["interior"]["improver_curve"],
               len(room.cameras))
    return res


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
    ax.set_title("R23: >= 3 views pairwise >= 100° apart (empty room, interior)")
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


def _conf(d) -> Confusion:
    return Confusion(d["correct_free"], d["free_as_object"], d["correct_object"], d["object_as_free"])


def _fmt_u(u):
    return "–" if u is None or not math.isfinite(u) else f"{u:.2f}"


def report_markdown(res: dict) -> str:
    L = ["# Hamersma 2011 on `c-arm-room`", ""]
    L.append(f"Setups: {', '.join(res['setups'])}; seed {res['seed']}; voxel sizes "
             f"{', '.join(f'{v * 100:.0f} cm' for v in res['voxels'])}; run time {res.get('seconds', 0):.0f} s."
             + (" QUICK run (two setups, no approach series): not figures to quote." if res["quick"] else ""))
    L.append("")
    L.append("Braking distances S (top speed, 0.2 s reaction, stop in 1 s): "
             + ", ".join(f"{AXIS_LABEL[a]} {math.degrees(v):.1f}°" if a != "longitudinal"
                         else f"{AXIS_LABEL[a]} {v * 100:.1f} cm" for a, v in res["braking"].items())
             + "; M = 2 S, L = 5 S.")
    L.append("")
    for label, rr in res["rigs"].items():
        L.append(f"# Rig `{label}` ({rr['cameras']} cameras)")
        L.append("")
        for vs in res["voxels"]:
            acc = rr["accuracy"][vs]
            variants = [k for k in (PRODUCT, "single", "paper", "full", "bound", "noiseless") if k in acc]
            prod = res["product"]
            pm_cm = 100 * prod["margin_m"]
            L.append(f"## Accuracy at {vs * 100:.0f} cm (tables 1-2), rig `{label}`")
            L.append("")
            L.append("free % = correct free / truly free; object % = correct object / truly occupied; the C-arm's "
                     f"own (freed) voxels are left out. **`shell` is the product**: {prod['frames']} consecutive ToF "
                     "frames per camera of the still scene fused per pixel (the median where they agree within "
                     f"{prod['agree_k']:.1f} sigma, else the nearest: fusion/temporal.py; fused noise "
                     f"{100 * prod['fused_sigma_m']:.2f} cm), centre pixel, centre depth + {pm_cm:.2f} cm (2 sigma of "
                     "the fused depth), and the room's known shell (floor, walls, ceiling) as each camera's "
                     f"background: a measurement within {100 * prod['tolerance_m']:.2f} cm (margin + 3 sigma) of the "
                     "shell is the shell, not a surface in the voxel. `single`: the same from one frame, margin "
                     f"{100 * MARGIN:.0f} cm, tolerance {100 * SHELL_TOLERANCE:.0f} cm. `paper`: the paper's own method "
                     f"(one frame, margin {100 * MARGIN:.0f} cm, no background; the column to compare with the paper); "
                     "`full`: one frame, every pixel of the voxel's projection, no background; `bound`: noiseless, "
                     "every pixel (what the resolution allows); `noiseless`: the product's map on noiseless images "
                     f"(what its rule and {pm_cm:.2f} cm margin allow against a centre-based truth). n1..n4, `unseen` "
                     "(truly free voxels in no camera's view) and `hidden` (truly free voxels no camera sees free "
                     "even in noiseless images) for `shell`.")
            L.append("")
            head = "| setup | " + " | ".join(f"free % {k} | object % {k}" for k in variants) + \
                   " | n1 | n2 | n3 | n4 | unseen | hidden | paper (2011) free / object |"
            L.append(head)
            L.append("|" + "---|" * (2 * len(variants) + 8))
            tot = {k: Confusion(0, 0, 0, 0) for k in variants}
            unseen_tot = 0
            for i, st in enumerate(res["setups"]):
                cells = []
                for k in variants:
                    c = _conf(acc[k][st])
                    tot[k] = tot[k] + c
                    cells += [_pct(c.free_accuracy), _pct(c.object_accuracy)]
                p = _conf(acc[PRODUCT][st])
                un = acc["unseen_free"][st]
                unseen_tot += un
                pp = PAPER["table2"].get(i + 1)
                L.append(f"| {st} | " + " | ".join(cells) + f" | {p.correct_free} | {p.free_as_object} | "
                         f"{p.correct_object} | {p.object_as_free} | {un} | {acc['hidden_free'][st]} | "
                         f"{'' if pp is None else f'{pp[0]} / {pp[1]}'} |")
            cells = []
            for k in variants:
                cells += [f"**{_pct(tot[k].free_accuracy)}**", f"**{_pct(tot[k].object_accuracy)}**"]
            tp = tot[PRODUCT]
            L.append("| **all** | " + " | ".join(cells) + f" | {tp.correct_free} | {tp.free_as_object} | "
                     f"{tp.correct_object} | {tp.object_as_free} | {unseen_tot} | {sum(acc['hidden_free'].values())} | "
                     f"{PAPER['free']} / {PAPER['object']} |")
            L.append("")
            agg = {}
            for st, per in rr["objects"][vs].items():
                for name, d in per.items():
                    a = agg.setdefault(name, [0, 0, d["smallest_extent_m"]])
                    a[0] += d["voxels"]; a[1] += d["seen_as_free"]; a[2] = min(a[2], d["smallest_extent_m"])
            worst = [kv for kv in sorted(agg.items(), key=lambda kv: -kv[1][1]) if kv[1][1]][:8]
            if worst:
                L.append("Objects seen as free (`shell`, all setups): " + "; ".join(
                    f"{k} {v[1]}/{v[0]} voxels (smallest extent {v[2] * 100:.0f} cm)" for k, v in worst) + ".")
                L.append("")
            # goals, judged on the product
            best_free = tp.free_accuracy
            best_obj = tp.object_accuracy
            tpp = tot["paper"]
            L.append(f"Goals at {vs * 100:.0f} cm (product `shell`): free >= {GOALS['free']} %: "
                     f"{'met' if 100 * best_free >= GOALS['free'] else 'NOT met'} ({100 * best_free:.2f} %); "
                     f"objects >= {GOALS['object']} %: {'met' if 100 * best_obj >= GOALS['object'] else 'NOT met'} "
                     f"({_pct(best_obj)} %). The paper's method (`paper`): free {_pct(tpp.free_accuracy)} %, "
                     f"objects {_pct(tpp.object_accuracy)} %.")
            n_free = tp.n_free
            hidden_tot = sum(acc["hidden_free"].values())
            if n_free and 100 * best_free < GOALS["free"]:
                ceiling = 100.0 * (1 - hidden_tot / n_free)
                L.append(f"Ceiling on free space: of the truly free voxels, {unseen_tot} ({100 * unseen_tot / n_free:.2f} %) "
                         f"are in no camera's view and {hidden_tot - unseen_tot} more "
                         f"({100 * (hidden_tot - unseen_tot) / n_free:.2f} %) are in view but in the shadow of something "
                         "(table, people, C-arm, furniture) for every camera: even noiseless images show none of them "
                         f"free, so free space is capped at {ceiling:.2f} % with this rig — "
                         + (f"the goal of {GOALS['free']} % is impossible by {GOALS['free'] - ceiling:.2f} points. "
                            if ceiling < GOALS["free"] else
                            f"above the goal of {GOALS['free']} %: what the cameras see is not what limits free space. ")
                         + f"The rest of the gap ({ceiling - 100 * tp.free_accuracy:.2f} points for `shell`, "
                         f"{ceiling - 100 * tpp.free_accuracy:.2f} for `paper`) is noise against the margin and "
                         "voxels whose centre lies within about a margin of a surface (objects, the C-arm, and — "
                         "for `paper` — the floor, walls and ceiling).")
                for key, k, mg in (("near_surface_missed", PRODUCT, pm_cm), ("near_surface_missed_paper", "paper",
                                                                               100 * MARGIN)):
                    near_d = acc.get(key)
                    tk = tot[k]
                    if near_d is not None and tk.free_as_object:
                        near_tot = sum(near_d.values())
                        L.append(f"Of the {tk.free_as_object} free voxels seen as object (`{k}`), {near_tot} "
                                 f"({100 * near_tot / tk.free_as_object:.1f} %; {100 * near_tot / n_free:.2f} % of the "
                                 f"free space) have their centre within half a voxel + the {mg:.2f} cm margin "
                                 "of a surface (obstacles, C-arm, shell): there the surface lies at most that far behind "
                                 "the centre, so the sensor noise against the margin decides; leaving them "
                                 f"out, free space is {100 * tk.correct_free / max(1, n_free - near_tot):.2f} %.")
            if "noiseless" in tot and 100 * best_free < GOALS["free"]:
                nl = 100 * tot["noiseless"].free_accuracy
                L.append(f"The product's map on **noiseless** images (same rule, same {pm_cm:.2f} cm margin, same "
                         f"background) frees {nl:.2f} % — "
                         + (f"so at {vs * 100:.0f} cm the goal of {GOALS['free']} % is out of reach of this rule with a "
                            f"2 sigma margin by {GOALS['free'] - nl:.2f} points before any noise: voxels whose centre "
                            "lies within the margin in front of a surface (or that hold a surface in front of their "
                            "free centre) are called free by the truth and can never be freed by a camera. "
                            if nl < GOALS["free"] else
                            f"above the goal: at {vs * 100:.0f} cm the sensor noise, not the rule, is what keeps "
                            f"free space {nl - 100 * best_free:.2f} points lower. ")
                         + "A smaller margin needs less noise per view (see the margin trade-off below).")
            if "bound" in tot and 100 * tot["bound"].object_accuracy < GOALS["object"]:
                b = tot["bound"].object_accuracy
                L.append(f"Noiseless cameras reading every pixel of each voxel reach {_pct(b)} % of the objects: "
                         f"the object goal is impossible with these cameras by {GOALS['object'] - 100 * b:.1f} points.")
            sw = rr.get("margin_sweep", {}).get(vs)
            if sw:
                L.append("")
                L.append(f"Margin trade-off at {vs * 100:.0f} cm of one frame per camera (`single`: the same "
                         f"frames and background; {MARGIN * 100:.0f} cm = 2 sigma of the ToF noise of one frame; the "
                         f"product fuses {prod['frames']} frames instead and keeps 2 sigma of the fused depth):")
                L.append("")
                L.append("| margin (cm) | free % | object % | free seen as object | object seen as free | "
                         "verdicts of the base motions (u = unsafe) |")
                L.append("|---|---|---|---|---|---|")
                for mg, d in sorted(sw.items(), key=lambda x: float(x[0])):
                    c = _conf(d)
                    vd = d.get("verdicts") or {}
                    vtxt = ", ".join(f"{k} {vd.get(k, 0)}" for k in ("s", "ts", "tts", "u")) if vd else "–"
                    L.append(f"| {float(mg) * 100:.1f} | {100 * c.free_accuracy:.3f} | {100 * c.object_accuracy:.2f} | "
                             f"{c.free_as_object} | {c.object_as_free} | {vtxt} |")
                ok = [float(mg) for mg, d in sw.items() if 100 * _conf(d).free_accuracy >= GOALS["free"]]
                L.append("")
                L.append((f"Free >= {GOALS['free']} % needs a margin of at most {max(ok) * 100:.1f} cm here"
                          if ok else f"No margin down to {min(float(m) for m in sw) * 100:.1f} cm reaches free >= "
                                     f"{GOALS['free']} % here")
                         + ": a smaller margin frees the voxels whose centre lies just in front of a surface, and "
                           "lets the noise free more of the objects' boundary voxels (object seen as free). With one "
                           "frame a smaller margin costs safety; the product lowers the noise instead (several "
                           "frames fused) and keeps 2 sigma (the verdict column counts the base motions only, "
                           "without the approach series below).")
            L.append("")
        for vs in res["voxels"]:
            rows = rr["verdicts"][vs]
            L.append(f"## Motion verdicts at {vs * 100:.0f} cm (table 4), rig `{label}`")
            L.append("")
            L.append("Reconstruction (product `shell`; `paper` = the paper's method on the same frames) vs "
                     "ground truth (same sweep, same exclusion of the C-arm's own volume); "
                     "s = same, ts = 1-2 levels more severe, tts = stop where the truth is free, u = less severe "
                     "(unsafe). u = first contact in multiples of S. `k x M`: the C-arm first advanced by k-1 S "
                     "along M, re-rendered and re-reconstructed.")
            L.append("")
            L.append("| setup | motion | reconstruction | truth | verdict | u recon | u truth | paper recon | "
                     "paper verdict |")
            L.append("|---|---|---|---|---|---|---|---|---|")
            for r in rows:
                L.append(f"| {r['setup']} | {r['motion']} | {r['reconstruction']} | {r['truth']} | {r['verdict']} | "
                         f"{_fmt_u(r['u_recon'])} | {_fmt_u(r['u_truth'])} | {r.get('paper_reconstruction', '')} | "
                         f"{r.get('paper_verdict', '')} |")
            cnt = {k: sum(r["verdict"] == k for r in rows) for k in ("s", "ts", "tts", "u")}
            cp = {k: sum(r.get("paper_verdict") == k for r in rows) for k in ("s", "ts", "tts", "u")}
            L.append("")
            L.append(f"{len(rows)} motions, `shell` (product): s {cnt['s']}, ts {cnt['ts']}, tts {cnt['tts']}, "
                     f"**u {cnt['u']}**; `paper` method: s {cp['s']}, ts {cp['ts']}, tts {cp['tts']}, u {cp['u']} "
                     f"(the paper (2011): 27 s, 6 ts/tts, 2 u of 35; goal: no u).")
            L.append("")
        if rr["calibration"]:
            L.append(f"## Calibration study (paper §6.1.2), rig `{label}`")
            L.append("")
            L.append("The map's camera model disturbed (each rotation angle uniform in ±1°, each translation "
                     "component in ±1 cm), images from the true cameras; all setups pooled; `shell` (product, its "
                     "background rendered with the disturbed cameras) and `paper`. "
                     "1° is about 4 pixels of these 320x240 70° cameras (the paper: about 1 pixel).")
            L.append("")
            L.append("| voxel | disturbance | free % shell | object % shell | free % paper | object % paper |")
            L.append("|---|---|---|---|---|---|")
            for vs, cal in rr["calibration"].items():
                for lab in ("none", "rotation ±1°", "rotation ±1°, calibrated", "translation ±1 cm", "both"):
                    if lab not in cal:
                        continue
                    d, dp = cal[lab][PRODUCT], cal[lab]["paper"]
                    L.append(f"| {float(vs) * 100:.0f} cm | {lab} | {_pct(d['free_accuracy'])} | "
                             f"{_pct(d['object_accuracy'])} | {_pct(dp['free_accuracy'])} | "
                             f"{_pct(dp['object_accuracy'])} |")
            L.append("")
            ce = rr.get("calibration_errors")
            if ce:
                L.append(f"`rotation ±1°, calibrated` (R34): the disturbed cameras refined with `depthguard calibrate`'s "
                         f"solver against the room's static CAD from the first setup's still frames (people and the "
                         f"C-arm in view), then the same reconstruction. Pose errors left over the {ce['cameras']} "
                         f"cameras: median {ce['after_deg_median']:.4f}° / {ce['after_mm_median']:.2f} mm, worst "
                         f"{ce['after_deg_max']:.4f}° / {ce['after_mm_max']:.2f} mm (disturbed: up to "
                         f"{ce['before_deg_max']:.2f}°).")
                L.append("")
    pl = res.get("placement")
    if pl:
        L.append("# Sensor placement (R23, fig. 4)")
        L.append("")
        L.append(f"Empty room (shell only: {', '.join(pl['shell'])}), {pl['voxel'] * 100:.0f} cm voxels. Criterion: "
                 ">= 3 cameras pairwise >= 100° apart in the horizontal plane. Candidates for the greedy improver: "
                 f"{pl['candidates']} positions every 0.5 m on wall rings "
                 + ", ".join(f"at {h} m looking at {list(t)}" for h, t in pl["rings"])
                 + " and a ceiling grid.")
        L.append("")
        L.append("The improver aims at 99.5 % of what all candidates together reach (at most 40 cameras).")
        L.append("")
        L.append("| region | the cell's 21 cameras | all candidates | improver: cameras | improver: share |")
        L.append("|---|---|---|---|---|")
        for reg, d in pl["regions"].items():
            L.append(f"| {reg} {np.round(d['lo'], 2).tolist()}..{np.round(d['hi'], 2).tolist()} | {_pct(d['rig_share'])} % | "
                     f"{_pct(d['candidates_all_share'])} % | {d['improver_cameras']} | {_pct(d['improver_share'])} % |")
        L.append("")
        box = pl["regions"]["box"]
        L.append("Why the whole box cannot pass: the cameras that see a voxel next to a wall all sit on the other "
                 "side of it (a camera on the near wall has it behind or beside itself), i.e. within a half plane "
                 "of azimuths; three azimuths pairwise >= 100° apart span more than 180°. Share of the box passing "
                 "per height (cell rig): " + ", ".join(f"{v:.2f}" for v in box["rig_share_by_z"]) + ".")
        L.append("")
        it = pl["regions"]["interior"]
        L.append("Fig. 4 (interior): share vs number of the cell's cameras, best first: "
                 + ", ".join(f"{i + 1}: {_pct(v)}" for i, v in enumerate(it["rig_curve"]))
                 + f". Improver ({it['improver_cameras']} cameras, paper: 21): "
                 + ", ".join(f"{i + 1}: {_pct(v)}" for i, v in enumerate(it["improver_curve"])) + ".")
        L.append("")
        L.append("Improver positions (interior): " + "; ".join(str(p) for p in it["improver_positions"]) + ".")
        L.append("")
    L.append("Pictures: " + ", ".join(Path(p).name for p in res["pictures"])
             + (", fig4_placement.png" if pl else "") + ".")
    L.append("")
    return "\n".join(L)
