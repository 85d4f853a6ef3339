"""The robot's capsules at a frame's capture joints are made on the camera's worker, not on the
fusion's thread (issue 29, R9, R12): each product carries the model's unpadded collision capsules
at its own capture joints, and the fusion's builds, given them, run no forward kinematics.

Truth: the robot model's own ``collision_segments`` at the product's joints, computed here; the
builds' calls of it counted per thread on a monitor fed simulated frames.
"""

from __future__ import annotations

import threading

import numpy as np
from sim_feed import fed_frames

CELL = "flacco-cell"


def test_products_carry_the_capture_joints_capsules_and_builds_run_no_kinematics(monkeypatch):
    from depthguard.runtime.monitor import Monitor
    from depthguard.sources.sim_source import SimFrames, SimWorld

    world = SimWorld(CELL, seed=0)
    frames = SimFrames(world).frames_until(0.6)
    rig = world.rig
    robot = rig.robot
    model_class = type(robot)
    unwrapped = model_class.collision_segments
    unwrapped_at = model_class.segments_at      # (the worker's: from the links it posed for its render)
    threads = []

    def counted(self, q, padding=0.0):
        threads.append((threading.current_thread().name, padding))
        return unwrapped(self, q, padding)

    def counted_at(self, poses, padding=0.0):
        threads.append((threading.current_thread().name, padding))
        return unwrapped_at(self, poses, padding)

    def real(q, padding):
        return unwrapped(robot, q, padding)

    monkeypatch.setattr(model_class, "collision_segments", counted)
    monkeypatch.setattr(model_class, "segments_at", counted_at)
    with Monitor(rig, rig.monitor) as mon, mon.replay():
        checked, builds = 0, []
        for f in fed_frames(mon, world, frames):
            p = mon._workers[f.camera_id].product
            assert p is not None and p.capsules is not None and p.capsules[0] is robot
            ab, r = real(p.q, 0.0)
            np.testing.assert_array_equal(p.capsules[1], ab)
            np.testing.assert_array_equal(p.capsules[2], r)
            checked += 1
            builds.append(mon.fusion.builds)
        assert mon.fusion.errors == 0, mon.fusion.last_error
    assert checked >= 20 and builds[-1] >= 10
    on_fusion = [t for t in threads if t[0] == "depthguard-fusion"]
    assert on_fusion == [], on_fusion[:3]
    assert any(t[0].startswith("depthguard-camera") and t[1] == 0.0 for t in threads)
