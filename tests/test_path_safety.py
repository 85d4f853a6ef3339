"""No colliding motion is judged safe because the robot hides what it touches (R21, R22, R37; issue 30).

flacco-cell, 'reach' (a hand 7 cm from the end effector) and 'hidden_hand' (a hand right behind
the robot as cam0 sees it): the runtime's free-space map from the simulator's noisy frames, the
robot removed at the frames' joints, the rig's defaults; random joint paths from the robot's
pose. Truth: the people's and the scene's own geometry (``Primitive.sdf``: the person's capsules)
at points along the robot's collision capsules (:class:`~depthguard.geometry.Capsule`, their own
``segment``) at dense poses — a segment collides when such a point of a capsule that moves comes
within the capsule's radius of an obstacle. The obstacles these segments meet lie inside or next
to the robot's padded start volume, or in its shadow: a map that freed the robot's padded volume
and a check that left it out judged them safe (12 and 6 segments here). Now every one is ``maybe``
or ``unsafe``.
"""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.filtering.expected import ExpectedDepth
from depthguard.runtime.free_space_map import RuntimeFreeSpace, check_path_in
from depthguard.sim import load_cell
from depthguard.sources.simulated import SimSource

PATHS = 20


@pytest.fixture(scope="module")
def cell():
    return load_cell("flacco-cell")


def truth_per_segment(robot, q, obstacles, per_segment=10, step=0.01):
    """(n-1,) bool collides, and (n-1,) m the contact points' nearest signed distance to the robot's
    unpadded start capsules (``Capsule.sdf``; nan: no contact), per segment of the path ``q``."""
    radii = np.array([c.radius for c in robot.capsules])
    start = robot.collision_capsules(q[0])
    ends0 = np.stack([np.concatenate(c.segment()) for c in start])              # (K, 6)
    f = np.linspace(0.0, 1.0, per_segment + 1)
    poses = np.concatenate([q[i] + f[:, None] * (q[i + 1] - q[i]) for i in range(len(q) - 1)])
    seg = np.repeat(np.arange(len(q) - 1), len(f))
    ends = np.stack([robot.collision_segments(p, 0.0)[0].reshape(-1, 6) for p in poses])    # (P, K, 6)
    moved = np.max(np.abs(ends - ends0[None]), axis=(0, 2)) > 1e-3              # (K,): sweeps something new
    n_u = max(2, int(np.max(np.linalg.norm(ends0[:, 3:] - ends0[:, :3], axis=1)) / step) + 1)
    u = np.linspace(0.0, 1.0, n_u)
    pts = ends[:, :, None, :3] + u[None, None, :, None] * (ends[:, :, None, 3:] - ends[:, :, None, :3])
    d = np.min([o.sdf(pts.reshape(-1, 3)) for o in obstacles], axis=0).reshape(pts.shape[:3])
    contact = (d <= radii[None, :, None]) & moved[None, :, None]                # (P, K, U)
    P, K, U = np.nonzero(contact)
    near = np.min([c.sdf(pts[P, K, U]) for c in start], axis=0) if len(P) else np.zeros(0)
    hit = np.zeros(len(q) - 1, bool)
    hit[seg[P]] = True
    where = np.full(len(q) - 1, np.inf)
    np.minimum.at(where, seg[P], near)
    return hit, np.where(hit, where, np.nan)


@pytest.mark.parametrize("situation", ["reach", "hidden_hand"])
def test_colliding_segments_near_the_robot_or_in_its_shadow_are_never_safe(cell, situation):
    rig = cell.rig
    cfg = rig.monitor
    t = cell.time_of(situation)
    q_now = cell.scene.robot_q(t)
    frames = SimSource(cell, seed=0).frames(t)
    rdepth = {c.id: np.asarray(ExpectedDepth(c, rig.robot, []).robot(q_now)) for c in rig.cameras}
    space = RuntimeFreeSpace(rig, voxel_size=cfg.free_space_voxel, robot_offset=cfg.robot_offset,
                             robot_padding=cfg.robot_padding, scene_padding=cfg.free_space_scene_padding)
    snap = space.build({k: f.depth for k, f in frames.items()}, rdepth, q_now, {k: t for k in frames})
    obstacles = cell.scene.obstacles_at(t)
    lo, hi = np.asarray(rig.robot.q_min, float), np.asarray(rig.robot.q_max, float)
    rng = np.random.default_rng(0)
    colliding, near_start, judged = 0, 0, []
    for _ in range(PATHS):
        target = np.clip(q_now + rng.uniform(-1.2, 1.2, size=len(q_now)), lo, hi)
        q = np.linspace(q_now, target, 21)
        v = check_path_in(snap, rig.robot, np.linspace(0.0, 2.0, 21), q, cfg.robot_padding)
        hit, where = truth_per_segment(rig.robot, q, obstacles)
        for s, h, w in zip(v.segments, hit, where):
            if h:
                colliding += 1
                near_start += bool(w <= cfg.robot_padding + snap.grid.voxel_size)
                judged.append(s.verdict)
    assert colliding >= 10 and near_start >= 5, (colliding, near_start)   # the case is really there
    assert "safe" not in judged, judged
