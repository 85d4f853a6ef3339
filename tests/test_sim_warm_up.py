"""The simulator's warm-up before a real-time run's clock (issue 29): it renders at the start and at
the first moment each person is in the scene, so that the first frames with a person do not load
the posing's and the person's render kernels on every camera's thread at once (every camera went
stale at 1.07 s on ur3-cell, whose operator walks in at 1 s).

Truth: the scenes' own scripts (each person's ``present`` window) and numba's dispatchers (a kernel
loaded from the disk cache or compiled adds a signature to its dispatcher): after the warm-up,
the frames in which the person walks in load nothing. (Without the person's time the posing's
kernel, ``body_pose._pose_parts``, was loaded there.)
"""

from __future__ import annotations

import pytest


@pytest.mark.parametrize("cell, situation, person_later", [("ur3-cell", None, True), ("flacco-cell", None, True),
                                                            ("ur3-cell", "arm_reaching", False)])
def test_warm_times_reach_each_person_that_is_not_there_at_the_start(cell, situation, person_later):
    from depthguard.sources.sim_source import SimFrames, SimWorld

    world = SimWorld(cell, situation=situation, seed=0)
    times = SimFrames(world)._warm_times()
    assert times[0] == 0.0
    people = world.scene.people
    assert people
    present_at = [any(p.is_present(world.scene_time(t)) for p in people) for t in times]
    assert any(present_at)                                   # a person is rendered before the clock
    assert (len(times) > 1) == person_later                  # a time of its own only where needed


def _overloads() -> dict:
    """Every numba dispatcher of the process and how many compiled signatures it holds (a kernel
    loaded from the disk cache or compiled adds one)."""
    import gc

    from numba.core.registry import CPUDispatcher

    return {id(d): (d, len(d.overloads)) for d in gc.get_objects() if isinstance(d, CPUDispatcher)}


def test_after_the_warm_up_the_first_frames_with_a_person_load_no_kernel():
    from depthguard.sources.sim_source import SimFrames, SimWorld

    world = SimWorld("ur3-cell", seed=0)
    sim = SimFrames(world)
    sim.warm_up()
    sim.frames_until(0.9)                                   # the run's first frames: nobody there yet
    before = _overloads()
    frames = sim.frames_until(1.6)                          # the operator walks in at 1 s
    assert any(f.stamp > 1.0 for f in frames)
    new = [f"{d.py_func.__module__}.{d.py_func.__qualname__}" for k, (d, n) in _overloads().items()
           if k not in before or before[k][1] != n]
    assert new == []
