"""The robot's padded volume in the depth grid (R12): capsules as depth intervals per principal pixel.

:class:`GridRobot` is the part of :class:`~depthguard.fusion.depth_grid.DepthGridMap` that turns
the robot's padded capsules (world frame, at every camera's capture joints) into the
principal's per-pixel depth intervals (cells inside are never obstacles) and the band of
slices the robot can reach (``reach``: the cells the other cameras must be asked about).
"""

from __future__ import annotations

import numpy as np

from depthguard.fusion import depth_grid_capsules, depth_grid_reach

__all__ = ["GridRobot"]


def _capsule_array(capsules) -> np.ndarray:
    """(C, 7) world capsules ``a, b, radius`` from a list of ``Capsule`` or ``(segments (C,2,3), radii (C,))``."""
    if capsules is None:
        return np.zeros((0, 7))
    if isinstance(capsules, tuple) and len(capsules) == 2 and np.ndim(capsules[0]) == 3:
        seg = np.asarray(capsules[0], dtype=np.float64)
        rad = np.asarray(capsules[1], dtype=np.float64)
        if seg.shape[1:] != (2, 3) or rad.shape != (len(seg),):
            raise ValueError(f"robot_capsules as (segments, radii) must be ((C, 2, 3), (C,)), "
                             f"got {seg.shape}, {rad.shape}")
        out = np.concatenate([seg.reshape(-1, 6), rad[:, None]], axis=1)
    else:
        rows = []
        for c in capsules:
            if not (hasattr(c, "segment") and hasattr(c, "radius")):
                raise ValueError(f"robot_capsules must hold Capsule objects (got {type(c).__name__})")
            a, b = c.segment()
            rows.append(np.r_[a, b, c.radius])
        out = np.asarray(rows, dtype=np.float64).reshape(-1, 7)
    if not np.all(np.isfinite(out)) or np.any(out[:, 6] < 0):
        raise ValueError("robot_capsules must have finite end points and radii >= 0")
    return out


def _segments_radii(capsules) -> tuple[np.ndarray, np.ndarray]:
    """``(segments (C, 2, 3), radii (C,))`` C-contiguous float64 (world, m) of the robot's
    capsules: :func:`~depthguard.robot.volume.robot_volume`'s arrays as they are, any other form
    through :func:`_capsule_array` (its checks and errors)."""
    if (isinstance(capsules, tuple) and len(capsules) == 2 and type(capsules[0]) is np.ndarray
            and type(capsules[1]) is np.ndarray and capsules[0].dtype == np.float64
            and capsules[1].dtype == np.float64 and capsules[0].ndim == 3 and capsules[0].shape[1:] == (2, 3)
            and capsules[1].shape == (capsules[0].shape[0],) and capsules[0].flags.c_contiguous
            and capsules[1].flags.c_contiguous):
        return capsules
    caps = _capsule_array(capsules)
    return np.ascontiguousarray(caps[:, :6].reshape(-1, 2, 3)), np.ascontiguousarray(caps[:, 6])


