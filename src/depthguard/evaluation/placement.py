"""Sensor placement check and improver (Hamersma 2011 §3.3, R23).

On the empty scene (only the static room), a voxel of the space of interest
*passes* when at least ``min_views`` (3) cameras see it — its centre in the
image and in range, not hidden by a static object — and three of them are
pairwise at least ``min_separation`` (100°) apart in the horizontal plane,
measured as the azimuth of the camera's position seen from the voxel. The
paper's argument: to hide a voxel from all three, three objects must each
block another line of sight.

Three angles on a circle are pairwise >= 100° apart exactly when the three
arcs between them are each >= 100° (their sum is 360°, so none exceeds 160°).

- :func:`visibility` — (C, N) which camera sees which voxel centre;
- :func:`passes_criterion` — (N,) the criterion (numba kernel; numpy twin
  :func:`passes_criterion_numpy` enumerates every triple);
- :func:`share_vs_cameras` — the share passing as cameras are added (fig. 4);
- :func:`candidate_cameras` / :func:`greedy_placement` — cameras along the
  walls and the ceiling, added greedily (then pruned) until the share reaches
  a target.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numba as nb
import numpy as np

from depthguard.camera import Camera
from depthguard.transforms import look_at

__all__ = ["visibility", "azimuths", "passes_criterion", "passes_criterion_numpy",
           "share_vs_cameras", "candidate_cameras", "greedy_placement", "PlacementResult"]


def visibility(cameras, points: np.ndarray, static_meshes=(), tol: float = 1e-3) -> np.ndarray:
    """(C, N) bool: camera ``c`` sees world point ``n`` on the empty scene.

    In view (image, ``[min_range, max_range]``) and not behind a static surface:
    the point's depth is below the rendered depth of ``static_meshes`` at its
    pixel minus ``tol`` metres (or nothing is rendered there).
    """
    from depthguard.render import render_depth

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.zeros((len(cameras), len(pts)), dtype=bool)
    meshes = list(static_meshes)
    for ci, cam in enumerate(cameras):
        ok = cam.in_view(pts)
        if meshes and ok.any():
            ds = cam.world_to_depth_space(pts[ok])
            u, v = cam.pixel_of(ds[:, 0], ds[:, 1])
            rd = render_depth(cam, meshes)[v, u]
            ok[np.flatnonzero(ok)] = (rd <= 0) | (ds[:, 2] < rd - tol)
        out[ci] = ok
    return out


def azimuths(cameras, points: np.ndarray) -> np.ndarray:
    """(C, N) radians: horizontal angle of each camera's position seen from each point."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pos = np.stack([c.position for c in cameras])
    dx = pos[:, None, 0] - pts[None, :, 0]
    dy = pos[:, None, 1] - pts[None, :, 1]
    return np.arctan2(dy, dx)


@nb.njit(cache=True, inline="always")
def _sep(a, b):
    d = abs(a - b) % (2.0 * math.pi)
    return min(d, 2.0 * math.pi - d)


@nb.njit(cache=True, parallel=True)
def _passes_kernel(seen, az, min_views, min_sep, out):
    C, N = seen.shape
    for n in nb.prange(N):
        k = 0
        for c in range(C):
            if seen[c, n]:
                k += 1
        ok = False
        if k >= min_views:
            if min_views < 3:
                ok = True
            else:
                for i in range(C):
                    if ok:
                        break
                    if not seen[i, n]:
                        continue
                    for j in range(i + 1, C):
                        if ok:
                            break
                        if not seen[j, n] or _sep(az[i, n], az[j, n]) < min_sep:
                            continue
                        for m in range(j + 1, C):
                            if seen[m, n] and _sep(az[i, n], az[m, n]) >= min_sep \
                                    and _sep(az[j, n], az[m, n]) >= min_sep:
                                ok = True
                                break
        out[n] = ok


