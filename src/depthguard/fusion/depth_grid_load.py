"""Loading a camera's per-pixel state into the depth grid (R9, R11, R12, R28, R32; issue 29).

:class:`GridLoad` is the part of :class:`~depthguard.fusion.depth_grid.DepthGridMap` that takes
each camera's :class:`~depthguard.fusion.depth_grid_state.CameraState` (made off the build, on
the camera's worker) into the grid — the principal's and the other cameras' used in place, with
their pyramids (:mod:`~depthguard.fusion.camera_views`) — or works it out from the frame where
none fits; and that keeps, per other camera, the request of its next :class:`~depthguard.fusion.depth_grid_share.CameraShare`.
"""

from __future__ import annotations

import numpy as np

from depthguard.fusion.camera_views import readable
from depthguard.fusion.depth_grid_state import bin_state, state_into
from depthguard.fusion.free32 import round_down_into

__all__ = ["GridLoad"]


class GridLoad:
    """The state loading of a :class:`~depthguard.fusion.depth_grid.DepthGridMap` (a mixin: the
    grid's buffers are its own)."""

    def share_request(self, k: int):
        """``(idx, want)``: the cells the builds asked of other camera ``k`` (index in ``others``)
        during an earlier frame of it (:func:`~depthguard.fusion.depth_grid_share.memo_request`,
        taken when its next frame loaded, with ``share_requests`` on), or None; the request of
        camera k's next :class:`~depthguard.fusion.depth_grid_share.CameraShare`."""
        return self._requests.get(k)

    def _principal_state(self, depth, robot_depth, state) -> None:
        """The principal's per-pixel state as ``_pfree`` / ``_pkind``: ``state``'s own arrays where
        it was made with this build's options and bin (no copy: a state is never written after
        it is made), else worked out here into the grid's buffers — binned with
        ``principal_bin > 1`` (from a full-resolution ``state`` by
        :func:`~depthguard.fusion.depth_grid_state.bin_state`, from the frame in one pass)."""
        b = self.principal_bin
        if (state is not None and state.bin == b and state.options == self._loaded_options_pending
                and not state.robot_free and state.free.shape == self.principal.shape
                and state.free.dtype == np.float64 and state.kind.dtype == np.int8
                and state.free.flags.c_contiguous and state.kind.flags.c_contiguous):
            self._pfree, self._pkind = state.free, state.kind        # used in place (read only)
            self.states_used += 1
            return
        self._pfree, self._pkind = self._pfree_own, self._pkind_own
        if b == 1:
            state_into(self.principal, depth, robot_depth, self._loaded_options_pending, False, self._silhouette,
                       self._gaps, self._pfree, self._pkind)
            return
        if state is not None and state.bin == 1 and state.options == self._loaded_options_pending \
                and not state.robot_free and state.free.shape == self.principal_full.shape:
            bin_state(state.free, state.kind, b, self._pfree, self._pkind)     # made at full resolution
            self.states_used += 1
            return
        state_into(self.principal_full, depth, robot_depth, self._loaded_options_pending, False, self._silhouette,
                   self._gaps, self._pfree, self._pkind, b)

    def _other_state(self, k, cam, depth, robot_depth, robot_free, state=None):
        """Other camera ``k``'s per-pixel state as its views read it
        (:class:`~depthguard.fusion.camera_views.CameraViews`): ``state``'s own arrays, not copied,
        when it was made with this build's options and role (returned; its pyramids too when it
        has them at the grid's levels), else worked out here into the grid's buffers (None
        returned). A state is never written after it is made, and the views hold it until
        camera k's next frame, so its worker's pool does not give its arrays out meanwhile.
        A usable state in float64 (a camera unit's, decoded from the network, or a caller's) is
        rounded down into the grid's float32 buffer (:mod:`~depthguard.fusion.free32`; its
        pyramids are then made by the build)."""
        if self._usable(state, cam, robot_free):
            if readable(state.free):
                if self._pyramids_usable(state):
                    self._views.point(k, state.free, state.pmin, state.pmax)
                else:
                    self._views.point(k, state.free, self._kpmin[k], self._kpmax[k])
                self.states_used += 1
                return state
            if state.free.dtype == np.float64:
                round_down_into(state.free, self._kfree[k])     # (its top-left: the camera's pixels)
                self._views.point(k, self._kfree[k], self._kpmin[k], self._kpmax[k])
                self.states_used += 1
                return None
        state_into(cam, depth, robot_depth, self._loaded_options_pending, robot_free, self._silhouette,
                   self._gaps, self._kfree[k], self._kkind)
        self._views.point(k, self._kfree[k], self._kpmin[k], self._kpmax[k])
        return None

    def _pyramids_usable(self, state) -> bool:
        """``state`` holds min / max pyramids with the levels of this grid's others, readable in place."""
        return (state.pmin is not None and state.levels == self._koff.shape[1] and readable(state.pmin)
                and readable(state.pmax))

    def _usable(self, state, cam, robot_free) -> bool:
        """``state`` (a :class:`~depthguard.fusion.depth_grid_state.CameraState` or None) was made
        with this build's options and camera ``cam``'s role, at its full resolution."""
        return (state is not None and state.options == self._loaded_options_pending
                and state.robot_free == bool(robot_free) and state.bin == 1 and state.free.shape == cam.shape)
