"""Noise models of simulated depth cameras (SPEC §1, issue 2 §6).

Each model turns an *ideal* depth image (rendered, ``(H, W)`` metres, 0 where
nothing was hit) into a *measured* one, the way the sensor would:

- ``structured_light`` (Kinect v1): depth ``z`` becomes disparity
  ``δ = fx·b / z`` (pixels), Gaussian disparity noise ``σ_δ`` is added, the
  disparity is quantised to ``1 / 2**disparity_bits`` pixel (1/8 for the
  Kinect) and turned back into depth. ``σ_δ = sigma_z2 · fx · b`` so that
  the depth noise before quantisation is ``σ_z = sigma_z2 · z²``; the
  quantisation steps in depth are ``Δz ≈ z² / (fx · b · 2**bits)``.
  (``sigma_a``, if set, adds depth noise on top.)
- ``stereo`` (RealSense D435): ``z + N(0, σ)``, ``σ = sigma_a + sigma_z2·z²``.
- ``tof`` (time of flight): ``z + N(0, σ)``, ``σ = sigma_a + sigma_z2·z²``
  (about 1 cm), and *flying pixels*: a share ``flying_fraction`` of the
  pixels on a depth edge between two surfaces take a depth uniformly
  between the two sides.
- ``ideal``: no noise.

For all models: pixels on a depth edge miss their return with probability
``edge_dropout`` (→ 0), and measured depths outside ``[min_range,
return_range]`` are invalid (→ 0). ``return_range`` (``SensorModel.returns_to``:
the model's ``return_range``, at least the camera's ``max_range``; for ``ideal``
the ``max_range``) is the farthest depth that returns at all: a surface beyond
the rated ``max_range`` but within it is measured with the same noise law, as a
real sensor does (the product reads ``m > max_range`` as "free up to
``max_range``, unknown behind"; other consumers as invalid). In noiseless mode
only the range rule is applied, to the ideal depth.

A depth *edge* pixel is a valid pixel with a 4-neighbour that is either
invalid (a silhouette against nothing) or differs in depth by more than
``jump_abs + jump_rel · min(z_p, z_q)`` metres.

Random draws, all from the ``numpy.random.Generator`` passed in, in this
order: one float32 standard normal per valid pixel in raster order (the
noise), as many more if a Kinect has ``sigma_a > 0``; then, per edge pixel
in raster order, one uniform for flying pixels (ToF) and one for dropout. The output is a
deterministic function of the input and the generator's state.

A real-time simulation may take the normals from a :class:`NormalBank` instead
(``apply_noise(..., bank=)``): a window of pre-drawn ones at an offset drawn
from the generator, in place of the draws of the first two kinds (the uniforms
are still drawn). Drawing 2 x 307 200 float32 normals is 3 ms of a 640x480
Kinect frame's 10 ms; a real-time run on a small machine cannot spare them.

The per-pixel work is two numba kernels, :func:`depth_edges_kernel` then
:func:`measure_kernel`, both run in parallel over image rows (``prange``).
The draws are still made once, serially, in raster order: the edge kernel
also counts the valid and the edge pixels of every row and turns the counts
into exclusive prefix sums (the index of each row's first normal and first
per-edge uniform), so every row of the measurement kernel knows where its
draws start. The result is therefore bit-identical whatever the number of
numba threads (and to the serial loop). :func:`measure_numpy` and
:func:`depth_edges` are the plain-numpy twins, used by the tests.
:class:`NoiseWorkspace` holds the scratch buffers, reused from call to call.
"""

from __future__ import annotations

import numba
import numpy as np

from depthguard.sensors import SensorModel

__all__ = ["NoiseWorkspace", "NormalBank", "apply_noise", "ideal_depth_kernel", "depth_edges", "depth_edges_kernel", "measure_kernel",
           "measure_numpy", "kinect_quantise", "depth_sigma", "EDGE_JUMP_ABS", "EDGE_JUMP_REL"]

EDGE_JUMP_ABS = 0.03   # metres
EDGE_JUMP_REL = 0.02   # per metre of depth

KIND_CODES = {"ideal": 0, "structured_light": 1, "stereo": 2, "tof": 3}


