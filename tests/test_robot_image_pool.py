"""The simulator's robot images (``CameraSim.robot_image``) in reused arrays (issue 29): an image
that something still holds is never written again, and one that nothing holds is reused.

Truth: a second :class:`~depthguard.filtering.expected.ExpectedDepth` rendering the robot at each
frame's capture joints (read from the simulated world's own joint history).
"""

from __future__ import annotations

import numpy as np

CELL = "flacco-cell"


def test_robot_images_are_reused_once_dropped_and_never_while_held():
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.sources.sim_source import SimFrames, SimWorld

    world = SimWorld(CELL, seed=0)
    sim = SimFrames(world)
    rig = world.rig
    own = {c.id: ExpectedDepth(c, rig.robot, rig.static_meshes()) for c in rig.cameras}
    held, t, n = [], 0.0, 0
    while t < 1.0:
        t += 0.05
        for f in sim.frames_until(t):
            img = f.robot_image
            assert img is not None
            truth = own[f.camera_id].robot(world.history.at(f.stamp))
            np.testing.assert_array_equal(img.depth, truth)
            np.testing.assert_array_equal(img.spans, own[f.camera_id].robot_spans)
            if n % 4 == 0:
                held.append((f.camera_id, f.stamp, img, truth.copy()))      # kept: must stay as made
            n += 1
    for cid, stamp, img, truth in held:
        np.testing.assert_array_equal(img.depth, truth)                  # not written since
    pools = sim.sim._robot_images
    assert sum(p.reused for p in pools.values()) > n // 2                 # the dropped ones came back
    assert n >= 40
