"""Voxels of the distributed camera units as an input of the monitor (R20, R25, R27, R29).

A camera unit (:mod:`depthguard.distributed.node`) filters its own camera and
sends only the voxels of unknown objects; the fusion server hands them out
(:mod:`depthguard.sources.units`). :class:`VoxelObstacles` keeps the newest
voxel set of every unit camera and lowers the monitor's distances with them:

- **conservative** (R25): a voxel is the axis-aligned cube of side ``s`` around
  its centre, and the distance from a point to that **box** is a lower bound of
  the distance to anything inside the voxel, so it is what counts (never the
  distance to the centre);
- only where it is below the distance the monitor already has and within
  ``rho`` (``inf`` stays "nothing within rho"); a point inside a box gets
  distance 0 and direction zero (no way out is known);
- **the robot's own volume**: a voxel whose centre lies inside one of the
  robot's padded capsules at the current pose (``robot_capsules``) does not
  count. The unit removed the robot at capture time already, but possibly at a
  stale pose (a unit without a joint stream removes it at a fixed pose) — a
  voxel of the robot itself would otherwise stop the robot for ever. Same rule
  as the depth grid's (R12, centre in one padded capsule), with the same
  price: an obstacle within the padding of the robot is not seen through this
  input;
- a unit's **staleness is its camera's** (R27): :meth:`VoxelObstacles.nearest`
  returns the capture stamp of every set it used, which the monitor treats
  like a camera frame's stamp. A set is replaced whole by the next one of its
  camera and kept until then — a unit that stops sending leaves its last set
  in place, growing old, until the monitor's staleness rule stops the robot.

Kernel: :func:`voxel_nearest` (numba, no allocation per call; the voxels of a set
are grouped in coarse cells when pushed, :func:`bucket`, and a cell farther than rho
and than the distance a point already has is skipped whole) and its plain numpy
twin :func:`voxel_nearest_numpy` (every voxel, no cells).
"""

from __future__ import annotations

import math
import threading
from typing import NamedTuple

import numba
import numpy as np

__all__ = ["VoxelObstacles", "UnitVoxels", "voxel_nearest", "voxel_nearest_numpy", "bucket"]

_NO_SEGMENTS = np.zeros((0, 2, 3), dtype=np.float64)
_NO_RADII = np.zeros(0, dtype=np.float64)


class UnitVoxels(NamedTuple):
    """One unit camera's newest voxel set: centres (N, 3) float64 world m (read-only, grouped
    by coarse cell: :func:`bucket`), voxel size s (m), capture stamp (s, the monitor's clock),
    and the cells (``cell_start``, ``cell_lo``, ``cell_hi``)."""
    centres: np.ndarray
    voxel_size: float
    stamp: float
    cell_start: np.ndarray
    cell_lo: np.ndarray
    cell_hi: np.ndarray


BUCKET_M = 0.16          # side of the coarse cells the voxels of a set are grouped in (m)


def bucket(centres: np.ndarray, voxel_size: float, cell: float = BUCKET_M):
    """Group voxel centres (N, 3) by coarse cells of side ``max(cell, 4 s)``: ``(centres sorted by
    cell (N, 3), cell_start (K + 1,) int64, cell_lo (K, 3), cell_hi (K, 3))`` — cell k holds the
    voxels ``cell_start[k]:cell_start[k + 1]`` and its box ``[cell_lo, cell_hi]`` contains every
    one of their voxel boxes (so the distance to it is a lower bound of theirs). Done once per
    pushed set, off the control thread."""
    c = np.ascontiguousarray(centres, dtype=np.float64).reshape(-1, 3)
    half = 0.5 * float(voxel_size)
    if len(c) == 0:
        return c, np.zeros(1, np.int64), np.zeros((0, 3)), np.zeros((0, 3))
    b = max(float(cell), 4.0 * float(voxel_size))
    k = np.floor(c / b).astype(np.int64)
    order = np.lexsort(k.T[::-1])
    c, k = np.ascontiguousarray(c[order]), k[order]
    new = np.ones(len(k), dtype=bool)
    new[1:] = np.any(k[1:] != k[:-1], axis=1)
    start = np.flatnonzero(new)
    cell_start = np.append(start, len(c)).astype(np.int64)
    lo = np.minimum.reduceat(c - half, start, axis=0)       # the same values the kernel computes
    hi = np.maximum.reduceat(c + half, start, axis=0)
    return c, cell_start, np.ascontiguousarray(lo), np.ascontiguousarray(hi)


