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

:func:`render_packed` runs on one core: each vertex is transformed and
projected once, then each face is culled, clipped, set up and drawn in turn
(its setup stays in registers; a face whose pixel box holds no pixel centre
costs no edge setup); the images are read out only over each row's span of
the pixels this call's and the last call's triangles cover
(:mod:`depthguard.render.raster_fill`, which holds the fill and the read-out).
:func:`render_packed_parallel` runs steps 1–2 over vertices / faces (into
slots) and step 3 over disjoint bands of rows with numba threads (no two tasks
write the same pixel: race-free, and the same image as the serial kernel).
On a loaded machine the serial kernel is the steadier one. (Issue 29: the
clustered UR3 in a 640x480 D435, 12k faces of which ~4.7k are drawn, most
covering a pixel or two: the per-face cost is what counts.)

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

The kernels are compiled with numba's ``error_model="numpy"`` (no zero-division check
per division): no division here can have a zero divisor (``z >= near > 0``, a
triangle's area is tested != 0, ``1/A`` only where ``A != 0``, ``1/w`` only where a
triangle won the pixel with ``w > 0``, a clipped edge has one end on each side of
the near plane).

Buffers (all preallocated by the caller, nothing is allocated here):

- ``vw`` (V, 3) float64 world vertices and ``faces`` (F, 3) int32 of all
  meshes one after the other, face indices local to their mesh; ``mesh_off``
  (M + 1, 2) int64 the first vertex and first face of each mesh (and the
  totals); only the first ``n_v`` / ``n_f`` rows are used. The kernels check
  them (finite vertices, indices within the mesh) before drawing anything,
  so bad input cannot make them read outside the buffers.
- ``face_label`` (F,) int32 mesh of each face (written by the kernel).
- ``vc`` (V, 6) float64 camera-frame vertices and, for those at or beyond
  the near plane, their pixel coordinates and ``1/z`` (workspace).
- parallel kernel only: ``tri`` (2F, 18) float64 per-slot setup (face ``f``
  owns slots ``2f, 2f+1``): for each of the three edges ``A, B`` and its
  anchor ``X, Y`` (12; ``E(S) = A (Sx - X) + B (Sy - Y)``), the ``1/z`` plane
  ``Pa, Pb`` with its anchor ``x0, y0, 1/z0`` (5), the top-left flags of the
  three edges as bits (1); ``box`` (2F, 4) int32 per-slot pixel bounding box
  ``u0, u1, v0, v1`` (empty when ``v0 > v1``).
- ``wbuf`` (H, W) float64 ``1/z`` z-buffer and ``sbuf`` (H, W) int32 winning
  packed face (workspace; all 0 / -1 between calls).
- ``depth`` (H, W) float32 metres (0 = nothing), ``labels`` (H, W) int32
  mesh label (-1 = nothing), ``face_ids`` (H, W) int32 packed face index
  (-1 = nothing): written only inside the rows' spans, so they must hold 0 / -1
  outside the last call's spans (``spans`` (H, 2) int32, per row ``[a, b)``,
  ``(0, 0)`` = none; updated by the kernel: this call's on return, so that
  every pixel of row ``v`` outside ``spans[v]`` is 0 / -1); ``rows`` (H, 2)
  int32 workspace (the spans as the triangles are drawn).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from depthguard.render.raster_fill import _fill, read_out_depth_rows, read_out_rows, reset_rows

__all__ = ["render_packed", "render_packed_parallel", "check_and_label"]

@njit(cache=True, error_model="numpy", inline="always")
def _transform_one(vw, R, t, vc, i):
    """``vc[i, :3] = R @ vw[i] + t`` (equation 1)."""
    x = vw[i, 0]
    y = vw[i, 1]
    z = vw[i, 2]
    for k in range(3):
        vc[i, k] = R[k, 0] * x + R[k, 1] * y + R[k, 2] * z + t[k]


