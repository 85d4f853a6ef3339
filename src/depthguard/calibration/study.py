"""Recovery study: random pose errors on the built-in cells, refined back (R34).

For each of ``n`` perturbations of a cell: one of its cameras (in turn) is
given a wrong pose — a rotation by an angle uniform in ``[0, rot_deg]``
about a uniformly random axis through the optical centre and a shift of
length uniform in ``[0, trans_m]`` in a uniformly random direction — while
the frames come from the true camera through its sensor's noise model
(:class:`~depthguard.sources.SimulatedCamera`, ``frames`` frames of the
cell's scene at ``t``: static CAD, robot, and whoever the scene has there).
The wrong pose is refined (:func:`~depthguard.calibration.calibrate.calibrate_camera`)
and compared with the truth: the rotation angle and the optical centre's
distance, and — when the scene leaves directions unconstrained — the error
within the constrained directions (the unconstrained ones keep the wrong
value by design and are reported).
"""

from __future__ import annotations

import math

import numpy as np

from depthguard.calibration.calibrate import calibrate_camera
from depthguard.calibration.refine import pose_error, so3_exp
from depthguard.calibration.scene import StaticScene

__all__ = ["perturb", "recovery_study", "summarise"]


def perturb(T: np.ndarray, rng: np.random.Generator, rot_deg: float, trans_m: float) -> np.ndarray:
    """A copy of the pose ``T`` (4, 4) turned about its optical centre by up to ``rot_deg`` about a
    random axis and shifted by up to ``trans_m`` in a random direction (module docstring)."""
    ax = rng.normal(size=3)
    ax /= np.linalg.norm(ax)
    ang = math.radians(rng.uniform(0.0, rot_deg))
    d = rng.normal(size=3)
    d *= rng.uniform(0.0, trans_m) / np.linalg.norm(d)
    out = np.array(T, dtype=np.float64)
    out[:3, :3] = so3_exp(ax * ang) @ out[:3, :3]
    out[:3, 3] = out[:3, 3] + d
    return out


def _constrained_error(cal, T_true: np.ndarray) -> tuple[float, float]:
    """``(deg, m)`` of the refined pose's error projected onto the constrained directions."""
    ref = cal.refinement
    Tr = cal.refined.world_from_camera
    dR = Tr[:3, :3] @ T_true[:3, :3].T
    ang = math.acos(max(-1.0, min(1.0, (np.trace(dR) - 1) / 2)))
    axis = np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]])
    w = axis / np.linalg.norm(axis) * ang if np.linalg.norm(axis) > 1e-15 else np.zeros(3)
    xi = np.concatenate([Tr[:3, 3] - T_true[:3, 3], w * ref.L])
    Vc = ref.eigenvectors[:, ref.constrained]
    xc = Vc @ (Vc.T @ xi)
    return math.degrees(float(np.linalg.norm(xc[3:])) / ref.L), float(np.linalg.norm(xc[:3]))


def recovery_study(cell_name: str, n: int = 20, rot_deg: float = 3.0, trans_m: float = 0.05, seed: int = 0,
                   frames: int = 2, t: float = 0.0, cameras=None, log=None) -> list[dict]:
    """One row per perturbation (module docstring): camera, the error given (deg, mm), after
    refinement, within the constrained directions, the unconstrained directions, iterations,
    seconds."""
    import time

    from depthguard.sim import load_cell
    from depthguard.sources import SimulatedCamera

    cell = load_cell(cell_name)
    rig = cell.rig
    scene = StaticScene(rig.static_meshes())
    meshes, _ = cell.scene.meshes_at(t, robot=True)
    q = cell.scene.robot_q(t) if rig.robot is not None else None
    cams = [rig.camera(c) for c in cameras] if cameras else list(rig.cameras)
    rng = np.random.default_rng(seed)
    sims: dict = {}
    rows = []
    for i in range(n):
        cam = cams[i % len(cams)]
        sim = sims.setdefault(cam.id, SimulatedCamera(cam, seed=seed + 17))
        # each perturbation its own noise (the noise is seeded by the stamp; the scene stays at t)
        measured = [np.array(sim.capture(meshes, stamp=1000.0 + i + k / 30.0), copy=True) for k in range(frames)]
        T0 = perturb(cam.world_from_camera, rng, rot_deg, trans_m)
        wrong = cam.with_pose(T0)
        t0 = time.perf_counter()
        cal = calibrate_camera(wrong, measured, scene, rig.robot, [q] if q is not None else None)
        sec = time.perf_counter() - t0
        g_deg, g_m = pose_error(T0, cam.world_from_camera)
        r_deg, r_m = pose_error(cal.refined.world_from_camera, cam.world_from_camera)
        c_deg, c_m = _constrained_error(cal, cam.world_from_camera)
        rows.append({"cell": cell_name, "camera": cam.id, "given_deg": g_deg, "given_mm": g_m * 1e3,
                     "deg": r_deg, "mm": r_m * 1e3, "constrained_deg": c_deg, "constrained_mm": c_m * 1e3,
                     "unconstrained": list(cal.refinement.unconstrained), "iterations": cal.refinement.iterations,
                     "converged": cal.refinement.converged, "before": cal.before.verdict,
                     "after": cal.after.verdict, "seconds": sec})
        if log is not None:
            r = rows[-1]
            log(f"{cell_name} {cam.id}: {g_deg:.2f} deg {g_m * 1e3:.0f} mm -> {r_deg:.4f} deg {r_m * 1e3:.2f} mm"
                + (f" (constrained: {c_deg:.4f} deg {c_m * 1e3:.2f} mm; unconstrained: "
                   f"{'; '.join(r['unconstrained'])})" if r["unconstrained"] else ""))
    return rows


def summarise(rows: list[dict]) -> dict:
    """Median and worst of the errors after refinement (all rows; and within the constrained
    directions), and how many rows had an unconstrained direction."""
    def col(k):
        return np.array([r[k] for r in rows], dtype=float)

    return {"n": len(rows), "median_deg": float(np.median(col("deg"))), "median_mm": float(np.median(col("mm"))),
            "worst_deg": float(col("deg").max()), "worst_mm": float(col("mm").max()),
            "median_constrained_deg": float(np.median(col("constrained_deg"))),
            "median_constrained_mm": float(np.median(col("constrained_mm"))),
            "worst_constrained_deg": float(col("constrained_deg").max()),
            "worst_constrained_mm": float(col("constrained_mm").max()),
            "degenerate": int(sum(bool(r["unconstrained"]) for r in rows)),
            "not_converged": int(sum(not r["converged"] for r in rows)),
            "seconds_median": float(np.median(col("seconds")))}
