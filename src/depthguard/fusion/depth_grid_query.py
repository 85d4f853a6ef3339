"""The depth grid's query (R10, R12, R7): distances of control points to the fused obstacles.

:class:`GridQuery` is the part of :class:`~depthguard.fusion.depth_grid.DepthGridMap` that
answers a query of points: with the lazy grid (the default) the first query of a frame
classifies the cells it needs (:func:`~depthguard.fusion.depth_grid_lazy.ensure_cells`, over
the image rows on numba's threads), then every query looks up
(:func:`~depthguard.fusion.depth_grid_lazy_lookup.grid_distances_lazy`); the eager grid looks
up its obstacle runs (:func:`~depthguard.fusion.depth_grid_lookup.grid_distances`).
"""

from __future__ import annotations

from depthguard.config import PRODUCT_INVALID, PRODUCT_METHOD, PRODUCT_RHO, PRODUCT_ROBOT_IN_OTHERS, PRODUCT_ROBOT_OFFSET   # the product's defaults, defined once
from depthguard.distance.api import DistanceResult, check_points, check_rho
from depthguard.fusion import depth_grid_kernels, depth_grid_lazy, depth_grid_lazy_lookup, depth_grid_lookup
from depthguard.fusion.depth_grid_data import lazy_frame, lazy_memo
from depthguard.numba_threads import NUMBA_NUM_THREADS, thread_settings

__all__ = ["GridQuery"]

PARALLEL_MIN_POINTS = 16     # below this many points a query runs on one thread (steadier)
ENSURE_CHUNK_ROWS = 4        # image rows per parallel work item of the per-frame classification
_METHODS = {"min": depth_grid_kernels.METHOD_MIN, "mean": depth_grid_kernels.METHOD_MEAN, "hybrid": depth_grid_kernels.METHOD_HYBRID}


