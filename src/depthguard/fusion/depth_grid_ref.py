"""Plain-numpy twins of the depth grid kernels (R10–R12), for the tests.

They read like the equations and go through :class:`~depthguard.camera.Camera`
for every projection (not through the compact ray tables), so they are an
independent path to the same answers:

* :func:`frame_state_numpy` — per-pixel free depth and kind (R9, R28).
* :func:`explicit_map_numpy` — the paper's explicit off-line table (R11): for
  every cell and every other camera, the pixels the cell projects onto and
  ``dstart`` (and ``dend``), from densely sampled points of the cell.
* :func:`grid_distances_numpy` — the on-line distance (R12), every cell of the
  region of surveillance at once, no walk and no pruning.
"""

from __future__ import annotations

import numpy as np

from depthguard.config import PRODUCT_INVALID, PRODUCT_METHOD, PRODUCT_ROBOT_OFFSET   # the product's defaults, defined once
from depthguard.camera import Camera, RETURN_LIMIT_FACTOR
from depthguard.distance.window import surveillance_window
from depthguard.fusion.depth_grid_kernels import D_ZERO, KIND_ROBOT, KIND_SURFACE, KIND_UNKNOWN

__all__ = ["frame_state_numpy", "explicit_map_numpy", "cell_corners_world",
           "cleared_numpy", "grid_distances_numpy"]


def frame_state_numpy(cam: Camera, depth, robot_depth=None, robot_offset=PRODUCT_ROBOT_OFFSET, invalid=PRODUCT_INVALID,
                      robot_free=False, silhouette_px=0, gap_px=0):
    """(free (H, W) float64, kind (H, W) int8) of one frame: free depth = ``do``
    (surface), ``dr`` (robot: ``measured >= dr - offset``), ``max_range`` (a finite return
    beyond it), ``min_range`` (invalid) — the last two ``inf`` with ``invalid="free"``.
    With ``invalid="unknown"``: ``silhouette_px > 0``: an invalid pixel within that many
    pixels of the robot's silhouette is a robot pixel free up to the smallest robot depth
    nearby (R32); else ``gap_px > 0``: an invalid pixel in a gap of at most ``gap_px`` is
    free up to the gap's nearer end."""
    d = np.asarray(depth, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(d) & (d > 0) & (d >= cam.min_range) & (d <= cam.max_range)
        beyond = np.isfinite(d) & (d > cam.max_range) & (d <= RETURN_LIMIT_FACTOR * cam.max_range)
    unknown = invalid == "unknown"
    free = np.where(valid, d, cam.min_range if unknown else np.inf)
    if unknown:
        free = np.where(beyond, cam.max_range, free)
    none = ~valid & ~beyond
    kind = np.where(valid, KIND_SURFACE, KIND_UNKNOWN).astype(np.int8)
    halo = np.zeros(d.shape, bool)
    if robot_depth is not None:
        dr = np.asarray(robot_depth, dtype=np.float64)
        robot = valid & (dr > 0) & (d >= dr - robot_offset)
        free = np.where(robot, np.inf if robot_free else dr, free)
        kind[robot] = KIND_ROBOT
        if silhouette_px > 0 and unknown:
            from depthguard.distance.silhouette import dilate_robot_depth_numpy

            drd = dilate_robot_depth_numpy(dr, silhouette_px)
            halo = none & (drd > 0)
            free = np.where(halo, drd, free)
            kind[halo] = KIND_ROBOT
    if gap_px > 0 and unknown:
        from depthguard.distance.gaps import gap_depth_numpy

        g = gap_depth_numpy(d, cam.min_range, cam.max_range, gap_px)
        free = np.where(none & ~halo & (g > 0), g, free)
    return free, kind


def cell_corners_world(principal: Camera, gx, gy, d1, d2) -> np.ndarray:
    """(..., 8, 3) world corners of the cells ``pixel (gx, gy) x [d1, d2]``
    (broadcast arrays): sub-pixel corners ``gx ± 1/2, gy ± 1/2`` at both depths."""
    gx, gy, d1, d2 = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (gx, gy, d1, d2)))
    ds = []
    for j in range(8):
        ds.append(np.stack([gx - 0.5 + (j & 1), gy - 0.5 + ((j >> 1) & 1),
                            d1 if (j >> 2) == 0 else d2], axis=-1))
    ds = np.stack(ds, axis=-2)
    return principal.depth_space_to_world(ds.reshape(-1, 3)).reshape(ds.shape)


