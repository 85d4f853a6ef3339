"""The free-space map in the runtime: the monitor's frames into R21 voxels, off the control path (R21, R37).

:class:`RuntimeFreeSpace` keeps a :class:`~depthguard.fusion.free_space.FreeSpaceMap` of the rig's
workspace box (default 5 cm voxels) and builds a :class:`FreeSpaceSnapshot` from the newest
product of every camera worker — the depth as measured and the robot rendered at *that frame's*
capture joints (R9, R30) — the same frames the distances use:

- **robot removed at capture joints:** a pixel whose depth is at or behind the robot's rendered
  depth less ``robot_offset`` (the monitor's setting) sees the robot, or something touching it:
  it frees the voxels in front of its depth but marks no surface
  (``FreeSpaceMap.update_robot_depth``), so the robot's surface, a hand on it and the robot's shadow stay unknown;
- **the known scene as background:** the rig's static meshes, rendered once per camera, and its
  learned scene (issue 31, ``scene: {learned: DIR}``; the nearer surface wins, as in the filter's
  expected depth) are the map's background (:meth:`FreeSpaceMap.set_background`): a measurement
  of the known scene frees the voxels in front of it and marks no surface, while the voxels
  inside it keep their surface. A learned pixel is a surface, not a volume: the path check's
  lighter padding (``scene_padding``) applies to the CAD's primitives only (:func:`known_scene_mask`);
  a learned table is met with the robot's full padding;
- **unknown stays unknown:** a voxel no camera sees free is :data:`UNKNOWN` when no camera saw a
  surface in it (hidden, out of view, invalid pixels) and :data:`OCCUPIED` when one did; a
  snapshot starts again from "all unknown" (no voxel stays free from an earlier update: space a
  person enters is not free in the next snapshot, space they leave is free in the next one the
  cameras see it free);
- **the robot's own current volume is not freed** (issue 30): the voxels whose centre lies
  inside its unpadded capsules at the newest joints are kept as ``machine`` (the body, which a
  path check leaves out: nothing else can be there) and keep the state the cameras gave them
  (unknown: no camera sees inside the robot). The padded shell around the body is judged like
  any other voxel — what the cameras cannot see because the robot is in the way is unknown.

Margin: 2 sigma of each camera's noise model at the voxel's own depth (``sigma_a + sigma_z2
z^2``; 1 cm when a camera names no sensor model) — issue 30: the worst case of the workspace
everywhere (4.5 cm for ur3-cell's D435s at 2.6 m) left the voxels a few cm in front of the table and
the robot unknown. Shell tolerance: 5 sigma at the far end of the workspace (the largest over the
cameras).

:class:`FreeSpaceWorker` runs :meth:`RuntimeFreeSpace.build` on its own background thread at
``hz`` (default 10) and swaps the newest snapshot in whole (one assignment); readers take
``worker.snapshot`` and never see half of one. Cost: one read per camera and voxel, bounded by
cameras x voxels whatever the scene (numba, :mod:`depthguard.fusion.free_space_centre`): each
camera's pairs in pixel order, read from the worker's own depth and robot depth (no copy, no mask;
the robot pixel test per pair), one pass to the states. ``depthguard bench --only monitor``
measures it (``monitor.freespace_update_ms``, beside the way before issue 30's change).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numpy as np

from depthguard.config import PRODUCT_ROBOT_OFFSET, PRODUCT_ROBOT_PADDING   # the product's defaults, defined once
from depthguard.control.path_check import FREE, OCCUPIED, UNKNOWN, body_mask, check_path_states
from depthguard.fusion.free_space import FreeSpaceMap
from depthguard.fusion.free_space_kernels import voxel_states
from depthguard.geometry.voxel_grid import VoxelGrid

__all__ = ["FreeSpaceSnapshot", "RuntimeFreeSpace", "FreeSpaceWorker", "map_margins", "FREE", "UNKNOWN", "OCCUPIED"]

DEFAULT_SIGMA = 0.01     # m: noise of a camera that names no sensor model


@dataclass(frozen=True)
class FreeSpaceSnapshot:
    """One built map: ``state`` (nx, ny, nz) uint8 FREE / UNKNOWN / OCCUPIED (never written after
    the swap), ``grid`` its :class:`VoxelGrid`, ``machine`` (nx, ny, nz) bool the robot's body at
    ``q`` (dof,) rad (voxel centres inside its capsules; not freed), ``stamp`` s the newest capture stamp used (NaN: no frame),
    ``stamps`` per camera the capture stamp used, ``build_s`` the wall seconds the build took,
    ``known`` (nx, ny, nz) bool the known scene's voxels (:func:`known_scene_mask`; None: none) and
    ``scene_padding`` m the path check's padding against them."""
    state: np.ndarray
    grid: VoxelGrid
    machine: np.ndarray
    q: np.ndarray | None
    stamp: float
    stamps: dict
    build_s: float
    known: np.ndarray | None = None
    scene_padding: float | None = None

    def counts(self) -> dict:
        return {"free": int(np.count_nonzero(self.state == FREE)),
                "unknown": int(np.count_nonzero(self.state == UNKNOWN)),
                "occupied": int(np.count_nonzero(self.state == OCCUPIED))}

    def obstacle_points(self) -> tuple[np.ndarray, np.ndarray]:
        """Centres (N, 3) float32 m of the occupied and unknown voxels, and their state (N,) uint8
        (1 unknown, 2 occupied): the map out for planners (R37)."""
        idx = np.nonzero(self.state != FREE)
        c = self.grid.lo + (np.stack(idx, axis=1) + 0.5) * self.grid.voxel_size
        return c.astype(np.float32), self.state[idx].astype(np.uint8)


