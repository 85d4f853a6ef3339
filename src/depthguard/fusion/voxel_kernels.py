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

__all__ = [
    "filter_voxelize", "filter_voxelize_numpy", "keep_mask_numpy", "density_max_count",
    "vote_free", "vote_free_numpy",
]


@nb.njit(cache=True, nogil=True)
def filter_voxelize(depth, expected, fx, fy, cx, cy, Rwc, twc, min_range, max_range,
                    offset_const, offset_k, key_lo, dims, voxel_size, lo, hi,
                    cam_pos, ang_u, ang_v, threshold,
                    grid, touched, out_keys, out_counts):
    """Fused R17 → R18 → R19 for one camera; no allocation.

    Parameters
    ----------
    depth, expected : (H, W) float32, metres.
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
    inv_s = 1.0 / voxel_size
    nt = 0
    n_kept = 0
    n_invalid = 0
    for v in range(H):
        yv = (v - cy) / fy
        for u in range(W):
            d = np.float64(depth[v, u])
            if not (d >= min_range and d <= max_range):   # also rejects NaN
                n_invalid += 1
                continue
            e = np.float64(expected[v, u])
            if e > 0.0 and not (d < e - (offset_const + offset_k * e * e)):
                continue
            n_kept += 1
            xc = (u - cx) * d / fx
            yc = yv * d
            px = Rwc[0, 0] * xc + Rwc[0, 1] * yc + Rwc[0, 2] * d + twc[0]
            py = Rwc[1, 0] * xc + Rwc[1, 1] * yc + Rwc[1, 2] * d + twc[1]
            pz = Rwc[2, 0] * xc + Rwc[2, 1] * yc + Rwc[2, 2] * d + twc[2]
            if not (px >= lo[0] and px < hi[0] and py >= lo[1] and py < hi[1]
                    and pz >= lo[2] and pz < hi[2]):
                continue
            ix = np.int64(math.floor(px * inv_s)) - key_lo[0]
            iy = np.int64(math.floor(py * inv_s)) - key_lo[1]
            iz = np.int64(math.floor(pz * inv_s)) - key_lo[2]
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
def vote_free(centres, depths, cams, margin, out_free):
    """Multi-camera voting: for each voxel centre, how many cameras see through it.

    Parameters
    ----------
    centres : (N, 3) float64 voxel centres (world, m).
    depths : (C, Hmax, Wmax) float32 measured images (padded; invalid = 0).
    cams : (C, 20) float64 rows ``[fx, fy, cx, cy, W, H, min_range, max_range,
        R (9, camera_from_world row-major), t (3)]``.
    margin : (N,) float64; camera ``c`` sees voxel ``i`` as free when its valid
        measured depth at the centre's pixel exceeds the centre's depth + margin[i].
    out_free : (N, C) bool, written.
    """
    N = centres.shape[0]
    C = cams.shape[0]
    for i in range(N):
        for c in range(C):
            out_free[i, c] = False
            fx = cams[c, 0]
            fy = cams[c, 1]
            x = cams[c, 8] * centres[i, 0] + cams[c, 9] * centres[i, 1] + cams[c, 10] * centres[i, 2] + cams[c, 17]
            y = cams[c, 11] * centres[i, 0] + cams[c, 12] * centres[i, 1] + cams[c, 13] * centres[i, 2] + cams[c, 18]
            z = cams[c, 14] * centres[i, 0] + cams[c, 15] * centres[i, 1] + cams[c, 16] * centres[i, 2] + cams[c, 19]
            if z <= 0.0:
                continue
            u = math.floor(x * fx / z + cams[c, 2] + 0.5)
            v = math.floor(y * fy / z + cams[c, 3] + 0.5)
            if u < 0 or v < 0 or u >= cams[c, 4] or v >= cams[c, 5]:
                continue
            d = depths[c, int(v), int(u)]
            if d >= cams[c, 6] and d <= cams[c, 7] and d > z + margin[i]:
                out_free[i, c] = True


def vote_free_numpy(cameras, depths, centres, margin):
    """Twin of :func:`vote_free`: (N, C) bool, camera c's measurement lies beyond the centre."""
    centres = np.asarray(centres, dtype=np.float64)
    out = np.zeros((len(centres), len(cameras)), dtype=bool)
    for c, cam in enumerate(cameras):
        ds = cam.world_to_depth_space(centres)
        with np.errstate(invalid="ignore"):
            u, v = cam.pixel_of(np.nan_to_num(ds[:, 0], nan=-1.0), np.nan_to_num(ds[:, 1], nan=-1.0))
            inside = (ds[:, 2] > 0) & (u >= 0) & (v >= 0) & (u < cam.width) & (v < cam.height)
        d = np.zeros(len(centres))
        img = np.asarray(depths[c], dtype=np.float64)
        d[inside] = img[v[inside], u[inside]]
        valid = np.isfinite(d) & (d >= cam.min_range) & (d <= cam.max_range)
        out[:, c] = inside & valid & (d > ds[:, 2] + margin)
    return out
