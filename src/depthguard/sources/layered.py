"""One simulated camera's frames as a static scene plus moving layers, in two passes (R16, R28, issue 29).

The static scene of a camera does not move: its ideal depth, its depth edges and the count of
its valid and edge pixels per row are computed once (:class:`LayeredCamera`). A frame brings
the moving layers — the robot at its joints, the people and props — as depth images (0 =
nothing), and only the pixels they can change are worked again:

1. :func:`layer_spans`: per row, the span ``[a, b)`` of a layer's nonzero pixels (a run list;
   on the built-in cells 10-30 % of a 640x480 image), read only inside the window its meshes
   project to (:func:`mesh_window`);
2. :func:`compose_edges`, one sweep down the rows: the previous frame's spans are restored from
   the static scene, the layers are combined with it per pixel in their spans — the robot's and
   the person's as two intervals, not their hull (the nearest surface wins:
   :func:`depthguard.render.composite.nearest_depth`'s rule) — and the depth edges are found
   again in the spans grown by the edge test's reach (one pixel and one row,
   :mod:`depthguard.sources.layer_edges`); the per-row counts of valid and edge pixels follow,
   so the draws are known before any is made;
3. the draws of :func:`depthguard.sources.noise.apply_noise`, in its order;
4. :func:`~depthguard.sources.frame_measure.measure_frame`: one pass over the image — the noise
   model, the range rule and the invalid pixels' policy (``camera_sim``'s step 3) together.

The result is bit for bit the frame of the former way (copy the static scene, ``nearest_depth``
of each layer, ``apply_noise``, ``returns_beyond_the_model``), which stays as
:func:`reference_frame` — with ``use_numpy=True`` on the plain-numpy twins — for the tests and
the bench (``sim.ur3_cell.frame_cpu_ms``). The kernels run on the calling thread and allocate
nothing; the frame's own image is the one allocation. Their loops run on 0-based row slices
(``a[v, a0:b0]``), so that the compiler makes vector instructions of them: a loop from a span's
start keeps numba's negative-index check and ran 3x slower (issue 29).
"""

from __future__ import annotations

import numba
import numpy as np

from depthguard.config import PRODUCT_INVALID   # the product's defaults, defined once
from depthguard.render.composite import nearest_depth
from depthguard.sources.frame_measure import dark_layer, depth_of, measure_frame
from depthguard.sources.layer_edges import _edges_span, static_edges
from depthguard.sources.noise import EDGE_JUMP_ABS, EDGE_JUMP_REL, _draws, _params, apply_noise

__all__ = ["LayeredCamera", "layer_spans", "mesh_window", "layer_window", "compose_edges", "measure_frame", "reference_frame",
           "POLICY_CODES"]

#: the invalid pixels' policies (``camera_sim.INVALID_POLICIES``) as kernel codes
POLICY_CODES = {None: 0, "unknown": 1, "free": 2}


@numba.njit(cache=True)      # microseconds: keeps the GIL (a release costs a retake behind the other threads)
def _copy_spans(dst, src):
    """``dst[:] = src`` for two (H, 2) int32 row spans."""
    for v in range(dst.shape[0]):
        dst[v, 0] = src[v, 0]
        dst[v, 1] = src[v, 1]


@numba.njit(cache=True, nogil=True)
def layer_spans(bits, spans, v0, v1, u0, u1):
    """Per row, the span of a layer's nonzero pixels (step 1 of the module docstring).

    bits : (H, W) uint32, the layer's float32 bits (``layer.view(np.uint32)``); spans : (H, 2)
    int32, filled with ``[a, b)`` such that every pixel of row ``v`` outside it is +0.0 (``(0,
    0)``: none). Only the window rows ``[v0, v1)``, columns ``[u0, u1)`` are read: the caller
    knows the layer is 0 outside it (:func:`mesh_window`; the whole image when it does not).
    Rows are scanned 16 words at a time from both ends. Returns the pixels spanned.
    """
    H, W = bits.shape
    v0 = max(v0, 0)
    v1 = min(v1, H)
    u0 = max(u0, 0)
    u1 = min(u1, W)
    total = 0
    for v in range(H):
        spans[v, 0] = 0
        spans[v, 1] = 0
        if v < v0 or v >= v1 or u1 <= u0:
            continue
        row = bits[v]
        a = u0
        while a + 16 <= u1:
            acc = np.uint32(0)
            for j in range(16):
                acc |= row[a + j]
            if acc != 0:
                break
            a += 16
        while a < u1 and row[a] == 0:
            a += 1
        if a == u1:
            continue
        b = u1
        while b - 16 >= a:
            acc = np.uint32(0)
            for j in range(16):
                acc |= row[b - 16 + j]
            if acc != 0:
                break
            b -= 16
        while row[b - 1] == 0:
            b -= 1
        spans[v, 0] = a
        spans[v, 1] = b
        total += b - a
    return total