class NormalBank:
    """Pre-drawn float32 standard normals for real-time simulations (module docstring).

    ``size`` normals drawn once from ``seed``; :meth:`take` returns a window of ``n`` of them
    (a view) at an offset drawn from the frame's generator. Within a frame the values are
    independent standard normals, as without the bank. Two frames take two windows of the
    same ``size`` values, so one may repeat part of another's noise shifted by the difference
    of their offsets (at the same pixels only when the offsets agree, probability ``1 /
    (size - n)``). The result is still a function of the generator's state, but not the
    one the exact draws give: fast runs and the reproductions do not use it.
    """

    def __init__(self, seed: int = 0, size: int = 1 << 22):
        if int(size) < 1:
            raise ValueError(f"a normal bank needs size >= 1 (got {size!r})")
        self.values = np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, 0xBA4C])) \
            .standard_normal(int(size), dtype=np.float32)

    def take(self, rng: np.random.Generator, n: int) -> np.ndarray | None:
        """``n`` standard normals (float32 view), or None when the bank holds fewer than ``n``."""
        size = len(self.values)
        if n > size:
            return None
        o = int(rng.integers(0, size - n + 1))
        return self.values[o:o + n]


class NoiseWorkspace:
    """Preallocated scratch buffers for :func:`apply_noise` on ``(H, W)`` images."""

    def __init__(self, shape: tuple[int, int]):
        self.shape = tuple(int(s) for s in shape)
        self.z = np.empty(self.shape, np.float64)       # ideal depth, 0 = nothing
        n = self.shape[0] * self.shape[1]
        self.gauss = np.empty(n, np.float32)            # N(0, 1) per valid pixel, raster order
        self.gauss2 = np.empty(n, np.float32)           # second N(0, 1) (Kinect sigma_a only)
        self.u_fly = np.empty(n, np.float64)            # U[0, 1) per edge pixel, raster order (ToF)
        self.u_drop = np.empty(n, np.float64)           # U[0, 1) per edge pixel, raster order (dropout)
        self.other = np.empty(self.shape, np.float64)   # depth across the edge
        self.edge = np.empty(self.shape, np.bool_)
        # (H + 1,) int64: [v] = valid / edge pixels in rows < v (exclusive prefix sums; [H] = total),
        # i.e. the index of row v's first normal / first per-edge uniform
        self.valid_start = np.zeros(self.shape[0] + 1, np.int64)
        self.edge_start = np.zeros(self.shape[0] + 1, np.int64)


def depth_sigma(model: SensorModel, z: np.ndarray | float) -> np.ndarray | float:
    """Standard deviation (metres) of the Gaussian depth noise at depth ``z``: ``sigma_a + sigma_z2·z²``.

    For the Kinect this is the noise before disparity quantisation.
    """
    return model.sigma_a + model.sigma_z2 * np.square(z)


def kinect_quantise(z: np.ndarray, fx: float, baseline: float, bits: int,
                    disparity_noise: np.ndarray | None = None) -> np.ndarray:
    """Depth through quantised disparity: ``fx·b / (round((fx·b/z + n)·2**bits) / 2**bits)``.

    ``z``: depths (> 0), metres; ``disparity_noise``: optional pixels added to
    the disparity before quantisation. Returns depths in metres; 0 where the
    quantised disparity is ≤ 0 (beyond any range).
    """
    z = np.asarray(z, dtype=np.float64)
    fb = fx * baseline
    steps = float(2 ** bits)
    disp = fb / z
    if disparity_noise is not None:
        disp = disp + disparity_noise
    q = np.rint(disp * steps) / steps
    with np.errstate(divide="ignore"):
        return np.where(q > 0, fb / np.where(q > 0, q, 1.0), 0.0)


