"""Kernels of the free-space map (R21): a gather and a compare per voxel and camera.

Model (built once from intrinsics and extrinsics, see
:class:`depthguard.fusion.free_space.FreeSpaceMap`), for ``C`` cameras and
``N`` voxels (flattened C-order over ``(nx, ny, nz)``), stored camera by camera
as the list of *pairs* (voxel, camera) where the camera can judge the voxel
(centre in front of it, inside the image, depth within ``[min_range, max_range]``);
the pairs of camera ``c`` are ``start[c] : start[c+1]``, in increasing voxel order:

- ``vox (P,) int32``: the voxel index;
- ``pix (P,) int32``: the pixel of the voxel centre's projection, as an index
  into the flat buffer of all images (``offs[c] + v * W + u``, ``u = floor(px + 1/2)``);
- ``zc (P,) float32``: depth ``z_c`` of the voxel centre in camera ``c``, metres;
- ``ru, rv (P,) uint8``: half-size in pixels of a window around ``pix`` that
  holds the projection of the whole voxel (only used with ``full=True``).

Per camera: ``half (C,)`` half the depth extent of any voxel,
``h_c = s/2 (|r_x| + |r_y| + |r_z|)`` with ``r`` the optical axis in the world
(row 3 of ``R``), so the voxel's depths span ``[z_c - h_c, z_c + h_c]``;
``far (C,)`` where "free" starts behind the centre: ``h_c`` for the
``"extent"`` depth test, ``0`` for the ``"centre"`` test (the paper, SPEC R21).

Per camera, with ``d`` the measured depth (R21):

- ``d`` invalid (0, NaN, below ``min_range``): no information;
- ``max_range < d <= RETURN_LIMIT_FACTOR max_range`` (a return beyond the rated range, R28;
  farther is invalid): read as ``max_range`` and never a
  surface — free up to the rated range, unknown behind, as the product's distances read it
  (:mod:`depthguard.sensors`; issue 30: the Kinects of flacco-cell see the far walls at 5-7.5 m,
  beyond their rated 4 m, so the space above the robot was never freed);
- ``d > z_c + far_c + m_c(z_c)``: the camera sees the voxel **free**;
- ``z_c - h_c <= d <= z_c + far_c + m_c(z_c)``: it sees a **surface** in the voxel;

with the margin ``m_c(z) = margin + grow_c z^2`` (a camera's noise sigma grows with the square of
the depth, R17/R21 "plus a margin": ``grow = 0`` is one margin everywhere);
- ``d < z_c - h_c``: the voxel is hidden from that camera: no information.

**Known background** (optional, ``use_bg``): ``bg`` is a second flat buffer
laid out like ``depth``, the expected depth ``B`` of the known static shell
(floor, walls, ceiling) at each pixel, 0 = nothing known. Where ``B > 0``:

- a camera never sees **free** a voxel whose centre is not in front of the
  shell at that pixel: free needs ``d > z_c + far_c + margin`` *and* ``z_c < B``
  (a measurement beyond the centre of a voxel behind the shell is noise; it
  counts as a surface);
- a measurement that matches the shell, ``|d - B| <= bg_tol``, in a voxel
  whose centre is in front of the shell (``z_c < B``) is the shell, not a
  surface *in* the voxel: that camera says nothing (instead of "surface").

Everything else is unchanged; with ``use_bg=False`` (or ``B = 0``) the rules
above are exactly those without a background. Only the centre-pixel mode
(``full=False``) supports a background.

**Pixels that see the robot** (R9, R30; issue 30): the map's own buffer holds
such a pixel's depth negated, ``-d`` (:meth:`FreeSpaceMap.update` with
``robot=``; a caller's negative depth is invalid and set to 0 first). The
measurement still says that nothing lies in front of ``d``, so the free test
applies to ``|d|`` as above; but the surface there is the robot *or something
touching it* (a hand on the robot), so such a pixel never counts a **surface**:
the voxels at and behind it stay unknown unless another camera sees them free.
In the ``full`` window mode a window whose nearest depth is a robot pixel counts
no surface either.

Combination over the cameras of one update: the voxel is free when
``n_free >= min_free_views`` or when ``n_free >= 1`` and no camera sees a
surface in it (free once is free, but a seen surface needs
``min_free_views`` cameras — the paper's three — to overrule it).

With ``full=True`` a camera calls the voxel free only if every pixel of the
window holding the voxel's projection is valid and beyond the threshold (the
nearest depth of the window is used for both tests); with ``full=False``
only the centre pixel is read, as in the paper.

:func:`free_space_update` runs in parallel over chunks of voxels; within a chunk camera
after camera (one image stays in cache); each voxel's counters belong to one
chunk, so they are written without races. The centre-pixel mode of the map uses
:func:`centre_counts` instead (issue 30): one camera at a time, its pairs in pixel
order, read from the camera's own image with the robot pixels tested per pair, then
:func:`combine_counts` — the same counts, about 5x less CPU (one thread).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from depthguard.camera import RETURN_LIMIT_FACTOR

__all__ = ["free_space_update", "centre_counts", "combine_counts", "voxel_states", "voxel_states_numpy",
           "free_space_update_numpy", "voxel_counts_numpy",
           "robot_pixels", "robot_pixels_numpy", "negate_where"]


@nb.njit(cache=True, parallel=True, nogil=True)
def free_space_update(depth, offs, widths, heights, rmin, rmax, vstart, chunk, vox, pix, zc, ru, rv,
                      half, far, bg, bg_tol, use_bg, margin, grow, min_free_views, full, accumulate,
                      n_free, n_surf, free_state, occupied):
    """R21: one update of the free-space map, in place.

    Parameters
    ----------
    depth : (sum H*W,) float32, metres — every camera's image, flattened, camera after camera.
    offs, widths, heights : (C,) int64 — where each image starts, its size.
    rmin, rmax : (C,) float64 — valid measurement range of each camera.
    vstart : (T+1,) int64 — voxel chunks ``vstart[t] : vstart[t+1]`` (one parallel task each).
    chunk : (C, T+1) int64 — the pairs of camera ``c`` for voxel chunk ``t`` are
        ``chunk[c, t] : chunk[c, t+1]``.
    vox, pix : (P,) int32; zc : (P,) float32; ru, rv : (P,) uint8;
    half, far : (C,) float64 — the model (module docstring).
    bg : (sum H*W,) float32 — expected depth of the known shell, laid out like ``depth``, 0 = none;
        read only when ``use_bg`` (centre-pixel mode only). bg_tol : float, metres — the
        shell match ``|d - B| <= bg_tol`` (module docstring).
    margin : float, metres; grow : (C,) float64, 1/m — camera ``c``'s margin at a voxel of centre
        depth ``z`` is ``margin + grow[c] z^2`` (the noise grows with depth; module docstring);
    min_free_views : int; full : bool.
    accumulate : bool — keep voxels that ``free_state`` already holds free.
    n_free, n_surf : (N,) uint8 — workspace, overwritten (cameras seeing free / a surface).
    free_state : (N,) bool, in/out — free voxels (sticky when ``accumulate``).
    occupied : (N,) bool, out — ``not free_state``.

    One parallel loop over voxel chunks; within a chunk, camera after camera
    (the image stays in cache), so every voxel's counters belong to one task.
    """
    T = vstart.shape[0] - 1
    C = chunk.shape[0]
    for t in nb.prange(T):
        for i in range(vstart[t], vstart[t + 1]):
            n_free[i] = 0
            n_surf[i] = 0
        for c in range(C):
            lo = rmin[c]
            hi = rmax[c]
            h = half[c]
            f = far[c] + margin
            gz = grow[c]
            rl = hi * RETURN_LIMIT_FACTOR
            W = widths[c]
            H = heights[c]
            off = offs[c]
            if not full:
                if use_bg:
                    for k in range(chunk[c, t], chunk[c, t + 1]):
                        p = pix[k]
                        d = depth[p]
                        rob = d < 0.0                   # a robot pixel: free in front, never a surface
                        if rob:
                            d = -d
                        if d > hi:                      # beyond the rated range: free up to it, no surface
                            d = hi if d <= rl else -1.0
                            rob = True
                        if d >= lo:
                            z = zc[k]
                            B = bg[p]
                            front = B <= 0.0 or z < B   # centre in front of the known shell
                            if d > z + f + gz * z * z and front:
                                n_free[vox[k]] += 1
                            elif d >= z - h and not rob:
                                if not (B > 0.0 and front and abs(np.float64(d) - np.float64(B)) <= bg_tol):
                                    n_surf[vox[k]] += 1
                    continue
                for k in range(chunk[c, t], chunk[c, t + 1]):
                    d = depth[pix[k]]
                    rob = d < 0.0
                    if rob:
                        d = -d
                    if d > hi:
                        d = hi if d <= rl else -1.0
                        rob = True
                    if d >= lo:
                        z = zc[k]
                        if d > z + f + gz * z * z:
                            n_free[vox[k]] += 1
                        elif d >= z - h and not rob:
                            n_surf[vox[k]] += 1
                continue
            for k in range(chunk[c, t], chunk[c, t + 1]):
                q = pix[k] - off
                u0 = q % W
                v0 = q // W
                a = np.int64(ru[k])
                b = np.int64(rv[k])
                d = np.inf
                bad = False
                rob = False
                for vv in range(max(v0 - b, 0), min(v0 + b + 1, H)):
                    base = off + vv * W
                    for uu in range(max(u0 - a, 0), min(u0 + a + 1, W)):
                        x = depth[base + uu]
                        xr = x < 0.0
                        if xr:
                            x = -x
                        if x > hi:
                            x = hi if x <= rl else -1.0
                            xr = True
                        if not (x >= lo):
                            bad = True
                        elif x < d:
                            d = x
                            rob = xr
                if bad:
                    continue
                z = zc[k]
                if d > z + f + gz * z * z:
                    n_free[vox[k]] += 1
                elif d >= z - h and not rob:
                    n_surf[vox[k]] += 1
        for i in range(vstart[t], vstart[t + 1]):
            free = n_free[i] >= min_free_views or (n_free[i] >= 1 and n_surf[i] == 0)
            if accumulate and free_state[i]:
                free = True
            free_state[i] = free
            occupied[i] = not free


@nb.njit(cache=True, nogil=True)
def centre_counts(depth, rdepth, offset, use_robot, spix, svox, szc, sbg, use_bg, bg_tol, lo, hi, h, f, gz,
                  n_free, n_surf):
    """R21, centre pixel: one camera's free and surface views, added to ``n_free``, ``n_surf``.

    The rules are those of :func:`free_space_update` with ``full=False`` (module docstring), read
    straight from the camera's own image — no copy into a shared buffer, no pass over pixels that
    no pair reads (issue 30: the 175k pairs of ur3-cell's four 640 x 480 cameras read 175k of 1.2M):

    depth : (H*W,) float32 m, the image as measured (NaN / 0 / negative invalid, a negative read as 0).
    rdepth : (H*W,) float32 m, the robot rendered at the frame's capture joints (0 = no robot), read
        when ``use_robot`` and only for a pair that would count a surface (the test decides nothing
        else; most pairs see free space or nothing): the pixel sees the robot (or what touches it; R9, R30) when
        ``rdepth > 0`` and ``depth >= rdepth - offset`` — :func:`robot_pixels` per pair — and it
        then frees in front of its depth and never counts a surface.
    offset : m. spix (K,) int32 the pairs' pixels ``v * W + u`` **in increasing order** (the image is
        read front to back), svox (K,) int32 their voxels, szc (K,) float32 the centre depths m,
        sbg (K,) float32 the known shell's depth B at the pixel (0 = none), read when ``use_bg``.
    bg_tol : m. lo, hi : the camera's range m; h : its half depth extent of a voxel m; f : ``far +
        margin`` m; gz : its margin growth 1/m (the margin at depth z is ``margin + gz z^2``).
    n_free, n_surf : (N,) uint8, in/out — one view added per pair that sees the voxel free / a surface.

    The pair's result is bit for bit that of :func:`free_space_update` on the buffer it loads (a
    robot pixel's depth negated there: a robot pixel counts only with a depth > 0)."""
    rl = hi * RETURN_LIMIT_FACTOR
    for k in range(spix.shape[0]):
        p = spix[k]
        x = depth[p]
        if x < 0.0:                          # a negative depth is invalid: 0
            x = np.float32(0.0)
        d = np.float64(x)
        beyond = d > hi
        if beyond:                           # beyond the rated range: free up to it, no surface
            d = hi if d <= rl else -1.0
        if not (d >= lo):
            continue
        z = np.float64(szc[k])
        if use_bg:
            B = sbg[k]
            front = B <= 0.0 or z < B        # centre in front of the known shell
            if d > z + f + gz * z * z and front:
                n_free[svox[k]] += 1
                continue
            if not (d >= z - h) or beyond or (B > 0.0 and front and abs(d - np.float64(B)) <= bg_tol):
                continue
        elif d > z + f + gz * z * z:
            n_free[svox[k]] += 1
            continue
        elif not (d >= z - h) or beyond:
            continue
        # a surface unless the pixel sees the robot: its depth read only here (most pairs are no surface)
        if use_robot and x > 0.0:
            r = rdepth[p]
            if r > 0.0 and x >= r - offset:
                continue
        n_surf[svox[k]] += 1


