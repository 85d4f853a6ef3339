"""One pass of measurement over a simulated frame (R16, R28, issue 29): step 4 of
:mod:`depthguard.sources.layered`.

The noise model of :func:`depthguard.sources.noise.measure_kernel` — same formulas, same order,
same draws — with the range rule and the invalid pixels' policy in the same pass, on the raw
float32 composite. A row whose pixels are all valid is measured by a loop of selects per law
(:func:`_row_additive`, :func:`_row_disparity`: the compiler's vector instructions, about 8x the
pixel-by-pixel loop), then its edge pixels (flying pixels, dropout) are measured again; other
rows pixel by pixel. :func:`dark_layer`: the dark clothing's pixels after it.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["measure_frame", "dark_layer", "depth_of"]


@numba.njit(cache=True, nogil=True, inline="always")
def depth_of(x):
    """A float32 depth as the noise model reads it: float64 metres, 0 where not finite or <= 0."""
    return np.float64(x) if (x > 0.0 and x < np.inf) else 0.0


@numba.njit(cache=True, nogil=True, inline="always")
def _noisy(kind, zp, g, g2, fb, steps, sigma_a, sigma_z2):
    """The noise model's depth (m) of a valid pixel at ``zp`` m with its normals ``g``, ``g2``
    (:func:`depthguard.sources.noise.measure_kernel`'s formulas, in its order)."""
    if kind == 1:
        d = fb / zp + sigma_z2 * fb * g
        q = np.rint(d * steps) / steps
        m = fb / q if q > 0.0 else 0.0
        if sigma_a > 0.0 and m > 0.0:
            m += sigma_a * g2
        return m
    if kind == 0:
        return zp
    return zp + (sigma_a + sigma_z2 * zp * zp) * g


@numba.njit(cache=True, nogil=True, inline="always")
def _finish(m, x, lo, hi, policy, fill):
    """The range rule, then the invalid pixels' policy: the float32 value of a pixel measured
    ``m`` m whose raw composite is ``x``."""
    if m < lo or m > hi:
        m = 0.0
    r = np.float32(m)
    if policy == 1:
        if x <= 0.0:
            r = fill
    elif policy == 2:
        if not r > 0.0:
            r = fill
    return r


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _row_additive(zr, gr, sigma_a, sigma_z2, lo, hi, policy, fill, orow):
    """A row of valid pixels (zr (W,) float32 m > 0) of the stereo / ToF law ``z + (sigma_a +
    sigma_z2 z^2) g`` with its normals ``gr`` (W,), the range rule and the policy, into ``orow``;
    selects only, so that the loop compiles to vector instructions (8x the pixel-by-pixel loop)."""
    for u in range(zr.shape[0]):
        zp = np.float64(zr[u])
        m = zp + (sigma_a + sigma_z2 * zp * zp) * np.float64(gr[u])
        m = 0.0 if (m < lo) | (m > hi) else m
        r = np.float32(m)
        orow[u] = fill if (policy == 2) & (not r > 0.0) else r


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _row_disparity(zr, gr, g2r, fb, steps, sigma_a, sigma_z2, lo, hi, policy, fill, orow):
    """:func:`_row_additive` for the structured-light law (disparity noise, quantisation,
    ``sigma_a`` on top with the second normals ``g2r``)."""
    for u in range(zr.shape[0]):
        zp = np.float64(zr[u])
        d = fb / zp + sigma_z2 * fb * np.float64(gr[u])
        q = np.rint(d * steps) / steps
        m = fb / q if q > 0.0 else 0.0
        m = m + sigma_a * np.float64(g2r[u]) if (sigma_a > 0.0) & (m > 0.0) else m
        m = 0.0 if (m < lo) | (m > hi) else m
        r = np.float32(m)
        orow[u] = fill if (policy == 2) & (not r > 0.0) else r


@numba.njit(cache=True, nogil=True, error_model="numpy")
def measure_frame(zc, edge, other, valid_row, edge_row, gauss, gauss2, u_fly, u_drop, kind, fb, steps,
                  sigma_a, sigma_z2, flying_fraction, edge_dropout, lo, hi, policy, fill, out):
    """Step 4 of the module docstring: ``out`` (H, W) float32 m, the measured frame.

    zc, edge, other, valid_row, edge_row : the frame's composite, edges (``other``, the depths
    across them, read only with flying pixels: ``u_fly`` not empty) and counts per row
    (:func:`compose_edges`); the draws and the model's terms as
    :func:`depthguard.sources.noise.measure_kernel` (kind 0: the range rule alone, as
    noiseless); policy : :data:`depthguard.sources.layered.POLICY_CODES` — 1 ``"unknown"``: a pixel whose composite is <= 0
    (nothing the scene models) reads ``fill``; 2 ``"free"``: every 0 reads ``fill``; 0: the raw
    sensor. A row whose pixels are all valid is measured in a loop without branches (the
    compiler's vector instructions), its edge pixels after; other rows pixel by pixel.
    """
    H, W = zc.shape
    n_fly = u_fly.shape[0]
    n_drop = u_drop.shape[0]
    two = kind == 1 and sigma_a > 0.0
    i = 0
    k = 0
    for v in range(H):
        zr = zc[v]
        orow = out[v]
        if valid_row[v] == W and kind != 0:
            gr = gauss[i:i + W]
            g2r = gauss2[i:i + W] if two else gr
            if kind == 1:
                _row_disparity(zr, gr, g2r, fb, steps, sigma_a, sigma_z2, lo, hi, policy, fill, orow)
            else:
                _row_additive(zr, gr, sigma_a, sigma_z2, lo, hi, policy, fill, orow)
            left = edge_row[v]
            u = 0
            while left > 0:                   # the row's edge pixels: flying pixels and dropout
                if edge[v, u]:
                    zp = np.float64(zr[u])
                    m = _noisy(kind, zp, np.float64(gr[u]), np.float64(g2r[u]), fb, steps, sigma_a, sigma_z2)
                    if n_fly > 0:
                        oz = np.float64(other[v, u])
                        if oz > 0.0 and u_fly[k] < flying_fraction:
                            m = zp + (u_fly[k] / flying_fraction) * (oz - zp)
                    if n_drop > 0 and u_drop[k] < edge_dropout:
                        m = 0.0
                    k += 1
                    left -= 1
                    orow[u] = _finish(m, zr[u], lo, hi, policy, fill)
                u += 1
            i += W
            continue
        for u in range(W):
            x = zr[u]
            zp = depth_of(x)
            m = 0.0
            if zp > 0.0:
                if kind == 0:
                    m = zp
                else:
                    m = _noisy(kind, zp, np.float64(gauss[i]), np.float64(gauss2[i]) if two else 0.0, fb,
                               steps, sigma_a, sigma_z2)
                    i += 1
                    if edge[v, u]:
                        if n_fly > 0:
                            oz = np.float64(other[v, u])
                            if oz > 0.0 and u_fly[k] < flying_fraction:
                                m = zp + (u_fly[k] / flying_fraction) * (oz - zp)
                        if n_drop > 0 and u_drop[k] < edge_dropout:
                            m = 0.0
                        k += 1
            orow[u] = _finish(m, x, lo, hi, policy, fill)
    return out


@numba.njit(cache=True, nogil=True)
def dark_layer(out, person, zc, p_spans):
    """``out`` 0 where ``person`` (H, W) float32 is seen (> 0 and not behind the composite ``zc``
    by more than 1e-6 m, float32 as numpy computes ``ideal + 1e-6``): dark clothing."""
    eps = np.float32(1e-6)
    for v in range(out.shape[0]):
        for u in range(p_spans[v, 0], p_spans[v, 1]):
            p = person[v, u]
            if p > 0.0 and p <= zc[v, u] + eps:
                out[v, u] = 0.0
