"""Depth-space distance for one camera: the public function and its workspace (SPEC §2, §9).

``depth_space_distance(cam, depth, points, rho, method, robot_depth)`` is the
convenience call. For a control loop keep a :class:`DistanceWorkspace` per
camera (model and data apart): :meth:`DistanceWorkspace.set_depth` once per
frame, :meth:`DistanceWorkspace.query` once per control cycle — neither
allocates (after the first call with the largest number of points).
"""

from __future__ import annotations

import threading
import weakref
from dataclasses import dataclass

import numba
import numpy as np

from depthguard.config import PRODUCT_RHO as RHO   # the product defaults, defined once in config
from depthguard.config import PRODUCT_INVALID, PRODUCT_METHOD, PRODUCT_ROBOT_OFFSET
from depthguard.camera import Camera, check_depth_image
from depthguard.distance import kernels
from depthguard.distance.gaps import GapBuffers, check_gap_px
from depthguard.distance.silhouette import SilhouetteBuffers, check_silhouette_px

__all__ = ["DistanceResult", "DistanceWorkspace", "depth_space_distance"]


@dataclass(frozen=True, eq=False)
class DistanceResult:
    """Distances from ``N`` control points to what one camera sees (R3–R7, R26).

    distance : (N,) float64 metres. ``inf`` means "no obstacle (surface, gray
        area or unknown ray) within ``rho``" — never a number to be read as a
        distance. ``0`` means the point lies inside a pixel's frustum (in the
        gray area behind a surface, or in an unknown ray).
    direction : (N, 3) float64 unit vectors in the world frame from the
        point towards the obstacle (min: to the nearest frustum point; mean
        and hybrid: the normalised mean of the per-pixel unit vectors, R7).
        Zero where the distance is ``inf``, where it is 0 (no defined
        direction) or where the per-pixel directions cancel.
    observed : (N,) bool. ``True``: the point projects inside the image and
        its depth lies in ``[min_range, max_range]``, so the camera judges
        it. A point hidden behind a surface is *observed* — it lies in the
        gray area, which the camera judges as possibly occupied, and its
        distance is 0. ``False``: the camera cannot judge the point (R26):
        outside the image, nearer than ``min_range``, farther than
        ``max_range`` or behind the camera. Its ``distance`` then covers only
        the frusta this camera sees (``inf`` for a point at or behind the
        camera plane) and must not be taken as free space.
    count : (N,) int64 pixels in the set ``S`` (``D <= rho``) for mean and
        hybrid; 1 or 0 for min.
    """

    distance: np.ndarray
    direction: np.ndarray
    observed: np.ndarray
    count: np.ndarray

    def __len__(self) -> int:
        return len(self.distance)

    def copy(self) -> "DistanceResult":
        return DistanceResult(self.distance.copy(), self.direction.copy(), self.observed.copy(),
                              self.count.copy())


def _check_choice(name: str, value: str, table: dict) -> int:
    try:
        return table[value]
    except (KeyError, TypeError):
        raise ValueError(f"{name} must be one of {', '.join(repr(k) for k in table)} (got {value!r})") from None


def check_rho(rho: float) -> float:
    try:
        r = float(rho)
    except (TypeError, ValueError):
        raise ValueError(f"rho must be a number of metres (got {rho!r})") from None
    if not (np.isfinite(r) and r > 0):
        raise ValueError(f"rho must be finite and > 0 metres (got {rho!r})")
    return r


def check_points(points) -> np.ndarray:
    """(N, 3) finite float64 world points (a single (3,) point is accepted)."""
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("points must be an (N, 3) array of numbers") from None
    if p.ndim == 1 and p.shape[0] == 3:
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("points must be finite (found NaN or inf)")
    return np.ascontiguousarray(p)