@nb.njit(cache=True, nogil=True)
def combine_counts(n_free, n_surf, min_free_views, accumulate, free_state, occupied):
    """R21: the voxels' verdicts from the views of all cameras (the paper's rule, module docstring):
    free when ``n_free >= min_free_views`` or ``n_free >= 1`` and ``n_surf == 0`` (or'ed with
    ``free_state`` when ``accumulate``); (N,) uint8 in, (N,) bool ``free_state`` and ``occupied`` out."""
    for i in range(n_free.shape[0]):          # no branch: the loop vectorises
        free = (n_free[i] >= min_free_views) | ((n_free[i] >= 1) & (n_surf[i] == 0)) | (accumulate & free_state[i])
        free_state[i] = free
        occupied[i] = not free


@nb.njit(cache=True, nogil=True)
def voxel_states(occupied, n_surf, free, unknown, seen, out):
    """The map's three states in one pass: ``out`` (N,) uint8 = ``free`` where not ``occupied``,
    else ``seen`` where a camera saw a surface (``n_surf > 0``), else ``unknown``; (N,) bool and
    uint8 in. Twin: :func:`voxel_states_numpy`."""
    for i in range(out.shape[0]):
        out[i] = free if not occupied[i] else (seen if n_surf[i] > 0 else unknown)
    return out


