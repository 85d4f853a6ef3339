"""The eager form of the depth grid's per-frame work: every principal column's obstacle runs at once (R12).

:func:`column_runs` classifies each column's cells from ``r(df)`` on by the rule the lazy form
(:mod:`depthguard.fusion.depth_grid_lazy`) applies to the cells a query needs, and stores the
obstacle cells as runs (``RUNS_PER_COLUMN`` per column, more merged on the safe side); the
distances from them are :func:`depthguard.fusion.depth_grid_lookup.grid_distances`. It is the
reference the lazy form is tested against, and the grid's path with ``lazy=False``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from depthguard.fusion.depth_grid_capsules import MAX_CAPS_PER_PIXEL, _in_caps
from depthguard.fusion.depth_grid_kernels import (KIND_SURFACE, RUN_END, _confirmed_cell, _range_cleared,
                                                  _range_confirmed)

__all__ = ["column_runs"]


@njit(cache=True, parallel=True, nogil=True)
def column_runs(pfree, pkind, pint, dmin, dd, nd, kfree, kpmin, kpmax, koff, kdims, rays, origins,
                kint, nk, caps, ncaps, cap_lo, cap_hi, cap_n, band, runs, nruns):
    """Per frame: the obstacle cells of every principal column as runs (R12).

    For pixel ``(u, v)`` with free depth ``df`` and kind: the measured surface
    cell ``r(do)`` is an obstacle (cases 2/3); the gray cells behind it (from
    ``r(do) + 1``), behind the robot (from ``r(dr)``, case 4) or on an invalid
    ray (from ``r(min_range)``) are obstacles unless another camera clears
    them (:func:`cell_cleared`); cells outside the grid cannot be cleared;
    cells inside a padded robot capsule never are obstacles. Stretches of
    cells are settled at once where the other cameras' min / max pyramids
    prove them all cleared / all confirmed (exact shortcuts), otherwise cell
    by cell.

    kfree, kpmin, kpmax : the other cameras' free depths and pyramids where they lie
        (:class:`~depthguard.fusion.camera_views.CameraViews`' tables, (K, 3) / (K, 2) int64).
    band : (H, W, 2) int32: only gray cells ``band[v, u, 0] <= gd <= band[v, u, 1]``
        are evaluated (:func:`reach_band`); gray cells outside count as obstacles
        unseen (safe). A full band evaluates the whole column.
    runs : (H, W, R, 2) int32 inclusive cell ranges ``[a, b]`` (``b = RUN_END``:
        to the end of the ray); nruns : (H, W) int32. More than ``R`` runs: the
        last run absorbs the rest, gaps included (conservative: more obstacle).
    """
    H = pfree.shape[0]
    W = pfree.shape[1]
    R = runs.shape[2]
    fx = pint[0]
    fy = pint[1]
    cx = pint[2]
    cy = pint[3]
    for v in prange(H):
        for u in range(W):
            nr = 0
            df = pfree[v, u]
            if not df < np.inf:
                nruns[v, u] = 0
                continue
            gs = int(math.floor((df - dmin) / dd))
            direct = pkind[v, u] == KIND_SURFACE
            ncp = cap_n[v, u] if ncaps > 0 else 0
            g_last = nd - 1
            for j in range(min(ncp, MAX_CAPS_PER_PIXEL)):
                g_last = max(g_last, int(math.floor((cap_hi[v, u, j] - dmin) / dd)))
            if ncp > MAX_CAPS_PER_PIXEL:
                g_last = max(g_last, nd + 1000)
            g = gs
            in_run = False
            sec_g = gs - 1               # slice whose near cross-section ``sec`` holds (nk == 1);
            sec = (False, df, df, df, df, df, df)   # (per-column values: not hoisted by parfors)
            known_until = g - 1
            known_obst = False
            span_next = 64
            while g <= g_last:
                d1 = dmin + g * dd
                d2 = d1 + dd
                incap = ncaps > 0 and _in_caps(cap_lo, cap_hi, ncp, v, u, d1, d2, caps, ncaps,
                                               fx, fy, cx, cy, g)
                if incap:
                    obst = False
                elif (g == gs and direct) or g < 0 or g >= nd:
                    obst = True
                elif nk == 0 or g < band[v, u, 0] or g > band[v, u, 1]:
                    obst = True
                elif g <= known_until:
                    obst = known_obst
                else:
                    # the stretch g..e may not reach a capsule's cells nor leave the grid
                    e = min(nd - 1, band[v, u, 1])
                    for j in range(min(ncp, MAX_CAPS_PER_PIXEL)):
                        if cap_lo[v, u, j] > d1:       # a capsule's cells may start after g
                            e = min(e, int(math.ceil((cap_lo[v, u, j] - dmin) / dd)) - 2)
                    if ncp > MAX_CAPS_PER_PIXEL:
                        e = g
                    span = min(span_next, e - g + 1)
                    settled = False
                    if span > 1:
                        da = d1
                        db = dmin + (g + span) * dd
                        if _range_cleared(kpmin, koff, kdims, rays, origins, kint, nk, u, v, da, db):
                            known_obst = False
                            settled = True
                        elif _range_confirmed(kpmax, koff, kdims, rays, origins, kint, nk, u, v, da, db):
                            known_obst = True
                            settled = True
                    if settled:
                        known_until = g + span - 1
                        span_next = min(2 * span, 256)
                        obst = known_obst
                    else:
                        # one stretch test per miss, its length shrinking fast: the cost
                        # stays within a small factor of the cell-by-cell test
                        span_next = max(span // 4, 1) if span > 1 else min(span_next * 2, 8)
                        # the far boundary as the next cell's near one (one float per boundary)
                        obst, sec, sec_g = _confirmed_cell(kfree, rays, origins, kint, nk, u, v, g, d1,
                                                           dmin + (g + 1) * dd, sec, sec_g)
                if obst:
                    if in_run:
                        runs[v, u, nr - 1, 1] = g
                    elif nr < R:
                        runs[v, u, nr, 0] = g
                        runs[v, u, nr, 1] = g
                        nr += 1
                        in_run = True
                    else:
                        runs[v, u, R - 1, 1] = g             # overflow: absorb, gap included
                        in_run = True
                else:
                    in_run = False
                g += 1
            # beyond the last examined cell: outside the grid, unknown -> obstacle
            if g_last >= nd - 1:
                if in_run:
                    runs[v, u, nr - 1, 1] = RUN_END
                elif nr < R:
                    runs[v, u, nr, 0] = g_last + 1
                    runs[v, u, nr, 1] = RUN_END
                    nr += 1
                else:
                    runs[v, u, R - 1, 1] = RUN_END
            nruns[v, u] = nr
