"""Speed and separation monitoring as a :mod:`~depthguard.control.policy` (ISO/TS 15066, R33).

Each cycle: the largest scale of the commanded joint velocity that keeps every
observed control point at least its protective separation distance ``S_p`` from
its nearest obstacle, with the protective stop's hysteresis
(:class:`depthguard.control.ssm_runtime.SpeedSeparation`, docs/SSM.md). The
commanded velocity is the cycle's ``qd`` or, when the caller gives none, the
joints' rate between the last two cycles. Its part: ``scale``, ``stop`` with the
nearest limiting point's reason, and the per-point table ``terms`` (m_cp, 13)
with ``term_names`` = :data:`depthguard.control.ssm.TERMS`. Distances are looked
for within ``max(rho, ssm.range)`` (:meth:`separation_range`): in the cycle's distances (the
grid's query reaches that far, :meth:`reach`) or, with ``ssm.known_scene: muted``, in the muted
voxels (the grid then needs only ``rho``). No repulsion, no joint box.
"""

from __future__ import annotations

import numpy as np

from depthguard.control.policy import Cycle, Part, PolicySetup
from depthguard.control.ssm import TERMS
from depthguard.control.ssm_runtime import SpeedSeparation

__all__ = ["SpeedSeparationPolicy"]


class SpeedSeparationPolicy:
    """R33 (module docstring)."""
    name = "ssm"

    def __init__(self, setup: PolicySetup):
        cfg = setup.config
        dof = setup.robot.dof
        self._cp_names = setup.cp_names
        self.ssm = SpeedSeparation(cfg.ssm, list(setup.cameras), len(setup.cp_names), dof, cfg.delta_d,
                                   cfg.gap_px, cfg.dt, cfg.principal_bin)
        self._qd_meas = np.zeros(dof)          # qd not given: from the joints of two cycles
        self._robot = setup.robot
        self._muted = setup.ssm_obstacles      # issue 31: the separation from what is not the known scene
        m = len(setup.cp_names)
        self._D = np.full(m, np.inf)
        self._V = np.zeros((m, 3))
        self._prev: tuple[float, np.ndarray] | None = None

    @staticmethod
    def reach(config) -> float:
        """The radius (m) SSM needs the depth grid's distances in: ``max(rho, ssm.range)``; with the
        known scene muted SSM takes its separation from the muted voxels instead (within
        :meth:`separation_range`), so it needs nothing from the grid beyond ``rho`` — the grid's
        work grows steeply with the radius (a 2 m query cost fr3-cell's build 100 ms, issue 29)."""
        if config.ssm.known_scene == "muted":
            return float(config.rho)
        return SpeedSeparationPolicy.separation_range(config)

    @staticmethod
    def separation_range(config) -> float:
        """Metres within which the separation is looked for: ``max(rho, ssm.range)`` (R33)."""
        return max(float(config.rho), float(config.ssm.range))

    def update(self, c: Cycle) -> Part:
        if c.qd is None:
            prev = self._prev
            if prev is not None and c.t > prev[0]:
                np.subtract(c.q, prev[1], out=self._qd_meas)
                self._qd_meas /= c.t - prev[0]
            self._prev = (c.t, c.q.copy())
            qd = self._qd_meas
        else:
            qd = np.asarray(c.qd, dtype=np.float64)
        D, V = c.distance, c.direction
        if self._muted is not None:            # the cameras' unknown objects, known scene and robot removed
            cfg = c.config
            self._D.fill(np.inf)
            self._V.fill(0.0)
            self._muted.nearest(c.positions, self.separation_range(cfg), self._D, self._V,
                                robot_capsules=self._robot.collision_segments(c.q, cfg.robot_padding))
            D, V = self._D, self._V
        s, stop = self.ssm.update(c.t, c.dt, D, V, c.positions, c.jacobians, qd, c.observed, c.frame_age)
        return Part(scale=float(s), stop=bool(stop), reasons=self.ssm.reason(self._cp_names) if stop else {},
                    terms=self.ssm.table.copy(), term_names=TERMS)