@numba.njit(cache=True, nogil=True)
def mesh_window(vertices, R, t, fx, fy, cx, cy, near, win):
    """Grow ``win`` (4,) int64 ``[v0, v1, u0, u1]`` (pixel rows / columns, half-open) to hold every
    pixel a renderer (``px = x fx / z + cx``, camera point ``R p + t``) can draw of triangles with
    the world ``vertices`` (V, 3) float64 m: their projected box and 2 pixels around it. A vertex
    at or behind the near plane ``near`` m (a clipped triangle reaches anywhere): the whole image.
    Returns False then."""
    for i in range(vertices.shape[0]):
        x, y, z = vertices[i, 0], vertices[i, 1], vertices[i, 2]
        zc = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
        if not zc > near:
            win[0] = -(1 << 30)
            win[1] = 1 << 30
            win[2] = -(1 << 30)
            win[3] = 1 << 30
            return False
        px = (R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]) * fx / zc + cx
        py = (R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]) * fy / zc + cy
        if not (abs(px) < 1e9 and abs(py) < 1e9):
            px = 1e9 if not px < 0.0 else -1e9
            py = 1e9 if not py < 0.0 else -1e9
        win[0] = min(win[0], np.int64(np.floor(py)) - 2)
        win[1] = max(win[1], np.int64(np.ceil(py)) + 3)
        win[2] = min(win[2], np.int64(np.floor(px)) - 2)
        win[3] = max(win[3], np.int64(np.ceil(px)) + 3)
    return True


def layer_window(meshes, cam, near: float, pose=None, win=None) -> tuple | None:
    """The pixel window ``(v0, v1, u0, u1)`` of camera ``cam`` that holds everything ``meshes``
    (world :class:`~depthguard.geometry.Mesh`) can draw with a renderer's near plane ``near`` m
    (:func:`mesh_window`), None: the whole image (also for meshes given another way). ``pose``:
    the camera's ``(R, t)`` as C-contiguous float64, ``win`` (4,) int64 scratch, to reuse."""
    R, tr = pose if pose is not None else (np.ascontiguousarray(cam.R, dtype=np.float64),
                                           np.ascontiguousarray(cam.t, dtype=np.float64))
    win = np.empty(4, np.int64) if win is None else win
    win[:] = (1 << 30, -(1 << 30), 1 << 30, -(1 << 30))
    for m in meshes:
        v = getattr(m, "vertices", None)
        if not (isinstance(v, np.ndarray) and v.dtype == np.float64 and v.ndim == 2 and v.shape[1] == 3):
            return None
        if not mesh_window(v, R, tr, float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy), float(near), win):
            return None
    return int(win[0]), int(win[1]), int(win[2]), int(win[3])


@numba.njit(cache=True, nogil=True, inline="always")
def _hull(spans, r0, r1, grow, W):
    """``[a, b)``: the hull of the non-empty ``spans[r0:r1]``, grown by ``grow`` and clipped to
    ``[0, W)``; ``(0, 0)`` when all are empty."""
    a = W
    b = 0
    for r in range(r0, r1):
        if spans[r, 1] > spans[r, 0]:
            a = min(a, spans[r, 0])
            b = max(b, spans[r, 1])
    if b <= a:
        return 0, 0
    return max(a - grow, 0), min(b + grow, W)


@numba.njit(cache=True, nogil=True, inline="always")
def _union(xa, xb, ya, yb):
    """The union of ``[xa, xb)`` and ``[ya, yb)`` (either may be empty) as a *pair* ``(a0, b0, a1,
    b1)``: two disjoint intervals, ``a0 <= b0 <= a1 <= b1`` (one interval: ``a1 = b1 = b0``;
    none: ``(0, 0, 0, 0)``), merged when they overlap or touch."""
    if xb <= xa:
        if yb <= ya:
            return 0, 0, 0, 0
        return ya, yb, yb, yb
    if yb <= ya:
        return xa, xb, xb, xb
    if ya < xa:
        xa, xb, ya, yb = ya, yb, xa, xb
    if ya <= xb:
        b = max(xb, yb)
        return xa, b, b, b
    return xa, xb, ya, yb


