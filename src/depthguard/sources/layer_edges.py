"""The depth-edge test of a simulated frame's composite (R16, issue 29): the kernels of
:mod:`depthguard.sources.layered`'s step 2, as :func:`depthguard.sources.noise.depth_edges`
defines the edges (a valid pixel next to an invalid one or to a depth step larger than
``jump_abs + jump_rel min(z_p, z_q)``; neighbours left, right, up, down; an image border has
none) — on rows of float64 metres (0 = invalid). :func:`static_edges`: once per camera;
:func:`_edges_span`: a span of a row, per frame. The interior pixels run on 0-based slices
(vector instructions: a loop from a span's start keeps numba's negative-index check, 3x slower).
"""

from __future__ import annotations

import numba
import numpy as np

from depthguard.sources.frame_measure import depth_of

__all__ = ["static_edges"]


@numba.njit(cache=True, nogil=True, inline="always")
def _pick(zp, zq, jump_abs, jump_rel, e, best, oth):
    """One neighbour ``zq`` of pixel ``zp`` (m, 0 = invalid) in the edge test: the updated ``(edge,
    largest step, depth across it)`` — :func:`depthguard.sources.noise._edge_step` written with
    selects, so that a loop of it compiles to vector instructions."""
    valid = zq > 0.0
    step = abs(zp - zq) if valid else np.inf
    is_e = (not valid) | (step > jump_abs + jump_rel * min(zp, zq))
    better = is_e & (step > best)
    return e | is_e, step if better else best, zq if better else oth


@numba.njit(cache=True, nogil=True, inline="always")
def _edge_general(zu, zm, zd, u, up, down, W, jump_abs, jump_rel):
    """``(edge, depth across)`` of pixel ``u`` of the sanitized row ``zm`` (float64 m, 0 = invalid)
    with the rows above / below (``up`` / ``down``: whether they exist) on an image border."""
    zp = zm[u]
    e = False
    best = 0.0
    oth = 0.0
    if zp > 0.0:
        if u > 0:
            e, best, oth = _pick(zp, zm[u - 1], jump_abs, jump_rel, e, best, oth)
        if u < W - 1:
            e, best, oth = _pick(zp, zm[u + 1], jump_abs, jump_rel, e, best, oth)
        if up:
            e, best, oth = _pick(zp, zu[u], jump_abs, jump_rel, e, best, oth)
        if down:
            e, best, oth = _pick(zp, zd[u], jump_abs, jump_rel, e, best, oth)
    return e, oth


@numba.njit(cache=True, nogil=True, inline="always")
def _is_edge(zp, zq, jump_abs, jump_rel):
    """Whether neighbour ``zq`` makes pixel ``zp`` an edge: :func:`_pick`'s ``is_e`` alone."""
    return (not zq > 0.0) | (abs(zp - zq) > jump_abs + jump_rel * min(zp, zq))


@numba.njit(cache=True, nogil=True, inline="always")
def _interior(zl, zm, zr, zu, zd, erow, orow, jump_abs, jump_rel):
    """The edge test of interior pixels (four neighbours, no branches): ``zm`` (n,) the pixels,
    ``zl``, ``zr`` their left / right neighbours, ``zu``, ``zd`` above / below (float64 m, 0 =
    invalid), into ``erow`` (n,) uint8 and ``orow`` (n,) float32 (the depth across); all slices
    from 0, so that the loop compiles to vector instructions (a loop from a span's start keeps
    numba's negative-index check: 3x slower, issue 29). Returns ``(valid, edge)`` counts."""
    nv = 0
    ne = 0
    for u in range(zm.shape[0]):
        zp = zm[u]
        e, best, oth = _pick(zp, zl[u], jump_abs, jump_rel, False, 0.0, 0.0)
        e, best, oth = _pick(zp, zr[u], jump_abs, jump_rel, e, best, oth)
        e, best, oth = _pick(zp, zu[u], jump_abs, jump_rel, e, best, oth)
        e, best, oth = _pick(zp, zd[u], jump_abs, jump_rel, e, best, oth)
        ok = zp > 0.0
        e = e & ok
        erow[u] = np.uint8(e)
        orow[u] = np.float32(oth if e else 0.0)
        nv += np.int64(ok)
        ne += np.int64(e)
    return nv, ne


