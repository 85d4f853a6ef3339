"""Feeding a monitor a simulated world's frames and joints in capture order (shared by tests)."""

from __future__ import annotations

#: s: the joint states sent up to a little after each frame's capture (as a joint source running ahead)
JOINT_LEAD = 0.004


class JointFeed:
    """The world's joint ticks pushed into ``mon`` up to a stamp, each once."""

    def __init__(self, mon, world, lead: float = JOINT_LEAD):
        self._mon, self._states, self._lead, self._j = mon, list(world.states), lead, 0

    def until(self, stamp: float) -> None:
        while self._j < len(self._states) and self._states[self._j][0] <= stamp + self._lead:
            self._mon.push_joints(*self._states[self._j])
            self._j += 1


def fed_frames(mon, world, frames, timeout: float = 60.0):
    """Each of ``frames`` after its joints and itself were pushed into ``mon`` and fused (``flush``)."""
    joints = JointFeed(mon, world)
    for f in frames:
        joints.until(f.stamp)
        mon.push_frame(f)
        mon.flush(timeout=timeout)
        yield f