@numba.njit(cache=True, nogil=True, inline="always")
def _pair_hull(r_spans, p_spans, r0, r1, grow, W):
    """The pair (:func:`_union`) of the robot's and the person's hulls (:func:`_hull`) over rows
    ``r0 .. r1 - 1``, each grown by ``grow``: the two layers apart, not the gap between them."""
    ra, rb = _hull(r_spans, r0, r1, grow, W)
    pa, pb = _hull(p_spans, r0, r1, grow, W)
    return _union(ra, rb, pa, pb)


@numba.njit(cache=True, nogil=True, inline="always")
def _copy(dst, src):
    """``dst[:] = src`` (n,), a loop from 0 (vector instructions)."""
    for u in range(dst.shape[0]):
        dst[u] = src[u]


@numba.njit(cache=True, nogil=True, inline="always")
def _restore(dst, src, v, x, y, n0, n1, n2, n3):
    """``dst[v, u] = src[v, u]`` for ``u`` in ``[x, y)`` outside the pair ``(n0, n1, n2, n3)``
    (all >= 0: plain slices)."""
    if y <= x:
        return
    _copy(dst[v, x:min(y, n0)], src[v, x:min(y, n0)])
    _copy(dst[v, max(x, n1):min(y, n2)], src[v, max(x, n1):min(y, n2)])
    _copy(dst[v, max(x, n3):y], src[v, max(x, n3):y])


@numba.njit(cache=True, nogil=True, inline="always")
def _nearest(zc, static, layer):
    """``zc = static`` with ``layer`` nearer where it has a surface (n,) float32 m:
    :func:`depthguard.render.composite.nearest_depth`'s rule, a loop from 0."""
    for u in range(zc.shape[0]):
        x = static[u]
        y = layer[u]
        zc[u] = y if (y > 0.0) & ((x == 0.0) | (y < x)) else x


@numba.njit(cache=True, nogil=True, inline="always")
def _nearest2(zc, static, person, robot):
    """:func:`_nearest` of the person, then of the robot, in one loop."""
    for u in range(zc.shape[0]):
        x = static[u]
        y = person[u]
        x = y if (y > 0.0) & ((x == 0.0) | (y < x)) else x
        y = robot[u]
        zc[u] = y if (y > 0.0) & ((x == 0.0) | (y < x)) else x


@numba.njit(cache=True, nogil=True, inline="always")
def _depths(zr, zc):
    """``zr`` (n,) float64 = :func:`~depthguard.sources.frame_measure.depth_of` of ``zc`` (n,) float32."""
    for u in range(zr.shape[0]):
        zr[u] = depth_of(zc[u])


@numba.njit(cache=True, nogil=True, inline="always")
def _blend(zc, static, robot, person, v, a, b, has_r, has_p):
    """Row ``v``, columns ``[a, b)`` (>= 0) of the composite: the nearest of static, person, robot
    (:func:`depthguard.render.composite.nearest_depth`'s rule, person first, then robot)."""
    if b <= a:
        return
    if has_p and has_r:
        _nearest2(zc[v, a:b], static[v, a:b], person[v, a:b], robot[v, a:b])
    elif has_p:
        _nearest(zc[v, a:b], static[v, a:b], person[v, a:b])
    else:
        _nearest(zc[v, a:b], static[v, a:b], robot[v, a:b])


