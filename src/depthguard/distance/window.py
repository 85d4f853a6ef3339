"""Region of surveillance (SPEC §2.1, R6).

Only pixels whose frustum can pass within ``rho`` of the control point are
scanned. **[fix]** The paper's closed form (eqs. 10–11,
:func:`paper_window`) is too small off the optical axis and, with its
``xs / 2``, covers only half the cube; :func:`surveillance_window` uses the
bounding box of the projections of the cube's 8 corners instead.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["surveillance_window", "ball_row_span", "paper_window", "grow_pixel_box", "start_point"]


@njit(cache=True, inline="always")
def grow_pixel_box(X, Y, Z, fx, fy, cx, cy, umin, umax, vmin, vmax):
    """Project the camera-frame point ``(X, Y, Z)`` (``Z > 0``, m) with the pinhole
    ``fx, fy, cx, cy`` (R1) and return the sub-pixel box ``(umin, umax, vmin, vmax)``
    grown to hold it (start from ``inf, -inf, inf, -inf``)."""
    pu = X * fx / Z + cx
    pv = Y * fy / Z + cy
    return min(umin, pu), max(umax, pu), min(vmin, pv), max(vmax, pv)


@njit(cache=True, inline="always")
def start_point(i, points, R, t, fx, fy, cx, cy, min_range, max_range, W, H,
                out_distance, out_direction, out_count, out_observed):
    """Control point ``i`` of ``points`` (N, 3) world metres in a camera ``R, t`` (world ->
    camera) for a distance kernel: eq. (1) its camera-frame ``xc, yc`` and depth ``dp``,
    eq. (2) its projection ``px, py``. Sets the point's outputs to "nothing within rho"
    (``inf``, count 0, zero direction) and ``observed`` (R26: in the image and range).
    Returns ``(dp > 0, xc, yc, dp, px, py)``; nothing else holds when ``dp <= 0``."""
    X = points[i, 0]
    Y = points[i, 1]
    Z = points[i, 2]
    xc = R[0, 0] * X + R[0, 1] * Y + R[0, 2] * Z + t[0]       # (1)
    yc = R[1, 0] * X + R[1, 1] * Y + R[1, 2] * Z + t[1]
    dp = R[2, 0] * X + R[2, 1] * Y + R[2, 2] * Z + t[2]
    out_direction[i, 0] = 0.0
    out_direction[i, 1] = 0.0
    out_direction[i, 2] = 0.0
    out_distance[i] = np.inf
    out_count[i] = 0
    if not dp > 0.0:
        out_observed[i] = False
        return False, xc, yc, dp, 0.0, 0.0
    px = xc * fx / dp + cx                                     # (2)
    py = yc * fy / dp + cy
    out_observed[i] = (dp >= min_range and dp <= max_range and px >= -0.5 and px < W - 0.5
                       and py >= -0.5 and py < H - 0.5)
    return True, xc, yc, dp, px, py


@njit(cache=True)
def surveillance_window(xc, yc, zc, r, fx, fy, cx, cy, min_range, W, H):
    """Region of surveillance (R6) of the camera-frame point ``(xc, yc, zc)``.

    The bounding box of the projections of the 8 corners of the cube of side
    ``2 r`` centred on the point (axes of the camera frame; it contains the
    ball of radius ``r``), as the inclusive pixel range ``u0..u1, v0..v1``
    clipped to the image (``u0 > u1`` or ``v0 > v1``: empty). When
    ``zc - r <= min_range`` the window is the whole image (this also covers
    corners at or behind the camera plane, whose projection is undefined).
    With every corner in front of the camera the box is exact: a frustum
    point within ``r`` lies in the cube, whose projection is the convex hull
    of the projected corners, so its pixel is inside the box.
    """
    if zc - r <= min_range:
        return 0, W - 1, 0, H - 1
    pxmin = np.inf
    pxmax = -np.inf
    pymin = np.inf
    pymax = -np.inf
    for sz in (-1.0, 1.0):
        z = zc + sz * r
        for sx in (-1.0, 1.0):
            px = (xc + sx * r) * fx / z + cx
            pxmin = min(pxmin, px)
            pxmax = max(pxmax, px)
        for sy in (-1.0, 1.0):
            py = (yc + sy * r) * fy / z + cy
            pymin = min(pymin, py)
            pymax = max(pymax, py)
    # pixel u covers [u - 1/2, u + 1/2): first and last pixel touched
    pxmin = min(max(pxmin, -1.0), W + 1.0)
    pxmax = min(max(pxmax, -1.0), W + 1.0)
    pymin = min(max(pymin, -1.0), H + 1.0)
    pymax = min(max(pymax, -1.0), H + 1.0)
    u0 = max(int(math.floor(pxmin + 0.5)), 0)
    u1 = min(int(math.floor(pxmax + 0.5)), W - 1)
    v0 = max(int(math.floor(pymin + 0.5)), 0)
    v1 = min(int(math.floor(pymax + 0.5)), H - 1)
    return u0, u1, v0, v1


def paper_window(px: float, py: float, dp: float, rho: float, fx: float, fy: float,
                 W: int, H: int) -> tuple[int, int, int, int]:
    """The paper's region of surveillance (eqs. 10–11), for comparison only:
    ``xs = rho fx / (dp - rho)``, window ``px ± xs / 2`` (likewise y), as the
    inclusive pixel range ``(u0, u1, v0, v1)`` clipped to the image."""
    xs = rho * fx / (dp - rho)
    ys = rho * fy / (dp - rho)
    u0 = max(int(math.floor(px - xs / 2 + 0.5)), 0)
    u1 = min(int(math.floor(px + xs / 2 + 0.5)), W - 1)
    v0 = max(int(math.floor(py - ys / 2 + 0.5)), 0)
    v1 = min(int(math.floor(py + ys / 2 + 0.5)), H - 1)
    return u0, u1, v0, v1


@njit(cache=True)
def _ball_a_interval(b, cx_, cy_, cz_, K, A):
    """Rays ``(a, b, 1)`` (normalised image coordinates) whose line meets the ball
    ``|q - c| <= r``: for fixed ``b`` the ``a`` with ``A a^2 + B a + C <= 0``, where
    ``K = |c|^2 - r^2``, ``A = K - cx^2``. Returns ``(lo, hi)``; ``lo > hi`` if none."""
    s = cy_ * b + cz_
    B = -2.0 * cx_ * s
    C = K * (b * b + 1.0) - s * s
    disc = B * B - 4.0 * A * C
    if disc < 0.0:
        return 1.0, -1.0
    sq = math.sqrt(disc)
    return (-B - sq) / (2.0 * A), (-B + sq) / (2.0 * A)


@njit(cache=True)
def ball_row_span(v, xc, yc, zc, r, fx, fy, cx, cy, u0, u1):
    """Columns ``u0'..u1'`` of image row ``v`` whose pixel cones meet the ball of radius
    ``r`` around the camera-frame point ``(xc, yc, zc)`` (a refinement of R6 inside the
    window ``u0..u1``; ``u0' > u1'``: none). Exact up to a one-pixel margin: the ball's
    projection is an ellipse (convex), so within the row's band ``b in [b1, b2]`` its
    extent in ``a`` is reached on the band's edges or at the ellipse's leftmost /
    rightmost points. Needs the ball in front of the camera (``zc - r > 0``).
    """
    rr = r * (1.0 + 1e-9) + 1e-12
    K = xc * xc + yc * yc + zc * zc - rr * rr
    A = K - xc * xc
    den = zc * zc - rr * rr
    if not (den > 0.0 and A > 0.0):
        return u0, u1
    b1 = (v - 0.5 - cy) / fy
    b2 = (v + 0.5 - cy) / fy
    lo, hi = _ball_a_interval(b1, xc, yc, zc, K, A)
    lo2, hi2 = _ball_a_interval(b2, xc, yc, zc, K, A)
    if lo2 <= hi2:
        if lo <= hi:
            lo = min(lo, lo2)
            hi = max(hi, hi2)
        else:
            lo, hi = lo2, hi2
    # leftmost / rightmost points: planes x = a z tangent to the ball
    root = math.sqrt(max(xc * xc + zc * zc - rr * rr, 0.0))
    for sgn in (-1.0, 1.0):
        a = (xc * zc + sgn * rr * root) / den
        nrm = math.sqrt(1.0 + a * a)
        dist = (xc - a * zc) / nrm                   # signed distance of c to the plane
        tz = zc - dist * (-a / nrm)                  # tangent point: c - dist * n, n = (1, 0, -a)/nrm
        ty = yc
        bt = ty / tz
        if bt >= b1 and bt <= b2:
            if lo <= hi:
                lo = min(lo, a)
                hi = max(hi, a)
            else:
                lo, hi = a, a
    if lo > hi:
        return 1, 0
    plo = min(max(lo * fx + cx, -2.0), u1 + 2.0)
    phi = min(max(hi * fx + cx, -2.0), u1 + 2.0)
    a0 = max(int(math.floor(plo + 0.5)) - 1, u0)
    a1 = min(int(math.floor(phi + 0.5)) + 1, u1)
    return a0, a1
