"""The slices of the depth grid that the robot's control points can reach (R12).

A frame's cells are classified only where a query can look at them: per
principal pixel a band of slices, from a world box (:func:`reach_band`) or
from the robot's capsules grown by the reach (:func:`reach_band_capsules`).
A band that is too wide only costs time; one too narrow would leave cells a
query needs unclassified, so both are grown by a slice at each end.
"""

from __future__ import annotations

import math

from numba import njit

from depthguard.fusion.depth_grid_capsules import _ray_capsule

__all__ = ["reach_band", "reach_band_capsules"]


@njit(cache=True, nogil=True)
def reach_band(lo, hi, Rwp, o, fx, fy, cx, cy, dmin, dd, pad, band):
    """Per principal pixel, the slices whose cells can meet the world box
    ``[lo, hi]`` (R12 work limited to where control points can reach).

    The pixel's centre ray ``o + d Rwp ((u - cx)/fx, (v - cy)/fy, 1)`` (``d`` =
    principal depth) is clipped by the box grown by ``pad`` metres per metre of
    depth (``pad >= hypot(1/fx, 1/fy) / 2`` covers the whole pixel frustum),
    then one slice is added at each end. band : (H, W, 2) int32 written
    ``[first, last]`` slice (``first > last``: none). A band that is too
    wide only costs time; the caller's box must hold the rho-balls.
    """
    H = band.shape[0]
    W = band.shape[1]
    for v in range(H):
        for u in range(W):
            c0 = (u - cx) / fx
            c1 = (v - cy) / fy
            t0 = 0.0
            t1 = 1e9
            for a in range(3):
                da = Rwp[a, 0] * c0 + Rwp[a, 1] * c1 + Rwp[a, 2]
                # |X_a - clamp| <= pad * d  -> lo_a - pad d <= o_a + d da <= hi_a + pad d
                # as linear constraints in d: (da + pad) d >= lo_a - o_a ; (da - pad) d <= hi_a - o_a
                p = da + pad
                q = lo[a] - o[a]
                if p > 0.0:
                    t0 = max(t0, q / p)
                elif p < 0.0:
                    t1 = min(t1, q / p)
                elif q > 0.0:
                    t1 = -1.0
                p = da - pad
                q = hi[a] - o[a]
                if p < 0.0:
                    t0 = max(t0, q / p)
                elif p > 0.0:
                    t1 = min(t1, q / p)
                elif q < 0.0:
                    t1 = -1.0
            if t0 > t1:
                band[v, u, 0] = 1
                band[v, u, 1] = 0
            else:
                band[v, u, 0] = int(math.floor((t0 - dmin) / dd)) - 1
                band[v, u, 1] = int(math.floor((min(t1, 1e6) - dmin) / dd)) + 1


@njit(cache=True, nogil=True)
def reach_band_capsules(caps, ncaps, boxes, fx, fy, cx, cy, dmin, dd, band):
    """Per principal pixel, the slices whose cells can meet one of the capsules
    ``caps`` (principal frame, (C, 7) a, b, radius; already grown by the reach
    and by the pixel's half diagonal at the farthest depth): the hull of the
    centre ray's intervals inside them, one slice added at each end.
    boxes : (C, 4) pixel boxes holding each capsule's projection.
    band : (H, W, 2) int32 written; ``first > last``: no slice."""
    H = band.shape[0]
    W = band.shape[1]
    for v in range(H):
        for u in range(W):
            band[v, u, 0] = 1
            band[v, u, 1] = 0
    for c in range(ncaps):
        for v in range(boxes[c, 2], boxes[c, 3] + 1):
            for u in range(boxes[c, 0], boxes[c, 1] + 1):
                a, b = _ray_capsule((u - cx) / fx, (v - cy) / fy, caps[c])
                if a > b:
                    continue
                g0 = int(math.floor((a - dmin) / dd)) - 1
                g1 = int(math.floor((b - dmin) / dd)) + 1
                if band[v, u, 0] > band[v, u, 1]:
                    band[v, u, 0] = g0
                    band[v, u, 1] = g1
                else:
                    band[v, u, 0] = min(band[v, u, 0], g0)
                    band[v, u, 1] = max(band[v, u, 1], g1)