@numba.njit(cache=True, nogil=True)
def compose_edges(static, s_edge, s_other, s_valid_cum, s_edge_cum, robot, r_spans, person, p_spans,
                  zc, edge, other, valid_row, edge_row, c_spans, e_spans, rows, jump_abs, jump_rel, do_edges):
    """Step 2 of the module docstring, in place, in one sweep down the rows.

    static (H, W) float32 m raw (0 = nothing) with its ``s_edge`` (H, W) uint8, ``s_other`` (H, W)
    float32 m, ``s_valid_cum``, ``s_edge_cum`` (H, W + 1) int32 (:func:`static_edges`); the layers
    ``robot``, ``person`` (H, W) float32 m with their spans ``r_spans``, ``p_spans`` (H, 2) int32
    (:func:`layer_spans`; all ``(0, 0)``: no layer, the image is then not read).
    The frame's state: ``zc`` (H, W) float32 the raw composite, ``edge``, ``other`` as the static
    ones (``other`` and ``s_other`` (1, W): not kept, a scratch row — only flying pixels read them),
    ``valid_row``, ``edge_row`` (H,) int64 the counts per row; ``c_spans``, ``e_spans`` (H, 4)
    int32 per row the pair (:func:`_union`: two disjoint intervals) of pixels composed and
    edge-tested, on entry the previous frame's (restored from the static scene first), on return
    this frame's; ``rows`` (3, W) float64 scratch: three rows of the composite as the edge test
    reads it (:func:`~depthguard.sources.frame_measure.depth_of`). ``do_edges`` False
    (noiseless): the composite alone. Row ``i`` is composed, row ``i - 2`` read into ``rows``,
    row ``i - 3`` edge-tested — while the rows are in the cache. The robot's and the person's
    pixels are worked as two intervals per row, not their hull (issue 29: the gap between them
    was a third of the hull's pixels on the ur3-cell, half on the flacco-cell).
    Returns ``(valid pixels, edge pixels)`` of the frame.
    """
    H, W = static.shape
    n_valid = 0
    n_edge = 0
    keep = other.shape[0] > 1                # the depths across the edges are kept (ToF)
    for i in range(H + 3):
        if i < H:                            # compose row i: the nearest of static, person, robot
            v = i
            ra, rb = r_spans[v, 0], r_spans[v, 1]
            pa, pb = p_spans[v, 0], p_spans[v, 1]
            a0, b0, a1, b1 = _union(ra, rb, pa, pb)
            # the previous frame's pixels that this one does not compose again: back to static
            _restore(zc, static, v, c_spans[v, 0], c_spans[v, 1], a0, b0, a1, b1)
            _restore(zc, static, v, c_spans[v, 2], c_spans[v, 3], a0, b0, a1, b1)
            c_spans[v, 0] = a0
            c_spans[v, 1] = b0
            c_spans[v, 2] = a1
            c_spans[v, 3] = b1
            has_r = rb > ra
            has_p = pb > pa
            _blend(zc, static, robot, person, v, a0, b0, has_r, has_p)   # a layer is 0 outside its span
            _blend(zc, static, robot, person, v, a1, b1, has_r, has_p)
        if not do_edges:
            if i < H:
                valid_row[i] = s_valid_cum[i, W]
                edge_row[i] = s_edge_cum[i, W]
                n_valid += valid_row[i]
                n_edge += edge_row[i]
            continue
        r = i - 2
        if r >= 0 and r < H:                 # row r as the edge tests of rows r - 1 .. r + 1 read it
            a0, b0, a1, b1 = _pair_hull(r_spans, p_spans, max(0, r - 2), min(H, r + 3), 2, W)
            zr = rows[r % 3]
            _depths(zr[a0:b0], zc[r, a0:b0])
            _depths(zr[a1:b1], zc[r, a1:b1])
        v = i - 3
        if v >= 0:                           # edge test of row v where the composite changed
            a0, b0, a1, b1 = _pair_hull(r_spans, p_spans, max(0, v - 1), min(H, v + 2), 1, W)
            for j in range(2):               # tested last frame, not now: the static scene's
                _restore(edge, s_edge, v, e_spans[v, 2 * j], e_spans[v, 2 * j + 1], a0, b0, a1, b1)
                if keep:
                    _restore(other, s_other, v, e_spans[v, 2 * j], e_spans[v, 2 * j + 1], a0, b0, a1, b1)
            e_spans[v, 0] = a0
            e_spans[v, 1] = b0
            e_spans[v, 2] = a1
            e_spans[v, 3] = b1
            valid_row[v] = s_valid_cum[v, W]
            edge_row[v] = s_edge_cum[v, W]
            for j in range(2):
                a = a0 if j == 0 else a1
                b = b0 if j == 0 else b1
                if b > a:
                    nv, ne = _edges_span(rows[(v + 2) % 3], rows[v % 3], rows[(v + 1) % 3], v > 0, v < H - 1, a, b,
                                         jump_abs, jump_rel, edge[v], other[v if keep else 0], keep)
                    valid_row[v] += nv - (s_valid_cum[v, b] - s_valid_cum[v, a])
                    edge_row[v] += ne - (s_edge_cum[v, b] - s_edge_cum[v, a])
            n_valid += valid_row[v]
            n_edge += edge_row[v]
    return n_valid, n_edge


