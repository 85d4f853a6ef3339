"""Bench group ``robot``: forward kinematics + control-point Jacobians for the 500 Hz loop (R14, R15).

``robot.lwr4.fk_jac9_us``: :meth:`RobotModel.forward` on the LWR IV — every
link pose plus the positions and (3, 7) Jacobians of the 9 control points of
Flacco 2015 — per call, preallocated workspace (goal <= 30 us; the control
cycle is 2 ms). ``robot.ur3.fk_jac8_us``: the same for the UR3 URDF chain
(11 links, 8 control points). Peer, measured in the same run: yourdfpy's own
FK of the UR3 URDF (``URDF.update_cfg`` + ``get_transform`` of ``tool0``;
FK only, no Jacobian). ``robot.lwr4.fk_jac9_alloc_us``: the allocating
convenience call ``control_point_jacobians(q)``, with the plain-numpy twin
as its peer. (pinocchio, not installed here, was measured at about 1.3 us
for FK + Jacobian in issue 2.)
"""

from __future__ import annotations

import time

import numpy as np

from depthguard.evaluation.bench import BenchContext, BenchRow, group


def _per_call_us(fn, batch: int, samples: int) -> np.ndarray:
    fn()
    out = np.empty(samples)
    for s in range(samples):
        t0 = time.perf_counter()
        for _ in range(batch):
            fn()
        out[s] = (time.perf_counter() - t0) / batch * 1e6
    return out


@group("robot")
def bench_robot(ctx: BenchContext) -> list[BenchRow]:
    import yourdfpy

    from depthguard.robot import load_robot, ur3_urdf_path
    from depthguard.robot.chain import point_jacobian_numpy

    rng = np.random.default_rng(ctx.seed)
    batch = 200 if ctx.quick else 2000
    samples = 5 if ctx.quick else max(ctx.repeats, 10)
    rows: list[BenchRow] = []

    ur_path = ur3_urdf_path()
    u = yourdfpy.URDF.load(str(ur_path), build_scene_graph=True, load_meshes=False)
    q_ur = rng.uniform(-np.pi, np.pi, 6)

    def peer():
        u.update_cfg(q_ur)
        return u.get_transform(frame_to="tool0", frame_from="world")

    tp = _per_call_us(peer, max(batch // 20, 10), samples)
    peer_us = float(np.median(tp))

    for name, n_cp_label in (("lwr4", "fk_jac9"), ("ur3", "fk_jac8")):
        robot = load_robot(name)
        data = robot.create_data()
        q = np.clip(rng.uniform(-np.pi, np.pi, robot.dof), robot.q_min, robot.q_max)
        t = _per_call_us(lambda: robot.forward(q, data), batch, samples)
        rows.append(BenchRow(f"robot.{name}.{n_cp_label}_us", float(np.median(t)), "us", None,
                             "yourdfpy FK of UR3 (update_cfg + get_transform)", peer_us,
                             f"{robot.chain.n_links} links, {len(robot.control_points)} control points, "
                             f"{robot.dof} dof; goal <= 30 us; worst sample {t.max():.1f} us"))

    lwr = load_robot("lwr4")
    q = lwr.q_home.copy()
    t = _per_call_us(lambda: lwr.control_point_jacobians(q), batch, samples)

    def twin():
        for cp in lwr.control_points:
            point_jacobian_numpy(lwr.chain, q, lwr.chain.link_index(cp.link), cp.offset, lwr.base)

    tn = _per_call_us(twin, max(batch // 100, 2), samples)
    rows.append(BenchRow("robot.lwr4.fk_jac9_alloc_us", float(np.median(t)), "us", None,
                         "plain-numpy twin (FK per point)", float(np.median(tn)),
                         "allocating convenience call control_point_jacobians(q)"))
    return rows