def known_scene_mask(rig, grid: VoxelGrid) -> np.ndarray:
    """(nx, ny, nz) bool: voxels whose centre lies inside one of the rig's CAD objects that is a
    primitive (box, cylinder, ...; ``Primitive.sdf <= 0``); a mesh object's voxels are not marked
    (they keep the robot's full padding in the path check)."""
    c = grid.centres()
    out = np.zeros(len(c), bool)
    for o in rig.objects:
        if o.primitive is None:
            continue
        lo, hi = o.mesh.bounds
        near = np.all((c >= np.asarray(lo) - 1e-9) & (c <= np.asarray(hi) + 1e-9), axis=1)
        if near.any():
            idx = np.flatnonzero(near)
            out[idx[o.primitive.sdf(c[idx]) <= 0.0]] = True
    return out.reshape(grid.shape)


def map_margins(cameras, workspace) -> tuple[float, float, dict]:
    """``(margin, tolerance, growth)``: the free test's margin at depth ``z`` for camera ``c`` is
    ``margin + growth[c] z^2`` — two sigma of its noise model ``sigma_a + sigma_z2 z^2`` at the
    voxel's own depth (``margin`` = 2 x the largest ``sigma_a``, 2 x 1 cm for a camera with no
    sensor model, at least 2 mm; ``growth[c] = 2 sigma_z2``); ``tolerance`` m (the known scene's
    match) 5 x the largest sigma at the far end of the ``workspace`` box (module docstring)."""
    from depthguard.sensors import sensor_model

    far = {c.id: workspace.depth_span(c)[1] for c in cameras}
    sig, sig_a, growth = 0.0, 1e-3, {}
    for c in cameras:
        if c.sensor is None:
            sig = max(sig, DEFAULT_SIGMA)
            sig_a = max(sig_a, DEFAULT_SIGMA)
            continue
        m = sensor_model(c.sensor)
        sig = max(sig, float(m.sigma_a + m.sigma_z2 * far[c.id] ** 2))
        sig_a = max(sig_a, float(m.sigma_a))
        growth[c.id] = 2.0 * float(m.sigma_z2)
    sig = max(sig, 1e-3)
    return 2.0 * sig_a, 5.0 * sig, growth