@numba.njit(cache=True, nogil=True)
def voxel_nearest(points, centres, half, rho, segments, radii, out_distance, out_direction,
                  cell_start, cell_lo, cell_hi):
    """Lower ``out_distance`` (m,) / set ``out_direction`` (m, 3) with the voxel boxes (module
    docstring). points (m, 3), centres (N, 3) world m grouped in cells (:func:`bucket`:
    cell_start (K + 1,), cell_lo / cell_hi (K, 3)); ``half`` = s / 2; segments (C, 2, 3),
    radii (C,): the robot's padded capsules (a voxel whose centre is inside one is skipped).
    Point i takes voxel j when ``d_ij <= rho`` and ``d_ij < out_distance[i]`` at the time j is
    visited (so the nearest, the first visited on ties). A cell farther from every point than
    rho and than the point's current distance is skipped whole. Returns the number of voxels
    that lowered a distance (outside the robot; the robot test is done only for those)."""
    m = points.shape[0]
    n_cap = radii.shape[0]
    used = 0
    for k in range(cell_lo.shape[0]):
        near = False
        for i in range(m):
            px = points[i, 0]
            py = points[i, 1]
            pz = points[i, 2]
            vx = min(max(px, cell_lo[k, 0]), cell_hi[k, 0]) - px
            vy = min(max(py, cell_lo[k, 1]), cell_hi[k, 1]) - py
            vz = min(max(pz, cell_lo[k, 2]), cell_hi[k, 2]) - pz
            d = math.sqrt(vx * vx + vy * vy + vz * vz)
            if d <= rho and d < out_distance[i]:
                near = True
                break
        if not near:
            continue
        for j in range(cell_start[k], cell_start[k + 1]):
            cx = centres[j, 0]
            cy = centres[j, 1]
            cz = centres[j, 2]
            lx = cx - half
            hx = cx + half
            ly = cy - half
            hy = cy + half
            lz = cz - half
            hz = cz + half
            lowers = False
            for i in range(m):
                px = points[i, 0]
                py = points[i, 1]
                pz = points[i, 2]
                vx = min(max(px, lx), hx) - px
                vy = min(max(py, ly), hy) - py
                vz = min(max(pz, lz), hz) - pz
                d = math.sqrt(vx * vx + vy * vy + vz * vz)
                if d <= rho and d < out_distance[i]:
                    lowers = True
                    break
            if not lowers:
                continue
            own = False
            for c in range(n_cap):
                ax = segments[c, 0, 0]
                ay = segments[c, 0, 1]
                az = segments[c, 0, 2]
                ux = segments[c, 1, 0] - ax
                uy = segments[c, 1, 1] - ay
                uz = segments[c, 1, 2] - az
                uu = ux * ux + uy * uy + uz * uz
                t = 0.0
                if uu > 0.0:
                    t = ((cx - ax) * ux + (cy - ay) * uy + (cz - az) * uz) / uu
                    t = min(max(t, 0.0), 1.0)
                ex = cx - (ax + t * ux)
                ey = cy - (ay + t * uy)
                ez = cz - (az + t * uz)
                if ex * ex + ey * ey + ez * ez <= radii[c] * radii[c]:
                    own = True
                    break
            if own:
                continue
            used += 1
            for i in range(m):
                px = points[i, 0]
                py = points[i, 1]
                pz = points[i, 2]
                vx = min(max(px, lx), hx) - px
                vy = min(max(py, ly), hy) - py
                vz = min(max(pz, lz), hz) - pz
                d = math.sqrt(vx * vx + vy * vy + vz * vz)
                if d <= rho and d < out_distance[i]:
                    out_distance[i] = d
                    if d > 0.0:
                        out_direction[i, 0] = vx / d
                        out_direction[i, 1] = vy / d
                        out_direction[i, 2] = vz / d
                    else:
                        out_direction[i, 0] = 0.0
                        out_direction[i, 1] = 0.0
                        out_direction[i, 2] = 0.0
    return used


def voxel_nearest_numpy(points, centres, half, rho, segments, radii, out_distance, out_direction) -> None:
    """Plain-numpy twin of :func:`voxel_nearest` (tests only): the nearest point of every
    voxel box ``clip(p, c - h, c + h)``, voxels with their centre inside a capsule removed."""
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    Cn = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    if len(P) == 0 or len(Cn) == 0:
        return
    if len(radii):
        a, b = segments[:, 0], segments[:, 1]                         # (C, 3)
        u = b - a
        uu = np.einsum("cj,cj->c", u, u)
        t = np.einsum("ncj,cj->nc", Cn[:, None, :] - a[None], u) / np.where(uu > 0, uu, 1.0)
        t = np.where(uu > 0, np.clip(t, 0.0, 1.0), 0.0)
        e = Cn[:, None, :] - (a[None] + t[..., None] * u[None])
        own = np.any(np.einsum("ncj,ncj->nc", e, e) <= radii[None] ** 2, axis=1)
        Cn = Cn[~own]
    nearest = np.clip(P[:, None, :], Cn[None] - half, Cn[None] + half)   # (m, N, 3)
    v = nearest - P[:, None, :]
    d = np.sqrt(np.sum(v * v, axis=2))                                 # (m, N)
    d = np.where(d <= rho, d, np.inf)
    if d.shape[1] == 0:
        return
    j = np.argmin(d, axis=1)
    dj = d[np.arange(len(P)), j]
    take = dj < out_distance
    out_distance[take] = dj[take]
    vj = v[np.arange(len(P)), j]
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = np.where(dj[:, None] > 0, vj / dj[:, None], 0.0)
    out_direction[take] = unit[take]