class GridRobot:
    """The robot's volume and reach of a :class:`~depthguard.fusion.depth_grid.DepthGridMap`
    (a mixin: the grid's buffers are its own)."""

    def _set_band(self, reach) -> None:
        if reach is None:
            if not self._band_full:           # the full band is already there: nothing to write
                self._band[..., 0] = -(1 << 30)
                self._band[..., 1] = 1 << 30
                self._band_full = True
            return
        self._band_full = False
        P = self.principal
        is_box = (isinstance(reach, tuple) and len(reach) == 2 and np.shape(reach[0]) == (3,)
                  and np.shape(reach[1]) == (3,))
        if not is_box:
            caps = _capsule_array(reach)
            if not len(caps):
                raise ValueError("reach as capsules needs at least one capsule")
            grow = self.d_max * float(np.hypot(1 / P.fx, 1 / P.fy))     # half diagonal x 2
            a = caps[:, 0:3] @ self._Rp.T + self._tp
            b = caps[:, 3:6] @ self._Rp.T + self._tp
            cc = np.ascontiguousarray(np.concatenate([a, b, caps[:, 6:7] + grow], axis=1))
            depth_grid_reach.reach_band_capsules(cc, len(cc), self._capsule_boxes(cc), P.fx, P.fy, P.cx, P.cy,
                                  self.d_min, self.delta_d, self._band)
            return
        lo, hi = (np.asarray(x, dtype=np.float64).reshape(3) for x in reach)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo <= hi)):
            raise ValueError(f"reach must be a finite box with lo <= hi (got {lo}, {hi})")
        pad = 2.0 * float(np.hypot(1 / P.fx, 1 / P.fy))
        depth_grid_reach.reach_band(lo, hi, np.ascontiguousarray(P.world_from_camera[:3, :3]),
                     np.ascontiguousarray(P.position), P.fx, P.fy, P.cx, P.cy, self.d_min, self.delta_d,
                     pad, self._band)

    @staticmethod
    def robot_reach(robot_capsules, rho: float, margin: float = 0.1):
        """The ``reach`` of :meth:`set_frames` for the robot's own control points:
        its capsules with radii grown by ``rho + margin`` (m), as ``(segments (C, 2, 3),
        radii (C,))``; ``margin`` covers the motion of the points between frames."""
        caps = _capsule_array(robot_capsules)
        if not len(caps):
            raise ValueError("robot_reach needs at least one capsule")
        return caps[:, :6].reshape(-1, 2, 3).copy(), caps[:, 6] + float(rho) + float(margin)

    def set_robot_capsules(self, robot_capsules) -> None:
        """Set the robot's padded volume (world capsules); part of :meth:`set_frames`. The
        ``(segments (C, 2, 3), radii (C,))`` float64 arrays of
        :func:`~depthguard.robot.volume.robot_volume` go to the principal's frame in one
        compiled call that checks them; other forms go through :func:`_capsule_array` first."""
        seg, rad = _segments_radii(robot_capsules)
        n = len(rad)
        if n > len(self._caps_buf):
            self._caps_buf = np.zeros((n, 7))
        if n and not depth_grid_capsules.principal_capsules(seg, rad, self._Rp, self._tp, self._caps_buf):
            raise ValueError("robot_capsules must have finite end points and radii >= 0")
        if n:
            self._caps = self._caps_buf[:n]
            P = self.principal
            depth_grid_capsules.capsule_intervals(self._caps, n, self._capsule_boxes(self._caps), P.fx, P.fy,
                                P.cx, P.cy, P.height, P.width, self._cap_lo, self._cap_hi, self._cap_n,
                                self._cap_written)
        else:
            self._caps = np.zeros((1, 7))
        self._ncaps = n
        self._frame += 1          # memoised cells (lazy) were classified with the old volume

    def _capsule_boxes(self, caps: np.ndarray) -> np.ndarray:
        """(C, 4) inclusive pixel boxes holding each capsule's projection (principal frame
        capsules): the projected corners of its axis-aligned bounding box, plus a pixel."""
        P = self.principal
        if len(caps) > len(self._boxes):
            self._boxes = np.zeros((len(caps), 4), dtype=np.int64)
        boxes = self._boxes[:len(caps)]
        depth_grid_capsules.capsule_boxes(caps, len(caps), P.fx, P.fy, P.cx, P.cy, P.height, P.width, boxes)
        return boxes

    def _capsule_boxes_numpy(self, caps: np.ndarray) -> np.ndarray:
        """The plain-numpy twin of :func:`~depthguard.fusion.depth_grid_capsules.capsule_boxes`."""
        P = self.principal
        boxes = np.zeros((len(caps), 4), dtype=np.int64)
        sgn = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
        for i, c in enumerate(caps):
            lo = np.minimum(c[0:3], c[3:6]) - c[6]
            hi = np.maximum(c[0:3], c[3:6]) + c[6]
            C = (lo + hi) / 2 + sgn * (hi - lo) / 2
            if np.any(C[:, 2] <= 1e-6):
                boxes[i] = (0, P.width - 1, 0, P.height - 1)
                continue
            pu = C[:, 0] * P.fx / C[:, 2] + P.cx
            pv = C[:, 1] * P.fy / C[:, 2] + P.cy
            boxes[i] = (max(int(np.floor(pu.min() + 0.5)) - 1, 0), min(int(np.floor(pu.max() + 0.5)) + 1, P.width - 1),
                        max(int(np.floor(pv.min() + 0.5)) - 1, 0), min(int(np.floor(pv.max() + 0.5)) + 1, P.height - 1))
        return boxes
