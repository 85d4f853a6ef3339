"""The cameras' shares of the depth grid's clearing, made on their workers (issue 29, R11, R12, R36).

A camera other than the principal clears gray cells of the principal's grid from its own
frame alone (:mod:`~depthguard.fusion.depth_grid_share`). :class:`CameraShares` lets each
camera's worker (:class:`~depthguard.runtime.ingest.CameraWorker`) work out that clearing right
after the frame's state, on its own thread, for the cells the fusion's builds asked of the
camera during its frame before the last (the grid's
:meth:`~depthguard.fusion.depth_grid.DepthGridMap.share_request`: the robot has moved a frame or
two since, the cells it needs hardly). The build installs it as that camera's memo
(:meth:`~depthguard.fusion.depth_grid.DepthGridMap.set_frames`, ``shares``) and evaluates only
the cells it does not cover: the same bits, off the build's path.

The grid's tables and request come from the grid the fusion's last build loaded; a share made
for other tables (the camera set changed meanwhile), or before the grid has a request, is None
or not installed: the build does the work itself, as without shares.

Only with ``monitor: camera_shares`` on (off by default): the shares take work off the fusion's
serial build but cost the workers more CPU than they save there (on the project's 2-core
machine 0.004-0.009 of a core per camera at every count from 2 to 16 cameras, with the same
frame-to-reaction p99; :class:`~depthguard.config.MonitorConfig`).
"""

from __future__ import annotations

import threading

from depthguard.fusion.depth_grid_share import CameraSharer, share_spec

__all__ = ["CameraShares"]


class CameraShares:
    """The shares of a :class:`~depthguard.runtime.monitor.Monitor`'s cameras (module docstring).
    ``made`` counts the shares made."""

    def __init__(self, monitor):
        self._monitor = monitor
        self._lock = threading.Lock()
        self._grid_of = None            # the grid the specs are of
        self._specs: dict = {}          # camera id -> ShareSpec of that grid
        self.made = 0

    def _grid(self):
        """The grid the fusion's last build loaded (the next build's, unless the camera set changes)."""
        front = self._monitor.fusion.front
        grid = None if front is None else front.grid
        return grid if hasattr(grid, "share_request") else None

    def spec(self, camera_id: str) -> tuple:
        """``(ShareSpec or None, grid)``: camera ``camera_id``'s
        :class:`~depthguard.fusion.depth_grid_share.ShareSpec` in that grid, and the grid."""
        grid = self._grid()
        with self._lock:
            if grid is not self._grid_of:
                self._grid_of = grid
                self._specs = {} if grid is None else {c.id: share_spec(grid, c.id) for c in grid.others}
            return self._specs.get(camera_id), grid

    def maker(self, camera_id: str):
        """``make(state) -> CameraShare | None`` for camera ``camera_id``'s worker (its thread only)."""
        sharer = CameraSharer()

        def make(state):
            spec, grid = self.spec(camera_id)
            if spec is None or state is None:
                return None
            share = sharer.make(spec, state, grid.share_request(spec.key[1]))
            if share is not None:
                self.made += 1
            return share

        return make
