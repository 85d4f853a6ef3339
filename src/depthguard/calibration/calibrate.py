"""Check and refine every camera of a rig against the known static scene (R34).

:func:`calibrate_camera` takes a camera, one or more of its depth frames
(H, W) float32 metres and the joints the robot stood at for each, and

1. fuses the frames per pixel (the median of the valid measurements; a pixel
   valid in fewer than half of them is left out — moving people vanish);
2. checks the pose it was given: residual statistics
   (:func:`~depthguard.calibration.residuals.residual_stats`), robot removed,
   and where the known scene fits best
   (:func:`~depthguard.calibration.refine.refine_pose`, also with
   ``refine=False``: the fit is then measured, not applied); the verdict is the
   worse of the two (:func:`~depthguard.calibration.verdict.judge`);
3. with ``refine=True`` takes the fit as the refined pose and reports the
   directions the scene does not constrain (kept as given);
4. checks the refined pose the same way.

:func:`calibrate_rig` does this for each camera of a rig; :func:`pose_diff`
prints what changed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from depthguard.calibration.refine import Refinement, pose_error, refine_pose
from depthguard.calibration.residuals import ResidualStats, residual_stats
from depthguard.calibration.scene import StaticScene
from depthguard.calibration.verdict import judge

__all__ = ["CameraCalibration", "calibrate_camera", "calibrate_rig", "fuse_frames", "pose_diff"]


def fuse_frames(frames) -> np.ndarray:
    """(H, W) float32 m: per-pixel median of the valid (finite, > 0) values of a list of (H, W)
    frames; 0 where fewer than half of the frames measured."""
    stack = np.stack([np.asarray(f, dtype=np.float32) for f in frames])
    if stack.shape[0] == 1:
        out = stack[0].copy()
        out[~np.isfinite(out)] = 0.0
        return out
    valid = np.isfinite(stack) & (stack > 0)
    data = np.where(valid, stack, np.nan)
    with np.errstate(all="ignore"):
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(data, axis=0)
    enough = valid.sum(axis=0) * 2 >= stack.shape[0]
    return np.where(enough & np.isfinite(med), med, 0.0).astype(np.float32)


@dataclass
class CameraCalibration:
    """One camera's check and refinement: ``before`` / ``after`` :class:`ResidualStats`, the
    ``refinement`` (the fit), the camera as given (``camera``) and refined (``refined``: the given
    one when the fit was not applied, ``applied`` False); ``fit_offset`` ``(degrees, metres)``
    from the given pose to the fit."""
    camera: object
    refined: object
    before: ResidualStats
    after: ResidualStats
    refinement: Refinement
    applied: bool = True
    fit_offset: tuple = (0.0, 0.0)

    @property
    def correction(self) -> tuple[float, float]:
        """``(degrees, metres)`` between the given and the refined pose."""
        return pose_error(self.camera.world_from_camera, self.refined.world_from_camera)

    def report(self) -> list[str]:
        """Lines for a terminal: the check before and after, the refinement, the unconstrained directions."""
        ref = self.refinement
        deg, m = self.correction
        if not self.applied:                       # --check-only: the fit measured, nothing refined
            lines = [f"camera {self.camera.id}: as given {self.before.line()}"]
            if ref.iterations:
                fd, fm = self.fit_offset
                lines.append(f"  the known scene fits best {fd:.3f} deg, {fm * 1e3:.1f} mm away ({ref.inliers} of "
                             f"{ref.pixels} pixels inliers; {'converged' if ref.converged else 'NOT converged'}); "
                             f"the check changes nothing")
            lines += [f"  NOT CONSTRAINED by the scene (not judged): {s}" for s in ref.unconstrained]
            return lines
        lines = [f"camera {self.camera.id}: as given {self.before.line()}",
                 f"  refined ({ref.iterations} iterations, {'converged' if ref.converged else 'NOT converged'}, "
                 f"{ref.inliers} of {ref.pixels} pixels inliers): moved {deg:.3f} deg, {m * 1e3:.1f} mm",
                 f"  refined pose: {self.after.line()}"]
        for s in ref.unconstrained:
            lines.append(f"  NOT CONSTRAINED by the scene (kept as given): {s}")
        return lines


def _robot_fn(robot, qs):
    if robot is None or not qs:
        return None
    uniq = []
    for q in qs:
        qa = np.asarray(q, dtype=np.float64)
        if not any(np.array_equal(qa, u) for u in uniq):
            uniq.append(qa)
    meshes = [list(robot.link_meshes(q)) for q in uniq]

    def robot_depth(cam) -> np.ndarray:
        from depthguard.render import Renderer
        r = Renderer(cam)
        out = np.zeros(cam.shape, dtype=np.float32)
        for ms in meshes:
            d, _ = r.render(ms)
            np.maximum(out, d, out=out)          # only "> 0 = robot" is used
        return out

    return robot_depth


def calibrate_camera(cam, frames, scene: StaticScene | None, robot=None, qs=None, refine: bool = True,
                     stride: int | None = None, learned=None) -> CameraCalibration:
    """Check (and refine) camera ``cam`` from ``frames`` (list of (H, W) float32 m) of the static
    scene ``scene``; ``robot`` and ``qs`` (one joint vector per frame, or fewer: the robot stood
    at each) remove the robot. ``stride``: sample every stride-th pixel (default 2 for images
    wider than 400 pixels, else 1).

    ``learned`` ((H, W) float32 m, 0 = unknown; issue 31): the camera's learned static scene,
    learned at the pose given. The check compares with the nearer of it and the CAD; the fit
    needs the CAD's planes: with a learned scene alone (``scene`` None) the pose is checked, not
    refined (a moved camera is relearned, ``depthguard rig learn-scene --replace``)."""
    from depthguard.camera import check_depth_image

    frames = list(frames)
    if not frames:
        raise ValueError(f"camera {cam.id}: no frame to calibrate with")
    for f in frames:
        check_depth_image(cam, f, "frame")
    measured = fuse_frames(frames)
    robot_depth = _robot_fn(robot, list(qs) if qs is not None else [])
    rd0 = robot_depth(cam) if robot_depth is not None else None
    expected = scene.view(cam).depth if scene is not None else np.zeros(cam.shape, dtype=np.float32)
    if learned is not None:
        from depthguard.render.composite import nearest_depth
        nearest_depth(expected, np.ascontiguousarray(learned, dtype=np.float32))
    before = residual_stats(cam, measured, expected, rd0)
    if scene is None:                      # a learned scene alone: no planes to fit, the check is the verdict
        ref = Refinement(np.array(cam.world_from_camera), 0, False, 0, 0, math.nan)
        return CameraCalibration(cam, cam, before, before, ref, applied=False, fit_offset=(0.0, 0.0))
    if stride is None:
        stride = 2 if cam.width > 400 else 1
    no_fit = None
    try:                                   # the fit, applied or not: the fine measure of the pose
        ref = refine_pose(cam, measured, scene, robot_depth, stride=stride)
    except ValueError as exc:              # no scene where the camera looks: cannot be judged
        ref, no_fit = Refinement(np.array(cam.world_from_camera), 0, False, 0, 0, math.nan), str(exc)
    offset = pose_error(cam.world_from_camera, ref.world_from_camera)
    before = judge(before, ref, offset, no_fit)
    if not refine:
        return CameraCalibration(cam, cam, before, before, ref, applied=False, fit_offset=offset)
    refined = cam.with_pose(ref.world_from_camera)
    rd1 = robot_depth(refined) if robot_depth is not None else None
    after = judge(residual_stats(refined, measured, scene.view(refined).depth, rd1), ref, (0.0, 0.0), no_fit)
    return CameraCalibration(cam, refined, before, after, ref, applied=True, fit_offset=offset)


def calibrate_rig(rig, frames: dict, qs: dict | None = None, refine: bool = True, log=None) -> dict:
    """``{camera id: CameraCalibration}`` for the cameras of ``rig`` that have frames in ``frames``
    (``{camera id: [depth, ...]}``); ``qs``: ``{camera id: [q, ...]}`` the joints at each frame."""
    learned = getattr(rig, "learned", {})           # issue 31: the learned scene checks too
    scene = StaticScene(rig.static_meshes()) if (rig.static_meshes() or not learned) else None
    out = {}
    for cid, fr in frames.items():
        cam = rig.camera(cid)
        ls = learned.get(cid)
        out[cid] = calibrate_camera(cam, fr, scene, rig.robot, (qs or {}).get(cid), refine=refine,
                                    learned=None if ls is None else ls.depth)
        if log is not None:
            log(f"calibrate: camera {cid} done ({out[cid].before.verdict} -> {out[cid].after.verdict})")
    return out


def pose_diff(cam_old, cam_new) -> str:
    """A few lines: the optical centre and the rotation before and after, and the change."""
    from depthguard.transforms import matrix_to_quat

    To, Tn = cam_old.world_from_camera, cam_new.world_from_camera
    deg, m = pose_error(To, Tn)
    d = Tn[:3, 3] - To[:3, 3]
    # the rotation change, world axes: R_new R_old^T
    dR = Tn[:3, :3] @ To[:3, :3].T
    ang = math.acos(max(-1.0, min(1.0, (np.trace(dR) - 1) / 2)))
    axis = np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]])
    axis = axis / np.linalg.norm(axis) if np.linalg.norm(axis) > 1e-12 else np.zeros(3)

    def v(a):
        return "(" + ", ".join(f"{x:+.4f}" for x in a) + ")"

    return "\n".join([
        f"camera {cam_old.id}: moved {m * 1e3:.1f} mm, turned {deg:.3f} deg",
        f"  position  {v(To[:3, 3])} -> {v(Tn[:3, 3])} m  (change {v(d * 1e3)} mm)",
        f"  rotation  quaternion xyzw {v(matrix_to_quat(To[:3, :3]))} -> {v(matrix_to_quat(Tn[:3, :3]))}",
        f"            turn {math.degrees(ang):.3f} deg about world axis {v(axis)}",
    ])
