"""Reaction policies (control.policy): a policy added as one module (tests/example_policy.py) runs in
the monitor beside the repulsion without an edit of the runtime; the most restrictive wins.

Truth: a second monitor fed the same frames and joints with the repulsion alone (the reference
for the override, the distances and the repulsion's box), and the policy's own rule applied by
the test to the distances the monitor reports.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import example_policy as gentle           # registers "gentle" (the module's last line)
from depthguard.control.policy import reaction_names
from depthguard.filtering.expected import ExpectedDepth
from depthguard.runtime.monitor import Monitor, warm_up
from depthguard.sim import load_cell
from depthguard.sources.frame import Frame


@pytest.fixture(scope="module")
def rig():
    rig = load_cell("flacco-cell").rig
    warm_up(rig, rig.monitor.with_changes(invalid="free"))
    return rig


def frames_with_a_slab(rig, q0, t_on):
    """Per camera: still frames, and from ``t_on`` a slab of pixels 0.2 m in front of the end
    effector along the principal camera's ray (an obstacle near the robot)."""
    still = {c.id: np.array(ExpectedDepth(c, rig.robot, rig.static_meshes()).known(q0), copy=True)
             for c in rig.cameras}
    data = rig.robot.create_data()
    rig.robot.forward(q0, data)
    cam = rig.cameras[0]
    px, py, dp = cam.world_to_depth_space(data.cp_positions[:1])[0]
    u, v = cam.pixel_of(px, py)
    slab = still[cam.id].copy()
    slab[max(v - 12, 0):v + 12, max(u - 12, 0):u + 12] = dp - 0.2
    return lambda cid, t: slab if (cid == cam.id and t >= t_on) else still[cid]


def drive(mon, rig, q0, image, t_end):
    out, dt = [], mon.config.dt
    period = 1.0 / mon.config.camera_hz
    next_frame = 0.0
    for k in range(int(round(t_end / dt)) + 1):
        t = k * dt
        mon.push_joints(t, q0)
        if t + 1e-9 >= next_frame:
            for c in mon.camera_ids:
                mon.push_frame(Frame(c, image(c, next_frame), next_frame))
            next_frame += period
            mon.flush()
        out.append(mon.step(t))
    return out


def test_a_policy_module_composes_with_the_repulsion_most_restrictive_wins(rig, tmp_path):
    assert "gentle" in reaction_names() and {"repulsion", "ssm"} <= set(reaction_names())
    q0 = np.asarray(rig.robot_q0, dtype=np.float64)
    image = frames_with_a_slab(rig, q0, t_on=0.1)
    base_cfg = rig.monitor.with_changes(invalid="free", stop_time=0.2, resume_time=0.3)
    with Monitor(rig, base_cfg) as mon:
        ref = drive(mon, rig, q0, image, 0.3)
    with Monitor(rig, base_cfg.with_changes(reactions=("repulsion", "gentle"))) as mon:
        got = drive(mon, rig, q0, image, 0.3)
    near_seen = stop_seen = 0
    near_since = None
    for r0, r in zip(ref, got):
        # the distances, the override and the repulsion are the repulsion-only monitor's
        np.testing.assert_array_equal(r.distance, r0.distance)
        assert r.override == r0.override
        np.testing.assert_array_equal(r.repulsion, r0.repulsion)
        cp = ~r.is_watch
        near = bool(np.any(r.observed[cp] & (r.distance[cp] < gentle.NEAR)))
        near_since = (near_since if near_since is not None else r.t) if near else None
        stop = near and r.t - near_since >= gentle.STOP_AFTER
        near_seen += near
        stop_seen += stop
        want_scale = 0.0 if stop else r0.override * (gentle.SCALE if near else 1.0)
        assert r.speed_scale == pytest.approx(want_scale, abs=1e-12)
        assert r.protective_stop == stop
        assert ("gentle" in r.reasons) == stop
        cap = gentle.QD_CAP if near else np.inf
        np.testing.assert_array_equal(r.qd_max, np.minimum(r0.qd_max, cap))
        np.testing.assert_array_equal(r.qd_min, np.maximum(r0.qd_min, -cap))
        rec = json.loads(json.dumps(r.to_dict()))
        assert rec["reaction_mode"] == "repulsion+gentle"
        assert rec["policies"]["gentle"]["near_cycles"] == near_seen
    assert near_seen > 10 and stop_seen > 0 and near_seen < len(got)     # both sides of the rule ran


def test_an_unknown_reaction_is_refused_naming_the_known_ones(rig):
    with pytest.raises(ValueError, match="unknown reaction 'nope'; known: .*repulsion.*ssm"):
        rig.monitor.with_changes(reactions=("repulsion", "nope"))


def test_the_shorthand_modes_name_the_same_policies(rig):
    cfg = rig.monitor
    for mode, names in (("repulsion", ("repulsion",)), ("ssm", ("ssm",)), ("both", ("repulsion", "ssm"))):
        c = cfg.with_changes(reaction=mode)
        assert c.policies == names and c.reaction_mode == mode
        assert c.query_rho == (c.rho if mode == "repulsion" else max(c.rho, c.ssm.range))


def test_ssm_with_the_known_scene_muted_needs_the_grid_only_within_rho(rig):
    """With ``ssm.known_scene: muted`` SSM's separation comes from the muted voxels within
    ``max(rho, ssm.range)``: the depth grid is queried within ``rho`` only (its work grows
    steeply with the radius, issue 29); ``tests/test_ssm_known_scene.py`` shows SSM still slows
    for what stands between ``rho`` and the range."""
    from depthguard.control.policy_ssm import SpeedSeparationPolicy

    for mode in ("ssm", "both"):
        c = rig.monitor.with_changes(reaction=mode, rho=0.3, ssm={"known_scene": "muted", "range": 1.5})
        assert c.query_rho == 0.3
        assert SpeedSeparationPolicy.separation_range(c) == 1.5
        c = c.with_changes(ssm={"known_scene": "obstacle", "range": 1.5})
        assert c.query_rho == 1.5
