"""The free-space map out for planners: occupied and unknown voxels as ``sensor_msgs/PointCloud2``
(R37; issue 30, "the map out").

:func:`obstacle_cloud` turns a :class:`~depthguard.runtime.free_space_map.FreeSpaceSnapshot` into
one cloud in the world frame: a point per voxel that is not free, at the voxel's centre, with
the fields ``x``, ``y``, ``z`` (FLOAT32, m) and ``state`` (UINT8: 1 unknown — no camera could
judge it —, 2 occupied — a camera saw a surface in it, or the known scene); little endian, 13
bytes a point, one row (``height`` 1, dense). The robot is removed: its body's voxels
(``snapshot.machine``) are left out, the unknown space around it is not. Voxel size and box are
the map's (``monitor.free_space_voxel``, the rig's workspace).

``McapResults.write_map`` writes it on ``/depthguard/obstacles`` of the results MCAP at every map
update of a run with the map on.
"""

from __future__ import annotations

import numpy as np

from depthguard.transport import ros_messages as rosmsg

__all__ = ["OBSTACLES_TOPIC", "POINT_DTYPE", "obstacle_points", "obstacle_cloud"]

OBSTACLES_TOPIC = "/depthguard/obstacles"
POINT_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("state", "u1")])


def obstacle_points(snapshot) -> np.ndarray:
    """(N,) :data:`POINT_DTYPE`: the centres and states of the voxels that are neither free nor
    the robot's body, in C order of the map's (i, j, k)."""
    keep = snapshot.state != 0
    keep &= ~snapshot.machine
    idx = np.nonzero(keep)
    g = snapshot.grid
    c = g.lo + (np.stack(idx, axis=1) + 0.5) * g.voxel_size
    out = np.empty(len(c), POINT_DTYPE)
    out["x"], out["y"], out["z"] = c[:, 0], c[:, 1], c[:, 2]
    out["state"] = snapshot.state[idx]
    return out


def obstacle_cloud(snapshot, stamp: float, frame_id: str = "world"):
    """The ``sensor_msgs/msg/PointCloud2`` of :func:`obstacle_points` at ``stamp`` s."""
    T = rosmsg.TYPESTORE.types
    PF = T["sensor_msgs/msg/PointField"]
    pts = obstacle_points(snapshot)
    fields = [PF(name=n, offset=POINT_DTYPE.fields[n][1], datatype=PF.FLOAT32 if n != "state" else PF.UINT8,
                 count=1) for n in ("x", "y", "z", "state")]
    return T["sensor_msgs/msg/PointCloud2"](
        header=rosmsg.header(stamp, frame_id), height=1, width=len(pts), fields=fields, is_bigendian=False,
        point_step=POINT_DTYPE.itemsize, row_step=POINT_DTYPE.itemsize * len(pts),
        data=np.frombuffer(pts.tobytes(), np.uint8).copy(), is_dense=True)