class RuntimeFreeSpace:
    """The runtime's free-space map (module docstring).

    rig : the :class:`~depthguard.rig.Rig` (workspace box, cameras, static meshes, robot).
    camera_ids : the cameras to use (default all of the rig's).
    voxel_size : m (default 0.05). robot_offset, robot_padding : m (the monitor's settings).
    bounds : ``(lo, hi)`` m, default the rig's workspace.
    """

    def __init__(self, rig, camera_ids=None, voxel_size: float = 0.05, robot_offset: float = PRODUCT_ROBOT_OFFSET,
                 robot_padding: float = PRODUCT_ROBOT_PADDING, bounds=None, scene_padding: float = 0.02):
        from depthguard.filtering.expected import ExpectedDepth

        ids = [c.id for c in rig.cameras] if camera_ids is None else list(camera_ids)
        self.rig = rig
        self.robot = rig.robot
        self.cameras = [rig.camera(c) for c in ids]
        lo, hi = (rig.workspace.lo, rig.workspace.hi) if bounds is None else bounds
        self.margin, self.tolerance, self.margin_growth = map_margins(self.cameras, rig.workspace)
        self.map = FreeSpaceMap(self.cameras, (lo, hi), voxel_size, margin=self.margin,
                                margin_growth=self.margin_growth)
        static = list(rig.static_meshes())
        # the known scene: the CAD and the learned scene (issue 31), nearer wins, as the filter's
        learned = {c.id: rig.learned_depth(c.id) if hasattr(rig, "learned_depth") else None for c in self.cameras}
        self.backgrounds = {c.id: np.asarray(ExpectedDepth(c, None, static, learned=learned[c.id]).static, np.float32)
                            for c in self.cameras}
        if static or any(v is not None for v in learned.values()):
            self.map.set_background(self.backgrounds, tolerance=self.tolerance)
        self.robot_offset = float(robot_offset)
        self.robot_padding = float(robot_padding)
        self.scene_padding = float(scene_padding)
        self.known = known_scene_mask(rig, self.grid)
        self.known.setflags(write=False)
        self._ids = frozenset(c.id for c in self.cameras)

    @property
    def grid(self) -> VoxelGrid:
        return self.map.grid

    def build(self, depths: dict, robot_depths: dict, q_now=None, stamps: dict | None = None) -> FreeSpaceSnapshot:
        """One map from ``depths`` (camera id -> (H, W) m, 0/NaN invalid) and ``robot_depths``
        (camera id -> (H, W) m, the robot rendered at that frame's capture joints, 0 = no robot);
        ``machine`` is the robot's body at ``q_now`` (dof,) rad (None: no body), never freed.
        Cameras left out say nothing."""
        t0 = time.perf_counter()
        use = {cid: d for cid, d in depths.items() if cid in self._ids}
        robot = {cid: rd for cid, rd in robot_depths.items() if cid in use and rd is not None}
        # the robot (or what touches it): no surface, tested per pair as the map reads the image
        self.map.update_robot_depth(use, robot, self.robot_offset)
        state = np.empty(self.grid.shape, dtype=np.uint8)     # a new array: a snapshot is never written again
        voxel_states(self.map.occupied.reshape(-1), self.map.counts()[1].reshape(-1), FREE, UNKNOWN, OCCUPIED,
                     state.reshape(-1))
        machine = np.zeros(self.grid.shape, bool)
        q = None
        if q_now is not None and self.robot is not None:
            q = np.asarray(q_now, dtype=np.float64).copy()
            machine = body_mask(self.grid.shape, self.grid.lo, self.grid.voxel_size, self.robot, q)
        st = dict(stamps or {})
        stamp = max(st.values()) if st else float("nan")
        return FreeSpaceSnapshot(state, self.grid, machine, q, stamp, st, time.perf_counter() - t0,
                                 self.known, self.scene_padding)

    def build_from_workers(self, workers: dict, q_now=None) -> FreeSpaceSnapshot | None:
        """:meth:`build` from the newest product of each camera worker (None: no product yet)."""
        depths, robot_depths, stamps = {}, {}, {}
        for cid, w in list(workers.items()):
            if cid not in self._ids:
                continue
            with w.lock:
                p = w.product
            if p is None:
                continue
            depths[cid], robot_depths[cid], stamps[cid] = p.depth, p.robot_depth, p.stamp
        if not depths:
            return None
        return self.build(depths, robot_depths, q_now, stamps)


