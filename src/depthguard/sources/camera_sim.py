"""The one camera simulator: a rig's depth cameras seeing a scene at a time and joints (R16, R28).

Every simulated depth frame of the package is made here — the ``sim:`` source
(:mod:`depthguard.sources.sim_source`), the closed loop of ``depthguard run`` / ``make demo``
(:mod:`depthguard.evaluation.closed_loop.loop`) and :class:`~depthguard.sources.simulated.SimSource`.

Model and data apart: :class:`CameraSim` is built once per rig (per camera the static scene
rendered once, a renderer for what moves, the sensor's noise model); a frame is a function of
``(camera, capture time, joints, moving meshes)`` and the seed:

1. the robot alone at ``q`` (also the self-removal image, R9) and the moving obstacles are
   rendered and combined per pixel with the static scene — the same image, bit for bit, as
   rendering everything (:mod:`depthguard.render.composite`);
2. the camera's noise model turns the ideal image into the measured one, its noise drawn from
   the frame's own generator (``seed``, camera, capture stamp: ``simulated.frame_rng``).
   Steps 1-3 are one :class:`~depthguard.sources.layered.LayeredCamera` per camera: the static
   scene's edges and counts are made once, a frame works again only the rows' spans the moving
   layers cover and measures the image in one pass, bit for bit the frame of ``apply_noise`` on
   the composite (issue 29: a ur3-cell 640x480 frame's CPU besides its renders 2.1x lower in
   the bench row ``sim.ur3_cell.frame_cpu_ms``, 3x in a whole shot). The robot layer has its own
   renderer; each renderer hands over per row the span of the pixels it drew
   (``Renderer.spans``), so the layers are not scanned again. The robot's vertices are posed
   once per joint values and the people and props once per time
   (:class:`~depthguard.sim.posed.PosedMeshes`), in place, and rendered where they lie
   (``Renderer.render_arrays``): no mesh is made per frame; a camera whose robot stands still
   (the same joints as its last frame: stopped, R27) keeps its robot image (a frame of ur3-cell
   0.78x the CPU then);
3. the invalid pixels follow one vocabulary, the monitor's (``MonitorConfig.invalid``, R28):
   ``"unknown"`` — no return stays 0, and a ray that meets nothing the scene models returns
   from beyond the rated range, as a real cell's walls would; ``"free"`` — every invalid
   pixel reads as the far end of the range; ``None`` — the raw sensor (0 where nothing);
4. ``dark``: pixels that see a moving obstacle return nothing (dark clothing).

:class:`CameraSchedule` is the cameras' timing, also once: ``hz`` per camera, every camera's
first frame at 0, then camera ``i`` on its own phase ``0.37 i`` periods (not synchronised).
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple, Sequence

import numpy as np

from depthguard.config import PRODUCT_INVALID
from depthguard.filtering.expected import ExpectedDepth
from depthguard.frame_pool import BufferPool
from depthguard.geometry.decimate import SIM_CELL
from depthguard.render import Renderer
from depthguard.render.composite import copy_depth_rows
from depthguard.sim.posed import PackedMeshes
from depthguard.sources.frame import RobotImage
from depthguard.sources.layered import LayeredCamera
from depthguard.sources.simulated import SimulatedCamera, frame_rng

__all__ = ["CameraSim", "CameraSchedule", "Shot", "INVALID_POLICIES"]

#: what an invalid pixel of a simulated frame becomes (module docstring, step 3)
INVALID_POLICIES = ("unknown", "free", None)


class Shot(NamedTuple):
    """One simulated frame: ``depth`` (H, W) float32 m (new array, 0 = no return), ``robot_depth``
    (H, W) float32 m of the robot alone (a copy, or None when not asked), and the wall seconds
    of rendering the robot and of the rest (scene, noise)."""
    depth: np.ndarray
    robot_depth: np.ndarray | None
    robot_s: float
    scene_s: float


class _RobotSlot:
    """The robot posed for a camera: ``vw`` (V, 3) float64 m world vertices at joints ``q``;
    ``posings`` counts the times ``vw`` was written (a camera's robot image drawn from it stays
    valid while the count does)."""

    __slots__ = ("vw", "q", "posings")

    def __init__(self, vw):
        self.vw, self.q, self.posings = vw, None, 0


class CameraSim:
    """The depth cameras ``cams`` of a cell (module docstring).

    robot : the :class:`~depthguard.robot.RobotModel` the frames show (None: no robot).
    static_meshes : world meshes that never move, rendered once per camera.
    seed, noiseless : the noise (:class:`~depthguard.sources.simulated.SimulatedCamera`).
    invalid : ``"unknown"`` | ``"free"`` | None (module docstring, step 3); default the
        product's (:data:`depthguard.config.PRODUCT_INVALID`).
    parallel : the renderers' numba threads (False: one, e.g. on a camera thread).

    One object per thread: each camera's buffers are reused from frame to frame; or, after
    :meth:`own_robot_buffers`, one thread per camera (each camera's renderers, noise and posed
    robot are its own).
    """

    def __init__(self, cams: Sequence, robot=None, static_meshes=(), seed: int = 0, noiseless: bool = False,
                 invalid: str | None = PRODUCT_INVALID, parallel: bool = False):
        if invalid not in INVALID_POLICIES:
            raise ValueError(f"invalid must be 'unknown', 'free' or None, got {invalid!r}")
        static = list(static_meshes)
        self.cams = {c.id: c for c in cams}
        self.robot = robot
        self.invalid = invalid
        self.seed = int(seed)
        # the robot as the simulated cameras see it: its meshes clustered to SIM_CELL
        self.expected = {c.id: ExpectedDepth(c, robot, static, parallel=parallel, robot_cell=SIM_CELL) for c in cams}
        self.sims = {c.id: SimulatedCamera(c, seed=seed, noiseless=noiseless) for c in cams}
        # the layers need depth alone: on one core, depth-only renderers (Renderer ids=False)
        self._moving = {c.id: Renderer(c, parallel=parallel, ids=parallel) for c in cams}
        self._robot = {c.id: Renderer(c, parallel=parallel, ids=parallel) for c in cams}   # the robot layer's own
        self._robot_images = {c.id: BufferPool() for c in cams}   # robot_image's arrays, reused once unheld
        # the robot's clustered links packed once; their world vertices posed once per joint
        # values, for every camera (RobotModel.render_link_vertices: the bits of render_link_meshes)
        self._robot_vw = None
        if hasattr(robot, "render_link_vertices") and hasattr(robot, "render_link_topology"):   # a RobotModel
            links = robot.render_link_topology(SIM_CELL)
            off = np.zeros((len(links) + 1, 2), np.int64)
            np.cumsum([len(m.vertices) for m in links], out=off[1:, 0])
            np.cumsum([len(m.faces) for m in links], out=off[1:, 1])
            off.setflags(write=False)           # fixed: the renderer checks it once (render_arrays)
            self._robot_off = off
            self._dof = robot.dof
            self._robot_faces = (np.ascontiguousarray(np.concatenate([m.faces for m in links]), dtype=np.int32)
                                 if links else np.zeros((0, 3), np.int32))
            self._robot_vw = np.zeros((int(off[-1, 0]), 3))
        # the posed robot's (vertices, joints) per camera: one shared slot (the cameras of one time
        # step pose it once), or each camera's own (own_robot_buffers: a thread per camera)
        shared = _RobotSlot(self._robot_vw)
        self._robot_slots = {c.id: shared for c in cams}
        # per camera (slot, its posings, image) of the robot layer last drawn: a robot standing still
        # (stopped, R27) is not drawn again; its renderer's image and spans are kept as they were
        # (the frame reads them only: LayeredCamera takes read-only views), the same bits
        self._robot_drawn: dict[str, tuple] = {}
        self._robot_in_shot: dict[str, bool] = {}   # the camera's last shot drew the posed robot layer
        self.layered = {c.id: LayeredCamera(self.expected[c.id].static, self.sims[c.id].model, c.fx, c.min_range,
                                            self.sims[c.id].model.returns_to(c.max_range), c.max_range,
                                            noiseless=noiseless, invalid=invalid) for c in cams}

    def own_robot_buffers(self) -> None:
        """Each camera poses the robot into its own buffer from now on (a thread per camera, R29:
        one camera's render never reads vertices another camera's thread is writing); the frames
        are the same bits."""
        if self._robot_vw is not None:
            self._robot_slots = {cid: _RobotSlot(np.zeros_like(self._robot_vw)) for cid in self.cams}

    @property
    def camera_ids(self) -> list[str]:
        return list(self.cams)

    def use_noise_bank(self, bank) -> None:
        """Every camera draws its noise's normals from ``bank`` (a
        :class:`~depthguard.sources.noise.NormalBank`: real-time runs)."""
        for sim in self.sims.values():
            sim.bank = bank

    def shot(self, camera_id: str, t: float, q, moving: Sequence = (), dark: bool = False,
             keep_robot: bool = False) -> Shot:
        """Camera ``camera_id``'s frame captured at ``t`` (s, the noise's stamp) with the robot at
        ``q`` (dof,) rad (None: no robot in the image) and the moving obstacles' world meshes
        ``moving`` (module docstring): a list of meshes, or a
        :class:`~depthguard.sim.posed.PackedMeshes` (posed in place once per time step, rendered
        where it lies)."""
        t0 = time.perf_counter()
        rd = rsp = psp = None
        self._robot_in_shot[camera_id] = False
        if self.robot is not None and q is not None and self._robot_vw is not None:
            vw = self._robot_vertices(q, camera_id)                  # as ExpectedDepth.robot renders it
            slot = self._robot_slots[camera_id]
            drawn = self._robot_drawn.get(camera_id)
            if drawn is not None and drawn[0] is slot and drawn[1] == slot.posings:
                rd = drawn[2]                   # the robot where this camera last drew it: its image as is
            else:
                rd = self._robot[camera_id].render_arrays(vw, self._robot_faces, self._robot_off)[0]  # its buffer
                self._robot_drawn[camera_id] = (slot, slot.posings, rd)
            rsp = self._robot[camera_id].spans
            self._robot_in_shot[camera_id] = True
        elif self.robot is not None and q is not None:               # another machine (sim/carm.py)
            qa = np.asarray(q, dtype=np.float64).reshape(-1)
            if qa.shape[0] != self.robot.dof or not np.all(np.isfinite(qa)):
                raise ValueError(f"expected {self.robot.dof} finite joint values, got {qa.tolist()}")
            meshes = self.robot.render_link_meshes(qa, SIM_CELL)
            rd = self._robot[camera_id].render(meshes)[0]            # the renderer's buffer
            self._robot_drawn.pop(camera_id, None)
            rsp = self._robot[camera_id].spans
        robot_depth = np.array(rd, copy=True) if keep_robot and rd is not None else None
        t1 = time.perf_counter()
        person = None
        if isinstance(moving, PackedMeshes):
            person = self._moving[camera_id].render_arrays(moving.vertices, moving.faces, moving.mesh_off)[0]
            psp = self._moving[camera_id].spans                    # the layer's spans, as drawn
        elif moving:
            moving = moving if isinstance(moving, list) else list(moving)
            person = self._moving[camera_id].render(moving)[0]      # the renderer's buffer
            psp = self._moving[camera_id].spans
        sim = self.sims[camera_id]
        # the robot occludes, as on a real cell; a user's rig without walls: R28 (module docstring)
        d = self.layered[camera_id].frame(rd, person, frame_rng(sim.seed, camera_id, t), bank=sim.bank, dark=dark,
                                          robot_spans=rsp, person_spans=psp)
        return Shot(d, robot_depth, t1 - t0, time.perf_counter() - t1)

    def robot_image(self, camera_id: str) -> RobotImage | None:
        """The robot layer of camera ``camera_id``'s last :meth:`shot`, copied into arrays of its
        own (the renderer's are drawn again by the next shot) with the joints it was drawn at, or None
        (no robot in that shot, or a robot that is not a RobotModel). Call on the shot's thread,
        before the camera's next shot. The rows' spans alone are copied (~0.1 ms against ~1 ms of
        a render: issue 29), into arrays of the camera's :class:`~depthguard.frame_pool.BufferPool`,
        given out again only once nothing refers to them (a fresh pair each time was ~0.1 ms of
        zeroing and page faults a frame, and a release of the GIL)."""
        drawn = self._robot_drawn.get(camera_id)
        if not self._robot_in_shot.get(camera_id) or drawn is None:
            return None
        slot, posings, rd = drawn
        if slot.posings != posings or slot.q is None:       # posed again since (a shared slot)
            return None
        pool = self._robot_images[camera_id]
        made = pool.made
        depth, spans = pool.take(((rd.shape, np.float32), ((rd.shape[0], 2), np.int32)))
        if pool.made != made:               # new arrays: every row's pixels are to be written
            spans[:, 0] = 0
            spans[:, 1] = rd.shape[1]
        copy_depth_rows(depth, spans, rd, self._robot[camera_id].spans)
        return RobotImage(slot.q.copy(), depth, spans, self.robot, self.cams[camera_id])

    def _robot_vertices(self, q, camera_id: str | None = None) -> np.ndarray:
        """The robot's (V, 3) world vertices at ``q`` (dof,) rad, all clustered links one after
        the other, in camera ``camera_id``'s slot (``__init__``); posed again only when ``q``
        changes (the cameras of one time step share them, unless each has its own)."""
        qa = np.asarray(q, dtype=np.float64).reshape(-1)
        if qa.shape[0] != self._dof or not np.isfinite(qa).all():
            raise ValueError(f"expected {self.robot.dof} finite joint values, got {qa.tolist()}")
        slot = self._robot_slots[camera_id] if camera_id is not None else next(iter(self._robot_slots.values()))
        if slot.q is None or not (slot.q == qa).all():                    # np.array_equal, same shapes
            self.robot.render_link_vertices(qa, SIM_CELL, slot.vw)
            slot.q = qa.copy()
            slot.posings += 1
        return slot.vw

    def depth(self, camera_id: str, t: float, q, moving: Sequence = (), dark: bool = False) -> np.ndarray:
        """The measured (H, W) float32 depth alone (:meth:`shot`)."""
        return self.shot(camera_id, t, q, moving, dark).depth


class CameraSchedule:
    """When ``n`` cameras at ``hz`` capture (module docstring): ``next[i]`` is camera ``i``'s next
    capture time (s from the simulator's 0)."""

    PHASE = 0.37        # camera i's phase: 0.37 i periods

    def __init__(self, n: int, hz: float):
        if not (math.isfinite(hz) and hz > 0):
            raise ValueError(f"camera rate must be > 0 Hz, got {hz!r}")
        self.period = 1.0 / float(hz)
        self.phase = [i * self.PHASE * self.period for i in range(n)]
        self.next = [0.0] * n           # every camera's first frame at 0 (they run before the robot moves)

    def due(self, i: int, t: float, tol: float = 1e-9) -> bool:
        """Whether camera ``i`` has a capture due at or before ``t`` (within ``tol`` s)."""
        return self.next[i] <= t + tol

    def after(self, i: int, t: float) -> float:
        """Camera ``i``'s first capture time after ``t``."""
        ph = self.phase[i]
        return ph + (math.floor((t - ph) / self.period + 1e-9) + 1) * self.period

    def take(self, i: int, t: float) -> None:
        """Camera ``i`` captured at ``t``: its next capture is the first of its phase after ``t``."""
        self.next[i] = self.after(i, t)

    def skip_to_latest(self, i: int, t: float) -> int:
        """Camera ``i`` behind by more than a period: its next capture becomes the latest due at
        ``t``; returns the number of captures skipped."""
        ph = self.phase[i]
        newest = ph + math.floor((t - ph) / self.period + 1e-9) * self.period
        skipped = int(round((newest - self.next[i]) / self.period))
        self.next[i] = newest
        return skipped