# ------------------------------------------------------------------- edges
def depth_edges(depth: np.ndarray, jump_abs: float = EDGE_JUMP_ABS,
                jump_rel: float = EDGE_JUMP_REL) -> tuple[np.ndarray, np.ndarray]:
    """Edge pixels of a depth image and the depth on the other side (numpy twin of the kernel).

    Returns ``(edge, other)``: ``edge`` (H, W) bool marks valid pixels next
    to an invalid pixel or to a depth step larger than
    ``jump_abs + jump_rel·min(z_p, z_q)``; ``other`` (H, W) float64 holds,
    for edge pixels, the depth of the 4-neighbour with the largest step
    (0 when that is an invalid pixel; ties go to the first of left, right,
    up, down).
    """
    z = np.asarray(depth, dtype=np.float64).copy()
    valid = np.isfinite(z) & (z > 0)
    z[~valid] = 0.0
    H, W = z.shape
    edge = np.zeros((H, W), bool)
    other = np.zeros((H, W))
    jump = np.zeros((H, W))
    shifts = (  # (slice of p, slice of its neighbour q): left, right, up, down
        ((slice(None), slice(1, None)), (slice(None), slice(0, W - 1))),
        ((slice(None), slice(0, W - 1)), (slice(None), slice(1, None))),
        ((slice(1, None), slice(None)), (slice(0, H - 1), slice(None))),
        ((slice(0, H - 1), slice(None)), (slice(1, None), slice(None))),
    )
    for sp, sq in shifts:
        zp, zq = z[sp], z[sq]
        vp, vq = valid[sp], valid[sq]
        step = np.where(vq, np.abs(zp - zq), np.inf)
        is_edge = vp & ((~vq) | (step > jump_abs + jump_rel * np.minimum(zp, zq)))
        larger = is_edge & (step > jump[sp])
        jump[sp] = np.where(larger, step, jump[sp])
        other[sp] = np.where(larger, zq, other[sp])
        edge[sp] |= is_edge
    return edge, other


@numba.njit(cache=True, parallel=True, nogil=True)
def ideal_depth_kernel(d, z):
    """``z`` (H, W) float64 = ``d`` where it is finite and > 0, else 0 (nothing hit): one pass,
    no temporaries (the numpy form, three boolean images and a masked write, took 0.5 ms of a
    640x480 frame's simulation)."""
    for v in numba.prange(d.shape[0]):
        for u in range(d.shape[1]):
            x = d[v, u]
            z[v, u] = x if (np.isfinite(x) and x > 0) else 0.0


@numba.njit(cache=True, inline="always")
def _edge_step(zp, zq, jump_abs, jump_rel, e, best, oth):
    """One neighbour ``zq`` of the valid pixel ``zp`` (:func:`depth_edges_kernel`): the updated
    ``(edge, largest step, depth across it)``."""
    if zq > 0.0:
        step = abs(zp - zq)
        if step <= jump_abs + jump_rel * min(zp, zq):
            return e, best, oth
    else:
        step = np.inf
    if step > best:
        return True, step, zq
    return True, best, oth


@numba.njit(cache=True, parallel=True, nogil=True)
def depth_edges_kernel(z, jump_abs, jump_rel, edge, other, valid_start, edge_start):
    """Kernel of :func:`depth_edges`, in parallel over the image rows.

    z : (H, W) float64, metres, 0 = invalid (no NaN); jump_abs (m), jump_rel (m per m) : the edge
    threshold. Fills ``edge`` (H, W) bool and ``other`` (H, W) float64 (metres, as
    :func:`depth_edges`), and ``valid_start``, ``edge_start`` (H + 1,) int64 with the exclusive
    prefix sums of the valid / edge pixels per row (``[v]`` = count in rows ``< v``, ``[H]`` =
    total): the offsets of each row's draws for :func:`measure_kernel`.
    Returns ``(number of edge pixels, number of valid pixels)``; independent of the thread count.
    """
    H, W = z.shape
    if edge.shape != z.shape or other.shape != z.shape:
        raise ValueError("depth_edges_kernel: edge and other must have the shape of z")
    if valid_start.shape[0] != H + 1 or edge_start.shape[0] != H + 1:
        raise ValueError("depth_edges_kernel: valid_start and edge_start need H + 1 elements")
    for v in numba.prange(H):
        n = 0
        n_valid = 0
        up = v > 0
        down = v < H - 1
        for u in range(W):
            zp = z[v, u]
            e = False
            best = 0.0
            oth = 0.0
            if zp > 0.0:
                n_valid += 1
                # the 4-neighbours in the order left, right, up, down (unrolled: a loop over
                # offset tuples with a bounds test per neighbour took 2.4 ms of a 640x480 image)
                if u > 0:
                    e, best, oth = _edge_step(zp, z[v, u - 1], jump_abs, jump_rel, e, best, oth)
                if u < W - 1:
                    e, best, oth = _edge_step(zp, z[v, u + 1], jump_abs, jump_rel, e, best, oth)
                if up:
                    e, best, oth = _edge_step(zp, z[v - 1, u], jump_abs, jump_rel, e, best, oth)
                if down:
                    e, best, oth = _edge_step(zp, z[v + 1, u], jump_abs, jump_rel, e, best, oth)
            edge[v, u] = e
            other[v, u] = oth
            if e:
                n += 1
        valid_start[v + 1] = n_valid   # per-row counts, summed below
        edge_start[v + 1] = n
    valid_start[0] = 0
    edge_start[0] = 0
    for v in range(H):                 # serial exclusive prefix sums (H elements)
        valid_start[v + 1] += valid_start[v]
        edge_start[v + 1] += edge_start[v]
    return edge_start[H], valid_start[H]