def _footprints(cam: Camera, pts_world: np.ndarray):
    """Bounding pixel box, seen flag and z range of point sets (..., M, 3) in ``cam``."""
    shp = pts_world.shape[:-1]
    ds = cam.world_to_depth_space(pts_world.reshape(-1, 3)).reshape(shp + (3,))
    z = ds[..., 2]
    with np.errstate(invalid="ignore"):
        seen = np.all((z >= cam.min_range) & (z <= cam.max_range), axis=-1)
        pu, pv = ds[..., 0], ds[..., 1]
        seen &= (np.nanmin(pu, -1) >= -0.5) & (np.nanmax(pu, -1) < cam.width - 0.5)
        seen &= (np.nanmin(pv, -1) >= -0.5) & (np.nanmax(pv, -1) < cam.height - 0.5)
        u0 = np.floor(np.nanmin(pu, -1) + 0.5)
        u1 = np.floor(np.nanmax(pu, -1) + 0.5)
        v0 = np.floor(np.nanmin(pv, -1) + 0.5)
        v1 = np.floor(np.nanmax(pv, -1) + 0.5)
    box = [np.where(seen, b, 0).astype(np.int64) for b in (u0, u1, v0, v1)]
    box[1] = np.where(seen, box[1], -1)
    box[3] = np.where(seen, box[3], -1)
    return seen, box, z.min(-1), z.max(-1)


def explicit_map_numpy(principal: Camera, others: list[Camera], d_min: float, delta_d: float,
                       n_d: int, samples: int = 4) -> dict:
    """The explicit off-line map (R11) of a (small) grid, from sampled cell points.

    Each cell is sampled on a ``(samples+1)^3`` lattice spanning it (its 8
    corners included) and the samples are projected with ``cam.world_to_depth_space``.

    Returns ``{camera id: {"seen": (H, W, n_d) bool, "box": (H, W, n_d, 4) int
    u0, u1, v0, v1, "dstart": (H, W, n_d), "dend": (H, W, n_d),
    "pixels": list of (M, 2) int arrays [u, v], row-major over (gy, gx, gd)}}``;
    "pixels" lists, for each cell ``k`` sees whole, every pixel hit by a sample
    or lying between hits (the bounding box of the projected cell).
    """
    H, W = principal.height, principal.width
    t = np.linspace(0.0, 1.0, samples + 1)
    gy, gx, gd = np.meshgrid(np.arange(H), np.arange(W), np.arange(n_d), indexing="ij")
    a, b, c = np.meshgrid(t, t, t, indexing="ij")
    a, b, c = a.ravel(), b.ravel(), c.ravel()
    ds = np.stack([gx[..., None] - 0.5 + a, gy[..., None] - 0.5 + b,
                   d_min + (gd[..., None] + c) * delta_d], axis=-1)
    pts = principal.depth_space_to_world(ds.reshape(-1, 3)).reshape(ds.shape)
    out = {}
    for cam in others:
        seen, (u0, u1, v0, v1), zmin, zmax = _footprints(cam, pts)
        pixels = []
        for s, a0, a1, b0, b1 in zip(seen.ravel(), u0.ravel(), u1.ravel(), v0.ravel(), v1.ravel()):
            if not s:
                pixels.append(np.zeros((0, 2), dtype=np.int64))
                continue
            uu, vv = np.meshgrid(np.arange(a0, a1 + 1), np.arange(b0, b1 + 1))
            pixels.append(np.stack([uu.ravel(), vv.ravel()], axis=1))
        out[cam.id] = {"seen": seen, "box": np.stack([u0, u1, v0, v1], axis=-1),
                       "dstart": zmin, "dend": zmax, "pixels": pixels}
    return out


def cleared_numpy(principal: Camera, others: list[Camera], kfree: list[np.ndarray],
                  gx, gy, d1, d2) -> np.ndarray:
    """(...) bool: some other camera sees the cell whole and every pixel of its
    footprint has free depth ``> dend`` (the rule of
    :mod:`depthguard.fusion.depth_grid_kernels`)."""
    corners = cell_corners_world(principal, gx, gy, d1, d2)
    out = np.zeros(corners.shape[:-2], dtype=bool)
    for cam, free in zip(others, kfree):
        seen, (u0, u1, v0, v1), _, zmax = _footprints(cam, corners)
        ok = seen.copy()
        wmax = int((u1 - u0).max(initial=0)) + 1
        hmax = int((v1 - v0).max(initial=0)) + 1
        for dv in range(hmax):
            for du in range(wmax):
                u = u0 + du
                v = v0 + dv
                inside = seen & (u <= u1) & (v <= v1)
                val = free[np.where(inside, v, 0), np.where(inside, u, 0)]
                ok &= ~inside | (val > zmax)
        out |= ok
    return out


