"""Learning the static scene from the cameras (issue 31; R9, R16, R30).

:class:`SceneLearner` takes one camera's frames of the cell with no person in
it, each with the robot's joints at its **capture** (R30), and removes the
robot the way the monitor does (:class:`~depthguard.filtering.expected.ExpectedDepth`
renders the link meshes at those joints; the moving links' silhouette is widened by
``robot_margin_px`` for the joints' and the meshes' tolerance, except where a return lies
clearly behind the robot; the base, which no joint moves, is not widened). A pixel covered
by the robot is *not observable* in that frame (NaN); a pixel without a return, or with one
nearer than the camera's rated range or farther than :data:`FAR_FACTOR` times it, is *no
return* (0). Returns a little beyond the rated range are learned: a surface near the range's
end (the floor's far edge) returns on either side of it from frame to frame, and left unknown
it would make the filter keep every in-range return there as an unknown object, where the
CAD's expected depth (which has no range) matches it. The frames are
kept at most ``max_frames`` (when full, every second one is dropped and the
stride doubles: the kept frames stay spread over the whole run) and
:meth:`SceneLearner.result` takes the per-pixel median
(:func:`depthguard.learned_scene.robust_depth`) and the band's sigma, the larger
of the sensor model's ``sigma(z)`` and the observed spread.

:func:`learn_from_sources` drives one frame source and one joint source (any of
``depthguard monitor``'s) for ``duration`` seconds of their own clock.
"""

from __future__ import annotations

import numpy as np

from depthguard.filtering.expected import ExpectedDepth
from depthguard.learned_scene import ABS_MARGIN, K_SIGMA, LearnedScene, robust_depth
from depthguard.sensors import depth_sigma

#: returns up to this many times the camera's rated range are learned (module docstring)
FAR_FACTOR = 1.5

__all__ = ["SceneLearner", "learn_from_sources", "compare_with_cad", "fixed_link_meshes", "base_silhouette"]


def fixed_link_meshes(robot, cell: float | None = None) -> list:
    """World meshes (clustered as the robot is rendered, :meth:`~depthguard.robot.RobotModel.render_link_meshes`)
    of the robot's links that no joint moves — its base: equal at two joint states that differ in
    every joint."""
    import math

    lo, hi = np.asarray(robot.q_min, float), np.asarray(robot.q_max, float)
    lo = np.where(np.isfinite(lo), lo, -math.pi)
    hi = np.where(np.isfinite(hi), hi, math.pi)
    a = robot.render_link_meshes(lo + 0.3 * (hi - lo), cell)
    b = robot.render_link_meshes(lo + 0.7 * (hi - lo), cell)
    return [ma for ma, mb in zip(a, b) if np.allclose(ma.vertices, mb.vertices, rtol=0.0, atol=1e-9)]