class VoxelObstacles:
    """Thread-safe store of the newest voxel set of every remote camera unit (module docstring).

    ``push`` from any thread (the source's thread); ``nearest`` from the control thread.
    """

    def __init__(self):
        self._lock = threading.Lock()
        self._sets: dict[str, UnitVoxels] = {}
        self.pushed = 0

    # ------------------------------------------------------------ input
    def push(self, camera_id: str, centres, voxel_size: float, stamp: float) -> None:
        """Replace camera ``camera_id``'s voxels: centres (N, 3) world m of cubes of side
        ``voxel_size`` m, captured at ``stamp`` s (the monitor's clock). ``ValueError`` on a
        bad shape, a non-finite value or a voxel size <= 0 (the old set then stays)."""
        c = np.array(centres, dtype=np.float64, copy=True, order="C")
        if c.size == 0:
            c = c.reshape(0, 3)
        if c.ndim != 2 or c.shape[1] != 3:
            raise ValueError(f"camera {camera_id!r}: voxel centres must be (N, 3), got {c.shape}")
        if not np.all(np.isfinite(c)):
            raise ValueError(f"camera {camera_id!r}: voxel centres must be finite")
        s = float(voxel_size)
        if not (math.isfinite(s) and s > 0):
            raise ValueError(f"camera {camera_id!r}: voxel size must be > 0 m (got {voxel_size!r})")
        st = float(stamp)
        if not math.isfinite(st):
            raise ValueError(f"camera {camera_id!r}: stamp must be finite (got {stamp!r})")
        c, start, lo, hi = bucket(c, s)
        for a in (c, start, lo, hi):
            a.setflags(write=False)
        with self._lock:
            self._sets[str(camera_id)] = UnitVoxels(c, s, st, start, lo, hi)
            self.pushed += 1

    def remove(self, camera_id: str) -> None:
        """Forget a camera's voxels (a unit no longer monitored); no error when unknown."""
        with self._lock:
            self._sets.pop(camera_id, None)

    def clear(self) -> None:
        with self._lock:
            self._sets.clear()

    # ------------------------------------------------------------ state
    @property
    def camera_ids(self) -> tuple[str, ...]:
        with self._lock:
            return tuple(self._sets)

    def get(self, camera_id: str) -> UnitVoxels | None:
        """The camera's current set (read-only centres), or None."""
        with self._lock:
            return self._sets.get(camera_id)

    def stamps(self) -> dict[str, float]:
        """camera id -> capture stamp of its current set."""
        with self._lock:
            return {c: v.stamp for c, v in self._sets.items()}

    # ------------------------------------------------------------ query (control thread)
    def nearest(self, points, rho: float, out_distance: np.ndarray, out_direction: np.ndarray,
                robot_capsules=None) -> dict[str, float]:
        """Lower ``out_distance`` (m,) float64 in place to the distance from each point (m, 3)
        world m to the nearest voxel box of any camera, where that is below the current value
        and ``<= rho``; ``out_direction`` (m, 3) float64 becomes the unit vector towards that
        box's nearest point (zero inside a box). ``robot_capsules``: ``(segments (C, 2, 3),
        radii (C,))`` m, e.g. ``robot.collision_segments(q, padding)``; a voxel whose centre
        lies inside one is the robot's own and does not count. Returns camera id -> capture
        stamp of every set consulted (for staleness, R27), empty when no set was pushed."""
        P = points if (isinstance(points, np.ndarray) and points.dtype == np.float64
                       and points.flags.c_contiguous) else np.ascontiguousarray(points, dtype=np.float64)
        if P.ndim != 2 or P.shape[1] != 3:
            raise ValueError(f"points must be (m, 3), got {P.shape}")
        m = P.shape[0]
        if out_distance.shape != (m,) or out_direction.shape != (m, 3):
            raise ValueError(f"out_distance must be ({m},) and out_direction ({m}, 3), got "
                             f"{out_distance.shape} and {out_direction.shape}")
        if out_distance.dtype != np.float64 or out_direction.dtype != np.float64:
            raise ValueError("out_distance and out_direction must be float64")
        if robot_capsules is None:
            seg, rad = _NO_SEGMENTS, _NO_RADII
        else:
            seg, rad = robot_capsules
            seg = np.ascontiguousarray(seg, dtype=np.float64).reshape(-1, 2, 3)
            rad = np.ascontiguousarray(rad, dtype=np.float64).reshape(-1)
            if len(seg) != len(rad):
                raise ValueError(f"robot_capsules: {len(seg)} segments but {len(rad)} radii")
        with self._lock:
            sets = list(self._sets.items())
        rho = float(rho)
        for _, v in sets:
            voxel_nearest(P, v.centres, 0.5 * v.voxel_size, rho, seg, rad, out_distance, out_direction,
                          v.cell_start, v.cell_lo, v.cell_hi)
        return {c: v.stamp for c, v in sets}