def grid_distances_numpy(principal: Camera, others: list[Camera], pfree, pkind, kfree,
                         d_min: float, delta_d: float, n_d: int, points, rho: float,
                         method: str = PRODUCT_METHOD, capsules=None):
    """Twin of :func:`~depthguard.fusion.depth_grid_lookup.grid_distances` (R10–R12).

    Every cell ``(u, v, gd)`` of the region of surveillance with
    ``gd`` in ``r(dp - rho) .. r(dp + rho)`` is classified at once:

    * case 1: ``free[v, u] > dp + rho`` — ignored;
    * the measured surface cell ``gd == r(do)`` of a surface pixel — obstacle;
    * a gray cell (behind the surface, or from ``r(dr)`` / ``r(min_range)`` on
      for a robot / invalid pixel) — obstacle unless another camera clears it
      (outside the grid: never cleared);
    * cells whose centre lies inside a padded robot capsule (``Capsule.sdf``) — never.

    Per pixel the nearest obstacle cell by the R10 distance (R3, R10, R5),
    then R7 over the pixels with ``D <= rho``.
    Returns ``(distance (N,), direction (N, 3) world, observed (N,), count (N,))``.
    """
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    N = len(P)
    dist = np.full(N, np.inf)
    direc = np.zeros((N, 3))
    count = np.zeros(N, dtype=np.int64)
    observed = principal.in_view(P)
    fx, fy, cx, cy = principal.fx, principal.fy, principal.cx, principal.cy
    pc = principal.world_to_camera(P)
    ds = principal.world_to_depth_space(P)
    for i in range(N):
        px, py, dp = ds[i]
        if not dp > 0:
            observed[i] = False
            continue
        u0, u1, v0, v1 = surveillance_window(pc[i, 0], pc[i, 1], dp, rho, fx, fy, cx, cy,
                                             principal.min_range, principal.width, principal.height)
        if u0 > u1 or v0 > v1:
            continue
        g0 = int(np.floor((dp - rho - d_min) / delta_d))
        g1 = int(np.floor((dp + rho - d_min) / delta_d))
        V, U, G = np.meshgrid(np.arange(v0, v1 + 1), np.arange(u0, u1 + 1), np.arange(g0, g1 + 1),
                              indexing="ij")
        df = pfree[V, U]
        kind = pkind[V, U]
        d1 = d_min + G * delta_d
        d2 = d1 + delta_d
        od = np.clip(dp, d1, d2)                                   # R10
        ox = np.clip(px, U - 0.5, U + 0.5)                         # R3
        oy = np.clip(py, V - 0.5, V + 0.5)
        vx = ((ox - cx) * od - (px - cx) * dp) / fx                # R5
        vy = ((oy - cy) * od - (py - cy) * dp) / fy
        vz = od - dp
        f = np.sqrt(vx * vx + vy * vy + vz * vz)
        gs = np.floor((df - d_min) / delta_d)
        case1 = df > dp + rho
        direct = (kind == KIND_SURFACE) & (G == gs)
        gray = (G > gs) | ((G == gs) & (kind != KIND_SURFACE))
        cand = ~case1 & (direct | gray) & (f <= rho)
        ingrid = (G >= 0) & (G < n_d)
        check = cand & gray & ingrid
        cleared = np.zeros_like(cand)
        if others and check.any():
            # the cell's far boundary as its next cell's near one (the kernels' float)
            cleared[check] = cleared_numpy(principal, others, kfree, U[check], V[check],
                                           d1[check], (d_min + (G + 1) * delta_d)[check])
        obst = cand & (direct | ~cleared)
        if capsules and obst.any():
            centres = principal.depth_space_to_world(
                np.stack([U[obst], V[obst], 0.5 * (d1[obst] + d2[obst])], axis=1).astype(np.float64))
            inside = np.zeros(len(centres), dtype=bool)
            for cap in capsules:
                inside |= cap.sdf(centres) <= 0.0
            obst[obst] = ~inside
        fo = np.where(obst, f, np.inf)
        gi = np.argmin(fo, axis=2)                                 # nearest cell per pixel
        fcol = np.take_along_axis(fo, gi[..., None], 2)[..., 0].ravel()
        vcol = np.stack([np.take_along_axis(a, gi[..., None], 2)[..., 0].ravel() for a in (vx, vy, vz)], 1)
        hit = np.isfinite(fcol)
        if not hit.any():
            continue
        Dh, Vh = fcol[hit], vcol[hit]
        Dh = np.where(Dh <= D_ZERO, 0.0, Dh)               # rounding noise: no direction
        if method == "min":
            j = int(np.argmin(Dh))
            dist[i], count[i] = Dh[j], 1
            v = Vh[j] / Dh[j] if Dh[j] > 0 else np.zeros(3)
        else:
            count[i] = len(Dh)
            dist[i] = Dh.mean() if method == "mean" else Dh.min()
            pos = Dh > 0
            s = (Vh[pos] / Dh[pos, None]).sum(0)
            nrm = np.linalg.norm(s)
            v = s / nrm if nrm > 0 else np.zeros(3)
        direc[i] = principal.R.T @ v
    return dist, direc, observed, count
