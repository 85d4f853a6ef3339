"""Pinhole depth camera and depth space (SPEC §1, R1).

Frames follow OpenCV / ROS ``CameraInfo``: x right, y down, z forward. The
depth ``dp`` of a point is its ``z`` in the camera frame, not the ray length.
Pixel centres sit at integer coordinates: pixel ``(u, v)`` covers
``[u - 1/2, u + 1/2) x [v - 1/2, v + 1/2)`` and ``u = floor(px + 1/2)``.

Shapes: points are ``(N, 3)`` float64 arrays in metres; images are
``(height, width)`` arrays indexed ``[v, u]``.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field

import numpy as np

from depthguard.transforms import as_rigid, invert_rigid

__all__ = ["Camera", "CameraError", "RETURN_LIMIT_FACTOR"]

#: A measured depth in (max_range, RETURN_LIMIT_FACTOR * max_range] is a return beyond the
#: rated range (free up to ``max_range``, unknown behind: R28). Above that no depth sensor
#: returns (a Kinect v1 to ~8 m of its rated 4, a D435 to ~10 of 6): the value is invalid —
#: most likely an image in the wrong units (millimetres read as metres) — and counts as no
#: return, unknown from the near range, never as free space.
RETURN_LIMIT_FACTOR = 3.0


class CameraError(ValueError):
    """A camera's parameters are not a valid pinhole depth camera."""


