"""Camera calibration against the known static scene: check, refine, watch (R34).

- :mod:`~depthguard.calibration.residuals`: the sensor noise, residual statistics of measured
  against expected static depth and a verdict per camera (good / suspicious / wrong / unknown);
- :mod:`~depthguard.calibration.scene`: the static meshes as per-face planes, rendered per pose;
- :mod:`~depthguard.calibration.refine`: robust point-to-plane ICP (Gauss-Newton, Tukey
  weights) with the directions the scene does not constrain;
- :mod:`~depthguard.calibration.calibrate`: one camera or a whole rig, and the pose diff;
- :mod:`~depthguard.calibration.rig_file`: the corrected rig file, the user's file otherwise intact;
- :mod:`~depthguard.calibration.study`: the recovery study on the built-in cells.

The watch while running is :mod:`depthguard.runtime.drift`. User guide: ``docs/CALIBRATION.md``.
"""

from depthguard.calibration.calibrate import (CameraCalibration, calibrate_camera, calibrate_rig, fuse_frames,
                                              pose_diff)
from depthguard.calibration.refine import Refinement, pose_error, refine_pose
from depthguard.calibration.residuals import ResidualStats, depth_sigma_of, residual_stats
from depthguard.calibration.scene import StaticScene

__all__ = ["CameraCalibration", "calibrate_camera", "calibrate_rig", "fuse_frames", "pose_diff", "Refinement",
           "pose_error", "refine_pose", "ResidualStats", "depth_sigma_of", "residual_stats", "StaticScene"]
