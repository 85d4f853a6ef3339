"""The simulator hands its robot layer over with each frame (issue 29): the monitor's camera worker
takes it instead of rendering the robot again, only where it is that render bit for bit (R9).

Truth: a second :class:`~depthguard.filtering.expected.ExpectedDepth` (the monitor's renderer,
made here) rendering the robot at the frame's capture joints, read from the simulated world's own
joint history; and a fast run's log written with the hand-over off. A worker that took an image it
should not (another robot, other joints, different bits) fails these checks: they are not vacuous
(the tampered-image case below).
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from sim_feed import JointFeed

CELL = "flacco-cell"


@pytest.fixture(scope="module")
def sim_frames():
    """flacco-cell's simulated frames over the first 1.2 s of its path, with the world they came from."""
    from depthguard.sources.sim_source import SimFrames, SimWorld

    world = SimWorld(CELL, seed=0)
    sim = SimFrames(world)
    frames = sim.frames_until(1.2)
    return world, frames


def test_a_simulated_frame_carries_the_robot_layer_the_monitor_renders_at_its_capture_joints(sim_frames):
    from depthguard.filtering.expected import ExpectedDepth

    world, frames = sim_frames
    rig = world.rig
    own = {c.id: ExpectedDepth(c, rig.robot, rig.static_meshes()) for c in rig.cameras}
    seen = 0
    for f in frames:
        img = f.robot_image
        assert img is not None and img.robot is rig.robot and img.camera is rig.camera(f.camera_id)
        q = world.history.at(f.stamp)                 # the capture joints, from the world's history
        assert img.q.tobytes() == np.asarray(q, dtype=np.float64).tobytes()
        truth = own[f.camera_id].robot(q)
        np.testing.assert_array_equal(img.depth, truth)
        np.testing.assert_array_equal(img.spans, own[f.camera_id].robot_spans)
        assert img.depth.dtype == np.float32 and img.depth is not f.depth
        seen += int(np.count_nonzero(img.depth) > 100)
    assert len(frames) >= 30 and seen >= len(frames) // 2        # the robot is in view


def _worker_products(world, frames, tamper=None):
    """A monitor's camera workers fed ``frames`` on this thread (the world's joint ticks);
    per camera the list of ``(q, robot depth copy)`` of every product, and the workers."""
    from depthguard.runtime.monitor import Monitor

    rig = world.rig
    mon = Monitor(rig, rig.monitor)
    mon.fusion.close()
    out = {cid: [] for cid in mon.camera_ids}
    try:
        joints = JointFeed(mon, world)               # the world's joint ticks, as its joint source sends them
        for f in frames:
            joints.until(f.stamp)
            w = mon._workers[f.camera_id]
            w._process(tamper(f) if tamper is not None else f, 0.0)
            p = w.product
            assert p is not None and p.stamp == f.stamp, w.last_refusal
            out[f.camera_id].append((p.q.copy(), np.array(p.robot_depth, copy=True)))
        return out, dict(mon._workers)
    finally:
        mon.close()


def test_the_worker_takes_the_image_after_its_checks_and_every_product_is_its_own_render(sim_frames):
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.runtime.ingest import HANDOVER_CHECKS

    world, frames = sim_frames
    rig = world.rig
    products, workers = _worker_products(world, frames)
    own = {c.id: ExpectedDepth(c, rig.robot, rig.static_meshes()) for c in rig.cameras}
    for cid, got in products.items():
        for q, rd in got:
            np.testing.assert_array_equal(rd, own[cid].robot(q))
        w = workers[cid]
        assert w.handover is True and w.handover_off is None
        assert w.robot_handed >= len(got) - HANDOVER_CHECKS - 2 and w.robot_handed > 0


def test_an_image_that_differs_turns_the_hand_over_off_and_others_are_not_taken(sim_frames):
    from depthguard.filtering.expected import ExpectedDepth

    world, frames = sim_frames
    rig = world.rig

    def one_pixel_off(f):
        img = f.robot_image
        d = img.depth.copy()
        v, u = np.argwhere(d > 0)[0] if np.any(d > 0) else (0, 0)
        d[v, u] += np.float32(0.001)
        return dataclasses.replace(f, robot_image=img._replace(depth=d))

    products, workers = _worker_products(world, frames, one_pixel_off)
    own = {c.id: ExpectedDepth(c, rig.robot, rig.static_meshes()) for c in rig.cameras}
    for cid, got in products.items():
        for q, rd in got:
            np.testing.assert_array_equal(rd, own[cid].robot(q))
        assert workers[cid].handover is False and workers[cid].robot_handed == 0
        assert "differs from this worker's render" in workers[cid].handover_off

    # other joints' bits, or another robot object: not taken, and the hand-over is not turned off
    def other_joints(f):
        img = f.robot_image
        return dataclasses.replace(f, robot_image=img._replace(q=img.q + 1e-12))

    def another_robot(f):
        return dataclasses.replace(f, robot_image=f.robot_image._replace(robot=object()))

    for tamper in (other_joints, another_robot):
        _, workers = _worker_products(world, frames, tamper)
        assert all(w.robot_handed == 0 and w.handover is None for w in workers.values()), tamper.__name__


def _fast_log(hand: bool) -> list[str]:
    from depthguard.runtime import runner
    from depthguard.runtime.monitor import Monitor
    from depthguard.sim.cells import load_cell
    from depthguard.sources.base import open_joints, open_source
    from depthguard.sources.sim_source import sim_world

    rig = load_cell(CELL).rig
    ctx = {}
    src = open_source(f"sim:{CELL}", rig, ctx)
    src.hand_robot = hand
    js = open_joints("sim", rig, ctx)
    lines = []
    with Monitor(rig, rig.monitor, sinks=[sim_world(ctx).on_reaction, lambda r: lines.append(json.dumps(r.to_dict()))]) as mon:
        runner.run(mon, [src], js, duration=1.5, fast=True)
        handed = sum(w.robot_handed for w in mon._workers.values())
    assert (handed > 0) == hand
    return lines


def test_a_fast_run_logs_the_same_bytes_with_the_hand_over_and_without():
    on, off = _fast_log(True), _fast_log(False)
    assert len(on) > 500 and on == off