@dataclass(frozen=True, eq=False)
class Camera:
    """An immutable pinhole depth camera with its pose in the world (R1).

    Parameters
    ----------
    id : str
        Name of the camera, unique within a rig.
    width, height : int
        Image size in pixels.
    fx, fy : float
        Focal lengths in pixels (``f * sx``, ``f * sy``), > 0.
    cx, cy : float
        Principal point in pixels, inside the image.
    world_from_camera : (4, 4) array
        Rigid pose of the camera frame in the world.
    min_range, max_range : float
        Valid measurement range in metres, ``0 <= min_range < max_range``.
    sensor : str or None
        Name of the sensor model used when the camera is simulated.
    """

    id: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    world_from_camera: np.ndarray = field(default_factory=lambda: np.eye(4))
    min_range: float = 0.4
    max_range: float = 6.0
    sensor: str | None = None

    def __post_init__(self) -> None:
        def bad(what: str) -> CameraError:
            return CameraError(f"camera {self.id!r}: {what}")

        if not isinstance(self.id, str) or not self.id:
            raise CameraError(f"camera id must be a non-empty string (got {self.id!r})")
        for name in ("width", "height"):
            val = getattr(self, name)
            if int(val) != val or val <= 0:
                raise bad(f"{name} must be a positive integer (got {val!r})")
            object.__setattr__(self, name, int(val))
        for name in ("fx", "fy", "cx", "cy", "min_range", "max_range"):
            val = float(getattr(self, name))
            if not math.isfinite(val):
                raise bad(f"{name} must be finite (got {val!r})")
            object.__setattr__(self, name, val)
        if self.fx <= 0 or self.fy <= 0:
            raise bad(f"focal length must be > 0 (got fx={self.fx}, fy={self.fy})")
        if not (-0.5 <= self.cx <= self.width - 0.5 and -0.5 <= self.cy <= self.height - 0.5):
            raise bad(
                f"principal point ({self.cx}, {self.cy}) lies outside the "
                f"{self.width}x{self.height} image"
            )
        if not (0.0 <= self.min_range < self.max_range):
            raise bad(
                f"range must satisfy 0 <= min_range < max_range "
                f"(got {self.min_range}, {self.max_range})"
            )
        try:
            T = as_rigid(self.world_from_camera)
        except ValueError as exc:
            raise bad(f"world_from_camera: {exc}") from None
        T.setflags(write=False)
        object.__setattr__(self, "world_from_camera", T)
        Tinv = invert_rigid(T)
        Tinv.setflags(write=False)
        object.__setattr__(self, "_camera_from_world", Tinv)

    # ------------------------------------------------------------------ pose
    @property
    def camera_from_world(self) -> np.ndarray:
        """(4, 4) inverse pose: ``P_c = R P_w + t`` (equation 1)."""
        return self._camera_from_world  # type: ignore[attr-defined]

    @property
    def R(self) -> np.ndarray:
        """(3, 3) rotation of ``camera_from_world``."""
        return self.camera_from_world[:3, :3]

    @property
    def t(self) -> np.ndarray:
        """(3,) translation of ``camera_from_world``."""
        return self.camera_from_world[:3, 3]

    @property
    def position(self) -> np.ndarray:
        """(3,) optical centre in the world."""
        return self.world_from_camera[:3, 3]

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape ``(height, width)``."""
        return (self.height, self.width)

    @property
    def hfov(self) -> float:
        """Horizontal field of view in radians (edge to edge of the image)."""
        return math.atan((self.cx + 0.5) / self.fx) + math.atan((self.width - 0.5 - self.cx) / self.fx)

    @property
    def vfov(self) -> float:
        """Vertical field of view in radians."""
        return math.atan((self.cy + 0.5) / self.fy) + math.atan((self.height - 0.5 - self.cy) / self.fy)

    def with_pose(self, world_from_camera: np.ndarray) -> "Camera":
        """The same intrinsics at another pose."""
        return Camera(self.id, self.width, self.height, self.fx, self.fy, self.cx, self.cy,
                      world_from_camera, self.min_range, self.max_range, self.sensor)

    def binned(self, b: int) -> "Camera":
        """The camera whose pixel is a ``b x b`` block of this one's (R10: the depth grid's
        principal at a coarser pixel, ``principal_bin``): ``ceil(W / b) x ceil(H / b)`` pixels,
        ``fx / b``, ``fy / b``, and the principal point where pixel ``(u, v)``'s block centre
        ``(b u + (b - 1) / 2, b v + (b - 1) / 2)`` of this camera projects; same pose and
        range. ``b = 1`` is this camera itself."""
        b = int(b)
        if b < 1:
            raise CameraError(f"camera {self.id!r}: a pixel bin must be >= 1 (got {b})")
        if b == 1:
            return self
        return Camera(self.id, -(-self.width // b), -(-self.height // b), self.fx / b, self.fy / b,
                      (self.cx + 0.5) / b - 0.5, (self.cy + 0.5) / b - 0.5, self.world_from_camera,
                      self.min_range, self.max_range, self.sensor)

    def key(self) -> str:
        """A stable hash of every parameter, for on-disk caches keyed by the rig."""
        h = hashlib.sha256()
        h.update(repr((self.id, self.width, self.height, self.fx, self.fy, self.cx, self.cy,
                       self.min_range, self.max_range)).encode())
        h.update(np.ascontiguousarray(self.world_from_camera, dtype=np.float64).tobytes())
        return h.hexdigest()[:16]

    def __repr__(self) -> str:
        p = self.position
        return (f"Camera(id={self.id!r}, {self.width}x{self.height}, fx={self.fx:.1f}, fy={self.fy:.1f}, "
                f"cx={self.cx:.1f}, cy={self.cy:.1f}, at=({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}))")

    # ------------------------------------------------------- conversions (R1)
    def world_to_camera(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) world points -> (N, 3) camera-frame points (equation 1)."""
        p = _points(points)
        return p @ self.R.T + self.t

    def camera_to_world(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) camera-frame points -> (N, 3) world points."""
        p = _points(points)
        T = self.world_from_camera
        return p @ T[:3, :3].T + T[:3, 3]

    def camera_to_depth_space(self, points_c: np.ndarray) -> np.ndarray:
        """(N, 3) camera-frame points -> (N, 3) depth-space ``(px, py, dp)`` (equation 2).

        Points with ``z <= 0`` get ``px = py = nan`` (no projection).
        """
        p = _points(points_c)
        z = p[:, 2]
        out = np.empty_like(p)
        with np.errstate(divide="ignore", invalid="ignore"):
            out[:, 0] = np.where(z > 0, p[:, 0] * self.fx / z + self.cx, np.nan)
            out[:, 1] = np.where(z > 0, p[:, 1] * self.fy / z + self.cy, np.nan)
        out[:, 2] = z
        return out

    def depth_space_to_camera(self, ds: np.ndarray) -> np.ndarray:
        """(N, 3) depth-space ``(px, py, dp)`` -> (N, 3) camera-frame points (equation 3)."""
        d = _points(ds)
        out = np.empty_like(d)
        out[:, 0] = (d[:, 0] - self.cx) * d[:, 2] / self.fx
        out[:, 1] = (d[:, 1] - self.cy) * d[:, 2] / self.fy
        out[:, 2] = d[:, 2]
        return out

    def world_to_depth_space(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) world points -> (N, 3) depth space."""
        return self.camera_to_depth_space(self.world_to_camera(points))

    def depth_space_to_world(self, ds: np.ndarray) -> np.ndarray:
        """(N, 3) depth space -> (N, 3) world points."""
        return self.camera_to_world(self.depth_space_to_camera(ds))

    def pixel_of(self, px: np.ndarray, py: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Integer pixel ``(u, v)`` containing sub-pixel ``(px, py)``: ``floor(p + 1/2)``."""
        return (np.floor(np.asarray(px) + 0.5).astype(np.int64),
                np.floor(np.asarray(py) + 0.5).astype(np.int64))

    def in_view(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: the world point projects inside the image, in front of the camera
        and within ``[min_range, max_range]`` of depth."""
        ds = self.world_to_depth_space(points)
        with np.errstate(invalid="ignore"):
            return ((ds[:, 2] >= self.min_range) & (ds[:, 2] <= self.max_range)
                    & (ds[:, 0] >= -0.5) & (ds[:, 0] < self.width - 0.5)
                    & (ds[:, 1] >= -0.5) & (ds[:, 1] < self.height - 0.5))

    def pixel_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """(H, W) float64 arrays of the pixel-centre coordinates ``u`` and ``v``."""
        return np.meshgrid(np.arange(self.width, dtype=np.float64),
                           np.arange(self.height, dtype=np.float64))

    def ray_directions(self) -> np.ndarray:
        """(H, W, 3) camera-frame rays through pixel centres, scaled to ``z = 1``."""
        u, v = self.pixel_grid()
        return np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy, np.ones_like(u)], axis=-1)

    def depth_to_points(self, depth: np.ndarray, frame: str = "world",
                        mask: np.ndarray | None = None) -> np.ndarray:
        """Back-project the valid pixels of a depth image (equation 3).

        This is the one place that turns depth into points.

        Parameters
        ----------
        depth : (H, W) array, metres; 0 or non-finite = no measurement.
        frame : ``"world"`` or ``"camera"``.
        mask : optional (H, W) bool; only these pixels are used.

        Returns
        -------
        (N, 3) float64 points, row-major pixel order.
        """
        d = check_depth_image(self, depth)
        valid = np.isfinite(d) & (d > 0)
        if mask is not None:
            valid &= mask
        v, u = np.nonzero(valid)
        z = d[v, u].astype(np.float64)
        pc = np.empty((z.size, 3))
        pc[:, 0] = (u - self.cx) * z / self.fx
        pc[:, 1] = (v - self.cy) * z / self.fy
        pc[:, 2] = z
        if frame == "camera":
            return pc
        if frame == "world":
            return self.camera_to_world(pc)
        raise ValueError(f"frame must be 'world' or 'camera' (got {frame!r})")


def check_depth_image(cam: Camera, depth: np.ndarray, name: str = "depth") -> np.ndarray:
    """Check that ``depth`` is a (H, W) real image matching ``cam``; return it as an array."""
    d = np.asarray(depth)
    if d.ndim != 2:
        raise ValueError(f"{name} for camera {cam.id!r} must be a 2-D image, got shape {d.shape}")
    if d.shape != cam.shape:
        raise ValueError(
            f"{name} for camera {cam.id!r} has shape {d.shape}, expected {cam.shape} (height, width)"
        )
    if not np.issubdtype(d.dtype, np.floating):
        raise ValueError(f"{name} for camera {cam.id!r} must be float metres, got dtype {d.dtype}")
    return d


def _points(points: np.ndarray) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim == 1 and p.shape[0] == 3:
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {np.shape(points)}")
    return p