@njit(cache=True, error_model="numpy", inline="always")
def _project_one(vc, i, near, fx, fy, cx, cy):
    """``vc[i, 3:6] = (px, py, 1/z)`` of a vertex at or beyond the near plane (equation 2,
    the operations of a per-face projection: the same bits); left as is otherwise."""
    z = vc[i, 2]
    if z >= near:
        iz = 1.0 / z
        vc[i, 3] = vc[i, 0] * fx * iz + cx
        vc[i, 4] = vc[i, 1] * fy * iz + cy
        vc[i, 5] = iz


@njit(cache=True, error_model="numpy", inline="always")
def _edge(x0, y0, x1, y1):
    """Edge function of the directed edge (x0,y0)->(x1,y1), anchored at its canonical end.

    Returns ``(A, B, px, py)`` with ``E(S) = A (Sx - px) + B (Sy - py)
    = (x1-x0)(Sy-y0) - (y1-y0)(Sx-x0)``, where ``(px, py)`` is the
    lexicographically smaller endpoint: the reversed edge gives exactly
    ``(-A, -B, px, py)``, and ``E`` is exactly 0 at both endpoints.
    """
    flip = (x1 < x0) | ((x1 == x0) & (y1 < y0))
    px = x1 if flip else x0
    py = y1 if flip else y0
    qx = x0 if flip else x1
    qy = y0 if flip else y1
    A = -(qy - py)
    B = qx - px
    return (-A if flip else A), (-B if flip else B), px, py


@njit(cache=True, error_model="numpy", inline="always")
def _tri_setup(x0, y0, iz0, x1, y1, iz1, x2, y2, iz2, W, H):
    """Screen-space setup of one triangle (``(x_i, y_i)`` pixel coordinates, ``iz_i = 1/z_i``).

    Returns ``(ok, A0, B0, X0, Y0, A1, B1, X1, Y1, A2, B2, X2, Y2, Pa, Pb, tl, u0, u1, v0, v1)``:
    per edge ``E(S) = A (Sx - X) + B (Sy - Y)`` (interior positive), the plane of ``1/z``
    (``w(S) = iz0 + Pa (Sx - x0) + Pb (Sy - y0)``), the top-left flags as bits and the pixel
    box; ``ok`` is False when the triangle cannot cover a pixel centre (its box holds none —
    tested first, in floats, so that most sub-pixel faces cost no edge setup — or its area is
    0 or not finite).
    """
    xmin = min(x0, min(x1, x2))
    xmax = max(x0, max(x1, x2))
    ymin = min(y0, min(y1, y2))
    ymax = max(y0, max(y1, y2))
    fu0 = math.ceil(max(xmin, -1.0))
    fu1 = math.floor(min(xmax, W * 1.0))
    fv0 = math.ceil(max(ymin, -1.0))
    fv1 = math.floor(min(ymax, H * 1.0))
    if max(fu0, 0.0) > min(fu1, W - 1.0) or max(fv0, 0.0) > min(fv1, H - 1.0):   # (a NaN passes:
        return False, 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0, 1, 0, 1, 0  # area test)
    A0, B0, X0, Y0 = _edge(x1, y1, x2, y2)  # opposite vertex 0
    A1, B1, X1, Y1 = _edge(x2, y2, x0, y0)  # opposite vertex 1
    A2, B2, X2, Y2 = _edge(x0, y0, x1, y1)  # opposite vertex 2
    area = A2 * (x2 - X2) + B2 * (y2 - Y2)  # E_2 at vertex 2 = twice the signed area
    if area == 0.0 or not math.isfinite(area):
        return False, 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0, 1, 0, 1, 0
    if area < 0.0:  # make the interior positive for all three edges
        A0, B0, A1, B1, A2, B2 = -A0, -B0, -A1, -B1, -A2, -B2
        area = -area
    u0 = max(int(fu0), 0)
    u1 = min(int(fu1), W - 1)
    v0 = max(int(fv0), 0)
    v1 = min(int(fv1), H - 1)
    # 1/z is linear in screen space: w(S) = sum_i iz_i E_i(S) / area = iz0 + Pa (Sx - x0) + Pb (Sy - y0)
    Pa = (iz0 * A0 + iz1 * A1 + iz2 * A2) / area
    Pb = (iz0 * B0 + iz1 * B1 + iz2 * B2) / area
    # top-left edges: oriented direction (dx, dy) = (B, -A); top-left iff dy < 0 or (dy == 0 and dx > 0)
    tl = (int((A0 > 0.0) | ((A0 == 0.0) & (B0 > 0.0))) | (int((A1 > 0.0) | ((A1 == 0.0) & (B1 > 0.0))) << 1)
          | (int((A2 > 0.0) | ((A2 == 0.0) & (B2 > 0.0))) << 2))
    return True, A0, B0, X0, Y0, A1, B1, X1, Y1, A2, B2, X2, Y2, Pa, Pb, tl, u0, u1, v0, v1


