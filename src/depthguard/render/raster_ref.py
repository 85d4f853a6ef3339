"""Plain-numpy twin of the rasteriser in :mod:`depthguard.render.raster` (R16).

Slow (a Python loop over triangles, numpy over each triangle's pixel box) and
only for tests on small images. It reads like the equations:

    P_c = R P_w + t                                   (1)
    px = x fx / z + cx,  py = y fy / z + cy           (2)
    1/z interpolated linearly in screen space (perspective-correct depth)

and follows the same conventions as the kernel: back faces culled in the
camera frame, Sutherland–Hodgman clipping against ``z = near`` (the polygon
started at the same vertex, fanned the same way), pixel centres at integer
coordinates, the top-left fill rule with canonically evaluated edges, and
nearest wins: the largest 1/z (float64; the first drawn on an exact tie),
stored as depth = float32(1 / (1/z)).
"""

from __future__ import annotations

import numpy as np

from depthguard.geometry.mesh import as_mesh

__all__ = ["render_depth_numpy"]


def render_depth_numpy(cam, meshes, near: float = 0.01, cull_back: bool = True):
    """Reference rendering of ``meshes`` (world coordinates) into ``cam``.

    Returns ``depth`` (H, W) float32 metres (0 = nothing), ``labels`` (H, W)
    int32 mesh index (-1 = nothing) and ``faces`` (H, W) int32 face index
    within that mesh (-1 = nothing).
    """
    H, W = cam.height, cam.width
    wbuf = np.zeros((H, W))                                      # 1/z, 0 = nothing
    labels = np.full((H, W), -1, dtype=np.int32)
    faces = np.full((H, W), -1, dtype=np.int32)
    for k, m in enumerate(meshes):
        m = as_mesh(m, name=f"meshes[{k}]")
        R, t, P = cam.R, cam.t, m.vertices
        # (1), written out row by row (the same order of operations as the kernel)
        vc = np.stack([R[j, 0] * P[:, 0] + R[j, 1] * P[:, 1] + R[j, 2] * P[:, 2] + t[j]
                       for j in range(3)], axis=1)
        for i, face in enumerate(m.faces):
            a, b, c = vc[face]
            if a[2] < near and b[2] < near and c[2] < near:
                continue
            if cull_back and np.dot(np.cross(b - a, c - a), a) >= 0.0:
                continue                                         # seen from behind
            for tri in _fan(_clip_near([a, b, c], near)):
                _draw(cam, tri, k, i, wbuf, labels, faces)
    depth = np.zeros((H, W), dtype=np.float32)
    hit = wbuf > 0.0
    depth[hit] = (1.0 / wbuf[hit]).astype(np.float32)
    return depth, labels, faces


def _clip_near(poly, near):
    """Sutherland–Hodgman against ``z >= near``, started so that the output is
    ``p, q, X(q,r), X(p,r)`` (one vertex behind) or ``p, X(p,q), X(p,r)`` (two behind)."""
    inside = [p[2] >= near for p in poly]
    n_in = sum(inside)
    if n_in == 2:
        start = (inside.index(False) + 1) % 3          # the vertex after the one behind
    elif n_in == 1:
        start = inside.index(True)
    else:
        start = 0
    poly = poly[start:] + poly[:start]
    inside = inside[start:] + inside[:start]
    out = []
    for i in range(3):
        p, q = poly[i], poly[(i + 1) % 3]
        if inside[i]:
            out.append(p)
        if inside[i] != inside[(i + 1) % 3]:
            pin, pout = (p, q) if inside[i] else (q, p)
            a = (near - pin[2]) / (pout[2] - pin[2])
            x = pin + a * (pout - pin)
            out.append(np.array([x[0], x[1], near]))
    return out


def _fan(poly):
    return [[poly[0], poly[i], poly[i + 1]] for i in range(1, len(poly) - 1)]


def _edge(p, q):
    """``(A, B, X, Y)`` with ``E(S) = (qx-px)(Sy-py) - (qy-py)(Sx-px) = A (Sx - X) + B (Sy - Y)``,
    anchored at the lexicographically smaller endpoint ``(X, Y)`` (exact antisymmetry)."""
    flip = (q[0], q[1]) < (p[0], p[1])
    if flip:
        p, q = q, p
    A = -(q[1] - p[1])
    B = q[0] - p[0]
    return (-A, -B, p[0], p[1]) if flip else (A, B, p[0], p[1])


def _draw(cam, tri, label, face, wbuf, labels, faces):
    """Z-buffer one triangle: where it covers a pixel centre with a larger ``1/z`` (nearer), it wins."""
    H, W = wbuf.shape
    iz = np.array([1.0 / p[2] for p in tri])
    s = [(p[0] * cam.fx * (1.0 / p[2]) + cam.cx, p[1] * cam.fy * (1.0 / p[2]) + cam.cy) for p in tri]  # (2)
    E = [_edge(s[1], s[2]), _edge(s[2], s[0]), _edge(s[0], s[1])]   # E[i] is opposite vertex i
    A2, B2, X2, Y2 = E[2]
    area = A2 * (s[2][0] - X2) + B2 * (s[2][1] - Y2)               # twice the signed area
    if area == 0.0 or not np.isfinite(area):
        return
    if area < 0.0:                                                # interior positive
        E = [(-A, -B, X, Y) for A, B, X, Y in E]
        area = -area
    xs, ys = [p[0] for p in s], [p[1] for p in s]
    u0, u1 = max(int(np.ceil(max(min(xs), -1.0))), 0), min(int(np.floor(min(max(xs), W))), W - 1)
    v0, v1 = max(int(np.ceil(max(min(ys), -1.0))), 0), min(int(np.floor(min(max(ys), H))), H - 1)
    if u0 > u1 or v0 > v1:
        return
    u, v = np.meshgrid(np.arange(u0, u1 + 1, dtype=np.float64), np.arange(v0, v1 + 1, dtype=np.float64))
    inside = np.ones(u.shape, dtype=bool)
    for A, B, X, Y in E:
        e = A * (u - X) + B * (v - Y)
        top_left = A > 0.0 or (A == 0.0 and B > 0.0)
        inside &= (e > 0.0) | ((e == 0.0) & top_left)
    # 1/z(u, v) = sum_i iz_i E_i(u, v) / area: linear in screen space
    Pa = (iz[0] * E[0][0] + iz[1] * E[1][0] + iz[2] * E[2][0]) / area
    Pb = (iz[0] * E[0][1] + iz[1] * E[1][1] + iz[2] * E[2][1]) / area
    w = Pa * (u - s[0][0]) + (iz[0] + Pb * (v - s[0][1]))
    win = wbuf[v0:v1 + 1, u0:u1 + 1]
    lab = labels[v0:v1 + 1, u0:u1 + 1]
    nearer = inside & (w > win)                 # nearest wins: the larger 1/z
    win[nearer] = w[nearer]
    lab[nearer] = label
    faces[v0:v1 + 1, u0:u1 + 1][nearer] = face
