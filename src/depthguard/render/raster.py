"""Numba z-buffer rasteriser: the kernels behind :class:`~depthguard.render.Renderer` (R16).

Pipeline (SPEC §1 conventions, SPEC §5 R16):

1. ``P_c = R P_w + t`` for every packed vertex (equation 1).
2. Per face: back-face culling in the camera frame (the face is seen from its
   outside when ``n · a < 0``, ``n = (b - a) x (c - a)`` with the outward CCW
   winding of :mod:`depthguard.geometry.mesh`, the camera at the origin);
   near-plane clipping (Sutherland–Hodgman against ``z = near``: 1 or 2
   triangles); projection ``px = x fx / z + cx``, ``py = y fy / z + cy``
   (equation 2); the triangle's edge functions and its plane of ``1/z`` in
   screen space (perspective-correct depth).
3. Per band of image rows: every pixel centre ``(u, v)`` (integers) inside a
   triangle offers ``w = (1/z)(u, v)``; the largest ``w`` (the nearest
   surface) wins, strictly (on an exact tie the triangle drawn first keeps the
   pixel); finally ``depth = float32(1 / w)``.

:func:`render_packed` runs on one core (the whole image is one band);
:func:`render_packed_parallel` runs steps 1–2 over vertices / faces and step
3 over disjoint bands of rows with numba threads (no two tasks write the same
pixel: race-free, and the same image as the serial kernel). On a loaded
machine the serial kernel is the steadier one.

Coverage and the fill rule: a pixel is covered when its centre is strictly
inside the projected triangle, or lies exactly on a *top* or *left* edge
(interior below a horizontal edge, or right of a non-horizontal one, image
y pointing down). Every edge function is evaluated from its endpoints taken
in a canonical (lexicographic) order, anchored at the first, and then
negated as needed, so a shared edge evaluates to exactly opposite values in
its two triangles: a pixel centre on a shared edge is drawn by exactly one of
them (no cracks, no double draws); the edge function is exactly 0 at the
edge's endpoints, so a vertex of a fan that falls on a pixel centre is drawn
once as well. Clip points on a shared edge are computed from the (in front,
behind) vertex pair, identically in both triangles. (Floating-point edge
functions, not fixed point: an edge passing within rounding of a pixel
centre may go either way, but consistently for its two triangles.)

Buffers (all preallocated by the caller, nothing is allocated here):

- ``vw`` (V, 3) float64 world vertices and ``faces`` (F, 3) int32 of all
  meshes one after the other, face indices local to their mesh; ``mesh_off``
  (M + 1, 2) int64 the first vertex and first face of each mesh (and the
  totals); only the first ``n_v`` / ``n_f`` rows are used. The kernels check
  them (finite vertices, indices within the mesh) before drawing anything,
  so bad input cannot make them read outside the buffers.
- ``face_label`` (F,) int32 mesh of each face (written by the kernel).
- ``vc`` (V, 3) float64 camera-frame vertices (workspace).
- ``tri`` (2F, 18) float64 per-slot setup: for each of the three edges
  ``A, B`` and its anchor ``X, Y`` (12; ``E(S) = A (Sx - X) + B (Sy - Y)``),
  the ``1/z`` plane ``Pa, Pb`` with its anchor ``x0, y0, 1/z0`` (5), the
  top-left flags of the three edges as bits (1).
- ``box`` (2F, 4) int32 per-slot pixel bounding box ``u0, u1, v0, v1``
  (empty when ``v0 > v1``); ``slot_label`` (2F, 2) int32: mesh label and
  packed face index of the slot.
- ``wbuf`` (H, W) float64 ``1/z`` z-buffer and ``sbuf`` (H, W) int32 winning slot
  (workspace; all 0 / -1 between calls).
- ``depth`` (H, W) float32 metres (0 = nothing), ``labels`` (H, W) int32
  mesh label (-1 = nothing), ``face_ids`` (H, W) int32 packed face index
  (-1 = nothing).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

__all__ = ["render_packed", "render_packed_parallel", "check_and_label"]


@njit(cache=True, inline="always")
def _transform_one(vw, R, t, vc, i):
    """``vc[i] = R @ vw[i] + t`` (equation 1)."""
    x = vw[i, 0]
    y = vw[i, 1]
    z = vw[i, 2]
    for k in range(3):
        vc[i, k] = R[k, 0] * x + R[k, 1] * y + R[k, 2] * z + t[k]


@njit(cache=True, inline="always")
def _edge(x0, y0, x1, y1):
    """Edge function of the directed edge (x0,y0)->(x1,y1), anchored at its canonical end.

    Returns ``(A, B, px, py)`` with ``E(S) = A (Sx - px) + B (Sy - py)
    = (x1-x0)(Sy-y0) - (y1-y0)(Sx-x0)``, where ``(px, py)`` is the
    lexicographically smaller endpoint: the reversed edge gives exactly
    ``(-A, -B, px, py)``, and ``E`` is exactly 0 at both endpoints.
    """
    flip = (x1 < x0) or (x1 == x0 and y1 < y0)
    if flip:
        px, py, qx, qy = x1, y1, x0, y0
    else:
        px, py, qx, qy = x0, y0, x1, y1
    A = -(qy - py)
    B = qx - px
    if flip:
        return -A, -B, px, py
    return A, B, px, py


@njit(cache=True, nogil=True)
def _setup_one(x0, y0, iz0, x1, y1, iz1, x2, y2, iz2, W, H, tri, box, s):
    """Screen-space setup of one triangle into slot ``s``; 1 if it may cover a pixel, else 0
    (slot marked empty). ``(x_i, y_i)`` pixel coordinates, ``iz_i = 1/z_i``."""
    box[s, 2] = 1
    box[s, 3] = 0  # empty unless filled below
    A0, B0, X0, Y0 = _edge(x1, y1, x2, y2)  # opposite vertex 0
    A1, B1, X1, Y1 = _edge(x2, y2, x0, y0)  # opposite vertex 1
    A2, B2, X2, Y2 = _edge(x0, y0, x1, y1)  # opposite vertex 2
    area = A2 * (x2 - X2) + B2 * (y2 - Y2)  # E_2 at vertex 2 = twice the signed area
    if area == 0.0 or not math.isfinite(area):
        return 0
    if area < 0.0:  # make the interior positive for all three edges
        A0, B0, A1, B1, A2, B2 = -A0, -B0, -A1, -B1, -A2, -B2
        area = -area
    xmin = min(x0, min(x1, x2))
    xmax = max(x0, max(x1, x2))
    ymin = min(y0, min(y1, y2))
    ymax = max(y0, max(y1, y2))
    u0 = max(int(math.ceil(max(xmin, -1.0))), 0)
    u1 = min(int(math.floor(min(xmax, W * 1.0))), W - 1)
    v0 = max(int(math.ceil(max(ymin, -1.0))), 0)
    v1 = min(int(math.floor(min(ymax, H * 1.0))), H - 1)
    if u0 > u1 or v0 > v1:
        return 0
    tri[s, 0] = A0
    tri[s, 1] = B0
    tri[s, 2] = X0
    tri[s, 3] = Y0
    tri[s, 4] = A1
    tri[s, 5] = B1
    tri[s, 6] = X1
    tri[s, 7] = Y1
    tri[s, 8] = A2
    tri[s, 9] = B2
    tri[s, 10] = X2
    tri[s, 11] = Y2
    # 1/z is linear in screen space: w(S) = sum_i iz_i E_i(S) / area = iz0 + Pa (Sx - x0) + Pb (Sy - y0)
    tri[s, 12] = (iz0 * A0 + iz1 * A1 + iz2 * A2) / area
    tri[s, 13] = (iz0 * B0 + iz1 * B1 + iz2 * B2) / area
    tri[s, 14] = x0
    tri[s, 15] = y0
    tri[s, 16] = iz0
    # top-left edges: oriented direction (dx, dy) = (B, -A); top-left iff dy < 0 or (dy == 0 and dx > 0)
    tri[s, 17] = (1.0 if (A0 > 0.0 or (A0 == 0.0 and B0 > 0.0)) else 0.0) \
        + (2.0 if (A1 > 0.0 or (A1 == 0.0 and B1 > 0.0)) else 0.0) \
        + (4.0 if (A2 > 0.0 or (A2 == 0.0 and B2 > 0.0)) else 0.0)
    box[s, 0] = u0
    box[s, 1] = u1
    box[s, 2] = v0
    box[s, 3] = v1
    return 1


@njit(cache=True, inline="always")
def _clip_point(xi, yi, zi, xo, yo, zo, near):
    """Point of the segment (inside -> outside) on the plane ``z = near``."""
    a = (near - zi) / (zo - zi)
    return xi + a * (xo - xi), yi + a * (yo - yi)


@njit(cache=True, inline="always")
def _setup_face(f, vc, faces, face_label, mesh_off, near, cull_back, fx, fy, cx, cy, W, H,
                tri, box, slot_label, s):
    """Cull, clip and set up face ``f`` into slots ``s`` (and ``s + 1``); returns the slots used."""
    lab = face_label[f]
    slot_label[s, 0] = lab
    slot_label[s, 1] = f
    vo = mesh_off[lab, 0]
    ia = faces[f, 0] + vo
    ib = faces[f, 1] + vo
    ic = faces[f, 2] + vo
    ax, ay, az = vc[ia, 0], vc[ia, 1], vc[ia, 2]
    bx, by, bz = vc[ib, 0], vc[ib, 1], vc[ib, 2]
    cx_, cy_, cz = vc[ic, 0], vc[ic, 1], vc[ic, 2]
    if az < near and bz < near and cz < near:
        return 0
    if cull_back:
        ux, uy, uz = bx - ax, by - ay, bz - az
        wx, wy, wz = cx_ - ax, cy_ - ay, cz - az
        nx = uy * wz - uz * wy
        ny = uz * wx - ux * wz
        nz = ux * wy - uy * wx
        if nx * ax + ny * ay + nz * az >= 0.0:
            return 0
    ina = az >= near
    inb = bz >= near
    inc = cz >= near
    n_in = int(ina) + int(inb) + int(inc)
    # rotate the face cyclically (winding kept) so that the polygon clipped by
    # Sutherland-Hodgman starts at p: one vertex behind -> it is r; two behind -> p is in front
    if n_in == 3 or (n_in == 2 and not inc) or (n_in == 1 and ina):
        px, py, pz, qx, qy, qz, rx, ry, rz = ax, ay, az, bx, by, bz, cx_, cy_, cz
    elif (n_in == 2 and not ina) or (n_in == 1 and inb):
        px, py, pz, qx, qy, qz, rx, ry, rz = bx, by, bz, cx_, cy_, cz, ax, ay, az
    else:
        px, py, pz, qx, qy, qz, rx, ry, rz = cx_, cy_, cz, ax, ay, az, bx, by, bz
    # project (equation 2); clip points lie on z = near
    ipz = 1.0 / pz
    spx = px * fx * ipz + cx
    spy = py * fy * ipz + cy
    inear = 1.0 / near
    if n_in == 3:      # triangle p, q, r
        iq = 1.0 / qz
        ir = 1.0 / rz
        s1x, s1y, i1 = qx * fx * iq + cx, qy * fy * iq + cy, iq
        s2x, s2y, i2 = rx * fx * ir + cx, ry * fy * ir + cy, ir
    elif n_in == 2:    # polygon p, q, X(q->r), X(p->r): fan (p, q, Xqr), (p, Xqr, Xpr)
        iq = 1.0 / qz
        x1, y1 = _clip_point(qx, qy, qz, rx, ry, rz, near)
        x2, y2 = _clip_point(px, py, pz, rx, ry, rz, near)
        s1x, s1y, i1 = qx * fx * iq + cx, qy * fy * iq + cy, iq
        s2x, s2y, i2 = x1 * fx * inear + cx, y1 * fy * inear + cy, inear
        s3x, s3y = x2 * fx * inear + cx, y2 * fy * inear + cy
    else:              # polygon p, X(p->q), X(p->r)
        x1, y1 = _clip_point(px, py, pz, qx, qy, qz, near)
        x2, y2 = _clip_point(px, py, pz, rx, ry, rz, near)
        s1x, s1y, i1 = x1 * fx * inear + cx, y1 * fy * inear + cy, inear
        s2x, s2y, i2 = x2 * fx * inear + cx, y2 * fy * inear + cy, inear
    k = _setup_one(spx, spy, ipz, s1x, s1y, i1, s2x, s2y, i2, W, H, tri, box, s)
    if n_in == 2:
        slot_label[s + k, 0] = lab
        slot_label[s + k, 1] = f
        k += _setup_one(spx, spy, ipz, s2x, s2y, inear, s3x, s3y, inear, W, H, tri, box, s + k)
    return k


@njit(cache=True, inline="always")
def _inside(x, A0, X0, r0, t0, A1, X1, r1, t1, A2, X2, r2, t2):
    """Pixel centre at column ``x`` of a row covered (edge values ``A (x - X) + r``, top-left ties)."""
    e0 = A0 * (x - X0) + r0
    if e0 < 0.0 or (e0 == 0.0 and not t0):
        return False
    e1 = A1 * (x - X1) + r1
    if e1 < 0.0 or (e1 == 0.0 and not t1):
        return False
    e2 = A2 * (x - X2) + r2
    if e2 < 0.0 or (e2 == 0.0 and not t2):
        return False
    return True


@njit(cache=True, nogil=True)
def _raster_rows(r0, r1, tri, box, slot_label, n_slots, wbuf, sbuf, depth, labels, face_ids):
    """Z-buffer slots ``0 .. n_slots-1`` into rows ``r0 .. r1-1``.

    The z-buffer holds ``w = 1/z`` (float64, 0 = nothing; nearer = larger ``w``,
    strictly, so on an exact tie the slot drawn first keeps the pixel) and the
    winning slot; the rows of ``depth = 1/w`` (float32, 0 = nothing),
    ``labels`` and ``face_ids`` (-1 = nothing) are written at the end. The
    z-buffer rows must be clear (0 / -1) on entry and are left clear on exit
    (cleared while the result is read out: one pass over memory less).
    """
    W = depth.shape[1]
    for s in range(n_slots):
        va = box[s, 2]
        vb = box[s, 3]
        if vb < r0 or va >= r1 or va > vb:
            continue
        va = max(va, r0)
        vb = min(vb, r1 - 1)
        ua = box[s, 0]
        ub = box[s, 1]
        A0 = tri[s, 0]
        B0 = tri[s, 1]
        X0 = tri[s, 2]
        Y0 = tri[s, 3]
        A1 = tri[s, 4]
        B1 = tri[s, 5]
        X1 = tri[s, 6]
        Y1 = tri[s, 7]
        A2 = tri[s, 8]
        B2 = tri[s, 9]
        X2 = tri[s, 10]
        Y2 = tri[s, 11]
        Pa = tri[s, 12]
        Pb = tri[s, 13]
        xw = tri[s, 14]
        yw = tri[s, 15]
        w0 = tri[s, 16]
        tl = int(tri[s, 17])
        t0 = (tl & 1) != 0
        t1 = (tl & 2) != 0
        t2 = (tl & 4) != 0
        narrow = ub - ua < 4
        i0 = 1.0 / A0 if A0 != 0.0 else 0.0
        i1 = 1.0 / A1 if A1 != 0.0 else 0.0
        i2 = 1.0 / A2 if A2 != 0.0 else 0.0
        for v in range(va, vb + 1):
            y = float(v)
            r0e = B0 * (y - Y0)
            r1e = B1 * (y - Y1)
            r2e = B2 * (y - Y2)
            rp = w0 + Pb * (y - yw)
            if narrow:  # a few columns: test each pixel
                for u in range(ua, ub + 1):
                    x = float(u)
                    if _inside(x, A0, X0, r0e, t0, A1, X1, r1e, t1, A2, X2, r2e, t2):
                        w = Pa * (x - xw) + rp
                        if w > wbuf[v, u]:
                            wbuf[v, u] = w
                            sbuf[v, u] = s
                continue
            # The covered pixels of a row form one interval (each edge test is monotone
            # in x, also in floating point). Estimate its ends from the edge crossings,
            # settle them with the exact tests, then fill without testing.
            lo = float(ua)
            hi = float(ub)
            if A0 > 0.0:
                lo = max(lo, X0 - r0e * i0)
            elif A0 < 0.0:
                hi = min(hi, X0 - r0e * i0)
            elif r0e < 0.0 or (r0e == 0.0 and not t0):
                continue
            if A1 > 0.0:
                lo = max(lo, X1 - r1e * i1)
            elif A1 < 0.0:
                hi = min(hi, X1 - r1e * i1)
            elif r1e < 0.0 or (r1e == 0.0 and not t1):
                continue
            if A2 > 0.0:
                lo = max(lo, X2 - r2e * i2)
            elif A2 < 0.0:
                hi = min(hi, X2 - r2e * i2)
            elif r2e < 0.0 or (r2e == 0.0 and not t2):
                continue
            if lo > hi + 1.0:
                continue
            a = max(ua, int(math.ceil(lo)) - 1)
            e = min(ub, int(math.floor(hi)) + 1)
            while a <= e and not _inside(float(a), A0, X0, r0e, t0, A1, X1, r1e, t1, A2, X2, r2e, t2):
                a += 1
            while e >= a and not _inside(float(e), A0, X0, r0e, t0, A1, X1, r1e, t1, A2, X2, r2e, t2):
                e -= 1
            for u in range(a, e + 1):
                w = Pa * (float(u) - xw) + rp
                if w > wbuf[v, u]:
                    wbuf[v, u] = w
                    sbuf[v, u] = s
    for v in range(r0, r1):
        for u in range(W):
            k = sbuf[v, u]
            if k >= 0:
                depth[v, u] = np.float32(1.0 / wbuf[v, u])
                labels[v, u] = slot_label[k, 0]
                face_ids[v, u] = slot_label[k, 1]
                wbuf[v, u] = 0.0   # leave the z-buffer cleared for the next call
                sbuf[v, u] = -1
            else:
                depth[v, u] = 0.0
                labels[v, u] = -1
                face_ids[v, u] = -1


@njit(cache=True, nogil=True)
def check_and_label(vw, n_v, faces, mesh_off, n_meshes, face_label):
    """Check the packed input and write ``face_label``.

    Returns ``(0, -1)`` if fine, ``(1, k)`` if a face of mesh ``k`` indexes a vertex
    outside that mesh, ``(2, -1)`` if a vertex is not finite.
    """
    for i in range(n_v):
        for k in range(3):
            if not math.isfinite(vw[i, k]):
                return 2, -1
    for k in range(n_meshes):
        nv = mesh_off[k + 1, 0] - mesh_off[k, 0]
        for f in range(mesh_off[k, 1], mesh_off[k + 1, 1]):
            face_label[f] = k
            for j in range(3):
                if faces[f, j] < 0 or faces[f, j] >= nv:
                    return 1, k
    return 0, -1


@njit(cache=True, nogil=True)
def render_packed(vw, n_v, faces, n_f, mesh_off, n_meshes, face_label, R, t, fx, fy, cx, cy,
                  near, cull_back, vc, tri, box, slot_label, wbuf, sbuf, depth, labels, face_ids):
    """Render packed buffers on one core (see the module docstring for shapes).

    Faces are set up into consecutive slots (culled / empty faces take none),
    then all rows are rasterised as one band. Returns ``(status, mesh, slots)``:
    status 0 = done, else the error of :func:`check_and_label` (nothing drawn).
    """
    H, W = depth.shape
    status, bad = check_and_label(vw, n_v, faces, mesh_off, n_meshes, face_label)
    if status != 0:
        return status, bad, 0
    for i in range(n_v):
        _transform_one(vw, R, t, vc, i)
    n = 0
    for f in range(n_f):
        n += _setup_face(f, vc, faces, face_label, mesh_off, near, cull_back, fx, fy, cx, cy, W, H,
                         tri, box, slot_label, n)
    _raster_rows(0, H, tri, box, slot_label, n, wbuf, sbuf, depth, labels, face_ids)
    return 0, -1, n


@njit(cache=True, parallel=True, nogil=True)
def render_packed_parallel(vw, n_v, faces, n_f, mesh_off, n_meshes, face_label, R, t, fx, fy, cx, cy,
                           near, cull_back, vc, tri, box, slot_label, n_bands, wbuf, sbuf,
                           depth, labels, face_ids):
    """Render packed buffers with numba threads: vertices and faces in parallel (face ``f``
    owns slots ``2f, 2f+1``), then ``n_bands`` disjoint bands of rows in parallel
    (no two tasks write the same pixel, so there are no races). Returns as :func:`render_packed`."""
    H, W = depth.shape
    status, bad = check_and_label(vw, n_v, faces, mesh_off, n_meshes, face_label)
    if status != 0:
        return status, bad, 0
    for i in prange(n_v):
        _transform_one(vw, R, t, vc, i)
    for f in prange(n_f):
        s = 2 * f
        box[s, 2] = 1        # both slots empty unless the face fills them: a culled face leaves
        box[s, 3] = 0        # its slots untouched, and they still hold the previous call's
        box[s + 1, 2] = 1    # triangles (drawn again: wrong pixels from the second call on)
        box[s + 1, 3] = 0
        _setup_face(f, vc, faces, face_label, mesh_off, near, cull_back, fx, fy, cx, cy, W, H,
                    tri, box, slot_label, s)
    rows = (H + n_bands - 1) // n_bands
    for b in prange(n_bands):
        r0 = b * rows
        _raster_rows(r0, min(H, r0 + rows), tri, box, slot_label, 2 * n_f, wbuf, sbuf,
                     depth, labels, face_ids)
    return 0, -1, 2 * n_f