@njit(cache=True, error_model="numpy", inline="always")
def _clip_point(xi, yi, zi, xo, yo, zo, near):
    """Point of the segment (inside -> outside) on the plane ``z = near``."""
    a = (near - zi) / (zo - zi)
    return xi + a * (xo - xi), yi + a * (yo - yi)


@njit(cache=True, error_model="numpy", inline="always")
def _clip_face(vc, ia, ib, ic, near, cull_back, fx, fy, cx, cy):
    """Cull and clip the face with packed vertex rows ``ia, ib, ic`` of ``vc`` (projected by
    :func:`_project_one`). Returns ``(n, px, py, pz, x1, y1, iz1, x2, y2, iz2, x3, y3)``:
    ``n`` screen triangles (0, 1 or 2) ``(P, S1, S2)`` and ``(P, S2, S3)``, the points in pixel
    coordinates with their ``1/z`` (``S3`` lies on the near plane, ``1/z = 1/near``)."""
    ax, ay, az = vc[ia, 0], vc[ia, 1], vc[ia, 2]
    bx, by, bz = vc[ib, 0], vc[ib, 1], vc[ib, 2]
    cx_, cy_, cz = vc[ic, 0], vc[ic, 1], vc[ic, 2]
    if az < near and bz < near and cz < near:
        return 0, 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0.
    if cull_back:
        ux, uy, uz = bx - ax, by - ay, bz - az
        wx, wy, wz = cx_ - ax, cy_ - ay, cz - az
        nx = uy * wz - uz * wy
        ny = uz * wx - ux * wz
        nz = ux * wy - uy * wx
        if nx * ax + ny * ay + nz * az >= 0.0:
            return 0, 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0.
    ina = az >= near
    inb = bz >= near
    inc = cz >= near
    n_in = int(ina) + int(inb) + int(inc)
    if n_in == 3:      # the common case: the projections are the vertices' own
        return (1, vc[ia, 3], vc[ia, 4], vc[ia, 5], vc[ib, 3], vc[ib, 4], vc[ib, 5],
                vc[ic, 3], vc[ic, 4], vc[ic, 5], 0., 0.)
    # rotate the face cyclically (winding kept) so that the polygon clipped by
    # Sutherland-Hodgman starts at p: one vertex behind -> it is r; two behind -> p is in front
    if (n_in == 2 and not inc) or (n_in == 1 and ina):
        ip, iq = ia, ib
        px, py, pz, qx, qy, qz, rx, ry, rz = ax, ay, az, bx, by, bz, cx_, cy_, cz
    elif (n_in == 2 and not ina) or (n_in == 1 and inb):
        ip, iq = ib, ic
        px, py, pz, qx, qy, qz, rx, ry, rz = bx, by, bz, cx_, cy_, cz, ax, ay, az
    else:
        ip, iq = ic, ia
        px, py, pz, qx, qy, qz, rx, ry, rz = cx_, cy_, cz, ax, ay, az, bx, by, bz
    # p is in front: its projection (equation 2) is the vertex's own; clip points lie on z = near
    inear = 1.0 / near
    if n_in == 2:      # polygon p, q, X(q->r), X(p->r): fan (p, q, Xqr), (p, Xqr, Xpr)
        x1, y1 = _clip_point(qx, qy, qz, rx, ry, rz, near)
        x2, y2 = _clip_point(px, py, pz, rx, ry, rz, near)
        return (2, vc[ip, 3], vc[ip, 4], vc[ip, 5], vc[iq, 3], vc[iq, 4], vc[iq, 5],
                x1 * fx * inear + cx, y1 * fy * inear + cy, inear, x2 * fx * inear + cx, y2 * fy * inear + cy)
    # polygon p, X(p->q), X(p->r)
    x1, y1 = _clip_point(px, py, pz, qx, qy, qz, near)
    x2, y2 = _clip_point(px, py, pz, rx, ry, rz, near)
    return (1, vc[ip, 3], vc[ip, 4], vc[ip, 5], x1 * fx * inear + cx, y1 * fy * inear + cy, inear,
            x2 * fx * inear + cx, y2 * fy * inear + cy, inear, 0., 0.)


