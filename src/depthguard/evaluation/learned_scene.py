"""The learned scene against the CAD on a built-in cell (issue 31, R38): ``depthguard reproduce learned-scene``.

A scene is learned from ``duration`` seconds of the cell's simulated frames with nobody in it and
the robot moving (:func:`~depthguard.filtering.scene_learner.learn_from_sources`, as ``depthguard
rig learn-scene`` does), then the rig **with** its CAD objects and the same rig **without** them,
the learned scene in their place, are asked the same questions; the truth of each answer is the
CAD rig's:

- :func:`pixel_table`: of the pixels the CAD covers within the camera's range, the share the
  learned scene reproduces within its band (:func:`~depthguard.filtering.scene_learner.compare_with_cad`);
  the same share of the CAD's pixels in front of the robot's base (the links no joint moves,
  bolted to the cell: in the camera's view of the cell they cover what lies behind them as a
  fixture would) and of the observable ones (not covered by the robot at every joint state);
  and the rest named: ``behind_base`` (the robot's links that no joint moves, and the learner's
  margin around them, cover them at every joint state: never observable while the robot is
  mounted, and never needed — at run time the robot is rendered in front of them at every frame),
  ``behind_arm`` (the moving links covered them in every kept frame: a longer or wider sweep
  would show them), ``no_return`` (seen, but returning in too few frames), ``edge`` and ``off``
  (learned, outside the band: on a depth edge of the CAD, elsewhere);
- :func:`filter_table`: the per-camera filter (R17) on frames of the cell's situations (people in
  the cell, the robot on its path): the share of all pixels it classifies the same (kept as an
  unknown object or removed as known scene / robot / invalid), and the voxels (R18, R19) either
  gives that the other does not;
- :func:`calibration_table`: the calibration check's verdict (R34) for each camera at its rig pose
  and turned by 2 degrees;
- :func:`drift_table`: the drift watch (R34) with the monitor's settings, on frames of a still
  camera and of one bumped by 2 degrees (``untrusted:<camera>`` or ``trusted``);
- :func:`ssm_table`: closed-loop runs (flacco-cell's scenarios) with speed and separation
  monitoring and ``ssm.known_scene: muted`` — the setting where the known scene changes SSM's
  answers: SSM violations, minimum true separation, protective stops.

The scene's camera may be scaled down by ``scale`` (tests: same field of view, 1/scale of the
pixels per side).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

__all__ = ["scaled_rig", "learn", "always_covered", "pixel_table", "filter_table", "calibration_table",
           "drift_table", "ssm_table", "turned", "evaluate", "report"]


def _scaled(cam, f: int):
    """``cam`` at 1/f of its resolution, same pose and field of view."""
    return dataclasses.replace(cam, width=cam.width // f, height=cam.height // f, fx=cam.fx / f, fy=cam.fy / f,
                               cx=(cam.cx + 0.5) / f - 0.5, cy=(cam.cy + 0.5) / f - 0.5)


def scaled_rig(rig, scale: int = 1):
    """``rig`` with every camera at 1/``scale`` of its pixels per side (1: the rig itself)."""
    if int(scale) == 1:
        return rig
    return dataclasses.replace(rig, cameras=[_scaled(c, int(scale)) for c in rig.cameras])


def turned(cam, deg: float):
    """``cam`` turned by ``deg`` degrees about the world vertical through its optical centre (a bump)."""
    from depthguard.calibration.refine import so3_exp

    T = cam.world_from_camera.copy()
    T[:3, :3] = so3_exp(np.array([0.0, 0.0, 1.0]) * math.radians(deg)) @ T[:3, :3]
    return cam.with_pose(T)


def learn(rig, cell_name: str, duration: float = 10.0, max_frames: int = 64, seed: int = 0, progress=None):
    """``(scenes, info)`` of :func:`~depthguard.filtering.scene_learner.learn_from_sources` on
    ``duration`` s of ``sim:CELL:alone`` (the simulator renders the CAD rig's scene; the
    learner removes the robot only)."""
    from depthguard.filtering.scene_learner import learn_from_sources
    from depthguard.sources.base import open_joints, open_source

    ctx: dict = {}
    frames = open_source(f"sim:{cell_name}:alone:seed={int(seed)}", rig, ctx)
    joints = open_joints("sim", rig, ctx)
    try:
        return learn_from_sources(rig, frames, joints, duration, max_frames=max_frames, progress=progress)
    finally:
        for s in (frames, joints):
            if hasattr(s, "close"):
                s.close()


def always_covered(cam, robot, n: int = 64, seed: int = 0) -> np.ndarray:
    """(H, W) bool: pixels of ``cam`` the robot covers at every one of ``n`` joint states drawn
    uniformly within its limits (the base, and links that turn about an axis through it): no
    motion of the robot during learning would show what lies behind them."""
    from depthguard.filtering.expected import ExpectedDepth

    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(robot.q_min, float), np.asarray(robot.q_max, float)
    lo = np.where(np.isfinite(lo), lo, -math.pi)
    hi = np.where(np.isfinite(hi), hi, math.pi)
    ex = ExpectedDepth(cam, robot)
    m = np.ones(cam.shape, bool)
    for q in rng.uniform(lo, hi, (int(n), len(lo))):
        m &= ex.robot(q) > 0
    return m


def pixel_table(rig, scenes: dict, info: dict) -> list[dict]:
    """Per camera: the CAD's pixels in range and the learned scene's agreement (module docstring;
    :func:`~depthguard.filtering.scene_learner.compare_with_cad`). ``behind_arm`` is split into
    ``behind_arm_always`` (pixels the robot covers at every sampled joint state,
    :func:`always_covered`: no sweep shows them) and ``behind_arm_run`` (a wider sweep would);
    ``share_observable`` is the share within the band of the CAD's pixels outside what the robot
    covers at every joint state (base included), ``observable`` their number."""
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.filtering.scene_learner import base_silhouette, compare_with_cad

    cad = list(rig.static_meshes())
    rows = []
    for cam in rig.cameras:
        sc, hidden = scenes[cam.id], info["hidden"][cam.id]
        c = ExpectedDepth(cam, None, cad).static
        base = base_silhouette(cam, rig.robot)
        r = compare_with_cad(cam, sc, c, hidden, base)
        cover = always_covered(cam, rig.robot) | base
        judged = (c >= cam.min_range) & (c <= cam.max_range)
        ok = judged & sc.known & (np.abs(sc.depth - c) <= sc.band())
        arm = judged & ~sc.known & hidden & ~base
        obs = judged & ~cover
        r.update(behind_arm_always=int((arm & cover).sum()), behind_arm_run=int((arm & ~cover).sum()),
                 observable=int(obs.sum()), share_observable=float((ok & obs).sum()) / max(int(obs.sum()), 1),
                 frames=info["frames"][cam.id], frames_kept=info["frames_kept"][cam.id])
        rows.append(r)
    return rows


def _learned_rig(rig, scenes: dict):
    """``rig`` without its CAD objects, the learned ``scenes`` in their place."""
    return dataclasses.replace(rig.without_cad(), learned=dict(scenes))


def filter_table(rig, scenes: dict, scene, times, seed: int = 7) -> list[dict]:
    """Per camera and time: the per-camera filter with the CAD vs with the learned scene on the
    simulated frame of ``scene`` (a :class:`~depthguard.sim.scene.Scene`: its robot path and
    people) at each of ``times`` (s): pixels classified the same, pixels kept by each, voxels."""
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.fusion.voxel_kernels import keep_mask_numpy
    from depthguard.fusion.voxels import VoxelFilter, offset_for_camera
    from depthguard.sources import SimulatedCamera

    cad = list(rig.static_meshes())
    ws = (rig.workspace.lo, rig.workspace.hi)
    rows = []
    for cam in rig.cameras:
        sim = SimulatedCamera(cam, seed=seed)
        ex_cad = ExpectedDepth(cam, rig.robot, cad)
        ex_l = ExpectedDepth(cam, rig.robot, (), learned=scenes[cam.id].depth)
        f_cad = VoxelFilter(cam, ws, static_meshes=cad, robot=rig.robot)
        f_l = VoxelFilter(cam, ws, robot=rig.robot, learned=scenes[cam.id].depth)
        off = offset_for_camera(cam)
        for t in times:
            q = scene.robot_q(t)
            meshes = cad + list(rig.robot.link_meshes(q)) + [p.mesh() for p in scene.dynamic_at(t)]
            d = sim.capture(meshes, stamp=float(t))
            k_cad = keep_mask_numpy(cam, d, np.array(ex_cad.known(q)), off.const, off.k)
            k_l = keep_mask_numpy(cam, d, np.array(ex_l.known(q)), off.const, off.k)
            a = {tuple(k) for k in f_cad.filter(d, q).keys}
            b = {tuple(k) for k in f_l.filter(d, q).keys}
            rows.append({"camera": cam.id, "t": float(t), "pixels": int(d.size),
                         "same_share": float(np.mean(k_cad == k_l)),
                         "kept_cad": int(k_cad.sum()), "kept_learned": int(k_l.sum()),
                         "voxels_cad": len(a), "voxels_learned": len(b),
                         "voxels_only_cad": len(a - b), "voxels_only_learned": len(b - a)})
    return rows


def _frames(cam_true, meshes, n: int, seed: int):
    from depthguard.sources import SimulatedCamera

    return [SimulatedCamera(cam_true, seed=seed + k).capture(meshes, stamp=float(k)) for k in range(n)]


def calibration_table(rig, scenes: dict, bump_deg: float = 2.0) -> list[dict]:
    """Per camera, at its rig pose and turned by ``bump_deg``: the calibration check's verdict
    (:func:`~depthguard.calibration.calibrate.calibrate_camera`, no refinement) with the CAD (the
    residuals and the CAD's fit, the worse of the two), with the CAD's residuals alone, and with
    the learned scene alone (residuals only: the fit needs the CAD's planes)."""
    from depthguard.calibration.calibrate import calibrate_camera, fuse_frames
    from depthguard.calibration.residuals import residual_stats
    from depthguard.calibration.scene import StaticScene
    from depthguard.filtering.expected import ExpectedDepth

    cad = list(rig.static_meshes())
    q0 = np.asarray(rig.robot_q0, float)
    meshes = cad + list(rig.robot.link_meshes(q0))
    scene = StaticScene(cad)
    rows = []
    for cam in rig.cameras:
        for pose, true in (("rig pose", cam), (f"turned {bump_deg:g} deg", turned(cam, bump_deg))):
            frames = _frames(true, meshes, 3, 20)
            a = calibrate_camera(cam, frames, scene, rig.robot, [q0], refine=False).before
            b = calibrate_camera(cam, frames, None, rig.robot, [q0], refine=False,
                                 learned=scenes[cam.id].depth).before
            res = residual_stats(cam, fuse_frames(frames), scene.view(cam).depth,
                                 np.array(ExpectedDepth(cam, rig.robot).robot(q0)))
            rows.append({"camera": cam.id, "pose": pose, "cad": a.verdict, "learned": b.verdict,
                         "cad_residuals": res.verdict, "cad_far": a.share_far, "learned_far": b.share_far})
    return rows


def drift_table(rig, scenes: dict, bump_deg: float = 2.0, frames: int = 5) -> list[dict]:
    """Per camera, still and bumped by ``bump_deg``: the drift watch's verdict after ``frames``
    frames, with the monitor's settings and the static scene each camera worker builds (the CAD's;
    the learned scene's with its spread as a sigma floor, :class:`~depthguard.runtime.ingest.CameraWorker`)."""
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.runtime.drift import DriftWatch

    cfg = rig.monitor
    kw = dict(k_sigma=cfg.drift_sigma, share=cfg.drift_share, frames=cfg.drift_frames)
    cad = list(rig.static_meshes())
    q0 = np.asarray(rig.robot_q0, float)
    meshes = cad + list(rig.robot.link_meshes(q0))
    rows = []
    for cam in rig.cameras:
        sc = scenes[cam.id]
        watches = {"cad": lambda: DriftWatch(cam, ExpectedDepth(cam, rig.robot, cad).static, **kw),
                   "learned": lambda: DriftWatch(cam, ExpectedDepth(cam, rig.robot, (), learned=sc.depth).static,
                                                 sigma=sc.sigma, **kw)}
        for pose, true in (("still", cam), (f"bumped {bump_deg:g} deg", turned(cam, bump_deg))):
            fr = _frames(true, meshes, frames, 40)
            row = {"camera": cam.id, "pose": pose}
            for name, make in watches.items():
                w = make()
                for k, d in enumerate(fr):
                    w.update(d, float(k))
                row[name] = f"untrusted:{cam.id}" if w.untrusted else "trusted"
                row[f"{name}_share"] = float(w.share)
            rows.append(row)
    return rows


def ssm_table(cell, scenes: dict, scenarios=("reach",), ssm_range: float = 0.8, seed: int = 0,
              progress=None) -> list[dict]:
    """Per scenario: closed-loop SSM runs with ``known_scene: muted``, the CAD rig vs the rig with the
    learned scene in place of its CAD (the simulator renders the cell's scene either way; the
    truth is the scene's geometry): SSM violations, minimum true separation, stops."""
    from depthguard.control.ssm_config import SSMConfig
    from depthguard.evaluation.closed_loop.loop import LoopConfig
    from depthguard.evaluation.closed_loop.scenarios import run_scenario
    from depthguard.evaluation.ssm_compare import row_of
    from depthguard.progress import log

    variants = {"cad": cell, "learned": dataclasses.replace(cell, rig=_learned_rig(cell.rig, scenes))}
    rows = []
    for name in scenarios:
        for label, c in variants.items():
            cfg = LoopConfig(reaction="ssm", ssm=SSMConfig(range=ssm_range, known_scene="muted"))
            prog = None if progress is None else (lambda it, total, _l=f"{name} / {label}": progress(it, total, _l))
            summary, res = run_scenario(name, seed=seed, config=cfg, cell=c, progress=prog, write=False)
            r = row_of(summary, res, "ssm")
            r["scene"] = label
            rows.append(r)
            log(f"ssm {name} / {label}: progress {_f(r['progress'], 2)}, min true separation "
                f"{_f(r['min_true_separation_m'], 3)} m, protective stops {r['protective_stops']}, "
                f"SSM violations {r['ssm_violations']}")
    return rows


def evaluate(cell_name: str, duration: float = 10.0, scale: int = 1, scenarios=(), seed: int = 0,
             progress=None, parts=("pixels", "filter", "calibration", "drift", "ssm")) -> dict:
    """Every table of the module docstring for built-in cell ``cell_name``; ``scenarios`` the
    closed-loop scenarios of :func:`ssm_table` (flacco-cell's; empty: no SSM runs)."""
    from depthguard.sim import load_cell

    cell = load_cell(cell_name)
    rig = scaled_rig(cell.rig, scale)
    scenes, info = learn(rig, cell_name, duration, seed=seed, progress=progress)
    out: dict = {"cell": cell_name, "duration_s": duration, "scale": scale,
                 "cameras": {c.id: [c.width, c.height] for c in rig.cameras}}
    if "pixels" in parts:
        out["pixels"] = pixel_table(rig, scenes, info)
    if "filter" in parts:
        times = sorted({s.time for s in cell.situations.values()}) or [1.0]
        out["filter"] = filter_table(rig, scenes, cell.scene, times)
    if "calibration" in parts:
        out["calibration"] = calibration_table(rig, scenes)
    if "drift" in parts:
        out["drift"] = drift_table(rig, scenes)
    if "ssm" in parts and scenarios:
        out["ssm"] = ssm_table(dataclasses.replace(cell, rig=rig), scenes, scenarios, seed=seed, progress=progress)
    return out


def _f(x, digits: int) -> str:
    """``x`` with ``digits`` decimals, or an em dash for None (no obstacle in the scenario)."""
    return "\u2014" if x is None else f"{x:.{digits}f}"


def report(res: dict) -> str:
    """The tables of :func:`evaluate` as markdown."""
    L = [f"### {res['cell']}: {res['duration_s']:g} s learned, cameras "
         + ", ".join(f"{k} {w}x{h}" for k, (w, h) in res["cameras"].items())]
    if "pixels" in res:
        L += ["", "| camera | CAD pixels in range | within band | share | share in front of the robot's base "
                  "| share of the observable | rest: behind "
                  "the base | behind the arm at every joint state | behind the arm in this run | no return | edge "
                  "| off |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in res["pixels"]:
            L.append(f"| {r['camera']} | {r['cad_pixels']} | {r['within_band']} | {100 * r['share']:.2f} % | "
                     f"{100 * r['share_outside_base']:.2f} % of {r['cad_pixels'] - r['base_pixels']} | "
                     f"{100 * r['share_observable']:.2f} % of {r['observable']} | {r['behind_base']} | "
                     f"{r['behind_arm_always']} | {r['behind_arm_run']} | {r['no_return']} | {r['edge']} | "
                     f"{r['off']} |")
    if "filter" in res:
        L += ["", "| camera | t s | pixels classified the same | kept CAD / learned | voxels CAD / learned "
                  "| only CAD / only learned |", "|---|---|---|---|---|---|"]
        for r in res["filter"]:
            L.append(f"| {r['camera']} | {r['t']:.2f} | {100 * r['same_share']:.3f} % | {r['kept_cad']} / "
                     f"{r['kept_learned']} | {r['voxels_cad']} / {r['voxels_learned']} | {r['voxels_only_cad']} / "
                     f"{r['voxels_only_learned']} |")
    if "calibration" in res:
        L += ["", "| camera | pose | calibration check, CAD (residuals and fit) | CAD residuals alone | learned "
                  "(residuals; share far CAD / learned) |", "|---|---|---|---|---|"]
        L += [f"| {r['camera']} | {r['pose']} | {r['cad']} | {r['cad_residuals']} | {r['learned']} "
              f"({100 * r['cad_far']:.1f} / {100 * r['learned_far']:.1f} %) |" for r in res["calibration"]]
    if "drift" in res:
        L += ["", "| camera | pose | drift watch, CAD (share far) | learned (share far) |", "|---|---|---|---|"]
        L += [f"| {r['camera']} | {r['pose']} | {r['cad']} ({100 * r['cad_share']:.2f} %) | {r['learned']} "
              f"({100 * r['learned_share']:.2f} %) |" for r in res["drift"]]
    if res.get("ssm"):
        L += ["", "| scenario | known scene (muted for SSM) | progress | min true separation m | protective stops "
                  "| time stopped s | SSM violations |", "|---|---|---|---|---|---|---|"]
        for r in res["ssm"]:
            L.append(f"| {r['scenario']} | {r['scene']} | {_f(r['progress'], 2)} | {_f(r['min_true_separation_m'], 3)} | "
                     f"{r['protective_stops']} | {r['time_stopped_s']:.2f} | {r['ssm_violations']} |")
    return "\n".join(L) + "\n"