def check_path_in(snapshot: FreeSpaceSnapshot, robot, stamps, q, padding: float, twin: bool = False):
    """The verdict per segment of a path in ``snapshot`` (:func:`check_path_states`)."""
    g = snapshot.grid
    exclude = snapshot.machine if snapshot.q is not None else None     # the body when the map was taken
    return check_path_states(snapshot.state, g.lo, g.voxel_size, robot, stamps, q, padding=padding,
                             exclude=exclude, map_stamp=snapshot.stamp, twin=twin, known=snapshot.known,
                             scene_padding=snapshot.scene_padding)


class FreeSpaceWorker:
    """Builds the map at ``hz`` on a background thread from the monitor's camera workers and swaps
    the newest :class:`FreeSpaceSnapshot` into :attr:`snapshot` (module docstring).

    ``latest_q()`` -> the newest joints (dof,) or None; ``on_snapshot(snap)`` is called after each
    swap (a sink, the path watch); keep it quick. ``threaded=False``: no thread; the caller builds
    with :meth:`update_now` at its own ``hz`` (a simulation in simulated time, whose map updates
    must not follow the wall clock)."""

    def __init__(self, space: RuntimeFreeSpace, workers: dict, latest_q, hz: float = 10.0, on_snapshot=None,
                 threaded: bool = True):
        if not (math.isfinite(hz) and hz > 0):
            raise ValueError(f"free-space rate must be > 0 Hz, got {hz!r}")
        self.space = space
        self.workers = workers
        self.latest_q = latest_q
        self.period = 1.0 / float(hz)
        self.on_snapshot = on_snapshot
        self.snapshot: FreeSpaceSnapshot | None = None
        self.builds = 0
        self.errors = 0
        self.last_error: str | None = None
        self._build_lock = threading.Lock()     # one build at a time: the map's buffers are shared
        self._stop = threading.Event()
        self._thread = None
        if threaded:
            self._thread = threading.Thread(target=self._run, name="depthguard-free-space", daemon=True)
            self._thread.start()

    def update_now(self) -> FreeSpaceSnapshot | None:
        """Build one map now on the calling thread and swap it in (tests, the CLI's one-shot check).
        ``on_snapshot`` is called under the build's lock: two builders (the map's thread and a
        caller) hand their maps on in the order they were swapped in, never an older one last."""
        with self._build_lock:
            snap = self.space.build_from_workers(self.workers, self.latest_q())
            if snap is not None:
                self.snapshot = snap
                self.builds += 1
                if self.on_snapshot is not None:
                    self.on_snapshot(snap)
        return snap

    def _run(self) -> None:
        from depthguard.runtime.ingest import background_thread

        background_thread()
        nxt = time.perf_counter()
        while not self._stop.is_set():
            try:
                self.update_now()
            except Exception as exc:           # a bad build never kills the thread; counted
                self.errors += 1
                self.last_error = f"{type(exc).__name__}: {exc}"
            nxt += self.period
            wait = nxt - time.perf_counter()
            if wait < 0:
                nxt = time.perf_counter()
                wait = 0.0
            self._stop.wait(wait)

    def close(self, timeout: float = 2.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