class SceneLearner:
    """One camera's learner (module docstring).

    cam : :class:`~depthguard.camera.Camera`; robot : :class:`~depthguard.robot.RobotModel` or None.
    ``add(depth, q)`` per frame: (H, W) depth m (0 / NaN = no return), (dof,) joints at capture.
    """

    def __init__(self, cam, robot=None, max_frames: int = 64, robot_margin_px: int = 2,
                 min_share: float = 0.5, min_frames: int = 3):
        self.camera = cam
        self.expected = ExpectedDepth(cam, robot)
        # the links no joint moves (the base): their outline needs no margin for the joints' tolerance
        self._base = base_silhouette(cam, robot)
        self.max_frames = max(4, int(max_frames))
        self.margin = int(robot_margin_px)
        self.min_share, self.min_frames = float(min_share), int(min_frames)
        self._stack = np.empty((self.max_frames,) + tuple(cam.shape), dtype=np.float32)
        self._n = 0
        self._stride = 1
        self._offered = 0
        self.frames = 0           # frames offered (all of them, kept or not)

    @property
    def kept(self) -> int:
        return self._n

    def add(self, depth: np.ndarray, q=None) -> None:
        self.frames += 1
        self._offered += 1
        if (self._offered - 1) % self._stride:
            return
        if self._n == self.max_frames:         # full: keep every second frame, take every second from now on
            self._stack[: self._n // 2] = self._stack[0: self._n: 2]
            self._n //= 2
            self._stride *= 2
            self._offered = 1
        cam = self.camera
        d = np.asarray(depth, dtype=np.float32)
        if d.shape != tuple(cam.shape):
            raise ValueError(f"camera {cam.id}: frame is {d.shape}, the camera {tuple(cam.shape)}")
        layer = self._stack[self._n]
        np.copyto(layer, d)
        with np.errstate(invalid="ignore"):
            layer[~((layer >= cam.min_range) & (layer <= FAR_FACTOR * cam.max_range))] = 0.0   # NaN, 0, out of range
        if q is not None and self.expected.robot_model is not None:
            layer[self._hidden_by_robot(layer, self.expected.robot(q))] = np.nan
        self._n += 1

    def _hidden_by_robot(self, layer: np.ndarray, rd: np.ndarray) -> np.ndarray:
        """(H, W) bool: the pixels of frame ``layer`` (m, 0 = no return) that the robot, rendered
        at ``rd`` (m, 0 = none), may hide: its silhouette, and the ring of ``robot_margin_px``
        around its moving links (the joints' and the meshes' tolerance; the base, whose links no
        joint moves, is exactly where it is rendered: no ring) except where the measurement lies
        clearly behind every robot surface within the margin (farther than the largest of them by
        the learned band, ``K_SIGMA sigma(z) + ABS_MARGIN``): that is the scene seen past the
        robot's outline. Without that exception the ring around the links that never move (the
        base) would never be learned, and the cell's filter, with no robot rendered there,
        would keep the table or floor there as an unknown object."""
        robot = rd > 0
        moving = robot & ~self._base
        if self.margin <= 0 or not moving.any():
            return robot
        from scipy.ndimage import binary_dilation, grey_dilation

        ring = binary_dilation(moving, iterations=self.margin) & ~robot
        far = grey_dilation(rd, size=(2 * self.margin + 1, 2 * self.margin + 1))   # the farthest robot surface near
        z = far[ring]
        behind = layer[ring] > z + K_SIGMA * depth_sigma(self.camera, z) + ABS_MARGIN
        ring[ring] = ~behind
        return robot | ring

    def always_hidden(self) -> np.ndarray:
        """(H, W) bool: pixels the robot covered in every kept frame (they stay unknown)."""
        return np.all(np.isnan(self._stack[: self._n]), axis=0)

    def result(self) -> LearnedScene:
        """The camera's :class:`~depthguard.learned_scene.LearnedScene` from the frames kept."""
        if self._n == 0:
            raise ValueError(f"camera {self.camera.id}: no frames to learn the scene from")
        depth, spread, seen = robust_depth(self._stack[: self._n], self.min_share, self.min_frames)
        sigma = np.maximum(depth_sigma(self.camera, depth).astype(np.float32), spread)
        sigma[depth <= 0] = 0.0
        return LearnedScene(self.camera, depth, sigma.astype(np.float32), seen, self.frames)


def learn_from_sources(rig, frame_source, joint_source, duration: float, max_frames: int = 64,
                       progress=None) -> dict:
    """camera id -> :class:`~depthguard.learned_scene.LearnedScene` from ``duration`` seconds of a
    frame and a joint source (``depthguard.sources``): the run's clock starts at the sources'
    first stamp (or 0 for the simulator); each frame takes the joints at its capture stamp from
    the joint states (interpolated, never extrapolated: a frame outside them is skipped and
    counted in ``info``). ``progress(iterable, total)`` wraps the run's steps (a progress bar).

    Returns ``(scenes, info)``: ``info`` = frames per camera (offered, kept), frames skipped
    for lack of joints, and per camera the pixels the robot hid in every kept frame."""
    from depthguard.robot.joint_history import JointHistory, OutsideHistory

    robot = rig.robot
    learners = {c.id: SceneLearner(c, robot, max_frames=max_frames) for c in rig.cameras}
    hist = JointHistory(robot.dof, span_s=5.0) if robot is not None else None
    firsts = [getattr(s, "first_stamp", None) for s in (frame_source, joint_source) if s is not None]
    firsts = [f() if callable(f) else f for f in firsts if f is not None]
    t0 = min(firsts) if firsts else 0.0
    for s in (frame_source, joint_source):
        if s is not None and hasattr(s, "start_clock"):
            s.start_clock(t0)
    step = 1.0 / 30.0
    skipped = 0
    unknown_cameras: set = set()
    n_steps = int(np.ceil(duration / step))
    steps = range(1, n_steps + 1)
    for k in (steps if progress is None else progress(steps, n_steps)):
        t = t0 + min(k * step, duration)
        if joint_source is not None:
            for stamp, q in joint_source.states_until(t):
                hist.push(stamp, q)
        for f in frame_source.frames_until(t):
            ln = learners.get(f.camera_id)
            if ln is None:
                unknown_cameras.add(f.camera_id)
                continue
            q = None
            if hist is not None:
                try:
                    q = hist.at(f.stamp)
                except OutsideHistory:
                    skipped += 1
                    continue
            ln.add(f.depth, q)
        if getattr(frame_source, "done", False) is True:
            break
    empty = [cid for cid, ln in learners.items() if ln.kept == 0]
    if empty:
        raise ValueError(f"no frames of camera{'s' if len(empty) > 1 else ''} {', '.join(empty)} within "
                         f"{duration:g} s of the source (skipped for lack of joints: {skipped})")
    scenes = {cid: ln.result() for cid, ln in learners.items()}
    info = {"hidden": {cid: ln.always_hidden() for cid, ln in learners.items()},"frames": {cid: ln.frames for cid, ln in learners.items()},
            "frames_kept": {cid: ln.kept for cid, ln in learners.items()}, "skipped_without_joints": skipped}
    return scenes, info


def compare_with_cad(cam, scene: LearnedScene, cad: np.ndarray, hidden=None, base=None) -> dict:
    """How well a learned scene reproduces the CAD's expected depth ``cad`` (H, W) m (0 = none).

    Judged pixels: the CAD covers them within the camera's rated range. ``within_band`` = share
    of them whose learned depth is within the band of the CAD depth; the rest is named by why:
    ``unknown`` (no learned surface) - of which ``hidden_by_robot`` (the robot covered them in
    every frame: ``hidden``, (H, W) bool, :meth:`SceneLearner.always_hidden`), split into
    ``behind_base`` (inside ``base``, (H, W) bool, the silhouette of the links no joint moves:
    never observable while the robot is mounted, and covered by the robot's rendering at every
    joint state at run time) and ``behind_arm`` (the moving links: a wider or longer sweep shows
    them), and ``no_return`` (not hidden, too few returns) -, ``edge`` (learned, outside the band,
    on a depth edge of the CAD: mixed pixels) and ``off`` (elsewhere). ``share_outside_base``:
    the share within the band of the judged pixels outside ``base``."""
    from scipy.ndimage import binary_dilation

    c = np.asarray(cad, dtype=np.float32)
    judged = (c >= cam.min_range) & (c <= cam.max_range)
    n = int(judged.sum())
    band = scene.band()
    ok = judged & scene.known & (np.abs(scene.depth - c) <= band)
    gy = np.zeros(c.shape, bool)
    gy[1:, :] |= np.abs(np.diff(c, axis=0)) > 0.03 + 0.02 * c[1:, :]
    gy[:, 1:] |= np.abs(np.diff(c, axis=1)) > 0.03 + 0.02 * c[:, 1:]
    edges = binary_dilation(gy, iterations=1)
    bad = judged & ~ok
    unknown = bad & ~scene.known
    hidden = unknown & hidden if hidden is not None else np.zeros_like(unknown)
    base = np.zeros_like(unknown) if base is None else np.asarray(base, bool)
    n_out = int((judged & ~base).sum())
    out = {"camera": cam.id, "cad_pixels": n, "within_band": int(ok.sum()),
           "share": float(ok.sum()) / n if n else float("nan"),
           "unknown": int(unknown.sum()), "hidden_by_robot": int(hidden.sum()),
           "behind_base": int((hidden & base).sum()), "behind_arm": int((hidden & ~base).sum()),
           "no_return": int((unknown & ~hidden).sum()),
           "edge": int((bad & ~unknown & edges).sum()), "off": int((bad & ~unknown & ~edges).sum()),
           "base_pixels": n - n_out,
           "share_outside_base": float((ok & ~base).sum()) / n_out if n_out else float("nan")}
    return out


def base_silhouette(cam, robot) -> np.ndarray:
    """(H, W) bool: the pixels of camera ``cam`` that the robot's base (:func:`fixed_link_meshes`)
    covers at every joint state (all False without a robot)."""
    fixed = fixed_link_meshes(robot) if robot is not None else []
    return (ExpectedDepth(cam, None, fixed).static > 0) if fixed else np.zeros(cam.shape, bool)