# ------------------------------------------------------------- measurement
@numba.njit(cache=True, parallel=True, nogil=True)
def measure_kernel(z, edge, other, valid_start, edge_start, gauss, gauss2, u_fly, u_drop, kind, fb,
                   steps, sigma_a, sigma_z2, flying_fraction, edge_dropout, lo, hi, out):
    """Measured depth of every pixel (module docstring), into ``out`` (H, W) float32, metres, 0 = invalid.

    Runs in parallel over the image rows: row ``v`` takes its normals from index
    ``valid_start[v]`` and its per-edge uniforms from ``edge_start[v]`` on, so the result is
    the same as the serial raster-order loop whatever the thread count.

    z, other : (H, W) float64, metres (z: 0 = invalid; other: depth across the edge, 0 = nothing);
    edge : (H, W) bool, edge pixels (valid ones only), as filled by :func:`depth_edges_kernel`;
    valid_start, edge_start : (H + 1,) int64, exclusive prefix sums of the valid / edge pixels per
    row, as filled by :func:`depth_edges_kernel`;
    gauss, gauss2 : (n_valid,) float32 N(0, 1) per valid pixel in raster order (gauss2 used only by
    a Kinect with sigma_a > 0, else may be empty);
    u_fly, u_drop : (n_edges,) float64 U[0, 1) per edge pixel in raster order (length 0 when unused);
    kind : 0 ideal, 1 structured light, 2 stereo, 3 tof; fb : fx·baseline (pixel·m);
    steps : disparity steps per pixel (2**bits); sigma_a (m), sigma_z2 (1/m) : noise terms;
    flying_fraction, edge_dropout : probabilities per edge pixel; lo, hi : the depths that return
    (``min_range``, ``return_range``), metres: a measurement outside ``[lo, hi]`` becomes 0.
    """
    H, W = z.shape
    if valid_start.shape[0] != H + 1 or edge_start.shape[0] != H + 1:
        raise ValueError("measure_kernel: valid_start and edge_start need H + 1 elements")
    if gauss.shape[0] < valid_start[H]:
        raise ValueError("measure_kernel: fewer normals than valid pixels")
    n_fly = u_fly.shape[0]
    n_drop = u_drop.shape[0]
    if (n_fly > 0 and n_fly < edge_start[H]) or (n_drop > 0 and n_drop < edge_start[H]):
        raise ValueError("measure_kernel: fewer uniforms than edge pixels")
    for v in numba.prange(H):
        i = valid_start[v]   # index of this row's first normal
        k = edge_start[v]    # index of this row's first per-edge uniform
        for u in range(W):
            zp = z[v, u]
            m = 0.0
            if zp > 0.0:
                g = np.float64(gauss[i])
                if kind == 1:
                    d = fb / zp + sigma_z2 * fb * g
                    q = np.rint(d * steps) / steps
                    m = fb / q if q > 0.0 else 0.0
                    if sigma_a > 0.0 and m > 0.0:
                        m += sigma_a * np.float64(gauss2[i])
                elif kind == 2 or kind == 3:
                    m = zp + (sigma_a + sigma_z2 * zp * zp) * g
                else:
                    m = zp
                i += 1
                if edge[v, u]:
                    if n_fly > 0 and other[v, u] > 0.0 and u_fly[k] < flying_fraction:
                        m = zp + (u_fly[k] / flying_fraction) * (other[v, u] - zp)
                    if n_drop > 0 and u_drop[k] < edge_dropout:
                        m = 0.0
                    k += 1
            if m < lo or m > hi:
                m = 0.0
            out[v, u] = m
    return out


