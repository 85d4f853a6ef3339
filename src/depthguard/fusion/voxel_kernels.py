"""Kernels of the per-camera voxel filter (R17–R19) and of multi-camera voting.

Each numba kernel has a plain-numpy twin named ``<kernel>_numpy`` that reads
like the equations and that the tests compare against; the twins are not used
in production paths. The twins back-project through
:meth:`depthguard.camera.Camera.depth_to_points` (the one depth→points path);
the fused kernel repeats equation (3) inline only for speed.

Conventions
-----------
* depth, expected : (H, W) float32 metres; measured 0 / NaN / out of
  ``[min_range, max_range]`` = invalid; expected 0 = nothing known there.
* keep rule (R17): ``d < e − (offset_const + offset_k·e²)`` where ``e > 0``;
  any valid ``d`` where ``e == 0``.
* voxel key (R18): ``k = floor(p / s)`` (int), world point ``p`` cropped to
  the workspace ``lo ≤ p < hi``; voxel ``k`` spans ``[k·s, (k+1)·s)``.
* density (R19): ``n_max(d) = (atan(s/d)/(hfov/W)) · (atan(s/d)/(vfov/H))``
  with ``d`` the distance from the optical centre to the voxel centre; a voxel
  with ``count < threshold · n_max`` is noise.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from depthguard.distance.window import grow_pixel_box

__all__ = [
    "filter_voxelize", "filter_voxelize_numpy", "keep_mask_numpy", "combine_expected_numpy", "density_max_count",
    "vote_free", "vote_free_numpy",
]


@nb.njit(cache=True, nogil=True)
def filter_voxelize(depth, expected, robot_depth, fx, fy, cx, cy, Rwc, twc, min_range, max_range,
                    offset_const, offset_k, key_lo, dims, voxel_size, lo, hi,
                    cam_pos, ang_u, ang_v, threshold,
                    grid, touched, out_keys, out_counts):
    """Fused R17 → R18 → R19 for one camera; no allocation.

    Parameters
    ----------
    depth, expected : (H, W) float32, metres (expected: the static CAD, 0 = nothing).
    robot_depth : (H, W) float32 rendered robot (0 = nothing); the expected depth of a pixel
        is the nearer of the two (R16) — fused here to save a pass over the image.
    fx, fy, cx, cy : intrinsics (pixels).  Rwc (3, 3), twc (3,): world_from_camera.
    min_range, max_range : valid measured range (m).
    offset_const, offset_k : keep offset ``offset_const + offset_k·e²`` (m, 1/m).
    key_lo : (3,) int64 key of the workspace's lowest voxel; dims (3,) int64 grid size.
    voxel_size : s (m). lo, hi : (3,) workspace box (m); kept points satisfy lo ≤ p < hi.
    cam_pos : (3,) optical centre (m). ang_u, ang_v : hfov/W, vfov/H (rad per pixel).
    threshold : R19 density threshold (fraction of n_max).
    grid : (prod(dims),) int32 workspace, all zero on entry and on exit.
    touched : (≥ H·W,) int64 scratch. out_keys : (≥ H·W, 3) int32; out_counts (≥ H·W,) int32.

    Returns
    -------
    (n_out, n_kept_pixels, n_invalid) — the first ``n_out`` rows of the outputs are
    the surviving voxels in order of first appearance (row-major pixel scan).
    """
    H, W = depth.shape
    ny = dims[1]
    nz = dims[2]
    nt = 0
    n_kept = 0
    n_invalid = 0
    for v in range(H):
        for u in range(W):
            d = np.float64(depth[v, u])
            if not (d >= min_range and d <= max_range):   # also rejects NaN
                n_invalid += 1
                continue
            e = np.float64(expected[v, u])
            r = np.float64(robot_depth[v, u])
            if r > 0.0 and (e <= 0.0 or r < e):
                e = r
            if e > 0.0 and not (d < e - (offset_const + offset_k * e * e)):
                continue
            n_kept += 1
            xc = (u - cx) * d / fx
            yc = (v - cy) * d / fy                  # same operation order as Camera.depth_to_points
            px = Rwc[0, 0] * xc + Rwc[0, 1] * yc + Rwc[0, 2] * d + twc[0]
            py = Rwc[1, 0] * xc + Rwc[1, 1] * yc + Rwc[1, 2] * d + twc[1]
            pz = Rwc[2, 0] * xc + Rwc[2, 1] * yc + Rwc[2, 2] * d + twc[2]
            if not (px >= lo[0] and px < hi[0] and py >= lo[1] and py < hi[1]
                    and pz >= lo[2] and pz < hi[2]):
                continue
            ix = np.int64(math.floor(px / voxel_size)) - key_lo[0]
            iy = np.int64(math.floor(py / voxel_size)) - key_lo[1]
            iz = np.int64(math.floor(pz / voxel_size)) - key_lo[2]
            if ix < 0 or iy < 0 or iz < 0 or ix >= dims[0] or iy >= ny or iz >= nz:
                continue
            flat = (ix * ny + iy) * nz + iz
            if grid[flat] == 0:
                touched[nt] = flat
                nt += 1
            grid[flat] += 1
    n_out = 0
    for i in range(nt):
        flat = touched[i]
        count = grid[flat]
        grid[flat] = 0
        iz = flat % nz
        iy = (flat // nz) % ny
        ix = flat // (ny * nz)
        kx = ix + key_lo[0]
        ky = iy + key_lo[1]
        kz = iz + key_lo[2]
        dx = (kx + 0.5) * voxel_size - cam_pos[0]
        dy = (ky + 0.5) * voxel_size - cam_pos[1]
        dz = (kz + 0.5) * voxel_size - cam_pos[2]
        dist = math.sqrt(dx * dx + dy * dy + dz * dz)
        alpha = math.atan(voxel_size / dist) if dist > 0.0 else 0.5 * math.pi
        n_max = (alpha / ang_u) * (alpha / ang_v)
        if count < threshold * n_max:
            continue
        out_keys[n_out, 0] = kx
        out_keys[n_out, 1] = ky
        out_keys[n_out, 2] = kz
        out_counts[n_out] = count
        n_out += 1
    return n_out, n_kept, n_invalid


def combine_expected_numpy(static, robot):
    """(H, W) expected depth: the nearer of static CAD and robot where either is known (R16)."""
    st = np.asarray(static, dtype=np.float32)
    rd = np.asarray(robot, dtype=np.float32)
    return np.where((rd > 0) & ((st <= 0) | (rd < st)), rd, st)


def keep_mask_numpy(cam, depth, expected, offset_const, offset_k):
    """(H, W) bool: valid measured pixels in front of the expected depth by the offset (R17)."""
    d = np.asarray(depth, dtype=np.float64)
    e = np.asarray(expected, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(d) & (d >= cam.min_range) & (d <= cam.max_range)
        in_front = d < e - (offset_const + offset_k * e ** 2)
    return valid & ((e <= 0) | in_front)


def density_max_count(cam, keys, voxel_size):
    """(N,) R19: ``n_max = (atan(s/d)/(hfov/W))·(atan(s/d)/(vfov/H))``, d = centre distance."""
    centres = (np.asarray(keys, dtype=np.float64) + 0.5) * voxel_size
    dist = np.linalg.norm(centres - cam.position, axis=1)
    alpha = np.arctan2(voxel_size, dist)
    return (alpha / (cam.hfov / cam.width)) * (alpha / (cam.vfov / cam.height))


def filter_voxelize_numpy(cam, depth, expected, offset_const, offset_k, lo, hi,
                          voxel_size, threshold):
    """Plain-numpy twin of :func:`filter_voxelize`: keys (N, 3) int64 sorted, counts (N,)."""
    keep = keep_mask_numpy(cam, depth, expected, offset_const, offset_k)
    p = cam.depth_to_points(np.asarray(depth, dtype=np.float32), frame="world", mask=keep)
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    p = p[np.all((p >= lo) & (p < hi), axis=1)]
    keys = np.floor(p / voxel_size).astype(np.int64)
    if len(keys) == 0:
        return np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
    keys, counts = np.unique(keys, axis=0, return_counts=True)
    ok = counts >= threshold * density_max_count(cam, keys, voxel_size)
    return keys[ok], counts[ok]


@nb.njit(cache=True, nogil=True)
def _to_cam(cams, c, x, y, z):
    xc = cams[c, 8] * x + cams[c, 9] * y + cams[c, 10] * z + cams[c, 17]
    yc = cams[c, 11] * x + cams[c, 12] * y + cams[c, 13] * z + cams[c, 18]
    zc = cams[c, 14] * x + cams[c, 15] * y + cams[c, 16] * z + cams[c, 19]
    return xc, yc, zc


@nb.njit(cache=True, nogil=True)
def vote_free(lows, voxel_size, depths, cams, margin, footprint, out_free):
    """Multi-camera voting: which cameras see through each voxel.

    Parameters
    ----------
    lows : (N, 3) float64 lowest corners of the voxels (world, m); voxel_size s (m).
    depths : (C, Hmax, Wmax) float32 measured images (padded; invalid = 0).
    cams : (C, 20) float64 rows ``[fx, fy, cx, cy, W, H, min_range, max_range,
        R (9, camera_from_world row-major), t (3)]``.
    margin : (N,) float64 (m).
    footprint : False — *centre* rule: camera c sees voxel i through when its valid
        measured depth at the pixel of the centre exceeds the centre's depth + margin[i];
        True — *footprint* rule: every pixel of the bounding box of the projected 8
        corners lies in the image and measures beyond the farthest corner + margin[i].
    out_free : (N, C) bool, written.
    """
    N = lows.shape[0]
    C = cams.shape[0]
    for i in range(N):
        for c in range(C):
            out_free[i, c] = False
            fx = cams[c, 0]
            fy = cams[c, 1]
            cx = cams[c, 2]
            cy = cams[c, 3]
            if not footprint:
                h = 0.5 * voxel_size
                x, y, z = _to_cam(cams, c, lows[i, 0] + h, lows[i, 1] + h, lows[i, 2] + h)
                if z <= 0.0:
                    continue
                u = math.floor(x * fx / z + cx + 0.5)
                v = math.floor(y * fy / z + cy + 0.5)
                if u < 0 or v < 0 or u >= cams[c, 4] or v >= cams[c, 5]:
                    continue
                d = depths[c, int(v), int(u)]
                if d >= cams[c, 6] and d <= cams[c, 7] and d > z + margin[i]:
                    out_free[i, c] = True
                continue
            umin = 1e18
            umax = -1e18
            vmin = 1e18
            vmax = -1e18
            zmax = 0.0
            behind = False
            for corner in range(8):
                x, y, z = _to_cam(cams, c, lows[i, 0] + voxel_size * (corner & 1),
                                  lows[i, 1] + voxel_size * ((corner >> 1) & 1),
                                  lows[i, 2] + voxel_size * ((corner >> 2) & 1))
                if z <= 0.0:
                    behind = True
                    break
                umin, umax, vmin, vmax = grow_pixel_box(x, y, z, fx, fy, cx, cy, umin, umax, vmin, vmax)
                zmax = max(zmax, z)
            if behind:
                continue
            u0 = math.floor(umin + 0.5)
            u1 = math.floor(umax + 0.5)
            v0 = math.floor(vmin + 0.5)
            v1 = math.floor(vmax + 0.5)
            if u0 < 0 or v0 < 0 or u1 >= cams[c, 4] or v1 >= cams[c, 5]:
                continue
            free = True
            lim = zmax + margin[i]
            for v in range(int(v0), int(v1) + 1):
                for u in range(int(u0), int(u1) + 1):
                    d = depths[c, v, u]
                    if not (d >= cams[c, 6] and d <= cams[c, 7] and d > lim):
                        free = False
                        break
                if not free:
                    break
            out_free[i, c] = free


def vote_free_numpy(cameras, depths, lows, voxel_size, margin, footprint=False):
    """Twin of :func:`vote_free`: (N, C) bool, camera c sees through voxel i."""
    lows = np.asarray(lows, dtype=np.float64)
    N = len(lows)
    out = np.zeros((N, len(cameras)), dtype=bool)
    corners = np.array([[(k >> a) & 1 for a in range(3)] for k in range(8)], dtype=np.float64)
    for c, cam in enumerate(cameras):
        img = np.asarray(depths[c], dtype=np.float64)
        valid_img = np.isfinite(img) & (img >= cam.min_range) & (img <= cam.max_range)
        if not footprint:
            ds = cam.world_to_depth_space(lows + voxel_size / 2)
            with np.errstate(invalid="ignore"):
                u, v = cam.pixel_of(np.nan_to_num(ds[:, 0], nan=-1.0), np.nan_to_num(ds[:, 1], nan=-1.0))
                inside = (ds[:, 2] > 0) & (u >= 0) & (v >= 0) & (u < cam.width) & (v < cam.height)
            for i in np.nonzero(inside)[0]:
                out[i, c] = valid_img[v[i], u[i]] and img[v[i], u[i]] > ds[i, 2] + margin[i]
            continue
        for i in range(N):
            ds = cam.world_to_depth_space(lows[i] + voxel_size * corners)      # (8, 3)
            if np.any(ds[:, 2] <= 0):
                continue
            u, v = cam.pixel_of(ds[:, 0], ds[:, 1])
            if u.min() < 0 or v.min() < 0 or u.max() >= cam.width or v.max() >= cam.height:
                continue
            win = (slice(v.min(), v.max() + 1), slice(u.min(), u.max() + 1))
            out[i, c] = bool(np.all(valid_img[win] & (img[win] > ds[:, 2].max() + margin[i])))
    return out