class LayeredCamera:
    """One camera's frame maker (module docstring): ``static`` (H, W) float32 m its static scene
    (0 = nothing), ``model`` its :class:`~depthguard.sensors.SensorModel`, ``fx`` px, the range
    ``lo``..``hi`` m that returns, ``max_range`` m, ``noiseless``, ``invalid`` the policy
    (``camera_sim``: ``"unknown"``, ``"free"`` or None). One object per thread."""

    def __init__(self, static, model, fx: float, lo: float, hi: float, max_range: float,
                 noiseless: bool = False, invalid: str | None = PRODUCT_INVALID):
        from depthguard.sources.simulated import BEYOND_RANGE

        self.static = np.ascontiguousarray(static, dtype=np.float32)
        H, W = self.shape = self.static.shape
        self.model, self.fx, self.lo, self.hi = model, float(fx), float(lo), float(hi)
        self.noise = not (noiseless or model.kind == "ideal")
        self.params = _params(model, fx) if self.noise else (0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0)
        self.policy = POLICY_CODES[invalid]
        self.fill = np.float32(BEYOND_RANGE * max_range if invalid == "unknown" else max_range - 1e-3)
        self.s_edge = np.zeros((H, W), np.uint8)
        # the depth across an edge: only a ToF's flying pixels read it (else a scratch row)
        flying = self.noise and self.params[5] > 0.0
        self.s_other = np.zeros((H if flying else 1, W), np.float32)
        self.s_valid_cum = np.zeros((H, W + 1), np.int32)
        self.s_edge_cum = np.zeros((H, W + 1), np.int32)
        static_edges(self.static, np.zeros((H, W), np.float64), EDGE_JUMP_ABS, EDGE_JUMP_REL, self.s_edge,
                     self.s_other, self.s_valid_cum, self.s_edge_cum)
        self.zc = self.static.copy()
        self.rows = np.zeros((3, W), np.float64)
        self.edge, self.other = self.s_edge.copy(), self.s_other.copy()
        self.valid_row = self.s_valid_cum[:, W].astype(np.int64)
        self.edge_row = self.s_edge_cum[:, W].astype(np.int64)
        self.c_spans = np.zeros((H, 4), np.int32)     # per row a pair of intervals (compose_edges)
        self.e_spans = np.zeros((H, 4), np.int32)
        self.r_spans = np.zeros((H, 2), np.int32)
        self.p_spans = np.zeros((H, 2), np.int32)
        self._empty = np.zeros((1, 1), np.float32)
        self._empty.flags.writeable = False
        self._person = self._empty
        n = H * W
        self.gauss = np.empty(n, np.float32)     # the draws' buffers (noise._draws)
        self.gauss2 = np.empty(n, np.float32)
        self.u_fly = np.empty(n, np.float64)
        self.u_drop = np.empty(n, np.float64)

    def _layer(self, layer, spans, window, given=None):
        if layer is None:
            spans.fill(0)
            return self._empty
        if layer.shape != self.shape or layer.dtype != np.float32 or not layer.flags.c_contiguous:
            raise ValueError(f"a layer must be a C-contiguous float32 {self.shape} image, got "
                             f"{layer.dtype} {layer.shape}")
        view = layer.view()                 # read-only, as a renderer may hand its images out:
        view.flags.writeable = False        # the kernels see one type whoever made the layer
        if given is not None:               # the renderer's own spans (Renderer.spans): taken as they are
            if given.shape != spans.shape:
                raise ValueError(f"a layer's spans must be ({self.shape[0]}, 2), got {given.shape}")
            if given.dtype == spans.dtype:
                _copy_spans(spans, given)      # (H, 2): numpy's copy of it gave the GIL away
            else:
                np.copyto(spans, given, casting="same_kind")
            return view
        v0, v1, u0, u1 = (0, self.shape[0], 0, self.shape[1]) if window is None else window
        layer_spans(view.view(np.uint32), spans, int(v0), int(v1), int(u0), int(u1))
        return view

    def compose(self, robot, person, robot_window=None, person_window=None, robot_spans=None,
                person_spans=None) -> tuple[int, int]:
        """Steps 1-2 of the module docstring: the frame's composite and edges of the layers
        ``robot`` and ``person`` ((H, W) float32 m or None), each 0 outside its window ``(v0, v1,
        u0, u1)`` (pixel rows / columns, half-open; None: anywhere); returns its ``(valid, edge)``
        pixels. ``robot_spans``, ``person_spans`` (H, 2) int32: per row the span ``[a, b)``
        outside which the layer is 0, when its renderer knows it (``Renderer.spans``: step 1
        is then skipped; the same spans, as every pixel a renderer draws has a depth > 0)."""
        r = self._layer(robot, self.r_spans, robot_window, robot_spans)
        p = self._person = self._layer(person, self.p_spans, person_window, person_spans)
        return compose_edges(self.static, self.s_edge, self.s_other, self.s_valid_cum, self.s_edge_cum,
                             r, self.r_spans, p, self.p_spans, self.zc, self.edge, self.other,
                             self.valid_row, self.edge_row, self.c_spans, self.e_spans, self.rows, EDGE_JUMP_ABS,
                             EDGE_JUMP_REL, self.noise)

    def frame(self, robot, person, rng: np.random.Generator, bank=None, dark: bool = False,
              out: np.ndarray | None = None, robot_window=None, person_window=None, robot_spans=None,
              person_spans=None) -> np.ndarray:
        """The measured (H, W) float32 m frame (``out``, or a new image) of the static scene with
        the layers ``robot`` and ``person`` ((H, W) float32 m or None), the noise drawn from
        ``rng`` (its normals from ``bank``, a :class:`~depthguard.sources.noise.NormalBank`, when
        given); ``dark``: the person's pixels return nothing; the windows and spans: :meth:`compose`."""
        n_valid, n_edges = self.compose(robot, person, robot_window, person_window, robot_spans, person_spans)
        if out is None:
            out = np.empty(self.shape, np.float32)
        if self.noise:
            g, g2, u_fly, u_drop = _draws(self.model, rng, self, int(n_edges), int(n_valid), bank)
            if len(u_fly) and self.other.shape[0] != self.shape[0]:    # (never: one rule, _params)
                raise RuntimeError("flying pixels drawn without the depths across the edges")
        else:
            g = g2 = self.gauss[:0]
            u_fly = u_drop = self.u_fly[:0]
        kind, fb, steps, sa, sz2, ff, ed = self.params
        measure_frame(self.zc, self.edge, self.other, self.valid_row, self.edge_row, g, g2, u_fly, u_drop, kind, fb, steps, sa, sz2, ff,
                      ed, self.lo, self.hi, self.policy, self.fill, out)
        if dark and person is not None:
            dark_layer(out, self._person, self.zc, self.p_spans)
        return out