@njit(cache=True, error_model="numpy", nogil=True)
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


@njit(cache=True, error_model="numpy", nogil=True)
def render_packed(vw, n_v, faces, n_f, mesh_off, n_meshes, face_label, R, t, fx, fy, cx, cy,
                  near, cull_back, vc, wbuf, sbuf, depth, labels, face_ids, rows, spans, ids=True):
    """Render packed buffers on one core (see the module docstring for shapes).

    The input is checked as it is used (each vertex before it is transformed, a face's
    indices before it is drawn), all before anything is drawn (a bad index returns
    before the z-buffer is read out). Each face is culled, clipped, set up and drawn in
    turn (its setup stays in registers), then the images are read out over the rows' spans
    of this call's and the last call's pixels (``rows``, ``spans``:
    :mod:`~depthguard.render.raster_fill`). Returns ``(status, mesh, triangles drawn)``:
    status 0 = done, else the error of :func:`check_and_label`. ``ids`` False: a depth-only
    render (``sbuf``, ``labels``, ``face_ids`` are not touched; the same depth and spans).
    """
    H, W = depth.shape
    for i in range(n_v):
        if not (math.isfinite(vw[i, 0]) and math.isfinite(vw[i, 1]) and math.isfinite(vw[i, 2])):
            return 2, -1, 0
        _transform_one(vw, R, t, vc, i)
        _project_one(vc, i, near, fx, fy, cx, cy)
    for k in range(n_meshes):   # indices first: a bad one must leave the z-buffer untouched
        nv = mesh_off[k + 1, 0] - mesh_off[k, 0]
        for f in range(mesh_off[k, 1], mesh_off[k + 1, 1]):
            face_label[f] = k
            if (faces[f, 0] < 0 or faces[f, 0] >= nv or faces[f, 1] < 0 or faces[f, 1] >= nv
                    or faces[f, 2] < 0 or faces[f, 2] >= nv):
                return 1, k, 0
    n = 0
    reset_rows(rows, np.int64(0), H, W)          # int64, not Literal[int](0): the one compiled signature
    for k in range(n_meshes):
        vo = mesh_off[k, 0]
        for f in range(mesh_off[k, 1], mesh_off[k + 1, 1]):
            m, px, py, pz, x1, y1, i1, x2, y2, i2, x3, y3 = _clip_face(
                vc, faces[f, 0] + vo, faces[f, 1] + vo, faces[f, 2] + vo, near, cull_back, fx, fy, cx, cy)
            for j in range(m):
                if j == 0:
                    (ok, A0, B0, X0, Y0, A1, B1, X1, Y1, A2, B2, X2, Y2, Pa, Pb, tl,
                     u0, u1, v0, v1) = _tri_setup(px, py, pz, x1, y1, i1, x2, y2, i2, W, H)
                else:
                    (ok, A0, B0, X0, Y0, A1, B1, X1, Y1, A2, B2, X2, Y2, Pa, Pb, tl,
                     u0, u1, v0, v1) = _tri_setup(px, py, pz, x2, y2, i2, x3, y3, i2, W, H)
                if not ok:
                    continue
                _fill(f, A0, B0, X0, Y0, A1, B1, X1, Y1, A2, B2, X2, Y2, Pa, Pb, px, py, pz, tl,
                      u0, u1, v0, v1, wbuf, sbuf, rows, ids)
                n += 1
    if ids:
        read_out_rows(np.int64(0), H, wbuf, sbuf, face_label, depth, labels, face_ids, rows, spans)
    else:
        read_out_depth_rows(np.int64(0), H, wbuf, depth, rows, spans)
    return 0, -1, n


