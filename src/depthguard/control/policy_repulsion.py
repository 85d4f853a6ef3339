"""The repulsion policy: the papers' reaction (Flacco 2012/2015; R13, R14) as a :mod:`~depthguard.control.policy`.

The end effector (control point 0) gets a repulsive velocity
``-v_max / (1 + exp((2 D / rho - 1) alpha)) * V`` (3,) m/s; every other control
point within ``rho`` caps the joint velocities that move it towards its
obstacle (R14); the joint position and speed limits bound the box too. The box
is times the supervision's override. It does not scale the commanded motion
(``scale`` 1): its part is the repulsion and the box. Distances beyond ``rho``
(looked for farther when another policy reaches farther, e.g. SSM) do not
repel. The arithmetic is one numba kernel, :func:`depthguard.control.repulsion_limits.repulsion_and_limits`.
"""

from __future__ import annotations

import numpy as np

from depthguard.control.policy import Cycle, Part, PolicySetup
from depthguard.control.joint_limits import INFLUENCE_TOL
from depthguard.control.repulsion_limits import _repulsion_and_limits_kernel

__all__ = ["Repulsion"]


class Repulsion:
    """R13 + R14 (module docstring)."""
    name = "repulsion"

    def __init__(self, setup: PolicySetup):
        robot = setup.robot
        self._q_min, self._q_max, self._qd_max = (np.ascontiguousarray(a, dtype=np.float64) for a in
                                                  (robot.q_min, robot.q_max, robot.qd_max))
        self._D = np.empty(len(setup.cp_names))
        self._cfg = None                             # the settings last read (they may change while running)

    def _read(self, cfg) -> None:
        self._cfg = cfg
        self._clip = cfg.query_rho > cfg.rho         # looked for farther for another policy: not repelled
        self._params = (float(cfg.dt), float(cfg.rho), float(cfg.v_max), float(cfg.alpha))

    @staticmethod
    def reach(config) -> float:
        return float(config.rho)

    def update(self, c: Cycle) -> Part:
        if c.config is not self._cfg:
            self._read(c.config)
        dt, rho, v_max, alpha = self._params
        D = c.distance
        if self._clip:
            np.copyto(self._D, D)
            self._D[self._D > rho] = np.inf
            D = self._D
        n = self._q_min.shape[0]
        rep, lo, hi = np.empty(3), np.empty(n), np.empty(n)       # fresh: the reaction keeps them
        # repulsion_and_limits' kernel called as it calls it, its floats read once per configuration (issue 29)
        _repulsion_and_limits_kernel(D, c.direction, c.jacobians, c.q, self._q_min, self._q_max, self._qd_max,
                                     dt, rho, v_max, alpha, float(c.override), INFLUENCE_TOL, rep, lo, hi)
        return Part(repulsion=rep, qd_min=lo, qd_max=hi)