def reference_frame(static, robot, person, model, fx: float, lo: float, hi: float, max_range: float,
                    rng: np.random.Generator, bank=None, noiseless: bool = False,
                    invalid: str | None = PRODUCT_INVALID, dark: bool = False, use_numpy: bool = False) -> np.ndarray:
    """The same frame the former way (module docstring): the static scene copied, each layer
    combined by ``nearest_depth``, ``apply_noise`` (its numpy twins with ``use_numpy``), the
    invalid policy and the dark pixels on whole images. The twin of :class:`LayeredCamera`."""
    from depthguard.sources.simulated import BEYOND_RANGE

    ideal = np.array(static, dtype=np.float32, copy=True)
    if person is not None:
        nearest_depth(ideal, person)
    if robot is not None:
        nearest_depth(ideal, robot)
    d = apply_noise(ideal, model, fx, rng, lo, max_range, noiseless=noiseless, use_numpy=use_numpy,
                    return_range=hi, bank=bank)
    if invalid == "free":
        d = np.where(d > 0, d, np.float32(max_range - 1e-3)).astype(np.float32)
    elif invalid == "unknown":
        d[ideal <= 0] = np.float32(BEYOND_RANGE * max_range)
    if dark and person is not None:
        d[(person > 0) & (person <= ideal + 1e-6)] = 0.0
    return d