# ----------------------------------------------------------------- numpy twins
def voxel_counts_numpy(depths, n_voxels, rmin, rmax, start, vox, pix, offs, zc, ru, rv, half, far,
                       margin, full, background=None, bg_tol=0.0, grow=None):
    """Plain-numpy twin of the per-camera tests: ``(n_free, n_surface)`` per voxel, (N,) each.

    ``depths`` is a list of (H, W) images in camera order, a robot pixel's depth negated (module
    docstring); the model as in the kernel.
    ``background``: optional list of (H, W) expected shell depths (0 = none) in camera
    order, with the match tolerance ``bg_tol`` (centre-pixel mode only). ``grow`` (C,) 1/m: the
    margin's growth with depth (None: none).
    """
    if background is not None and full:
        raise ValueError("a background is supported only with full=False (centre pixel)")
    n_free = np.zeros(n_voxels, dtype=np.int64)
    n_surf = np.zeros(n_voxels, dtype=np.int64)
    for c, img in enumerate(depths):
        img = np.asarray(img, dtype=np.float32)
        rob_px = img < 0                                         # robot pixels (module docstring)
        img = np.abs(img)
        beyond = (img > rmax[c]) & (img <= RETURN_LIMIT_FACTOR * rmax[c])    # free up to the rated range, no surface
        img = np.where(beyond, np.float32(rmax[c]), img)
        rob_px = rob_px | beyond
        H, W = img.shape
        sl = slice(start[c], start[c + 1])
        v_idx = vox[sl]
        q = pix[sl].astype(np.int64) - offs[c]
        valid_px = (img >= rmin[c]) & (img <= rmax[c])          # NaN compares False
        if full:
            u0, v0 = q % W, q // W
            d = np.full(len(q), np.inf, dtype=np.float32)
            rob = np.zeros(len(q), dtype=bool)
            ok = np.ones(len(q), dtype=bool)
            R = int(max(ru[sl].max(initial=0), rv[sl].max(initial=0)))
            for dv in range(-R, R + 1):
                for du in range(-R, R + 1):
                    uu, vv = u0 + du, v0 + dv
                    use = ((np.abs(du) <= ru[sl]) & (np.abs(dv) <= rv[sl])
                           & (uu >= 0) & (uu < W) & (vv >= 0) & (vv < H))
                    uc, vc = np.clip(uu, 0, W - 1), np.clip(vv, 0, H - 1)
                    x, xv = img[vc, uc], valid_px[vc, uc]
                    ok &= ~use | xv
                    nearer = use & xv & (x < d)
                    rob = np.where(nearer, rob_px[vc, uc], rob)
                    d = np.where(nearer, x, d)
        else:
            d = img.ravel()[q]
            ok = valid_px.ravel()[q]
            rob = rob_px.ravel()[q]
        z = zc[sl].astype(np.float64)
        d = d.astype(np.float64)
        m = margin + (0.0 if grow is None else float(grow[c])) * z * z
        if background is None:
            free = ok & (d > z + far[c] + m)
            surf = ok & ~free & (d >= z - half[c]) & ~rob
        else:
            B = np.asarray(background[c], dtype=np.float32).ravel()[q].astype(np.float64)
            front = (B <= 0) | (z < B)
            shell = (B > 0) & front & (np.abs(np.float64(d) - np.float64(B)) <= bg_tol)
            free = ok & (d > z + far[c] + m) & front
            surf = ok & ~free & (d >= z - half[c]) & ~shell & ~rob
        np.add.at(n_free, v_idx, free)
        np.add.at(n_surf, v_idx, surf)
    return n_free, n_surf