@njit(cache=True, error_model="numpy", parallel=True, nogil=True)
def render_packed_parallel(vw, n_v, faces, n_f, mesh_off, n_meshes, face_label, R, t, fx, fy, cx, cy,
                           near, cull_back, vc, tri, box, n_bands, wbuf, sbuf,
                           depth, labels, face_ids, rows, spans):
    """Render packed buffers with numba threads: vertices and faces in parallel (face ``f``
    sets up slots ``2f, 2f+1`` of ``tri`` / ``box``), then ``n_bands`` disjoint bands of rows
    in parallel (no two tasks write the same pixel, so there are no races), drawing the slots
    in order: the image of :func:`render_packed`. Returns as :func:`render_packed`."""
    H, W = depth.shape
    status, bad = check_and_label(vw, n_v, faces, mesh_off, n_meshes, face_label)
    if status != 0:
        return status, bad, 0
    for i in prange(n_v):
        _transform_one(vw, R, t, vc, i)
        _project_one(vc, i, near, fx, fy, cx, cy)
    for f in prange(n_f):
        vo = mesh_off[face_label[f], 0]
        m, px, py, pz, x1, y1, i1, x2, y2, i2, x3, y3 = _clip_face(
            vc, faces[f, 0] + vo, faces[f, 1] + vo, faces[f, 2] + vo, near, cull_back, fx, fy, cx, cy)
        for j in range(2):
            s = 2 * f + j
            box[s, 2] = 1        # empty unless the face fills it (a slot is rewritten every call)
            box[s, 3] = 0
            if j >= m:
                continue
            if j == 0:
                (ok, A0, B0, X0, Y0, A1, B1, X1, Y1, A2, B2, X2, Y2, Pa, Pb, tl,
                 u0, u1, v0, v1) = _tri_setup(px, py, pz, x1, y1, i1, x2, y2, i2, W, H)
            else:
                (ok, A0, B0, X0, Y0, A1, B1, X1, Y1, A2, B2, X2, Y2, Pa, Pb, tl,
                 u0, u1, v0, v1) = _tri_setup(px, py, pz, x2, y2, i2, x3, y3, i2, W, H)
            if not ok:
                continue
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
            tri[s, 12] = Pa
            tri[s, 13] = Pb
            tri[s, 14] = px
            tri[s, 15] = py
            tri[s, 16] = pz
            tri[s, 17] = tl
            box[s, 0] = u0
            box[s, 1] = u1
            box[s, 2] = v0
            box[s, 3] = v1
    n = 0
    for s in range(2 * n_f):
        if box[s, 2] <= box[s, 3]:
            n += 1
    band = (H + n_bands - 1) // n_bands
    for b in prange(n_bands):
        r0 = b * band
        r1 = min(H, r0 + band)
        reset_rows(rows, r0, r1, W)
        for s in range(2 * n_f):
            va = box[s, 2]
            vb = box[s, 3]
            if vb < r0 or va >= r1 or va > vb:
                continue
            _fill(s >> 1, tri[s, 0], tri[s, 1], tri[s, 2], tri[s, 3], tri[s, 4], tri[s, 5], tri[s, 6],
                  tri[s, 7], tri[s, 8], tri[s, 9], tri[s, 10], tri[s, 11], tri[s, 12], tri[s, 13],
                  tri[s, 14], tri[s, 15], tri[s, 16], int(tri[s, 17]), box[s, 0], box[s, 1],
                  max(va, r0), min(vb, r1 - 1), wbuf, sbuf, rows)
        read_out_rows(r0, r1, wbuf, sbuf, face_label, depth, labels, face_ids, rows, spans)
    return 0, -1, n