def measure_numpy(z, edge, other, gauss, gauss2, u_fly, u_drop, kind, fb, steps, sigma_a, sigma_z2,
                  flying_fraction, edge_dropout, lo, hi) -> np.ndarray:
    """Plain-numpy twin of :func:`measure_kernel` (same arguments, returns (H, W) float32)."""
    valid = z > 0
    zs = np.where(valid, z, 1.0)
    g = np.zeros(z.shape)
    g[valid] = gauss[: valid.sum()]   # boolean indexing walks raster order
    g2 = np.zeros(z.shape)
    if len(gauss2):
        g2[valid] = gauss2[: valid.sum()]
    gauss, gauss2 = g, g2
    if kind == 1:
        d = fb / zs + sigma_z2 * fb * gauss
        q = np.rint(d * steps) / steps
        m = np.where(q > 0, fb / np.where(q > 0, q, 1.0), 0.0)
        if sigma_a > 0:
            m = np.where(m > 0, m + sigma_a * gauss2, 0.0)
    elif kind in (2, 3):
        m = zs + (sigma_a + sigma_z2 * zs * zs) * gauss
    else:
        m = zs.copy()
    ev, eu = np.nonzero(edge & valid)  # raster order: the order of the per-edge draws
    if len(u_fly):
        f = u_fly[: len(ev)]
        fly = (other[ev, eu] > 0) & (f < flying_fraction)
        zp = z[ev, eu]
        m[ev[fly], eu[fly]] = zp[fly] + (f[fly] / flying_fraction) * (other[ev, eu][fly] - zp[fly])
    if len(u_drop):
        drop = u_drop[: len(ev)] < edge_dropout
        m[ev[drop], eu[drop]] = 0.0
    m = np.where(valid, m, 0.0)
    m[(m < lo) | (m > hi)] = 0.0
    return m.astype(np.float32)


def _draws(model: SensorModel, rng: np.random.Generator, ws: NoiseWorkspace, n_edges: int, n_valid: int,
           bank: NormalBank | None = None):
    """The random draws of one measurement, in the documented order, into views of ``ws``
    (the normals: windows of ``bank`` when one is given and holds enough).

    Returns ``(gauss, gauss2, u_fly, u_drop)``: (n_valid,) float32 normals, the second ones
    (n_valid,) or (0,), and (n_edges,) or (0,) float64 uniforms.
    """
    gauss = bank.take(rng, n_valid) if bank is not None else None
    if gauss is None:
        gauss = ws.gauss[:n_valid]
        rng.standard_normal(out=gauss, dtype=np.float32)
    gauss2 = ws.gauss2[:0]
    if model.kind == "structured_light" and model.sigma_a > 0:
        gauss2 = bank.take(rng, n_valid) if bank is not None else None
        if gauss2 is None:
            gauss2 = ws.gauss2[:n_valid]
            rng.standard_normal(out=gauss2, dtype=np.float32)
    u_fly = ws.u_fly[:0]
    if model.kind == "tof" and model.flying_pixels and model.flying_fraction > 0:
        u_fly = ws.u_fly[:n_edges]
        rng.random(out=u_fly)       # the same stream as rng.random(n_edges)
    u_drop = ws.u_drop[:0]
    if model.edge_dropout > 0:
        u_drop = ws.u_drop[:n_edges]
        rng.random(out=u_drop)
    return gauss, gauss2, u_fly, u_drop


