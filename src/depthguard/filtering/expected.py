"""The expected depth of the known scene in one camera (R9, R16, R17, R30).

The static CAD scene does not move: it is rendered once per camera. The
robot moves: it is rendered at the joints of each frame's **capture** (R30),
into a preallocated image. Both are the same z-buffer renderer
(:class:`depthguard.render.Renderer`), so the expected depth of the whole
known scene is the per-pixel nearest of the two
(:func:`depthguard.render.composite.nearest_depth`).

A cell without CAD (issue 31) has a static scene learned from its own cameras
(:mod:`depthguard.learned_scene`): ``learned`` joins the CAD, and where both
say something the nearer surface wins (what is nearer is what the camera sees).

One object per camera and per thread: the renderer's buffers are reused.
"""

from __future__ import annotations

import numpy as np

from depthguard.render import Renderer
from depthguard.render.composite import nearest_depth

__all__ = ["ExpectedDepth"]


class ExpectedDepth:
    """Expected depth of camera ``cam`` (a :class:`~depthguard.camera.Camera`).

    robot : a :class:`~depthguard.robot.RobotModel` or None.
    static_meshes : list of world :class:`~depthguard.geometry.Mesh` (the rig's objects).
    parallel : the renderer's numba threads (False: one thread, for worker threads).
    learned : (H, W) float32 m, the camera's learned static scene (0 = unknown) or None
        (:meth:`depthguard.rig.Rig.learned_depth`); the nearer of it and the CAD is ``static``.
    robot_cell : m, the robot's meshes are rendered clustered to this
        (:meth:`~depthguard.robot.RobotModel.render_link_meshes`; default
        :data:`~depthguard.geometry.decimate.RENDER_CELL`, the monitor's; the simulator uses
        :data:`~depthguard.geometry.decimate.SIM_CELL`).

    ``static`` is the (H, W) float32 static scene in metres (0 = nothing);
    :meth:`robot` renders the robot at ``q`` and returns the renderer's (H, W) float32
    image (read-only, overwritten by the next call: copy it to keep it); :meth:`known`
    the nearest of both.
    """

    def __init__(self, cam, robot=None, static_meshes=(), parallel: bool = False, learned=None,
                 robot_cell: float | None = None):
        self.camera = cam
        self.robot_model = robot
        self.robot_cell = robot_cell
        # depth only (no labels, no face ids: nothing here reads them): the same depth bits with a
        # third less memory traffic per pixel of a triangle's box (issue 29; the parallel kernel draws ids)
        self._renderer = Renderer(cam, parallel=parallel, ids=bool(parallel))
        meshes = list(static_meshes)
        self.static = (np.array(self._renderer.render(meshes)[0], dtype=np.float32, copy=True) if meshes
                       else np.zeros(cam.shape, dtype=np.float32))
        if learned is not None:
            ld = np.asarray(learned, dtype=np.float32)
            if ld.shape != tuple(cam.shape):
                raise ValueError(f"camera {cam.id}: learned scene is {ld.shape}, the camera {tuple(cam.shape)}")
            nearest_depth(self.static, np.ascontiguousarray(ld))
        self._known = np.zeros(cam.shape, dtype=np.float32)
        self._no_robot = np.zeros(cam.shape, dtype=np.float32)
        self._no_robot.flags.writeable = False
        self._no_spans = np.zeros((cam.shape[0], 2), dtype=np.int32)
        self._no_spans.flags.writeable = False
        # a RobotModel fills the bound renderer's vertex buffer itself (no meshes made per frame)
        self._vertices = None
        self._last_q = None                  # the joints of the image in the renderer's buffer
        if robot is not None and hasattr(robot, "render_link_vertices"):
            self._vertices = self._renderer.bind(robot.render_link_topology(robot_cell))

    def robot(self, q, poses: np.ndarray | None = None) -> np.ndarray:
        """(H, W) float32 m: the robot's link meshes at joints ``q`` (clustered to ``robot_cell``;
        0 where no robot). A **read-only view of the renderer's buffer**, overwritten by the next
        call (copy it to keep it); the renderer reads out only the pixels the robot can cover
        now or covered last time, so nothing may write into it (R9, R16, R30). ``poses``: the
        links' world poses (L, 4, 4) at ``q`` the caller worked out already
        (:meth:`~depthguard.robot.RobotModel.forward`; a camera worker poses once a frame for
        this render and its capsules, issue 29), or None."""
        if self.robot_model is None:
            return self._no_robot
        model = self.robot_model
        if type(q) is np.ndarray and q.dtype == np.float64 and q.shape == (model.dof,):
            qa = q                             # (a worker's joints: no conversion)
        else:
            qa = np.asarray(q, dtype=np.float64).reshape(-1)
        if qa.shape[0] != model.dof or not np.isfinite(qa).all():
            raise ValueError(f"expected {model.dof} finite joint values, got {qa.tolist()}")
        if self._vertices is not None:
            if self._last_q is not None and (qa == self._last_q).all():
                return self._renderer.depth      # a robot at rest: the image is still there
            self._last_q = None
            if poses is None:
                model.render_link_vertices(qa, self.robot_cell, self._vertices)
            else:
                model.render_vertices_at(poses, self.robot_cell, self._vertices)
            depth = self._renderer.render_bound()[0]
            self._last_q = qa.copy()
            return depth
        return self._renderer.render(model.render_link_meshes(qa, self.robot_cell))[0]

    @property
    def robot_spans(self) -> np.ndarray:
        """(H, 2) int32 (read-only, overwritten by the next :meth:`robot` call): per row the span
        ``[a, b)`` outside which the image :meth:`robot` returned last is 0 (``(0, 0)``: all of the
        row), the renderer's ``spans`` — what :func:`~depthguard.render.composite.copy_depth_rows`
        copies (R16)."""
        return self._no_spans if self.robot_model is None else self._renderer.spans

    def known(self, q) -> np.ndarray:
        """(H, W) float32 m: static scene and robot at ``q`` together (R16); reused buffer."""
        rd = self.robot(q)
        np.copyto(self._known, self.static)
        nearest_depth(self._known, rd)
        return self._known
