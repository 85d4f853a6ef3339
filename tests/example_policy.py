"""A reaction policy added as one module (docs/ARCHITECTURE.md, "How to add a reaction").

``gentle``: while any observed control point is within ``NEAR`` m of an obstacle the robot
moves at most at ``SCALE`` of its commanded speed and no joint faster than ``QD_CAP`` rad/s;
after ``STOP_AFTER`` s of such cycles it holds a protective stop. It logs how many near
cycles it has seen. Registering it is the module's last line; nothing else changes.
"""

from __future__ import annotations

import numpy as np

from depthguard.control.policy import Part, register_reaction

NEAR = 0.35        # m
SCALE = 0.25
QD_CAP = 0.1       # rad/s
STOP_AFTER = 0.05  # s


class Gentle:
    def __init__(self, setup):
        self.dof = setup.robot.dof
        self.near_cycles = 0
        self.near_since = None

    def update(self, cycle):
        near = bool(np.any(cycle.observed & (cycle.distance < NEAR)))
        self.near_cycles += near
        self.near_since = (self.near_since if self.near_since is not None else cycle.t) if near else None
        stop = near and cycle.t - self.near_since >= STOP_AFTER
        cap = np.full(self.dof, QD_CAP if near else np.inf)
        return Part(scale=SCALE if near else 1.0, stop=stop,
                    reasons={"gentle": f"held near an obstacle for {STOP_AFTER} s"} if stop else {},
                    qd_min=-cap, qd_max=cap, record={"near_cycles": self.near_cycles})


register_reaction("gentle", Gentle)