@numba.njit(cache=True, nogil=True, inline="always")
def _interior_flags(zl, zm, zr, zu, zd, erow, jump_abs, jump_rel):
    """:func:`_interior`'s flags alone (no depth across: half the work)."""
    nv = 0
    ne = 0
    for u in range(zm.shape[0]):
        zp = zm[u]
        ok = zp > 0.0
        e = ok & (_is_edge(zp, zl[u], jump_abs, jump_rel) | _is_edge(zp, zr[u], jump_abs, jump_rel)
                  | _is_edge(zp, zu[u], jump_abs, jump_rel) | _is_edge(zp, zd[u], jump_abs, jump_rel))
        erow[u] = np.uint8(e)
        nv += np.int64(ok)
        ne += np.int64(e)
    return nv, ne


@numba.njit(cache=True, nogil=True)
def _edges_span(zu, zm, zd, up, down, a, b, jump_abs, jump_rel, erow, orow, keep=True):
    """Edge test of pixels ``[a, b)`` of the row ``zm`` (W,) float64 m (0 = invalid: the composite
    as :func:`~depthguard.sources.frame_measure.depth_of` reads it), with the rows above / below ``zu``, ``zd`` (``up`` / ``down``:
    whether they exist), into ``erow`` (W,) uint8 and ``orow`` (W,) float32 m, as
    :func:`depthguard.sources.noise.depth_edges` (neighbours left, right, up, down; an image
    border has none); the interior pixels in a loop of selects (vector instructions).
    ``keep`` False: ``orow`` is not written (a scratch row: only flying pixels read the depths
    across the edges), and the interior pixels' loop tests the edges alone (the same flags,
    half the work: issue 29). Returns the span's ``(valid, edge)`` counts."""
    W = zm.shape[0]
    ia = max(a, 1)
    ib = min(b, W - 1)
    if not (up and down) or ib <= ia:         # no interior: every pixel on the border path
        ia = b
        ib = b
    nv = 0
    ne = 0
    if ib > ia:                               # interior pixels, on 0-based slices (vector instructions)
        if keep:
            nv, ne = _interior(zm[ia - 1:ib - 1], zm[ia:ib], zm[ia + 1:ib + 1], zu[ia:ib], zd[ia:ib],
                               erow[ia:ib], orow[ia:ib], jump_abs, jump_rel)
        else:
            nv, ne = _interior_flags(zm[ia - 1:ib - 1], zm[ia:ib], zm[ia + 1:ib + 1], zu[ia:ib], zd[ia:ib],
                                     erow[ia:ib], jump_abs, jump_rel)
    for u in range(a, ia):                    # the image's border pixels
        e, oth = _edge_general(zu, zm, zd, u, up, down, W, jump_abs, jump_rel)
        erow[u] = np.uint8(e)
        orow[u] = np.float32(oth)
        nv += np.int64(zm[u] > 0.0)
        ne += np.int64(e)
    for u in range(max(ib, ia), b):
        e, oth = _edge_general(zu, zm, zd, u, up, down, W, jump_abs, jump_rel)
        erow[u] = np.uint8(e)
        orow[u] = np.float32(oth)
        nv += np.int64(zm[u] > 0.0)
        ne += np.int64(e)
    return nv, ne


@numba.njit(cache=True, nogil=True)
def static_edges(static, z, jump_abs, jump_rel, edge, other, valid_cum, edge_cum):
    """The static scene's edges, once per camera, of the raw (H, W) float32 image ``static``:
    ``edge`` (H, W) uint8, ``other`` (H, W) float32 m (the depth across the edge, as
    :func:`depthguard.sources.noise.depth_edges`), and ``valid_cum``, ``edge_cum`` (H, W + 1)
    int32: per row the valid / edge pixels left of each column (``[v, W]``: the row's count).
    ``z`` (H, W) float64: scratch (``static`` as the noise reads it, :func:`~depthguard.sources.frame_measure.depth_of`)."""
    H, W = static.shape
    for v in range(H):
        for u in range(W):
            z[v, u] = depth_of(static[v, u])
    for v in range(H):
        _edges_span(z[max(v - 1, 0)], z[v], z[min(v + 1, H - 1)], v > 0, v < H - 1, np.int64(0), W, jump_abs, jump_rel,
                    edge[v], other[v if other.shape[0] > 1 else 0], other.shape[0] > 1)
        valid_cum[v, 0] = 0
        edge_cum[v, 0] = 0
        for u in range(W):
            valid_cum[v, u + 1] = valid_cum[v, u] + (1 if z[v, u] > 0.0 else 0)
            edge_cum[v, u + 1] = edge_cum[v, u] + edge[v, u]