def free_space_update_numpy(depths, n_voxels, rmin, rmax, start, vox, pix, offs, zc, ru, rv, half, far,
                            margin, min_free_views, full=False, previous_free=None, background=None, bg_tol=0.0,
                            grow=None):
    """Plain-numpy twin of :func:`free_space_update`: (N,) bool ``occupied``.

    free = n_free >= min_free_views  or  (n_free >= 1 and n_surface == 0),
    or'ed with ``previous_free`` when given (accumulation). ``background``, ``bg_tol``:
    see :func:`voxel_counts_numpy`.
    """
    n_free, n_surf = voxel_counts_numpy(depths, n_voxels, rmin, rmax, start, vox, pix, offs, zc, ru, rv,
                                        half, far, margin, full, background, bg_tol, grow)
    free = (n_free >= min_free_views) | ((n_free >= 1) & (n_surf == 0))
    if previous_free is not None:
        free |= previous_free
    return ~free


@nb.njit(cache=True, nogil=True)
def robot_pixels(depth, robot_depth, offset, out):
    """Issue 30, one pass: ``out`` (H, W) bool = the pixels that see the robot or something
    touching it: ``robot_depth > 0`` and ``depth >= robot_depth - offset`` (m; NaN: not).
    Twin: :func:`robot_pixels_numpy`."""
    H, W = depth.shape
    for v in range(H):
        for u in range(W):
            r = robot_depth[v, u]
            out[v, u] = r > 0.0 and depth[v, u] >= r - offset
    return out


def robot_pixels_numpy(depth, robot_depth, offset):
    """Plain numpy twin of :func:`robot_pixels` (its arithmetic: the offset subtracted in float64)."""
    with np.errstate(invalid="ignore"):
        return (robot_depth > 0) & (depth >= np.asarray(robot_depth, dtype=np.float64) - offset)


@nb.njit(cache=True, nogil=True)
def negate_where(seg, mask):
    """``seg[mask] = -seg[mask]`` in place, (H, W) float32 and bool (the robot pixels' encoding)."""
    H, W = seg.shape
    for v in range(H):
        for u in range(W):
            if mask[v, u]:
                seg[v, u] = -seg[v, u]


def voxel_states_numpy(occupied, n_surf, free, unknown, seen):
    """Plain numpy twin of :func:`voxel_states`."""
    return np.where(occupied, np.where(n_surf > 0, seen, unknown), free).astype(np.uint8)