@nb.njit(cache=True, parallel=True)
def _gain_kernel(seen, az, chosen, passing, cand, min_sep, out):
    """For each candidate camera: how many voxels not yet passing would pass with it added
    (a new passing triple must contain the candidate and two chosen cameras)."""
    K = chosen.shape[0]
    N = seen.shape[1]
    for ci in nb.prange(cand.shape[0]):
        c = cand[ci]
        g = 0
        for n in range(N):
            if passing[n] or not seen[c, n]:
                continue
            hit = False
            for a in range(K):
                i = chosen[a]
                if not seen[i, n] or _sep(az[i, n], az[c, n]) < min_sep:
                    continue
                for b in range(a + 1, K):
                    j = chosen[b]
                    if seen[j, n] and _sep(az[j, n], az[c, n]) >= min_sep and _sep(az[i, n], az[j, n]) >= min_sep:
                        hit = True
                        break
                if hit:
                    break
            if hit:
                g += 1
        out[ci] = g


def passes_criterion(seen: np.ndarray, az: np.ndarray, min_views: int = 3,
                     min_separation_deg: float = 100.0) -> np.ndarray:
    """R23: (N,) bool — at least ``min_views`` cameras see the voxel and (for 3 or more)
    three of them are pairwise ``>= min_separation_deg`` apart in azimuth.

    ``seen`` (C, N) bool from :func:`visibility`; ``az`` (C, N) radians from :func:`azimuths`.
    """
    seen = np.ascontiguousarray(seen, dtype=np.bool_)
    az = np.ascontiguousarray(az, dtype=np.float64)
    if seen.shape != az.shape or seen.ndim != 2:
        raise ValueError(f"seen and az must both be (C, N), got {seen.shape} and {az.shape}")
    out = np.empty(seen.shape[1], dtype=np.bool_)
    # a triple can only be exhibited if it exists; min_sep compared with a hair of slack
    _passes_kernel(seen, az, int(min_views), math.radians(min_separation_deg) - 1e-12, out)
    return out


def passes_criterion_numpy(seen: np.ndarray, az: np.ndarray, min_views: int = 3,
                           min_separation_deg: float = 100.0) -> np.ndarray:
    """Numpy twin: try every triple of cameras (vectorised over voxels)."""
    C, N = seen.shape
    enough = seen.sum(axis=0) >= min_views
    if min_views < 3:
        return enough
    lim = math.radians(min_separation_deg) - 1e-12

    def sep(a, b):
        d = np.abs(a - b) % (2 * np.pi)
        return np.minimum(d, 2 * np.pi - d)

    ok = np.zeros(N, dtype=bool)
    for i, j, m in itertools.combinations(range(C), 3):
        ok |= (seen[i] & seen[j] & seen[m] & (sep(az[i], az[j]) >= lim)
               & (sep(az[i], az[m]) >= lim) & (sep(az[j], az[m]) >= lim))
    return ok & enough


def share_vs_cameras(seen: np.ndarray, az: np.ndarray, order, **kw) -> np.ndarray:
    """(len(order),) share of voxels passing with the first 1, 2, ... cameras of ``order``."""
    order = list(order)
    out = np.empty(len(order))
    for n in range(1, len(order) + 1):
        idx = order[:n]
        out[n - 1] = passes_criterion(seen[idx], az[idx], **kw).mean()
    return out