class DistanceWorkspace:
    """Preallocated buffers of the depth-space distance for one camera.

    Parameters
    ----------
    cam : Camera
    max_points : int
        Initial capacity of the output buffers (they grow if a query asks
        for more points; growth is the only allocation).
    parallel : ``"auto"`` (default), True or False
        Run the points in parallel (numba ``prange``). ``"auto"``: when there
        are at least ``kernels.PARALLEL_MIN_POINTS`` points and numba has more
        than one thread. A parallel launch costs a few microseconds on an idle
        machine but waits for a free core on a loaded one.

    Use::

        ws = DistanceWorkspace(cam, max_points=32)
        ws.set_depth(depth, robot_depth=rd)          # per frame
        res = ws.query(points, rho=0.4, method="hybrid")   # per cycle
    """

    def __init__(self, cam: Camera, max_points: int = 64, parallel: bool | str = "auto"):
        if not isinstance(cam, Camera):
            raise ValueError(f"cam must be a depthguard Camera (got {type(cam).__name__})")
        self.cam = cam
        self._R = np.ascontiguousarray(cam.R, dtype=np.float64)
        self._t = np.ascontiguousarray(cam.t, dtype=np.float64)
        self.d0 = np.full(cam.shape, np.inf)       # obstacle start depth per pixel
        self._no_robot = np.zeros((1, 1), dtype=np.float32)
        self._silhouette: SilhouetteBuffers | None = None     # made on the first silhouette_px > 0
        self._gaps: GapBuffers | None = None                  # made on the first gap_px > 0
        self._alloc(max(int(max_points), 1))
        self.has_depth = False
        self.lock = threading.Lock()
        if parallel not in ("auto", True, False):
            raise ValueError(f"parallel must be 'auto', True or False (got {parallel!r})")
        self.parallel = parallel

    def _alloc(self, n: int) -> None:
        self.capacity = n
        self._dist = np.empty(n)
        self._dir = np.empty((n, 3))
        self._count = np.empty(n, dtype=np.int64)
        self._obs = np.empty(n, dtype=np.bool_)

    def set_depth(self, depth: np.ndarray, robot_depth: np.ndarray | None = None,
                  invalid: str = PRODUCT_INVALID, robot_mode: str = "drop",
                  robot_offset: float = PRODUCT_ROBOT_OFFSET, silhouette_px: int = 0, gap_px: int = 0) -> None:
        """Load one frame: compute each pixel's obstacle start depth (R1, R9, R28, R32).

        depth : (H, W) float metres; valid in ``[min_range, max_range]``; a finite value
            beyond ``max_range`` is a return beyond the rated range; 0, NaN, inf or below
            ``min_range`` = invalid (no return).
        robot_depth : (H, W) float, the robot rendered into this camera at its
            current joints (0 = no robot; see :func:`~depthguard.distance.self_removal.robot_depth`).
            A pixel is the robot's where ``measured >= robot_depth - robot_offset`` (R9).
        invalid : ``"unknown"`` (default, safe, R28): an invalid pixel's whole
            ray is unknown from ``min_range`` on, i.e. an obstacle frustum
            starting at ``min_range``; a return beyond the rated range (``m >
            max_range``) is free up to ``max_range``, its frustum starts there.
            ``"free"``: both are ignored (nothing on the ray).
        robot_mode : what a robot pixel becomes (R9: free up to the robot's
            depth ``dr``, unknown behind it).
            ``"drop"`` (default): the pixel is ignored altogether, as the
            paper does for one camera (§3.5). The robot's own control points
            then never see their own link; what hides right behind the robot
            is not seen by this camera — the depth grid (R12 step 4) confirms
            those cells with the other cameras.
            ``"shadow"``: the pixel's frustum starts at ``dr`` (free up to
            the robot, its shadow counted as obstacle). Safe for points that
            are not on the robot, but a control point on or inside a link
            that the camera sees lies in its own shadow and reads 0.
        robot_offset : metres, > 0 margin for noise between measurement and render.
        silhouette_px : int >= 0 pixels (default 0: off, today's answers). With a
            ``robot_depth`` and ``invalid="unknown"``, an *invalid* pixel within
            ``silhouette_px`` pixels (the ``(2n+1)^2`` window) of the robot's rendered
            silhouette takes the robot pixel's meaning per ``robot_mode`` with the
            smallest robot depth of its window ``drd`` (``"drop"``: ignored;
            ``"shadow"``: frustum from ``drd``): the sensors' dropout at the robot's
            outline is not an obstacle next to the robot (R32). Invalid pixels
            farther away stay unknown from ``min_range`` (R28); valid pixels are
            unchanged. See :mod:`depthguard.distance.silhouette` for the price (an
            all-invalid obstacle next to the robot looks ``silhouette_px`` pixels smaller).
        gap_px : int >= 0 pixels (default 0: off, today's answers). With
            ``invalid="unknown"``, an invalid pixel (outside the silhouette rule) in a run of
            at most ``gap_px`` invalid pixels along its row or column, bounded by returns on
            both sides, starts at the nearer end's depth (``min(m, max_range)``) instead of
            ``min_range``: the edge dropout of the fixed scene. The price: an all-invalid
            object at most ``gap_px`` pixels wide in front of both neighbours can be missed
            (:mod:`depthguard.distance.gaps`).
        """
        cam = self.cam
        d = check_depth_image(cam, depth)
        pol = _check_choice("invalid", invalid, kernels.INVALID_POLICIES)
        mode = _check_choice("robot_mode", robot_mode, kernels.ROBOT_MODES)
        off = float(robot_offset)
        if not (np.isfinite(off) and off >= 0):
            raise ValueError(f"robot_offset must be finite and >= 0 metres (got {robot_offset!r})")
        n_sil = check_silhouette_px(silhouette_px)
        n_gap = check_gap_px(gap_px)
        if robot_depth is None:
            rd, use = self._no_robot, False
        else:
            rd, use = check_depth_image(cam, robot_depth, name="robot_depth"), True
        sil = kernels.NO_SILHOUETTE[np.dtype(np.float32 if rd.dtype == np.float32 else np.float64)]   # off
        if use and n_sil > 0 and pol == kernels.INVALID_UNKNOWN:
            if self._silhouette is None:
                self._silhouette = SilhouetteBuffers(cam.shape)
            sil = self._silhouette.dilate(rd, n_sil)
        gaps = kernels.NO_GAP                      # off
        if n_gap > 0 and pol == kernels.INVALID_UNKNOWN:
            if self._gaps is None:
                self._gaps = GapBuffers(cam.shape)
            gaps = self._gaps.gaps(d, cam.min_range, cam.max_range, n_gap)
        kernels.obstacle_start_depth(d, rd, use, cam.min_range, cam.max_range, pol, mode, off, self.d0, sil, gaps)
        self.has_depth = True

    def query(self, points: np.ndarray, rho: float = RHO, method: str = PRODUCT_METHOD) -> DistanceResult:
        """Distances of ``points`` (N, 3) world metres to the current frame (R3–R7).

        The arrays of the result are views of the workspace's buffers,
        overwritten by the next query: ``.copy()`` the result to keep it.
        """
        if not self.has_depth:
            raise ValueError("DistanceWorkspace.query: call set_depth(depth) first")
        p = check_points(points)
        r = check_rho(rho)
        m = _check_choice("method", method, kernels.METHODS)
        n = len(p)
        if n > self.capacity:
            self._alloc(n)
        cam = self.cam
        par = self.parallel
        if par == "auto":
            par = n >= kernels.PARALLEL_MIN_POINTS and numba.get_num_threads() > 1
        kernel = kernels.depth_space_distances if par else kernels.depth_space_distances_serial
        kernel(self.d0, self._R, self._t, cam.fx, cam.fy, cam.cx, cam.cy,
               cam.min_range, cam.max_range, p, n, r, m,
               self._dist, self._dir, self._count, self._obs)
        return DistanceResult(self._dist[:n], self._dir[:n], self._obs[:n], self._count[:n])


