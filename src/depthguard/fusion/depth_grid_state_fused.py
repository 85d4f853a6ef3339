"""A frame's per-pixel state in one pass over the image (R9, R28, R32): the camera worker's kernel.

:func:`frame_state_fused` gives exactly the arrays of
:func:`~depthguard.fusion.depth_grid_kernels.frame_state` (or, binned,
:func:`~depthguard.fusion.depth_grid_state.frame_state_binned`) fed with the dilated robot depth
(:func:`~depthguard.distance.silhouette.dilate_robot_depth`) and the small-gap depth
(:func:`~depthguard.distance.gaps.gap_depth`), without making those two images: measured pixels
(nearly all) go through a branch-free loop that LLVM vectorises, a chunk of a row holding an
invalid pixel is gone over again by the whole rule between its first and last invalid pixel, and
the two rules that only invalid pixels read are worked out there — the silhouette's column min
over the robot's rows dilated near its pixels (:func:`_robot_rows`), the small gap by
:func:`~depthguard.distance.gaps.gap_at`. Measured on ``ur3-cell`` 640x480 frames (one thread):
the state with both rules 3-4.7 ms before, about 1-1.5 ms after, on a loaded machine
(``depthguard bench --only share``: ``share.state_cpu_ms``). The principal's binned state
(``principal_bin`` 3-4, issue 29) folds the pixels' measured rule into the blocks branch-free the
same way and takes only the blocks holding an invalid pixel through the whole rule: 0.95 against
0.72 ms for the full-resolution state alone on one ``ur3-cell`` frame at bin 4 (it was 3.4-3.6 ms,
every pixel through the whole rule). The plain-numpy twin stays
:func:`~depthguard.fusion.depth_grid_ref.frame_state_numpy`; the unfused passes stay as
:func:`~depthguard.fusion.depth_grid_state.state_into_unfused` (tests hold the two equal, bit for bit).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from depthguard.camera import RETURN_LIMIT_FACTOR
from depthguard.distance.gaps import gap_at
from depthguard.fusion.depth_grid_kernels import KIND_ROBOT, KIND_SURFACE, KIND_UNKNOWN
from depthguard.fusion.free32 import as_free

__all__ = ["frame_state_fused"]


@njit(cache=True, parallel=True, nogil=True)
def _robot_rows(robot_depth, n, tmp, masked, rows, spans):
    """The robot's rows for the silhouette rule (R32) of :func:`frame_state_fused`: per row ``v``
    of ``robot_depth`` (H, W) m the first and last column with a robot pixel (``> 0``) in
    ``rows[v]`` (``-1, -2`` where none), and the box ``(v0, v1, u0, u1)`` of them returned
    (``v1 < v0``: no robot); in ``tmp`` (>= H, >= W, the dtype of ``robot_depth``) rows
    ``v0..v1`` over columns ``u0 - n .. u1 + n`` (clipped) hold the smallest robot depth within
    ``n`` columns (+inf where none): the row pass of
    :func:`~depthguard.distance.silhouette.dilate_robot_depth`, whose column pass the state
    pass does at the invalid pixels alone; ``masked`` (like ``tmp``) is scratch. ``spans`` (>= H, 2)
    int32: per row ``[a, b)`` outside which ``robot_depth`` is 0 (a renderer's spans,
    :func:`~depthguard.render.composite.copy_depth_rows`; ``(0, W)``: the whole row): only those
    pixels are looked at.
    A row's window minimum is worked out within ``n`` columns of its own robot pixels (beyond,
    every window holds no robot: +inf), not over the whole box (issue 29: an arm across the
    image has a box several times its rows' extent)."""
    H, W = robot_depth.shape
    inf = tmp.dtype.type(np.inf)
    for v in prange(H):
        s0 = max(min(np.int64(spans[v, 0]), W), 0)
        s1 = max(min(np.int64(spans[v, 1]), W), s0)
        row = robot_depth[v, s0:s1]
        a = np.int32(W)
        b = np.int32(-1)
        for u in range(s1 - s0):           # branch-free in 32-bit lanes: LLVM vectorises it
            pos = row[u] > 0.0
            uu = np.int32(u)
            a = min(a, uu if pos else np.int32(W))
            b = max(b, uu if pos else np.int32(-1))
        rows[v, 0] = a + s0 if b >= 0 else -1
        rows[v, 1] = b + s0 if b >= 0 else -2
    v0 = H
    v1 = -1
    u0 = W
    u1 = -1
    for v in range(H):
        if rows[v, 0] >= 0:
            v0 = min(v0, v)
            v1 = v
            u0 = min(u0, rows[v, 0])
            u1 = max(u1, rows[v, 1])
    if v1 < 0:
        return v0, v1, u0, u1
    ua = max(u0 - n, 0)
    ub = min(u1 + n, W - 1)
    for v in prange(v0, v1 + 1):
        if rows[v, 0] < 0:
            trow = tmp[v, ua:ub + 1]
            for i in range(ub - ua + 1):
                trow[i] = inf
            continue
        # beyond n columns of the row's robot pixels every window holds none: +inf there
        la = max(rows[v, 0] - n, ua)
        lb = min(rows[v, 1] + n, ub)
        head = tmp[v, ua:la]
        for i in range(la - ua):
            head[i] = inf
        tail = tmp[v, lb + 1:ub + 1]
        for i in range(ub - lb):
            tail[i] = inf
        L = lb - la + 1
        trow = tmp[v, la:lb + 1]
        src = robot_depth[v, la:lb + 1]
        mrow = masked[v, la:lb + 1]
        for i in range(L):
            x = src[i]
            x = x if x > 0.0 else inf
            mrow[i] = x
            trow[i] = x
        # the min over the window i - n .. i + n (clipped): a min selects, so these are the values
        # of dilate_robot_depth's row pass (the views are indexed from 0: LLVM vectorises the loops)
        for k in range(1, min(n, L - 1) + 1):
            ahead = mrow[k:]
            tk = trow[k:]
            for i in range(L - k):
                x = ahead[i]
                trow[i] = x if x < trow[i] else trow[i]
            for i in range(L - k):
                x = mrow[i]
                tk[i] = x if x < tk[i] else tk[i]
    return v0, v1, u0, u1


@njit(cache=True, nogil=True, inline="always")
def _fused_pixel(depth, robot_depth, use_robot, min_range, max_range, robot_offset, invalid_free, robot_free,
                 tmp, v0, v1, ga, gb, ua, ub, n_sil, n_gap, v, u):
    """``(free depth, kind)`` of pixel ``(v, u)``: the rule of
    :func:`~depthguard.fusion.depth_grid_kernels.pixel_state`, with the dilated robot depth
    (rows of ``tmp`` from :func:`_robot_rows`, its column min here) and the small-gap depth
    (:func:`~depthguard.distance.gaps.gap_at`) worked out at this pixel when the rule reads them."""
    m = np.float64(depth[v, u])
    if not ((m == m) and m > 0.0 and m >= min_range and m <= max_range):
        if invalid_free:
            return np.inf, KIND_UNKNOWN
        if m > max_range and m <= RETURN_LIMIT_FACTOR * max_range:   # a return beyond the rated range
            return max_range, KIND_UNKNOWN
        if v >= ga and v <= gb and u >= ua and u <= ub:
            ra = max(v - n_sil, v0)
            rb = min(v + n_sil, v1)
            x = tmp[ra, u]
            for r in range(ra + 1, rb + 1):
                y = tmp[r, u]
                x = y if y < x else x
            drd = np.float64(x)
            if drd < np.inf:
                return drd, KIND_ROBOT
        if n_gap > 0:
            g = gap_at(depth, v, u, min_range, max_range, n_gap)
            if g > 0.0:
                return g, KIND_UNKNOWN
        return min_range, KIND_UNKNOWN
    if use_robot:
        dr = np.float64(robot_depth[v, u])
        if dr > 0.0 and m >= dr - robot_offset:
            return (np.inf if robot_free else dr), KIND_ROBOT
    return m, KIND_SURFACE


#: pixels per chunk of a row in :func:`frame_state_fused`: a chunk with an invalid pixel is
#: gone over again by the whole rule
_CHUNK = 64


@njit(cache=True, nogil=True, inline="always")
def _measured(m, dr, use_robot, min_range, max_range, robot_offset, robot_free, beyond_free, limit):
    """``(free depth, kind, ruled)`` of a pixel measured ``m`` with robot depth ``dr`` (m) by the
    rule of :func:`_fused_pixel` for the pixels it decides without looking around: a measured
    pixel (its last lines) and a return beyond the rated range up to ``limit`` (m,
    ``RETURN_LIMIT_FACTOR * max_range``: free up to ``beyond_free`` — ``max_range``, or inf with
    ``invalid="free"`` —, unknown behind); ``ruled`` False for the other pixels (no return,
    nearer than ``min_range``, beyond ``limit``), where the first two are meaningless.
    Branch-free."""
    ok = (m == m) & (m > 0.0) & (m >= min_range) & (m <= max_range)
    beyond = (m > max_range) & (m <= limit)
    r = use_robot & (dr > 0.0) & (m >= dr - robot_offset)
    f = (np.inf if robot_free else dr) if r else m
    k = np.int8(KIND_ROBOT) if r else np.int8(KIND_SURFACE)
    f = f if ok else beyond_free
    k = k if ok else np.int8(KIND_UNKNOWN)
    return f, k, ok | beyond


@njit(cache=True, nogil=True, inline="always")
def _valid_row(drow, rrow, use_robot, min_range, max_range, robot_offset, robot_free, beyond_free, limit, frow,
               krow):
    """The state of the pixels of a row's piece (views ``drow``, ``rrow`` in, ``frow``, ``krow``
    out, indexed from 0 so that LLVM vectorises the loop; ``rrow`` is read whatever ``use_robot``:
    a branch there stops the vectoriser), each taken as measured; ``(first, last)``: the first and
    last index of a pixel that is not (``n, -1`` where none)."""
    n = frow.shape[0]
    first = np.int32(n)
    last = np.int32(-1)
    for u in range(n):
        dr = np.float64(rrow[u])
        f, k, ok = _measured(np.float64(drow[u]), dr, use_robot, min_range, max_range, robot_offset, robot_free,
                             beyond_free, limit)
        frow[u] = as_free(f, frow)
        krow[u] = k
        uu = np.int32(u)
        first = min(first, np.int32(n) if ok else uu)
        last = max(last, np.int32(-1) if ok else uu)
    return first, last


@njit(cache=True, nogil=True, inline="always")
def _valid_row_pairs(d0, d1, r0, r1, use_robot, min_range, max_range, robot_offset, robot_free, beyond_free, limit,
                     frow, krow):
    """The 2 x 2 binned state (the block rule of :func:`bin_state`) of a piece of two rows (views
    ``d0``, ``d1``, ``r0``, ``r1`` of twice the length of ``frow``, ``krow``), each pixel taken
    as measured; ``(first, last)``: the first and last block with a pixel that is not (``n, -1``
    where none; ``r0``, ``r1`` are read whatever ``use_robot``)."""
    n = frow.shape[0]
    first = np.int32(n)
    last = np.int32(-1)
    for i in range(n):
        a0 = np.float64(r0[2 * i])
        a1 = np.float64(r0[2 * i + 1])
        a2 = np.float64(r1[2 * i])
        a3 = np.float64(r1[2 * i + 1])
        f0, k0, ok0 = _measured(np.float64(d0[2 * i]), a0, use_robot, min_range, max_range, robot_offset, robot_free,
                                beyond_free, limit)
        f1, k1, ok1 = _measured(np.float64(d0[2 * i + 1]), a1, use_robot, min_range, max_range, robot_offset,
                                robot_free, beyond_free, limit)
        f2, k2, ok2 = _measured(np.float64(d1[2 * i]), a2, use_robot, min_range, max_range, robot_offset, robot_free,
                                beyond_free, limit)
        f3, k3, ok3 = _measured(np.float64(d1[2 * i + 1]), a3, use_robot, min_range, max_range, robot_offset,
                                robot_free, beyond_free, limit)
        # the block's smallest (free, kind), pairwise: the same as bin_state's pixel-by-pixel order,
        # since a measured pixel's free depth is never NaN (the order of a min does not matter)
        fa, ka = _lexmin(f0, k0, f1, k1)
        fb, kb = _lexmin(f2, k2, f3, k3)
        m, k = _lexmin(fa, ka, fb, kb)
        frow[i] = as_free(m, frow)
        krow[i] = k
        ok = ok0 & ok1 & ok2 & ok3
        ii = np.int32(i)
        first = min(first, np.int32(n) if ok else ii)
        last = max(last, np.int32(-1) if ok else ii)
    return first, last


@njit(cache=True, nogil=True, inline="always")
def _lexmin(f0, k0, f1, k1):
    """The smaller of ``(f0, k0)`` and ``(f1, k1)``: the smaller free depth, the smaller kind where
    they are equal (the rule of :func:`bin_state`); branch-free."""
    take = (f1 < f0) | ((f1 == f0) & (k1 < k0))
    return (f1 if take else f0), (k1 if take else k0)


@njit(cache=True, parallel=True)  # no nogil: numba's launcher takes the GIL to start each prange region
# (numba/np/ufunc/parallel.py): called without the GIL, a call with k regions took it back 1 + 2k times, not k
def frame_state_fused(depth, robot_depth, use_robot, min_range, max_range, robot_offset, invalid_free, robot_free,
                      n_sil, n_gap, b, tmp, masked, rows, out_free, out_kind, robot_spans, pmin, pmax, p1):
    """A frame's per-pixel state in one pass over the image (R9, R28, R32): exactly
    :func:`~depthguard.fusion.depth_grid_kernels.frame_state` (``b = 1``) or
    :func:`frame_state_binned` (``b > 1``) fed with
    :func:`~depthguard.distance.silhouette.dilate_robot_depth` (``n_sil`` px, 0: off) and
    :func:`~depthguard.distance.gaps.gap_depth` (``n_gap`` px, 0: off), without those images:
    the robot's rows are dilated within its box (:func:`_robot_rows`) and both rules are
    worked out at the invalid pixels that read them. Binned (``b > 1``): the blocks of pixels
    ruled as measured branch-free (:func:`_valid_row_pairs` at ``b = 2``, :func:`_fold_row4` /
    :func:`_fold_phase` otherwise), the blocks with another pixel and a partial last column of
    blocks by the whole rule (:func:`_block_rule`).

    depth, robot_depth : (H, W) float m (``robot_depth`` read only when ``use_robot``);
    tmp, masked : (>= H, >= W) scratch of ``robot_depth``'s dtype; rows : (>= H, 2) int64 scratch;
    out_free (float64 m, or float32 rounded down: :func:`~depthguard.fusion.free32.as_free`) /
    out_kind (int8) : (>= ceil(H / b), >= ceil(W / b)), the top-left written; robot_spans : (>= H, 2) int32, per row ``[a, b)`` outside which ``robot_depth`` is 0
    (a renderer's spans, or ``(0, W)``: the robot's pixels are looked for there alone, :func:`_robot_rows`);
    pmin, pmax : flat pyramids of ``out_free``'s dtype (:func:`~depthguard.fusion.depth_grid_state.pyramid_layout`)
    whose level 1 is written with the state when ``p1`` (its offset) >= 0 and ``b = 1``, from each
    pair of rows as it is made (:func:`_level1_row`: the bits of
    :func:`~depthguard.fusion.depth_grid_state.state_pyramids`, without reading the state
    again — 2.5 MB of a 640x480 frame, issue 29); ``p1 < 0``: not written (empty arrays will do).
    No allocation.
    """
    H, W = depth.shape
    limit = RETURN_LIMIT_FACTOR * max_range    # a return beyond the rated range up to this: no look around
    beyond_free = np.inf if invalid_free else np.float64(max_range)
    v0 = H
    v1 = -1
    ga = 0
    gb = -1
    ua = 0
    ub = -1
    if use_robot and n_sil > 0 and not invalid_free:
        v0, v1, u0, u1 = _robot_rows(robot_depth, n_sil, tmp, masked, rows, robot_spans)
        if v1 >= v0:
            ga = max(v0 - n_sil, 0)
            gb = min(v1 + n_sil, H - 1)
            ua = max(u0 - n_sil, 0)
            ub = min(u1 + n_sil, W - 1)
    if b == 1:
        for j in prange((H + 1) // 2):      # pairs of rows: level 1 of the pyramids from each pair
            for v in range(2 * j, min(2 * j + 2, H)):
                # chunks of a row: every pixel by the rule of a measured one (branch-free, vectorised),
                # then the chunk's invalid pixels, if any (between the first and the last), by the whole rule
                ra, rb = _row_span(robot_spans, v, W, use_robot)
                for u0 in range(0, W, _CHUNK):
                    u1 = min(u0 + _CHUNK, W)
                    # a chunk outside the row's robot span reads no robot depth (0 there): its depth
                    # stands in, ruled without the robot (the same bits, 1.2 MB less read a frame)
                    rob = u0 < rb and ra < u1
                    first, last = _valid_row(depth[v, u0:u1], robot_depth[v, u0:u1] if rob else depth[v, u0:u1],
                                             rob, min_range, max_range, robot_offset, robot_free, beyond_free,
                                             limit, out_free[v, u0:u1], out_kind[v, u0:u1])
                    for u in range(u0 + first, u0 + last + 1):
                        m = np.float64(depth[v, u])
                        if not (((m == m) and m > 0.0 and m >= min_range and m <= max_range) or
                                (m > max_range and m <= limit)):
                            f, k = _fused_pixel(depth, robot_depth, use_robot, min_range, max_range, robot_offset,
                                                invalid_free, robot_free, tmp, v0, v1, ga, gb, ua, ub, n_sil,
                                                n_gap, v, u)
                            out_free[v, u] = as_free(f, out_free)
                            out_kind[v, u] = k
            if p1 >= 0:
                wl = (W + 1) // 2
                _level1_row(out_free[2 * j, :W], out_free[min(2 * j + 1, H - 1), :W],
                            pmin[p1 + j * wl:p1 + j * wl + wl], pmax[p1 + j * wl:p1 + j * wl + wl])
        return
    hb = -(-H // b)
    wb = -(-W // b)
    if b == 2 and H % 2 == 0 and W % 2 == 0:
        for j in prange(hb):               # the common case: blocks of measured pixels branch-free
            ra0, rb0 = _row_span(robot_spans, 2 * j, W, use_robot)
            ra1, rb1 = _row_span(robot_spans, 2 * j + 1, W, use_robot)
            ra = min(ra0, ra1)
            rb = max(rb0, rb1)
            for i0 in range(0, wb, _CHUNK // 2):
                i1 = min(i0 + _CHUNK // 2, wb)
                rob = 2 * i0 < rb and ra < 2 * i1          # (as in the b == 1 loop)
                rr = robot_depth if rob else depth
                first, last = _valid_row_pairs(depth[2 * j, 2 * i0:2 * i1], depth[2 * j + 1, 2 * i0:2 * i1],
                                               rr[2 * j, 2 * i0:2 * i1], rr[2 * j + 1, 2 * i0:2 * i1], rob,
                                               min_range, max_range, robot_offset, robot_free, beyond_free, limit,
                                               out_free[j, i0:i1], out_kind[j, i0:i1])
                for i in range(i0 + first, i0 + last + 1):   # blocks with an invalid pixel: by the whole rule
                    inv = False
                    for c in range(4):
                        m = np.float64(depth[2 * j + (c >> 1), 2 * i + (c & 1)])
                        inv |= not (((m == m) and m > 0.0 and m >= min_range and m <= max_range) or
                                    (m > max_range and m <= limit))
                    if not inv:
                        continue
                    m, k = _fused_pixel(depth, robot_depth, use_robot, min_range, max_range, robot_offset,
                                        invalid_free, robot_free, tmp, v0, v1, ga, gb, ua, ub, n_sil, n_gap,
                                        2 * j, 2 * i)
                    for c in range(1, 4):
                        f, kk = _fused_pixel(depth, robot_depth, use_robot, min_range, max_range, robot_offset,
                                             invalid_free, robot_free, tmp, v0, v1, ga, gb, ua, ub, n_sil, n_gap,
                                             2 * j + (c >> 1), 2 * i + (c & 1))
                        if f < m or (f == m and kk < k):
                            m = f
                            k = kk
                    out_free[j, i] = as_free(m, out_free)
                    out_kind[j, i] = k
        return
    # b > 2 (``principal_bin`` 3, 4 today) or an odd image: per row of blocks, each of its ``b``
    # rows' ``b`` column phases folded into the full blocks branch-free (a pixel that is not ruled
    # as measured makes its block -inf), then the blocks so marked and a last partial column of
    # blocks by the whole rule
    nfull = W // b
    rr = robot_depth if use_robot else depth
    for j in prange(hb):
        va = j * b
        vb = min(H, va + b)
        frow = out_free[j, :nfull]
        krow = out_kind[j, :nfull]
        for i in range(nfull):
            frow[i] = np.inf
            krow[i] = np.int8(127)
        for v in range(va, vb):
            ra, rb = _row_span(robot_spans, v, W, use_robot)
            rob = ra < rb                      # a row without robot pixels reads no robot depth
            rv = rr if rob else depth
            if b == 4:
                _fold_row4(depth[v, :nfull * b], rv[v, :nfull * b], rob, min_range, max_range,
                          robot_offset, robot_free, beyond_free, limit, frow, krow)
                continue
            for c in range(b):
                _fold_phase(depth[v, c:nfull * b:b], rv[v, c:nfull * b:b], rob, min_range, max_range,
                            robot_offset, robot_free, beyond_free, limit, frow, krow)
        for i in range(wb):
            if i < nfull and out_free[j, i] != -np.inf:
                continue
            m, k = _block_rule(depth, robot_depth, use_robot, min_range, max_range, robot_offset, invalid_free,
                               robot_free, tmp, v0, v1, ga, gb, ua, ub, n_sil, n_gap, va, vb, i * b,
                               min(W, i * b + b))
            out_free[j, i] = as_free(m, out_free)
            out_kind[j, i] = k


@njit(cache=True, nogil=True, inline="always")
def _level1_row(a, b, omin, omax):
    """One row of the pyramids' level 1 from two rows ``a``, ``b`` (W,) of free depths (the same row
    twice at an odd height's last): ``omin`` / ``omax`` (ceil(W / 2),) the min / max of each 2 x 2
    block, the last column of an odd width repeating itself — the level-1 loop of
    :func:`~depthguard.fusion.depth_grid_state.state_pyramids`, the same bits (a min / max selects,
    and a free depth is never NaN)."""
    W = a.shape[0]
    half = W // 2
    for u in range(half):
        omin[u] = min(min(a[2 * u], a[2 * u + 1]), min(b[2 * u], b[2 * u + 1]))
        omax[u] = max(max(a[2 * u], a[2 * u + 1]), max(b[2 * u], b[2 * u + 1]))
    if omin.shape[0] > half:
        omin[half] = min(a[W - 1], b[W - 1])
        omax[half] = max(a[W - 1], b[W - 1])


@njit(cache=True, nogil=True, inline="always")
def _row_span(spans, v, W, use_robot):
    """``(a, b)``: row ``v``'s robot span ``[a, b)`` of ``spans`` (>= H, 2) int32 clipped to
    ``0..W`` (``b <= a``: no robot pixel in the row, nor anywhere without ``use_robot``)."""
    if not use_robot:
        return 0, 0
    a = max(min(np.int64(spans[v, 0]), W), 0)
    return a, max(min(np.int64(spans[v, 1]), W), a)


@njit(cache=True, nogil=True, inline="always")
def _fold_phase(drow, rrow, use_robot, min_range, max_range, robot_offset, robot_free, beyond_free, limit, frow,
                krow):
    """Fold one pixel per block into the blocks' ``(free, kind)`` ``frow``, ``krow`` (n,) by the
    block rule of :func:`bin_state` (:func:`_lexmin`): ``drow``, ``rrow`` (n,) views (strided: one
    column phase of a row) of the depth and the robot depth (read whatever ``use_robot``), each
    pixel taken as measured (:func:`_measured`); a pixel it does not rule gives ``-inf``, which
    marks its block for the whole rule. Branch-free."""
    for i in range(frow.shape[0]):
        f, k, ok = _measured(np.float64(drow[i]), np.float64(rrow[i]), use_robot, min_range, max_range,
                             robot_offset, robot_free, beyond_free, limit)
        f = f if ok else -np.inf
        fm, km = _lexmin(frow[i], krow[i], f, k)
        frow[i] = as_free(fm, frow)
        krow[i] = km


@njit(cache=True, nogil=True, inline="always")
def _fold_row4(drow, rrow, use_robot, min_range, max_range, robot_offset, robot_free, beyond_free, limit, frow,
               krow):
    """Fold a row's pixels into its blocks' ``(free, kind)`` ``frow``, ``krow`` (n,) by the block
    rule of :func:`bin_state` (:func:`_lexmin`): ``drow``, ``rrow`` (n b,) the row's depth and robot
    depth (read whatever ``use_robot``), each pixel taken as measured (:func:`_measured`); a pixel
    it does not rule gives ``-inf``, which marks its block for the whole rule. Branch-free."""
    for i in range(frow.shape[0]):
        f0, k0 = _marked(drow[4 * i], rrow[4 * i], use_robot, min_range, max_range, robot_offset, robot_free,
                         beyond_free, limit)
        f1, k1 = _marked(drow[4 * i + 1], rrow[4 * i + 1], use_robot, min_range, max_range, robot_offset,
                         robot_free, beyond_free, limit)
        f2, k2 = _marked(drow[4 * i + 2], rrow[4 * i + 2], use_robot, min_range, max_range, robot_offset,
                         robot_free, beyond_free, limit)
        f3, k3 = _marked(drow[4 * i + 3], rrow[4 * i + 3], use_robot, min_range, max_range, robot_offset,
                         robot_free, beyond_free, limit)
        fa, ka = _lexmin(f0, k0, f1, k1)
        fb, kb = _lexmin(f2, k2, f3, k3)
        fa, ka = _lexmin(fa, ka, fb, kb)
        fm, km = _lexmin(frow[i], np.float64(krow[i]), fa, ka)
        frow[i] = as_free(fm, frow)
        krow[i] = np.int8(km)


@njit(cache=True, nogil=True, inline="always")
def _marked(m, dr, use_robot, min_range, max_range, robot_offset, robot_free, beyond_free, limit):
    """``(free, kind)`` of a pixel measured ``m`` with robot depth ``dr`` (m) by :func:`_measured`,
    ``-inf`` where that does not rule it (the mark of a block for the whole rule)."""
    f, k, ok = _measured(np.float64(m), np.float64(dr), use_robot, min_range, max_range, robot_offset, robot_free,
                         beyond_free, limit)
    return (f if ok else -np.inf), np.float64(k)


@njit(cache=True, nogil=True, inline="always")
def _block_rule(depth, robot_depth, use_robot, min_range, max_range, robot_offset, invalid_free, robot_free,
                tmp, v0, v1, ga, gb, ua, ub, n_sil, n_gap, va, vb, ia, ib):
    """``(free, kind)`` of the block of pixels ``va .. vb - 1`` x ``ia .. ib - 1`` by the whole rule
    (:func:`_fused_pixel`) and the block rule of :func:`bin_state`, pixel by pixel in its order."""
    m = np.inf
    k = -1
    for v in range(va, vb):
        for u in range(ia, ib):
            f, kk = _fused_pixel(depth, robot_depth, use_robot, min_range, max_range, robot_offset,
                                 invalid_free, robot_free, tmp, v0, v1, ga, gb, ua, ub, n_sil, n_gap, v, u)
            if f < m or k < 0 or (f == m and kk < k):
                m = f
                k = kk
    return m, k