def candidate_cameras(room_lo, room_hi, target, template: Camera, spacing: float = 0.5,
                      wall_height: float | None = None, inset: float = 0.05,
                      ceiling: bool = True, rings=None) -> list[Camera]:
    """Candidate cameras on the walls and the ceiling.

    Walls: one ring of positions every ``spacing`` m along the perimeter at
    ``wall_height`` (default: just under the ceiling) looking at ``target`` (3,), or
    several rings given as ``rings=[(height, target), ...]``. Ceiling: a grid
    ``spacing`` m apart looking at ``target``. Intrinsics and range from ``template``.
    ``room_lo``/``room_hi`` are the inner faces of the walls, floor and ceiling;
    cameras sit ``inset`` m inside them.
    """
    lo = np.asarray(room_lo, float) + inset
    hi = np.asarray(room_hi, float) - inset
    target = np.asarray(target, float)
    if rings is None:
        rings = [(hi[2] if wall_height is None else float(wall_height), target)]
    poses = []
    for zc, tgt in rings:
        tgt = np.asarray(tgt, float)
        if not (lo[2] <= zc <= hi[2]):
            raise ValueError(f"wall ring height {zc} m lies outside the room [{lo[2]:.2f}, {hi[2]:.2f}]")
        for x in np.arange(lo[0], hi[0] + 1e-9, spacing):
            poses += [((x, lo[1], zc), tgt), ((x, hi[1], zc), tgt)]
        for y in np.arange(lo[1] + spacing, hi[1] - spacing + 1e-9, spacing):
            poses += [((lo[0], y, zc), tgt), ((hi[0], y, zc), tgt)]
    if ceiling:
        for x in np.arange(lo[0] + spacing, hi[0] - spacing + 1e-9, spacing):
            for y in np.arange(lo[1] + spacing, hi[1] - spacing + 1e-9, spacing):
                poses.append(((x, y, hi[2]), target))
    cams = []
    for k, (e, tgt) in enumerate(poses):
        e = np.asarray(e, float)
        if np.linalg.norm((tgt - e)[:2]) < 1e-6:  # straight down: any heading will do
            T = look_at(e, tgt, up=(0.0, 1.0, 0.0))
        else:
            T = look_at(e, tgt)
        cams.append(Camera(f"cand{k:03d}", template.width, template.height, template.fx, template.fy,
                           template.cx, template.cy, T, template.min_range, template.max_range,
                           template.sensor))
    return cams


@dataclass
class PlacementResult:
    chosen: list[int]                 # indices into the candidates, in the order added
    share: list[float]                # share passing after each addition
    final_share: float
    cameras: list[Camera] = field(default_factory=list)


def greedy_placement(seen: np.ndarray, az: np.ndarray, candidates, target_share: float = 1.0,
                     max_cameras: int = 40, prune: bool = True, start=(), min_views: int = 3,
                     min_separation_deg: float = 100.0) -> PlacementResult:
    """Greedy improver (R23): add the candidate that makes most voxels pass (ties, and
    while fewer than three cameras are placed: the one bringing most voxels closer to
    three views) until ``target_share`` is reached, then drop any camera whose removal
    keeps the share at the target. ``start``: indices already placed."""
    kw = dict(min_views=min_views, min_separation_deg=min_separation_deg)
    seen = np.ascontiguousarray(seen, dtype=np.bool_)
    az = np.ascontiguousarray(az, dtype=np.float64)
    C, N = seen.shape
    chosen = list(start)
    share = []
    passing = passes_criterion(seen[chosen], az[chosen], **kw) if chosen else np.zeros(N, bool)
    best_share = float(passing.mean())
    lim = math.radians(min_separation_deg) - 1e-12
    gains = np.zeros(C, dtype=np.int64)
    while best_share < target_share - 1e-12 and len(chosen) < max_cameras:
        cand = np.array([c for c in range(C) if c not in chosen], dtype=np.int64)
        if not len(cand):
            break
        nviews = seen[chosen].sum(axis=0) if chosen else np.zeros(N, dtype=np.int64)
        progress = (np.minimum(nviews[None, :] + seen[cand], 3)).sum(axis=1)
        if len(chosen) >= 2:
            _gain_kernel(seen, az, np.asarray(chosen, dtype=np.int64), passing, cand, lim, gains[:len(cand)])
            g = gains[:len(cand)]
        else:
            g = np.zeros(len(cand), dtype=np.int64)
        best = max(range(len(cand)), key=lambda k: (g[k], progress[k]))
        chosen.append(int(cand[best]))
        passing = passes_criterion(seen[chosen], az[chosen], **kw)
        best_share = float(passing.mean())
        share.append(best_share)
    if prune and best_share >= target_share - 1e-12:
        for c in list(chosen)[::-1]:
            idx = [x for x in chosen if x != c]
            if idx and passes_criterion(seen[idx], az[idx], **kw).mean() >= target_share - 1e-12:
                chosen = idx
        best_share = float(passes_criterion(seen[chosen], az[chosen], **kw).mean())
    return PlacementResult(chosen, share, best_share, [candidates[i] for i in chosen])
