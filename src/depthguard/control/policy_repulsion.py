"""The repulsion policy: the papers' reaction (Flacco 2012/2015; R13, R14) as a :mod:`~depthguard.control.policy`.

The end effector (control point 0) gets a repulsive velocity
``-v_max / (1 + exp((2 D / rho - 1) alpha)) * V`` (3,) m/s; every other control
point within ``rho`` caps the joint velocities that move it towards its
obstacle (R14); the joint position and speed limits bound the box too. The box
is times the supervision's override. It does not scale the commanded motion
(``scale`` 1): its part is the repulsion and the box. Distances beyond ``rho``
(looked for farther when another policy reaches farther, e.g. SSM) do not
repel. The arithmetic is one numba kernel, :func:`depthguard.control.reaction.reaction`.
"""

from __future__ import annotations

import numpy as np

from depthguard.control.policy import Cycle, Part, PolicySetup
from depthguard.control.reaction import reaction

__all__ = ["Repulsion"]


class Repulsion:
    """R13 + R14 (module docstring)."""
    name = "repulsion"

    def __init__(self, setup: PolicySetup):
        robot = setup.robot
        self._q_min, self._q_max, self._qd_max = (np.ascontiguousarray(a, dtype=np.float64) for a in
                                                  (robot.q_min, robot.q_max, robot.qd_max))
        self._D = np.empty(len(setup.cp_names))
        self._out = (np.empty(3), np.empty(robot.dof), np.empty(robot.dof))

    @staticmethod
    def reach(config) -> float:
        return float(config.rho)

    def update(self, c: Cycle) -> Part:
        cfg = c.config
        D = c.distance
        if cfg.query_rho > cfg.rho:                 # looked for farther for another policy: not repelled
            np.copyto(self._D, D)
            self._D[self._D > cfg.rho] = np.inf
            D = self._D
        rep, lo, hi = reaction(D, c.direction, c.jacobians, c.q, self._q_min, self._q_max, self._qd_max,
                               cfg.dt, cfg.rho, cfg.v_max, cfg.alpha, c.override, out=self._out)
        return Part(repulsion=rep.copy(), qd_min=lo.copy(), qd_max=hi.copy())
