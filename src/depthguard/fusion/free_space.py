"""Free-space reconstruction from many depth cameras (Hamersma 2011, R21).

The workspace box is cut into cubic voxels; voxel ``(i, j, k)`` spans
``lo + [i, i+1) * voxel_size`` (likewise ``j``, ``k``). Every voxel starts
**occupied** (unknown is obstacle, R25). For each camera the centre of each
voxel is projected once (the *model*); an update is then a gather and a
compare per voxel and camera (:mod:`depthguard.fusion.free_space_kernels`):

- a camera sees the voxel **free** when its measured depth ``d`` at the
  voxel's pixel exceeds the voxel's depth plus ``margin``. ``depth_test=
  "centre"`` (default; the paper and SPEC R21): ``d > z_c + margin``, the depth
  of the voxel centre. ``depth_test="extent"`` (conservative): ``d > z_c + h_c
  + margin``, beyond the voxel's whole depth extent (``h_c`` = half the depth
  extent of a cube of side ``s`` along that camera's optical axis, at most
  ``s*sqrt(3)/2``);
- it sees a **surface** in the voxel when ``z_c - h_c <= d`` and ``d`` is not free;
- otherwise (hidden behind a nearer surface, invalid pixel, out of view) it
  says nothing.

Safety consequence of the ``"centre"`` test: a surface in the far half of a
voxel (behind its centre) does not stop a camera calling the voxel free — an
error of at most half a voxel in depth, matching a ground truth that calls a
voxel occupied when its centre is inside an object. ``"extent"`` never frees
a voxel that a camera sees a surface in, at the cost of a layer of voxels in
front of every surface seen as object.

**How "once free, free" and "a surface needs three" combine in one update**
(the paper, §3.1–3.2): a voxel is free when at least ``min_free_views``
cameras (default 3) see it free, or when at least one camera sees it free
and no camera sees a surface in it. A camera that merely cannot see the
voxel (occlusion) never turns it back to occupied — that is the paper's
"once free it cannot be set occluded by other cameras" — but a camera that
sees a surface *in* the voxel does, unless three cameras overrule it.

**A known background** (the room's shell: floor, walls, ceiling — what a real
cell knows exactly and never moves): :meth:`FreeSpaceMap.set_background`
takes, once, per camera the expected depth ``B`` of that shell at each pixel
(rendered with :func:`depthguard.render.render_depth`, 0 = nothing) and a
tolerance ``t``. Then, per camera and voxel (centre depth ``z_c``):

- a measurement matching the shell, ``|d - B| <= t``, is the shell, not a
  surface *in* the voxel: the camera sees the voxel free if ``d > z_c +
  margin`` (as before), otherwise it says nothing (instead of "surface");
- a camera only does so, and only ever sees a voxel free, when the voxel's
  centre lies in front of the shell at its pixel (``z_c < B``): a voxel whose
  centre is behind (inside) the shell keeps every surface view it had without
  a background and gets no free view from such a camera (a measurement beyond
  its centre is noise there and counts as a surface), so the background never
  frees it. (``B`` is read at the pixel under the voxel centre: for a
  centre less than about half a pixel footprint inside the shell, a camera at a
  grazing angle can still place it in front — as it could without a background.)

Everything else is unchanged. Without it, the noise (sigma 1 cm for ToF)
makes some camera measure the floor or a wall *inside* the voxels along it,
so that layer needs three free views; with it one free view and no other
surface suffice. Choose ``t`` as margin + a few sigma (the reproduction uses
2 cm + 3 x 1 cm = 5 cm), like the offset of the per-camera filter (R17).
**Safety consequence:** anything within ``t`` in front of the shell (a hand
flat on a wall, a foot on the floor) is taken as the shell — the same
trade-off as the R17 filter's offset: such a voxel is still never freed by a
camera that measures it in front of its centre, but it no longer counts as a
surface against other cameras' free views. Only ``footprint="centre"``
supports a background.

**Over time.** By default every :meth:`FreeSpaceMap.update` starts again from
"all occupied": the map is a snapshot of the frames given, so a person who
walks into space that was free is an obstacle in the next update (a sticky
map would be stale data, R27). ``update(..., accumulate=True)`` keeps every voxel that was free
since the last :meth:`reset` ("once free stays free"), meant for a static scene seen by cameras
delivering frames at different times; it is unsafe for moving obstacles.

**Voxels larger than a pixel.** The paper reads only the pixel under the
voxel centre. A thin object (thinner than the voxel, not on the centre ray
of any camera) is then missed: the voxel is declared free although part of
it is occupied (*object seen as free*). ``footprint="full"`` reads every
pixel of a window holding the voxel's whole projection and calls the voxel
free only if all are valid and beyond the depth threshold (with
``depth_test="extent"``: nothing seen anywhere in the voxel) — conservative,
at the cost of more *free seen as object* next to edges and a slower update
(about 20x at 5 cm in the C-arm room). A voxel only partly inside a camera's
image, or nearer to it than ``max_window`` allows, is not judged by that
camera in ``"full"`` mode.

**The machine's own volume** (the C-arm, the robot) cannot collide with
itself: :meth:`FreeSpaceMap.add_free_volume` frees every voxel the machine
touches. Safety consequence: an obstacle inside those voxels (a hand on the
C-arm) is erased; the motion check (:mod:`depthguard.control.motion_check`)
starts from the same set so that the machine never collides with itself.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from depthguard.camera import Camera, check_depth_image
from depthguard.fusion.free_space_centre import CentrePairs
from depthguard.fusion.free_space_kernels import combine_counts, free_space_update, negate_where as _negate_where, robot_pixels
from depthguard.geometry.voxel_grid import VoxelGrid

__all__ = ["FreeSpaceMap"]

_MAX_ENTRIES = 400_000_000  # cameras x voxels; ~4 GB of model beyond this


class FreeSpaceMap:
    """Free-space voxel map from many depth cameras (R21, SPEC §9).

    Parameters
    ----------
    cameras : sequence of :class:`~depthguard.camera.Camera` (ids unique).
    bounds : ``(lo, hi)`` two 3-vectors, metres; rounded up to whole voxels.
    voxel_size : float, metres.
    margin : float, metres (default 0.0) — a camera calls a voxel free only if its
        measured depth exceeds the voxel's depth by more than this; choose about
        two sigma of the depth noise.
    margin_growth : optional dict camera id -> ``g`` 1/m (default none): that camera's margin at a
        voxel of centre depth ``z`` is ``margin + g z^2`` — two sigma of a noise model
        ``sigma_a + sigma_z2 z^2`` is ``margin = 2 sigma_a``, ``g = 2 sigma_z2``: the margin of
        each voxel at its own depth, not the worst case of the workspace everywhere (R17, R21).
    min_free_views : int (default 3) — cameras needed to overrule a seen surface.
    footprint : ``"centre"`` (the paper) or ``"full"`` (see the module docstring).
    depth_test : ``"centre"`` (the paper) or ``"extent"`` (see the module docstring).
    max_window : with ``footprint="full"``, a camera whose window for a voxel would be
        wider than ``2*max_window+1`` pixels (the voxel is very near it) does not judge it.

    ``update(depths)`` returns ``occupied`` (nx, ny, nz) bool; the array is owned
    by the map and overwritten by the next update (copy it to keep it).
    """

    def __init__(self, cameras, bounds, voxel_size: float, margin: float = 0.0,
                 min_free_views: int = 3, footprint: str = "centre", depth_test: str = "centre",
                 max_window: int = 7, margin_growth=None):
        cams = list(cameras)
        if not cams:
            raise ValueError("FreeSpaceMap needs at least one camera")
        for c in cams:
            if not isinstance(c, Camera):
                raise ValueError(f"cameras must be depthguard.Camera objects, got {type(c).__name__}")
        ids = [c.id for c in cams]
        if len(set(ids)) != len(ids):
            raise ValueError(f"camera ids must be unique, got {ids}")
        try:
            lo, hi = bounds
        except (TypeError, ValueError):
            raise ValueError("bounds must be a pair (lo, hi) of 3-vectors") from None
        self.grid = VoxelGrid(lo, hi, voxel_size)
        margin = float(margin)
        if not (math.isfinite(margin) and margin >= 0):
            raise ValueError(f"margin must be a finite number >= 0 metres (got {margin!r})")
        if int(min_free_views) != min_free_views or min_free_views < 1:
            raise ValueError(f"min_free_views must be a positive integer (got {min_free_views!r})")
        if footprint not in ("centre", "full"):
            raise ValueError(f"footprint must be 'centre' or 'full' (got {footprint!r})")
        if depth_test not in ("centre", "extent"):
            raise ValueError(f"depth_test must be 'centre' or 'extent' (got {depth_test!r})")
        if int(max_window) != max_window or not (0 <= max_window <= 127):
            raise ValueError(f"max_window must be an integer in [0, 127] (got {max_window!r})")
        n = self.grid.size
        if n * len(cams) > _MAX_ENTRIES:
            raise ValueError(f"{len(cams)} cameras x {n} voxels is too large a model; use larger voxels or a smaller box")
        self.cameras = cams
        self.margin = margin
        self.min_free_views = int(min_free_views)
        self.footprint = footprint
        self.depth_test = depth_test
        self.max_window = int(max_window)
        self._ids = ids
        # ---- model (immutable after construction): (voxel, camera) pairs, camera by camera
        C = len(cams)
        if C > 255:
            raise ValueError(f"at most 255 cameras (got {C})")
        sizes = np.array([c.width * c.height for c in cams], dtype=np.int64)
        self.offs = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
        self.widths = np.array([c.width for c in cams], dtype=np.int64)
        self.heights = np.array([c.height for c in cams], dtype=np.int64)
        self.rmin = np.array([c.min_range for c in cams], dtype=np.float64)
        self.rmax = np.array([c.max_range for c in cams], dtype=np.float64)
        self.half = np.empty(C, dtype=np.float64)
        centres = self.grid.centres()
        corners = self.grid.corners() if footprint == "full" else None
        parts = [self._project(ci, cam, centres, corners) for ci, cam in enumerate(cams)]
        self.start = np.concatenate([[0], np.cumsum([len(p[0]) for p in parts])]).astype(np.int64)
        self.vox = np.concatenate([p[0] for p in parts]).astype(np.int32)
        self.pix = np.concatenate([p[1] for p in parts]).astype(np.int32)
        self.zc = np.concatenate([p[2] for p in parts]).astype(np.float32)
        self.ru = np.concatenate([p[3] for p in parts]).astype(np.uint8)
        self.rv = np.concatenate([p[4] for p in parts]).astype(np.uint8)
        self.far = self.half.copy() if depth_test == "extent" else np.zeros(C)
        growth = dict(margin_growth or {})
        if set(growth) - set(ids):
            raise ValueError(f"margin_growth names unknown camera ids {sorted(set(growth) - set(ids))}; known: {ids}")
        self.grow = np.array([float(growth.get(i, 0.0)) for i in ids], dtype=np.float64)
        if not np.all(np.isfinite(self.grow) & (self.grow >= 0)):
            raise ValueError(f"margin_growth must be finite numbers >= 0 (1/m), got {growth}")
        # parallel tasks: chunks of voxels, with each camera's pair range per chunk
        T = int(min(64, max(1, n // 512)))
        self.vstart = np.linspace(0, n, T + 1).astype(np.int64)
        self.chunk = np.empty((C, T + 1), dtype=np.int64)
        for ci in range(C):
            a, b = self.start[ci], self.start[ci + 1]
            self.chunk[ci] = a + np.searchsorted(self.vox[a:b], self.vstart)
        for a in (self.vstart, self.chunk, self.start, self.vox, self.pix, self.zc, self.ru, self.rv, self.half, self.far, self.grow,
                  self.offs, self.widths, self.heights, self.rmin, self.rmax):
            a.setflags(write=False)
        # ---- data (preallocated workspace)
        self._depth = np.zeros(int(sizes.sum()), dtype=np.float32)
        self._nf = np.zeros(n, dtype=np.uint8)
        self._ns = np.zeros(n, dtype=np.uint8)
        self._free = np.zeros(n, dtype=bool)
        self._occ = np.ones(n, dtype=bool)
        self._bg = np.zeros(int(sizes.sum()), dtype=np.float32)   # known shell depth, 0 = none
        self._use_bg = False
        self.background_tolerance = 0.0
        self.machine = np.zeros(self.grid.shape, dtype=bool)
        # centre pixel: each camera's pairs in pixel order, read from the cameras' own images (issue 30)
        self._centre = CentrePairs(cams, self.start, self.pix, self.vox, self.zc, self.offs) if footprint == "centre" else None

    # ------------------------------------------------------------------ model
    def _project(self, ci: int, cam: Camera, centres: np.ndarray, corners: np.ndarray | None):
        """The pairs of camera ``ci``: (voxel index, flat pixel, centre depth, ru, rv)."""
        s = self.grid.voxel_size
        ax = cam.R[2]  # optical axis in the world
        self.half[ci] = 0.5 * s * float(np.abs(ax).sum())
        ds = cam.world_to_depth_space(centres)
        with np.errstate(invalid="ignore"):
            u = np.floor(ds[:, 0] + 0.5)
            v = np.floor(ds[:, 1] + 0.5)
            ok = ((ds[:, 2] >= cam.min_range) & (ds[:, 2] <= cam.max_range)
                  & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height))
        ru = rv = np.zeros(len(centres))
        if corners is not None:
            nx, ny, nz = self.grid.shape
            dc = cam.world_to_depth_space(corners)
            with np.errstate(invalid="ignore"):
                cu = np.floor(dc[:, 0] + 0.5)
                cv = np.floor(dc[:, 1] + 0.5)
                cok = ((dc[:, 2] >= cam.min_range) & (cu >= 0) & (cu < cam.width)
                       & (cv >= 0) & (cv < cam.height))
            cu = cu.reshape(nx + 1, ny + 1, nz + 1)
            cv = cv.reshape(nx + 1, ny + 1, nz + 1)
            cok = cok.reshape(nx + 1, ny + 1, nz + 1)
            uc = np.where(ok, u, 0).reshape(nx, ny, nz)
            vc = np.where(ok, v, 0).reshape(nx, ny, nz)
            ru = np.zeros((nx, ny, nz))
            rv = np.zeros((nx, ny, nz))
            allok = np.ones((nx, ny, nz), dtype=bool)
            for a in (0, 1):
                for b in (0, 1):
                    for c in (0, 1):
                        sl = (slice(a, a + nx), slice(b, b + ny), slice(c, c + nz))
                        allok &= cok[sl]
                        with np.errstate(invalid="ignore"):
                            ru = np.fmax(ru, np.abs(cu[sl] - uc))
                            rv = np.fmax(rv, np.abs(cv[sl] - vc))
            ru, rv = ru.ravel(), rv.ravel()
            ok &= allok.ravel() & (ru <= self.max_window) & (rv <= self.max_window)
        idx = np.flatnonzero(ok)
        pix = self.offs[ci] + v[idx].astype(np.int64) * cam.width + u[idx].astype(np.int64)
        return idx, pix, ds[idx, 2], ru[idx], rv[idx]

    def projection(self, voxel: int, camera: int) -> tuple[int, float] | None:
        """Pixel index ``v * W + u`` (in that camera's image) and centre depth of a voxel
        (flat index) in camera ``camera`` (index), or None if that camera cannot judge it."""
        a, b = int(self.start[camera]), int(self.start[camera + 1])
        k = a + int(np.searchsorted(self.vox[a:b], voxel))
        if k >= b or self.vox[k] != voxel:
            return None
        return int(self.pix[k] - self.offs[camera]), float(self.zc[k])

    def twin_args(self) -> tuple:
        """The model arguments of the numpy twin (after the images and the voxel count)."""
        return (self.rmin, self.rmax, self.start, self.vox, self.pix, self.offs, self.zc, self.ru, self.rv,
                self.half, self.far)

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.grid.shape

    @property
    def voxel_size(self) -> float:
        return self.grid.voxel_size

    @property
    def lo(self) -> np.ndarray:
        return self.grid.lo

    @property
    def camera_ids(self) -> list[str]:
        return list(self._ids)

    # ------------------------------------------------------------------- data
    def _load_depths(self, depths: Mapping[str, np.ndarray]) -> None:
        if not isinstance(depths, Mapping):
            raise ValueError("depths must be a dict camera id -> (H, W) depth image")
        unknown = set(depths) - set(self._ids)
        if unknown:
            raise ValueError(f"depths has images for unknown camera ids {sorted(unknown)}; known: {self._ids}")
        for ci, cam in enumerate(self.cameras):
            seg = self._depth[self.offs[ci]: self.offs[ci] + cam.width * cam.height]
            img = depths.get(cam.id)
            if img is None:
                seg.fill(0.0)  # a missing camera says nothing
                continue
            d = check_depth_image(cam, img)
            # copied with negatives as 0 (invalid): a negative depth in the buffer is a robot pixel
            np.maximum(d, np.float32(0.0), out=seg.reshape(cam.height, cam.width), casting="unsafe")

    def _mark_robot(self, robot: Mapping[str, np.ndarray]) -> None:
        """Negate the depth of the robot pixels in the map's buffer (after :meth:`_load_depths`,
        which made a caller's negative depth 0: invalid)."""
        unknown = set(robot) - set(self._ids)
        if unknown:
            raise ValueError(f"robot has masks for unknown camera ids {sorted(unknown)}; known: {self._ids}")
        for ci, cam in enumerate(self.cameras):
            m = robot.get(cam.id)
            if m is None:
                continue
            m = np.asarray(m)
            if m.shape != (cam.height, cam.width) or m.dtype != np.bool_:
                raise ValueError(f"robot mask of camera {cam.id!r}: shape {m.shape} dtype {m.dtype}, expected bool "
                                 f"{(cam.height, cam.width)}")
            seg = self._depth[self.offs[ci]: self.offs[ci] + cam.width * cam.height].reshape(cam.height, cam.width)
            _negate_where(seg, m)

    def set_background(self, backgrounds: Mapping[str, np.ndarray] | None, tolerance: float = 0.05) -> None:
        """Set (once; the shell never moves) the expected depth of the known static shell.

        Parameters
        ----------
        backgrounds : dict camera id -> (H, W) expected depth in metres of the room's fixed
            shell (floor, walls, ceiling), e.g. :func:`depthguard.render.render_depth` of its
            meshes; 0 / NaN = nothing known at that pixel. Cameras left out have no
            background. ``None`` removes the background (back to the plain rule).
        tolerance : float, metres (default 0.05) — a measurement within this of the
            background is the shell; margin + a few sigma of the depth noise (module docstring).

        Every later :meth:`update` applies the background rule (module docstring).
        """
        if backgrounds is None:
            self._bg.fill(0.0)
            if self._centre is not None:
                self._centre.set_background(None, self.offs)
            self._use_bg = False
            self.background_tolerance = 0.0
            return
        if self.footprint != "centre":
            raise ValueError("a background is supported only with footprint='centre'")
        tol = float(tolerance)
        if not (math.isfinite(tol) and tol >= 0):
            raise ValueError(f"tolerance must be a finite number >= 0 metres (got {tolerance!r})")
        if not isinstance(backgrounds, Mapping):
            raise ValueError("backgrounds must be a dict camera id -> (H, W) expected depth image")
        unknown = set(backgrounds) - set(self._ids)
        if unknown:
            raise ValueError(f"backgrounds has images for unknown camera ids {sorted(unknown)}; known: {self._ids}")
        for ci, cam in enumerate(self.cameras):
            seg = self._bg[self.offs[ci]: self.offs[ci] + cam.width * cam.height]
            img = backgrounds.get(cam.id)
            if img is None:
                seg.fill(0.0)
                continue
            b = np.asarray(img, dtype=np.float32)
            if b.shape != (cam.height, cam.width):
                raise ValueError(f"background of camera {cam.id!r}: shape {b.shape}, expected "
                                 f"{(cam.height, cam.width)}")
            np.copyto(seg.reshape(cam.height, cam.width), np.where(np.isfinite(b) & (b > 0), b, 0.0))
        self._centre.set_background(self._bg, self.offs)
        self.background_tolerance = tol
        self._use_bg = True

    def background_twin_args(self) -> dict:
        """Keyword arguments of the numpy twin for the current background (empty if none)."""
        if not self._use_bg:
            return {"grow": self.grow} if self.grow.any() else {}
        imgs = [self._bg[self.offs[ci]: self.offs[ci] + c.width * c.height].reshape(c.height, c.width)
                for ci, c in enumerate(self.cameras)]
        out = {"background": imgs, "bg_tol": self.background_tolerance}
        if self.grow.any():
            out["grow"] = self.grow
        return out

    def update(self, depths: Mapping[str, np.ndarray], accumulate: bool = False,
               robot: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
        """R21: fuse one set of depth images into the map.

        Parameters
        ----------
        depths : dict camera id -> (H, W) float depth image in metres (0 / NaN / negative = invalid).
            Cameras left out say nothing (their voxels stay occupied unless other
            cameras free them).
        accumulate : keep the voxels that were free since :meth:`reset` (static scene only).
        robot : optional dict camera id -> (H, W) bool, the pixels that see the robot (or
            something touching it; R9, R30): they free the voxels in front of their depth
            but never count a surface, so what the robot hides stays unknown
            (:mod:`~depthguard.fusion.free_space_kernels`).

        With a background set (:meth:`set_background`) its rule applies.

        Returns
        -------
        occupied : (nx, ny, nz) bool view of the map's buffer (valid until the next update).
        """
        if self.footprint == "centre":
            return self._update_centre(depths, robot, None, 0.0, accumulate)
        self._load_depths(depths)
        if robot:
            self._mark_robot(robot)
        return self._update_full(accumulate)

    def update_robot_depth(self, depths: Mapping[str, np.ndarray], robot_depths: Mapping[str, np.ndarray],
                           offset: float, accumulate: bool = False) -> np.ndarray:
        """:meth:`update` with the robot pixels (R9, R30) given as the robot rendered at each frame's
        capture joints: ``robot_depths`` camera id -> (H, W) float m (0 = no robot; a camera left
        out has none); a pixel sees the robot (or what touches it) when ``robot_depth > 0`` and
        ``depth >= robot_depth - offset`` (m) — :func:`~depthguard.fusion.free_space_kernels.robot_pixels`.
        Centre pixel: tested per pair as the image is read, no mask made (issue 30). Returns
        ``occupied`` as :meth:`update`."""
        off = float(offset)
        if self.footprint == "centre":
            return self._update_centre(depths, None, robot_depths, off, accumulate)
        self._check_ids(robot_depths, "robot_depths", "robot depths")
        masks = {}
        for cid, rd in robot_depths.items():
            if rd is not None and cid in depths:
                ci = self._ids.index(cid)
                masks[cid] = robot_pixels(check_depth_image(self.cameras[ci], depths[cid]),
                                          check_depth_image(self.cameras[ci], rd, "robot depth"), off,
                                          np.empty(self.cameras[ci].shape, dtype=bool))
        self._load_depths(depths)
        self._mark_robot(masks)
        return self._update_full(accumulate)

    def _check_ids(self, images, name: str, what: str) -> None:
        if not isinstance(images, Mapping):
            raise ValueError(f"{name} must be a dict camera id -> (H, W) image")
        unknown = set(images) - set(self._ids)
        if unknown:
            raise ValueError(f"{name} has {what} for unknown camera ids {sorted(unknown)}; known: {self._ids}")

    def _update_full(self, accumulate: bool) -> np.ndarray:
        """The window mode (or any mode) from the map's flat buffer (:func:`free_space_update`)."""
        self.machine[...] = False  # the machine moves: add its current volume after each update
        free_space_update(self._depth, self.offs, self.widths, self.heights, self.rmin, self.rmax,
                          self.vstart, self.chunk, self.vox, self.pix, self.zc, self.ru, self.rv,
                          self.half, self.far, self._bg, self.background_tolerance, self._use_bg,
                          self.margin, self.grow, self.min_free_views, self.footprint == "full", bool(accumulate),
                          self._nf, self._ns, self._free, self._occ)
        return self.occupied

    def _update_centre(self, depths, masks, robot_depths, offset: float, accumulate: bool) -> np.ndarray:
        """The centre-pixel update camera by camera from the callers' own images (:mod:`.free_space_centre`)."""
        self._check_ids(depths, "depths", "images")
        if masks:
            self._check_ids(masks, "robot", "masks")
        if robot_depths:
            self._check_ids(robot_depths, "robot_depths", "robot depths")
        work = self._centre.inputs(depths, masks, robot_depths)
        self._centre.count(work, offset, self.rmin, self.rmax, self.half, self.far + self.margin, self.grow,
                           self._use_bg, self.background_tolerance, self._nf, self._ns)
        self.machine[...] = False  # the machine moves: add its current volume after each update
        combine_counts(self._nf, self._ns, self.min_free_views, bool(accumulate), self._free, self._occ)
        return self.occupied

    @property
    def occupied(self) -> np.ndarray:
        """(nx, ny, nz) bool: the current map (True = occupied or unknown)."""
        return self._occ.reshape(self.grid.shape)

    def counts(self) -> tuple[np.ndarray, np.ndarray]:
        """Of the last update: (nx, ny, nz) uint8 arrays — how many cameras saw each voxel
        free, and how many saw a surface in it (views of internal buffers)."""
        return self._nf.reshape(self.grid.shape), self._ns.reshape(self.grid.shape)

    def reset(self) -> None:
        """Every voxel occupied again (forget all free space and the machine volume)."""
        self._free[...] = False
        self._occ[...] = True
        self.machine[...] = False

    def add_free_volume(self, primitives, padding: float = 0.0) -> np.ndarray:
        """Mark the machine's own current volume free (R21).

        ``primitives``: geometry primitives (Box, Capsule, Cylinder, Sphere, ...) of
        the machine at its current pose, world frame. Every voxel they (padded by
        ``padding`` metres) touch is freed; see :meth:`VoxelGrid.touched_by`. Call it
        after each :meth:`update` (an update forgets the previous machine volume).
        Returns the (nx, ny, nz) bool mask of those voxels (also kept as
        :attr:`machine`, the volume a motion check excludes).
        """
        mask = self.grid.touched_by(primitives, padding)
        self.machine |= mask
        self.occupied[mask] = False
        return mask

    def view_counts(self) -> np.ndarray:
        """(nx, ny, nz) int: how many cameras can judge each voxel (centre in view and range)."""
        return np.bincount(self.vox, minlength=self.grid.size).reshape(self.grid.shape)
