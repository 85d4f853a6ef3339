"""Simulated scenes with ground truth, and the built-in cells (issue 2 §7).

``load_cell(name)`` / ``list_cells()``; a :class:`Scene` gives obstacles,
robot joint values, meshes, true distances and occupancy at any time.
"""

from depthguard.sim.carm import CArm, CArmPose
from depthguard.sim.cells import Cell, Situation, list_cells, load_cell
from depthguard.sim.people import BodyShape, Carry, Key, Person
from depthguard.sim.scene import JointPath, Prop, Scene

__all__ = ["Scene", "Cell", "Situation", "load_cell", "list_cells", "CArm", "CArmPose", "Person", "Key",
           "Carry", "BodyShape", "Prop", "JointPath"]