class GridQuery:
    """The queries of a :class:`~depthguard.fusion.depth_grid.DepthGridMap` (a mixin: the grid's
    buffers are its own)."""

    def query(self, points, rho: float = PRODUCT_RHO, method: str = PRODUCT_METHOD,
              threads: int | None = None, rho_core: float | None = None) -> DistanceResult:
        """Distances of control points (N, 3) world metres to the fused obstacles (R12).

        threads : numba threads for this call. Default: one thread below
            ``PARALLEL_MIN_POINTS`` points (a parallel region costs more than it
            saves for a few points, and waits for the slowest thread on a busy
            machine), all threads from there. The first query of a frame (lazy)
            classifies the cells it needs first, per pixel over the merged slice
            range of all points, on all threads by default (a few ms of work that
            splits well over image rows), then looks up.

        rho_core : (lazy grid only) the mean / hybrid direction from the pixels within
            ``rho_core <= rho``, the distance from every pixel within ``rho`` (a point with
            none within ``rho_core`` gets the nearest and its direction); default ``rho``.
            A result with ``rho > rho_core`` bounds the distance of a point that has moved
            since (:mod:`depthguard.runtime.distances`).

        The arrays of the result are views of reused buffers, overwritten by
        the next query: ``.copy()`` the result to keep it.
        """
        if not self.has_frames:
            raise ValueError("DepthGridMap.query: call set_frames(depths) first")
        p = check_points(points)
        r = check_rho(rho)
        try:
            m = _METHODS[method]
        except (KeyError, TypeError):
            raise ValueError(f"method must be one of 'min', 'mean', 'hybrid' (got {method!r})") from None
        rc = r if rho_core is None else check_rho(rho_core)
        if rc > r:
            raise ValueError(f"rho_core must be <= rho (got rho_core={rho_core!r}, rho={rho!r})")
        if rc < r and not self.lazy:
            raise ValueError("rho_core < rho needs the lazy grid (lazy=True)")
        n = len(p)
        if n > self._cap:
            self._alloc_points(n)
        if threads is not None and int(threads) < 1:
            raise ValueError(f"threads must be >= 1 (got {threads!r})")
        auto = threads is None and n < PARALLEL_MIN_POINTS
        chosen = 0 if threads is None else min(int(threads), NUMBA_NUM_THREADS)    # 0: the caller's count
        prefill = self.lazy and self._queried != self._frame
        self._queried = self._frame
        # the thread counts and chunk size set and restored in compiled calls that keep the GIL
        # (numba's Python functions for them are ctypes calls, each giving the GIL away: issue 29)
        before = thread_settings(chosen, ENSURE_CHUNK_ROWS if prefill else -1)
        try:
            if prefill:                       # the frame's cells, merged per pixel (and on all
                self._ensure_rows(p, n, r)    # threads unless the caller chose)
            lookup = 1 if auto else chosen
            thread_settings(lookup, before[1])
            self._run_query(p, n, r, m, rc, (lookup or before[0]) == 1)
        finally:
            thread_settings(before[0], before[1])
        return DistanceResult(self._dist[:n], self._dir[:n], self._obs[:n], self._count[:n])

    def principal_view(self) -> tuple:
        """``(R (3, 3), t (3,), pint, W, H)``: the principal camera's world → camera transform and
        intrinsics row (fx, fy, cx, cy, …, min range, max range), the image the points' R26
        test uses (:mod:`depthguard.runtime.distances`)."""
        P = self.principal
        return self._Rp, self._tp, self._pint, P.width, P.height

    def _ensure(self, p, n, r) -> None:
        """Classify (lazy, on the current numba threads) every cell a query of ``p`` needs.
        Rows are handed out in chunks of a few (the work gathers around the robot, so two
        contiguous halves of the image would leave one thread idle)."""
        before = thread_settings(0, ENSURE_CHUNK_ROWS)
        try:
            self._ensure_rows(p, n, r)
        finally:
            thread_settings(0, before[1])

    def _ensure_rows(self, p, n, r) -> None:
        depth_grid_lazy.ensure_cells(self._lazy_model, lazy_frame(self), lazy_memo(self), p, n, r, self._ws, self._span)

    def _run_query(self, p, n, r, m, rc=None, fill=None) -> None:
        """The lookup. Lazy grid: ``fill`` True = it runs on one thread and classifies on the way
        the cells a point needs that no query of this frame classified; False = those cells are
        classified first, on the current threads; None = True when numba runs one thread."""
        if self.lazy:
            if fill is None:
                fill = thread_settings(0, -1)[0] == 1
            if not fill:
                self._ensure(p, n, r)
            depth_grid_lazy_lookup.grid_distances_lazy(self._lazy_model, lazy_frame(self), lazy_memo(self), p, n, r, m,
                                                       (self._dist, self._dir, self._count, self._obs), fill,
                                                       self._axbuf, r if rc is None else rc)
            return
        depth_grid_lookup.grid_distances(self._pfree, self._runs, self._nruns, self._tile_first, self._Rp, self._tp, self._pint,
                         self.d_min, self.delta_d, p, n, r, m,
                         self._dist, self._dir, self._count, self._obs)

    def distance(self, depths: dict, points, rho: float = PRODUCT_RHO, method: str = PRODUCT_METHOD,
                 robot_depths: dict | None = None, *, robot_capsules=None,
                 robot_offset: float = PRODUCT_ROBOT_OFFSET, invalid: str = PRODUCT_INVALID,
                 robot_in_others: str = PRODUCT_ROBOT_IN_OTHERS, reach=None, lazy: bool = True,
                 silhouette_px: int = 0, gap_px: int = 0) -> DistanceResult:
        """Distance from control points to what all cameras see together (SPEC §3, §9).

        depths, robot_depths : dict camera id -> (H, W) images (see :meth:`set_frames`).
        points : (N, 3) world metres. rho : radius of surveillance (m).
        method : ``"min"``, ``"mean"`` or ``"hybrid"`` (R7 over the principal's pixels,
            one distance per pixel: its nearest obstacle cell).
        robot_capsules, robot_offset, invalid, robot_in_others, reach, lazy, silhouette_px, gap_px :
            see :meth:`set_frames` (``silhouette_px=0`` and ``gap_px=0``, the defaults, are off;
            the product runs with silhouette_px=4, R32).

        Returns a :class:`~depthguard.distance.DistanceResult` with fresh arrays:
        ``distance`` (N,) m, ``inf`` = no obstacle within ``rho``; ``direction``
        (N, 3) world unit vectors towards the obstacle; ``observed`` (N,) =
        the point lies in the principal's image and range.
        """
        self.set_frames(depths, robot_depths, robot_offset=robot_offset, robot_capsules=robot_capsules,
                        invalid=invalid, robot_in_others=robot_in_others, reach=reach, lazy=lazy,
                        silhouette_px=silhouette_px, gap_px=gap_px)
        return self.query(points, rho=rho, method=method).copy()
