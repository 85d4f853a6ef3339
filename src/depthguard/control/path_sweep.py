"""The sweep of a path check (R22, R37): which voxel states the swept, padded robot touches.

:func:`sweep_states` is the numba kernel (``cache=True``), :func:`sweep_states_numpy` its plain
numpy twin (the tests hold them equal); the rule is :mod:`depthguard.control.path_check`'s.

Only a voxel whose state is worse than the segment's worst so far can change the answer, and
outside the robot's own body (``exclude``) such voxels are few: the occupied voxels once the
segment has met unknown space, the unknown and occupied ones before. The kernel counts them
once per call — a summed-volume table per threshold (``state >= 1``, ``state == 2``) and a
prefix count along each voxel column — and skips a capsule's box, and then each column of it,
that holds none. The voxels it still visits are those the full scan would visit with the same
outcome, in the same order, so the answers (worst state, first voxel, outside) are the full
scan's (tested against the twin): what changed is the cost, from every voxel of every capsule's
box at every sample (a free map) to a few loads per box.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["sweep_states", "sweep_states_numpy", "candidate_counts"]

_HALF_DIAG = math.sqrt(3.0) / 2.0


@numba.njit(cache=True, nogil=True)
def candidate_counts(state, exclude, sat, col):
    """Counts of the voxels a segment can still be made worse by, outside ``exclude``.

    state (nx, ny, nz) uint8, exclude (nx, ny, nz) bool; outputs ``sat`` (2, nx+1, ny+1, nz+1)
    int32 summed-volume tables and ``col`` (2, nx, ny, nz+1) int32 prefix counts along z, index 0
    for ``state >= 1``, 1 for ``state == 2``."""
    nx, ny, nz = state.shape
    for t in range(2):
        for i in range(nx + 1):
            for j in range(ny + 1):
                sat[t, i, j, 0] = 0
        for j in range(ny + 1):
            for k in range(nz + 1):
                sat[t, 0, j, k] = 0
        for i in range(nx + 1):
            for k in range(nz + 1):
                sat[t, i, 0, k] = 0
    for i in range(nx):
        for j in range(ny):
            c0 = 0
            c1 = 0
            col[0, i, j, 0] = 0
            col[1, i, j, 0] = 0
            for k in range(nz):
                st = state[i, j, k]
                if not exclude[i, j, k]:
                    if st >= 1:
                        c0 += 1
                    if st == 2:
                        c1 += 1
                col[0, i, j, k + 1] = c0
                col[1, i, j, k + 1] = c1
                for t in range(2):
                    sat[t, i + 1, j + 1, k + 1] = (col[t, i, j, k + 1] + sat[t, i, j + 1, k + 1] + sat[t, i + 1, j, k + 1]
                                                   - sat[t, i, j, k + 1])


@numba.njit(cache=True, inline="always")
def _box_count(sat, t, i0, i1, j0, j1, k0, k1):
    """Voxels counted in table ``t`` within ``[i0, i1) x [j0, j1) x [k0, k1)``."""
    return (sat[t, i1, j1, k1] - sat[t, i0, j1, k1] - sat[t, i1, j0, k1] - sat[t, i1, j1, k0]
            + sat[t, i0, j0, k1] + sat[t, i0, j1, k0] + sat[t, i1, j0, k0] - sat[t, i0, j0, k0])


@numba.njit(cache=True, nogil=True)
def sweep_states(state, exclude, known, dpad, lo, s, A, B, R, seg, n_seg, worst, first, outside):
    """Numba kernel: per segment the worst state (0/1/2) of a voxel touched, the flat index of the
    first such voxel (-1: none) and whether the swept robot leaves the box (module docstring of
    :mod:`depthguard.control.path_check`).

    state (nx, ny, nz) uint8, exclude (nx, ny, nz) bool, known (nx, ny, nz) bool the known scene's
    voxels, touched with radii ``R - dpad`` (m), lo (3,) m, s m, A/B (S, K, 3) m, R (S, K)
    m, seg (S,) int64; outputs worst (n_seg,) uint8, first (n_seg,) int64, outside (n_seg,) bool."""
    nx, ny, nz = state.shape
    sat = np.empty((2, nx + 1, ny + 1, nz + 1), np.int32)
    col = np.empty((2, nx, ny, nz + 1), np.int32)
    candidate_counts(state, exclude, sat, col)
    hd = s * 0.8660254037844386
    for i in range(n_seg):
        worst[i] = 0
        first[i] = -1
        outside[i] = False
    lo_i = np.empty(3, np.int64)
    hi_i = np.empty(3, np.int64)
    for k in range(A.shape[0]):
        g = seg[k]
        for c in range(A.shape[1]):
            ax, ay, az = A[k, c, 0], A[k, c, 1], A[k, c, 2]
            bx, by, bz = B[k, c, 0], B[k, c, 1], B[k, c, 2]
            r = R[k, c]
            reach = r + hd
            dx, dy, dz = bx - ax, by - ay, bz - az
            L2 = dx * dx + dy * dy + dz * dz
            pa = (ax, ay, az)
            pb = (bx, by, bz)
            for d in range(3):
                mn = min(pa[d], pb[d])
                mx = max(pa[d], pb[d])
                n_d = state.shape[d]
                if mn - r < lo[d] or mx + r > lo[d] + n_d * s:
                    outside[g] = True
                a = int(math.floor((mn - reach - lo[d]) / s))
                b = int(math.floor((mx + reach - lo[d]) / s)) + 1
                lo_i[d] = min(max(a, 0), n_d)
                hi_i[d] = min(max(b, 0), n_d)
            if worst[g] == 2:                   # the segment is unsafe already: nothing worse to find
                continue
            if _box_count(sat, worst[g], lo_i[0], hi_i[0], lo_i[1], hi_i[1], lo_i[2], hi_i[2]) == 0:
                continue                        # nothing in the box can make the segment worse
            r2 = reach * reach
            rk = max(r - dpad, 0.0) + hd
            rk2 = rk * rk
            for ii in range(lo_i[0], hi_i[0]):
                cx = lo[0] + (ii + 0.5) * s
                for jj in range(lo_i[1], hi_i[1]):
                    w = worst[g]
                    if w == 2 or col[w, ii, jj, hi_i[2]] == col[w, ii, jj, lo_i[2]]:
                        continue                # no voxel of this column can make it worse
                    cy = lo[1] + (jj + 0.5) * s
                    for kk in range(lo_i[2], hi_i[2]):
                        st = state[ii, jj, kk]
                        if st <= worst[g] or exclude[ii, jj, kk]:
                            continue
                        cz = lo[2] + (kk + 0.5) * s
                        u = 0.0
                        if L2 > 0.0:
                            u = ((cx - ax) * dx + (cy - ay) * dy + (cz - az) * dz) / L2
                            u = min(max(u, 0.0), 1.0)
                        ex, ey, ez = cx - ax - u * dx, cy - ay - u * dy, cz - az - u * dz
                        e2 = ex * ex + ey * ey + ez * ez
                        if e2 <= r2 and (e2 <= rk2 or not known[ii, jj, kk]):
                            worst[g] = st
                            first[g] = (ii * ny + jj) * nz + kk
    return worst


def sweep_states_numpy(state, exclude, known, dpad, lo, s, A, B, R, seg, n_seg):
    """Plain numpy twin of :func:`sweep_states`: (worst, first, outside) per segment. ``first`` may
    name another voxel of the same worst state than the kernel's; the tests compare states."""
    worst = np.zeros(n_seg, np.uint8)
    first = np.full(n_seg, -1, np.int64)
    outside = np.zeros(n_seg, bool)
    shape = np.array(state.shape)
    hd = s * _HALF_DIAG
    for k in range(len(A)):
        g = seg[k]
        for c in range(A.shape[1]):
            a, b, r = A[k, c], B[k, c], R[k, c]
            mn, mx = np.minimum(a, b), np.maximum(a, b)
            if np.any(mn - r < lo) or np.any(mx + r > lo + shape * s):
                outside[g] = True
            i0 = np.clip(np.floor((mn - r - hd - lo) / s).astype(int), 0, shape)
            i1 = np.clip(np.floor((mx + r + hd - lo) / s).astype(int) + 1, 0, shape)
            if np.any(i1 <= i0):
                continue
            idx = np.stack(np.meshgrid(*[np.arange(i0[d], i1[d]) for d in range(3)], indexing="ij"), -1).reshape(-1, 3)
            cen = lo + (idx + 0.5) * s
            ab = b - a
            L2 = float(ab @ ab)
            u = np.clip((cen - a) @ ab / L2, 0.0, 1.0) if L2 > 0 else np.zeros(len(cen))
            dist = np.linalg.norm(cen - a - u[:, None] * ab, axis=1)
            kn = known[idx[:, 0], idx[:, 1], idx[:, 2]]
            hit = (dist <= r + hd) & (~kn | (dist <= max(r - dpad, 0.0) + hd))
            hit &= ~exclude[idx[:, 0], idx[:, 1], idx[:, 2]]
            st = state[idx[:, 0], idx[:, 1], idx[:, 2]] * hit
            if st.size and st.max() > worst[g]:
                m = int(np.argmax(st))
                worst[g] = st[m]
                first[g] = int(np.ravel_multi_index(tuple(idx[m]), state.shape))
    return worst, first, outside
