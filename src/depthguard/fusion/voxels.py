"""Per-camera filter to voxels of unknown objects (Oščádal 2022; R16–R19).

One :class:`VoxelFilter` per camera (model and workspace apart): it takes the
expected depth of the known scene (static CAD + the robot at its current
joints, R16) from :class:`depthguard.filtering.expected.ExpectedDepth` — the one
expected depth of the package, the same the monitor's camera workers use —, keeps the
measured pixels that lie in front of it by more than an offset (R17), turns
them into world voxels ``floor(p / s)`` with point counts, cropped to the
workspace (R18), and drops voxels that hold fewer points than
``threshold × n_max(d)`` (R19). Voxel size and threshold may change while
running (:meth:`VoxelFilter.configure`).

:func:`vote` is the multi-camera check the paper leaves as future work: a voxel
reported by one camera is dropped when at least two other cameras see through
it (their measured depth at the voxel centre's pixel lies beyond it).

Invalid pixels (0, NaN, outside the camera's range) are dropped from the voxel
output and counted (``VoxelSet.n_invalid``) so that a caller applying the R28
policy knows how much of the view could not be judged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, NamedTuple, Sequence

import numpy as np

from depthguard.camera import Camera, check_depth_image
from depthguard.filtering.expected import ExpectedDepth
from depthguard.fusion import voxel_kernels

__all__ = ["VoxelSet", "VoxelFilter", "FilterOffset", "offset_for_camera", "vote",
           "regrid", "union", "pack_keys", "unpack_keys", "VOXEL_SIZE_RANGE"]

VOXEL_SIZE_RANGE = (0.01, 0.1)       # R18: 10–100 mm
MAX_GRID_CELLS = 64_000_000          # workspace grid of counts (int32): 256 MB at most


class VoxelSet(NamedTuple):
    """Voxels of unknown objects from one camera (R18).

    keys : (N, 3) int32, voxel ``k`` spans ``[k·s, (k+1)·s)`` in the world (m).
    counts : (N,) int32 points per voxel.
    voxel_size : s in metres.
    n_kept : pixels that passed the R17 test; n_invalid : invalid pixels.
    """
    keys: np.ndarray
    counts: np.ndarray
    voxel_size: float
    n_kept: int = 0
    n_invalid: int = 0

    def centres(self) -> np.ndarray:
        """(N, 3) float64 voxel centres in the world (m)."""
        return (self.keys.astype(np.float64) + 0.5) * self.voxel_size

    def __len__(self) -> int:  # type: ignore[override]
        return int(self.keys.shape[0])


@dataclass(frozen=True)
class FilterOffset:
    """R17 offset ``const + k·e²`` (m), ``e`` the expected depth."""
    const: float = 0.02
    k: float = 0.005

    def __post_init__(self):
        if not (math.isfinite(self.const) and math.isfinite(self.k)) or self.const < 0 or self.k < 0:
            raise ValueError(f"filter offset must be finite and >= 0 (got const={self.const}, k={self.k})")

    def __call__(self, e):
        return self.const + self.k * np.asarray(e) ** 2


def offset_for_camera(cam: Camera) -> FilterOffset:
    """Offset covering the camera's noise model: ``0.01 + 3σ_a`` plus ``(3σ_z2 + quantisation)·e²``.

    Without a known sensor model: 0.02 m + 0.005·e².
    """
    from depthguard.sensors import SENSOR_MODELS

    m = SENSOR_MODELS.get(cam.sensor or "")
    if m is None:
        return FilterOffset()
    k = 3.0 * m.sigma_z2
    if m.disparity_bits and m.baseline > 0:
        k += 1.0 / (cam.fx * m.baseline * 2 ** m.disparity_bits)   # one disparity step at depth e
    return FilterOffset(const=0.01 + 3.0 * m.sigma_a, k=k)


def _check_voxel_size(s: float) -> float:
    s = float(s)
    lo, hi = VOXEL_SIZE_RANGE
    if not (math.isfinite(s) and lo - 1e-9 <= s <= hi + 1e-9):
        raise ValueError(f"voxel size must be within {lo * 1000:.0f}-{hi * 1000:.0f} mm (got {s * 1000:g} mm)")
    return s


def _check_threshold(t: float) -> float:
    t = float(t)
    if not (math.isfinite(t) and 0.0 <= t <= 1.0):
        raise ValueError(f"density threshold must be within [0, 1] (got {t})")
    return t


class VoxelFilter:
    """The per-camera filter: measured depth → voxels of unknown objects (R16–R19).

    Parameters
    ----------
    cam : Camera.
    workspace : (lo, hi) two (3,) corners of the box (m); points outside are cropped.
    voxel_size : s in metres, 0.01–0.1 (R18). threshold : R19 density fraction (0.55).
    offset : :class:`FilterOffset` (default from the camera's sensor model).
    static_meshes : known static CAD (list of Mesh, world frame).
    robot : RobotModel or None — rendered at the joints given to :meth:`filter`.
    learned : (H, W) float32 m, the camera's learned static scene (issue 31, 0 = unknown) or None;
        with the CAD, the nearer surface wins (:class:`~depthguard.filtering.expected.ExpectedDepth`).

    The workspace arrays (count grid, scratch, outputs) are allocated here and on
    :meth:`configure`, never per frame.
    """

    def __init__(self, cam: Camera, workspace, *, voxel_size: float = 0.02, threshold: float = 0.55,
                 offset: FilterOffset | None = None, static_meshes: Sequence = (), robot=None, learned=None):
        self.cam = cam
        lo, hi = (np.asarray(w, dtype=np.float64).reshape(3) for w in workspace)
        if not np.all(np.isfinite(lo) & np.isfinite(hi)) or np.any(hi <= lo):
            raise ValueError(f"workspace must satisfy min < max on every axis (got {lo}, {hi})")
        self.lo, self.hi = lo, hi
        self.offset = offset if offset is not None else offset_for_camera(cam)
        self.static_meshes = list(static_meshes)
        self.learned = learned
        self.robot = robot
        self._expected = None             # ExpectedDepth, made on first use (the expected= path never renders)
        self._empty_expected = np.zeros(cam.shape, dtype=np.float32)
        self._robot_q: np.ndarray | None = None
        self._robot_img = self._empty_expected
        n = cam.width * cam.height
        self._touched = np.empty(n, dtype=np.int64)
        self._out_keys = np.empty((n, 3), dtype=np.int32)
        self._out_counts = np.empty(n, dtype=np.int32)
        T = cam.world_from_camera
        self._Rwc = np.ascontiguousarray(T[:3, :3])
        self._twc = np.ascontiguousarray(T[:3, 3])
        self._cam_pos = np.ascontiguousarray(cam.position, dtype=np.float64)
        self._ang_u = cam.hfov / cam.width
        self._ang_v = cam.vfov / cam.height
        self.voxel_size = 0.0
        self.threshold = 0.55
        self.configure(voxel_size=voxel_size, threshold=threshold)

    # ------------------------------------------------------------- settings
    def configure(self, voxel_size: float | None = None, threshold: float | None = None) -> None:
        """Change voxel size (10–100 mm) and/or density threshold while running."""
        if threshold is not None:
            self.threshold = _check_threshold(threshold)
        if voxel_size is None or float(voxel_size) == self.voxel_size:
            return
        s = _check_voxel_size(voxel_size)
        key_lo = np.floor(self.lo / s).astype(np.int64)
        key_hi = np.floor(np.nextafter(self.hi, -np.inf) / s).astype(np.int64)
        dims = key_hi - key_lo + 1
        cells = int(np.prod(dims))
        if cells > MAX_GRID_CELLS:
            raise ValueError(f"workspace {self.lo}-{self.hi} at {s * 1000:g} mm needs {cells} voxels "
                             f"(limit {MAX_GRID_CELLS}); use a larger voxel size")
        self._key_lo, self._dims = key_lo, dims
        self._grid = np.zeros(cells, dtype=np.int32)
        self.voxel_size = s

    # ---------------------------------------------------- expected depth R16
    def _expected_depth(self):
        """The camera's :class:`~depthguard.filtering.expected.ExpectedDepth` (static scene
        rendered once, here; the robot per joints), made on first use."""
        if self._expected is None:
            self._expected = ExpectedDepth(self.cam, self.robot, self.static_meshes, learned=self.learned)
        return self._expected

    def _static_depth(self) -> np.ndarray:
        """(H, W) float32 static CAD (0 = nothing): :attr:`ExpectedDepth.static`, rendered once."""
        if not self.static_meshes and self.learned is None:
            return self._empty_expected
        return self._expected_depth().static

    def _robot_depth(self, q) -> np.ndarray:
        """(H, W) float32 robot at ``q`` (0 = nothing), :meth:`ExpectedDepth.robot`; rendered again
        only when ``q`` changes (the image is the ExpectedDepth's reused buffer)."""
        if self.robot is None or q is None:
            return self._empty_expected
        q = np.asarray(q, dtype=np.float64)
        ed = self._expected_depth()
        if self._robot_q is not None and np.array_equal(q, self._robot_q):
            return self._robot_img
        self._robot_q = None               # a failed render leaves no stale cache behind
        self._robot_img = ed.robot(q)      # the ExpectedDepth's buffer, overwritten by its next render
        self._robot_q = q.copy()
        return self._robot_img

    def expected_depth(self, q=None) -> np.ndarray:
        """(H, W) float32 expected depth (m, 0 = nothing known): static CAD + robot at ``q`` (R16).

        The static part is rendered once and cached; the robot is rendered when ``q``
        changes. (:meth:`filter` fuses the two inside the kernel instead.)
        """
        from depthguard.fusion.voxel_kernels import combine_expected_numpy

        return combine_expected_numpy(self._static_depth(), self._robot_depth(q))

    # --------------------------------------------------------------- filter
    def filter(self, depth: np.ndarray, q=None, expected: np.ndarray | None = None) -> VoxelSet:
        """Voxels of unknown objects in one frame (R17–R19).

        depth : (H, W) float32 measured depth (m). q : robot joints (rad) for the
        expected depth, or ``expected`` given directly ((H, W) float32, 0 = unknown;
        then the known scene is not rendered).
        """
        d = check_depth_image(self.cam, depth)
        if d.dtype != np.float32:
            d = d.astype(np.float32)
        if expected is None:
            static, robot = self._static_depth(), self._robot_depth(q)
        else:
            static = check_depth_image(self.cam, expected, "expected depth")
            if static.dtype != np.float32:
                static = static.astype(np.float32)
            robot = self._empty_expected
        cam = self.cam
        n, n_kept, n_invalid = voxel_kernels.filter_voxelize(
            d, static, robot, cam.fx, cam.fy, cam.cx, cam.cy, self._Rwc, self._twc,
            cam.min_range, cam.max_range, self.offset.const, self.offset.k,
            self._key_lo, self._dims, self.voxel_size, self.lo, self.hi,
            self._cam_pos, self._ang_u, self._ang_v, self.threshold,
            self._grid, self._touched, self._out_keys, self._out_counts)
        return VoxelSet(self._out_keys[:n].copy(), self._out_counts[:n].copy(), self.voxel_size,
                        int(n_kept), int(n_invalid))

    __call__ = filter


# ------------------------------------------------------------------ helpers
def pack_keys(keys: np.ndarray) -> np.ndarray:
    """(N, 3) int keys → (N,) int64, 21 bits per axis (keys in [−2²⁰, 2²⁰))."""
    k = np.asarray(keys, dtype=np.int64)
    if k.size and (k.min() < -(1 << 20) or k.max() >= (1 << 20)):
        raise ValueError("voxel keys out of the packable range [-2^20, 2^20)")
    o = k + (1 << 20)
    return (o[:, 0] << 42) | (o[:, 1] << 21) | o[:, 2]


def unpack_keys(packed: np.ndarray) -> np.ndarray:
    """Inverse of :func:`pack_keys`: (N,) int64 → (N, 3) int64."""
    p = np.asarray(packed, dtype=np.int64)
    m = (1 << 21) - 1
    return np.stack([(p >> 42) & m, (p >> 21) & m, p & m], axis=1) - (1 << 20)


def regrid(keys: np.ndarray, s_old: float, s_new: float) -> np.ndarray:
    """Conservative change of voxel size: every new voxel that overlaps an old one.

    (N, 3) int keys at ``s_old`` → (M, 3) int64 unique keys at ``s_new`` covering
    the union of the old voxels (no obstacle is lost when settings change while
    units still send the old size).
    """
    k = np.asarray(keys, dtype=np.int64)
    if s_old == s_new or len(k) == 0:
        return np.unique(k.reshape(-1, 3), axis=0)
    eps = 1e-9
    lo = np.floor(k * s_old / s_new + eps).astype(np.int64)
    hi = np.ceil((k + 1) * s_old / s_new - eps).astype(np.int64) - 1
    span = int((hi - lo).max()) + 1
    offs = np.stack(np.meshgrid(*(np.arange(span),) * 3, indexing="ij"), -1).reshape(-1, 3)
    cand = (lo[:, None, :] + offs[None, :, :])
    ok = np.all(cand <= hi[:, None, :], axis=2)
    return np.unique(cand[ok], axis=0)


def union(sets: Sequence[VoxelSet], voxel_size: float) -> np.ndarray:
    """(M, 3) int64 sorted unique keys at ``voxel_size``: the union of several units' voxels.

    Sets at another voxel size are re-gridded conservatively (:func:`regrid`).
    """
    parts = [regrid(v.keys, v.voxel_size, voxel_size) if v.voxel_size != voxel_size
             else np.asarray(v.keys, dtype=np.int64) for v in sets if len(v)]
    if not parts:
        return np.zeros((0, 3), dtype=np.int64)
    return unpack_keys(np.unique(pack_keys(np.concatenate(parts))))


def _camera_table(cameras: Sequence[Camera]) -> np.ndarray:
    rows = []
    for c in cameras:
        rows.append([c.fx, c.fy, c.cx, c.cy, c.width, c.height, c.min_range, c.max_range,
                     *c.R.reshape(-1), *c.t])
    return np.asarray(rows, dtype=np.float64)


def vote(sets: Mapping[str, VoxelSet], cameras: Sequence[Camera], depths: Mapping[str, np.ndarray],
         min_free: int = 2, offset: FilterOffset | None = None, rule: str = "footprint") -> dict[str, VoxelSet]:
    """Multi-camera voting (Oščádal 2022, future work): drop a voxel that at least
    ``min_free`` *other* cameras see through.

    ``rule="footprint"`` (default, conservative): camera c sees voxel v through when every
    pixel covered by v's projection measures beyond v's farthest corner + ``offset(r)``.
    ``rule="centre"``: the measured depth at the pixel of v's centre exceeds the centre's
    depth + ``s·√3/2 + offset(r)``. ``r`` is the distance from the voxel to the farthest
    camera. Returns new sets (counts kept).
    """
    if min_free < 1:
        raise ValueError(f"min_free must be >= 1 (got {min_free})")
    if rule not in ("footprint", "centre"):
        raise ValueError(f"rule must be 'footprint' or 'centre' (got {rule!r})")
    offset = offset or FilterOffset()
    cams = list(cameras)
    ids = [c.id for c in cams]
    missing = [k for k in sets if k not in ids]
    if missing:
        raise ValueError(f"voxel sets for unknown cameras {missing}; cameras: {ids}")
    Hm = max(c.height for c in cams)
    Wm = max(c.width for c in cams)
    stack = np.zeros((len(cams), Hm, Wm), dtype=np.float32)
    for i, c in enumerate(cams):
        if c.id in depths:
            d = check_depth_image(c, depths[c.id])
            stack[i, :c.height, :c.width] = np.nan_to_num(d, nan=0.0)
    table = _camera_table(cams)
    pos = np.stack([c.position for c in cams])
    out = {}
    for cid, vs in sets.items():
        if len(vs) == 0:
            out[cid] = vs
            continue
        s = vs.voxel_size
        centres = vs.centres()
        r = np.max(np.linalg.norm(centres[:, None, :] - pos[None], axis=2), axis=1)
        margin = offset(r) + (0.0 if rule == "footprint" else s * math.sqrt(3) / 2)
        free = np.zeros((len(centres), len(cams)), dtype=bool)
        voxel_kernels.vote_free(np.ascontiguousarray(vs.keys * s, dtype=np.float64), s, stack, table,
                    np.ascontiguousarray(margin, dtype=np.float64), rule == "footprint", free)
        free[:, ids.index(cid)] = False
        keep = free.sum(axis=1) < min_free
        out[cid] = VoxelSet(vs.keys[keep], vs.counts[keep], vs.voxel_size, vs.n_kept, vs.n_invalid)
    return out