_WORKSPACES: "weakref.WeakKeyDictionary[Camera, DistanceWorkspace]" = weakref.WeakKeyDictionary()
_WS_LOCK = threading.Lock()


def workspace_for(cam: Camera) -> DistanceWorkspace:
    """The cached workspace of ``cam`` (created on first use, dropped with the camera)."""
    with _WS_LOCK:
        ws = _WORKSPACES.get(cam)
        if ws is None:
            ws = DistanceWorkspace(cam)
            _WORKSPACES[cam] = ws
        return ws


def depth_space_distance(cam: Camera, depth: np.ndarray, points: np.ndarray, rho: float = RHO,
                         method: str = PRODUCT_METHOD, robot_depth: np.ndarray | None = None,
                         invalid: str = PRODUCT_INVALID, robot_mode: str = "drop",
                         robot_offset: float = PRODUCT_ROBOT_OFFSET, silhouette_px: int = 0,
                         gap_px: int = 0) -> DistanceResult:
    """Distance from control points to everything one depth camera sees (SPEC §2, R3–R9, R28).

    Each obstacle pixel stands for its whole frustum from the measured depth
    ``do`` on (surface plus gray area, R1). For a point ``P = (px, py, dp)``
    in depth space the nearest frustum point is ``ôx = clamp(px, ōx - 1/2,
    ōx + 1/2)`` (likewise y, R3), ``ôd = do if do > dp else dp`` (R4), and
    the distance vector follows R5. Pixels are scanned in the region of
    surveillance (R6); ``min``, ``mean`` and ``hybrid`` aggregate them (R7).

    Approximation: R3–R5 give the distance to a point of the frustum, so
    ``D >= D_exact``; and ``D <= D_exact / cos(phi) + delta``, where ``phi``
    is the largest angle between the optical axis and a ray of the pixel and
    ``delta = do * hypot(1/fx, 1/fy)`` (the pixel's footprint at ``do``)
    when ``dp < do``, else 0.

    Parameters
    ----------
    cam : Camera
    depth : (H, W) float metres, 0/NaN/below min_range = invalid; beyond max_range = a return
        beyond the rated range (see :meth:`DistanceWorkspace.set_depth`).
    points : (N, 3) world metres.
    rho : radius of surveillance, metres (> 0).
    method : ``"min"``, ``"mean"`` or ``"hybrid"`` (default, for control).
    robot_depth : optional (H, W) robot rendered into ``cam`` (R9).
    invalid, robot_mode, robot_offset, silhouette_px, gap_px : see :meth:`DistanceWorkspace.set_depth`
        (``silhouette_px=0`` and ``gap_px=0``, the defaults, are off; the product runs with
        silhouette_px=4, R32).

    Returns
    -------
    DistanceResult with fresh arrays (see its docstring for ``inf``, 0 and ``observed``).
    """
    if not isinstance(cam, Camera):
        raise ValueError(f"cam must be a depthguard Camera (got {type(cam).__name__})")
    ws = workspace_for(cam)
    with ws.lock:
        ws.set_depth(depth, robot_depth, invalid=invalid, robot_mode=robot_mode, robot_offset=robot_offset,
                     silhouette_px=silhouette_px, gap_px=gap_px)
        return ws.query(points, rho=rho, method=method).copy()
