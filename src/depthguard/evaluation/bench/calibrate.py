"""Bench group ``calibrate``: a camera's pose check and refinement against the static scene (R34).

``calibrate.ms_per_camera``: wall milliseconds of
:func:`depthguard.calibration.calibrate_camera` for one 640x480 RealSense D435
of the built-in ``ur3-cell`` (camera ``camA``), given 2° and 3 cm off its true
pose, one noisy frame: the check at the given pose, the refinement (robust
point-to-plane ICP, Gauss-Newton with analytic Jacobians; the static scene and
the robot re-rendered each iteration) and the check at the refined pose. One
core, median over the repetitions after a warm-up.

Peer, measured in the same run on the same frame: the same refinement with
SciPy's general solver — the same projective association and robust loss,
each association solved by :func:`scipy.optimize.least_squares` (trust region
reflective, ``soft_l1`` loss, the same analytic Jacobian), re-associated until
the pose stops moving. Both results' pose errors against the truth are in the
note: the peer is also a second implementation of the solve.
"""

from __future__ import annotations

import math

import numpy as np

from depthguard.evaluation.bench import BenchContext, BenchRow, group, time_call


def _frame():
    from depthguard.calibration.refine import so3_exp
    from depthguard.sim import load_cell
    from depthguard.sources import SimulatedCamera

    rig = load_cell("ur3-cell").rig
    cam = rig.camera("camA")
    q = np.asarray(rig.robot_q0, dtype=np.float64)
    meshes = list(rig.static_meshes()) + list(rig.robot.link_meshes(q))
    depth = SimulatedCamera(cam, seed=1).capture(meshes, stamp=0.0)
    T = cam.world_from_camera.copy()
    T[:3, :3] = so3_exp(math.radians(2.0) * np.array([0.36, 0.48, 0.8])) @ T[:3, :3]
    T[:3, 3] += np.array([0.02, -0.02, 0.01])
    return rig, cam, cam.with_pose(T), q, depth


def scipy_refine(cam, measured, scene, robot_depth=None, stride: int = 2, max_outer: int = 30):
    """The peer (module docstring): ``(4, 4)`` refined ``world_from_camera``."""
    from scipy.ndimage import binary_dilation
    from scipy.optimize import least_squares

    from depthguard.calibration.refine import _sample, so3_exp
    from depthguard.calibration.residuals import depth_sigma_of, edge_mask

    vv, uu, z, ray = _sample(cam, measured, stride)
    pc = ray * z[:, None]
    sig_z = depth_sigma_of(cam, z)
    T = np.array(cam.world_from_camera, dtype=np.float64)
    for _ in range(max_outer):
        c = cam.with_pose(T)
        view = scene.view(c)
        bad = edge_mask(view.depth) | (view.face < 0)
        if robot_depth is not None:
            bad |= binary_dilation(np.asarray(robot_depth(c)) > 0, iterations=6)
        sel = ~bad[vv, uu]
        f = view.face[vv[sel], uu[sel]]
        n, d = view.normal[f], view.offset[f]
        R0, o0 = T[:3, :3].copy(), T[:3, 3].copy()
        q_c = pc[sel] @ np.ascontiguousarray(R0.T)         # camera points, world axes, about the centre
        sig = sig_z[sel] * np.maximum(np.abs(np.einsum("ij,ij->i", ray[sel] @ np.ascontiguousarray(R0.T), n)), 0.05)
        base = np.einsum("ij,ij->i", q_c + o0, n) - d
        keep = np.isfinite(base) & np.isfinite(sig)
        q_c, n, d, sig = q_c[keep], n[keep], d[keep], sig[keep]

        def resid(x):
            Rx = so3_exp(x[3:])
            return (np.einsum("ij,ij->i", q_c @ np.ascontiguousarray(Rx.T) + o0 + x[:3], n) - d) / sig

        def jac(x):
            Rx = so3_exp(x[3:])
            p = q_c @ np.ascontiguousarray(Rx.T)
            return np.concatenate([n, np.cross(p, n)], axis=1) / sig[:, None]

        sol = least_squares(resid, np.zeros(6), jac=jac, loss="soft_l1", f_scale=3.0, method="trf")
        x = sol.x
        T = np.eye(4)
        T[:3, :3] = so3_exp(x[3:]) @ R0
        T[:3, 3] = o0 + x[:3]
        if np.linalg.norm(x[:3]) < 2e-5 and np.linalg.norm(x[3:]) < 2e-6:
            break
    return T


@group("calibrate")
def bench_calibrate(ctx: BenchContext) -> list[BenchRow]:
    from depthguard.calibration import StaticScene, calibrate_camera, pose_error
    from depthguard.calibration.calibrate import _robot_fn

    rig, truth, wrong, q, depth = _frame()
    scene = StaticScene(rig.static_meshes())
    reps = 3 if ctx.quick else 10
    holder = {}

    def ours():
        holder["cal"] = calibrate_camera(wrong, [depth], scene, rig.robot, [q])

    t = time_call(ours, reps, warmup=1)
    cal = holder["cal"]
    e_deg, e_m = pose_error(cal.refined.world_from_camera, truth.world_from_camera)
    robot = _robot_fn(rig.robot, [q])

    def peer():
        holder["T"] = scipy_refine(wrong, depth, scene, robot)

    tp = time_call(peer, 1 if ctx.quick else 3, warmup=0)
    p_deg, p_m = pose_error(holder["T"], truth.world_from_camera)
    note = (f"ur3-cell camA 640x480 D435, 2.0 deg + 3 cm off, one frame; ours: {cal.refinement.iterations} "
            f"iterations, left {e_deg:.4f} deg / {e_m * 1e3:.2f} mm, worst {t.max() * 1e3:.0f} ms (checks before "
            f"and after included); peer scipy least_squares (trf, soft_l1, same association and Jacobian, refine "
            f"only): left {p_deg:.4f} deg / {p_m * 1e3:.2f} mm")
    return [BenchRow("calibrate.ms_per_camera", float(np.median(t) * 1e3), "ms", None,
                     "scipy least_squares", float(np.median(tp) * 1e3), note)]