def _params(model: SensorModel, fx: float) -> tuple:
    kind = KIND_CODES.get(model.kind)
    if kind is None:
        raise ValueError(f"sensor {model.name!r}: unknown kind {model.kind!r}")
    fb = fx * model.baseline
    if kind == 1 and (fb <= 0 or model.disparity_bits <= 0):
        raise ValueError(f"sensor {model.name!r}: structured light needs baseline > 0 and disparity_bits > 0")
    return kind, fb, float(2 ** model.disparity_bits), model.sigma_a, model.sigma_z2, \
        model.flying_fraction if model.flying_pixels else 0.0, model.edge_dropout


def apply_noise(ideal: np.ndarray, model: SensorModel, fx: float, rng: np.random.Generator,
                min_range: float | None = None, max_range: float | None = None,
                noiseless: bool = False, ws: NoiseWorkspace | None = None,
                out: np.ndarray | None = None, use_numpy: bool = False,
                return_range: float | None = None, bank: NormalBank | None = None) -> np.ndarray:
    """Measured depth from ideal depth with ``model``'s noise (module docstring).

    Parameters
    ----------
    ideal : (H, W) float, metres; 0 / non-finite = nothing hit.
    model : the sensor model (``sensors.py``).
    fx : focal length in pixels (the Kinect disparity depends on it).
    rng : the generator all random draws come from.
    min_range, max_range : rated range in metres (default: the model's).
    return_range : the farthest depth that returns, metres (default
        ``model.returns_to(max_range)``: the model's return range, at least ``max_range``;
        ``max_range`` for ``ideal``). Measurements outside ``[min_range, return_range]``
        are 0; those in ``(max_range, return_range]`` are kept (beyond the rated range).
    noiseless : only the range rule, no noise, no dropout.
    ws, out : optional preallocated workspace and (H, W) float32 output.
    bank : optional :class:`NormalBank` the normals are taken from (real-time simulations).
    use_numpy : run the numpy twins instead of the kernels (tests).

    Returns
    -------
    (H, W) float32 metres, 0 = invalid.

    The kernels run in parallel over the image rows on numba's threads; the result
    does not depend on the thread count (bit-identical to the numpy twins).
    """
    d = np.asarray(ideal)
    if d.ndim != 2:
        raise ValueError(f"ideal depth must be a 2-D image, got shape {d.shape}")
    lo = model.min_range if min_range is None else float(min_range)
    hi = model.returns_to(max_range) if return_range is None else float(return_range)
    if max_range is not None and not (hi >= float(max_range)):
        raise ValueError(f"return_range ({hi}) must be >= max_range ({max_range})")
    if ws is None or ws.shape != d.shape:
        ws = NoiseWorkspace(d.shape)
    if out is None:
        out = np.empty(d.shape, np.float32)
    elif out.shape != d.shape or out.dtype != np.float32:
        raise ValueError(f"out must be float32 of shape {d.shape}, got {out.dtype} {out.shape}")
    z = ws.z
    if use_numpy:
        np.copyto(z, d)
        z[~(np.isfinite(z) & (z > 0))] = 0.0
    else:
        ideal_depth_kernel(d, z)
    if noiseless or model.kind == "ideal":
        np.copyto(out, z, casting="same_kind")
        out[(z < lo) | (z > hi)] = 0.0
        return out
    kind, fb, steps, sa, sz2, ff, ed = _params(model, fx)
    if use_numpy:
        edge, other = depth_edges(z)
        g, g2, u_fly, u_drop = _draws(model, rng, ws, int(edge.sum()), int((z > 0).sum()), bank)
        out[...] = measure_numpy(z, edge, other, g, g2, u_fly, u_drop, kind, fb, steps, sa, sz2,
                                 ff, ed, lo, hi)
        return out
    n_edges, n_valid = depth_edges_kernel(z, EDGE_JUMP_ABS, EDGE_JUMP_REL, ws.edge, ws.other,
                                          ws.valid_start, ws.edge_start)
    g, g2, u_fly, u_drop = _draws(model, rng, ws, int(n_edges), int(n_valid), bank)
    return measure_kernel(z, ws.edge, ws.other, ws.valid_start, ws.edge_start, g, g2, u_fly, u_drop,
                          kind, fb, steps, sa, sz2, ff, ed, lo, hi, out)
