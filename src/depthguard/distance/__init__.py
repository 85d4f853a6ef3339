"""Depth-space distance for one camera (SPEC §2, R3–R9; Flacco et al. 2014).

``depth_space_distance`` and :class:`DistanceResult` are the public surface;
:class:`DistanceWorkspace` is the allocation-free form for control loops;
:mod:`.cartesian` is the point-cloud baseline (R8); :mod:`.self_removal`
renders the robot into a camera (R9).
"""

from depthguard.distance.api import DistanceResult, DistanceWorkspace, depth_space_distance

__all__ = ["DistanceResult", "DistanceWorkspace", "depth_space_distance"]
