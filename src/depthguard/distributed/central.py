"""Centralised mode: every camera's image into one process, same pipeline (R20, for comparison).

The comparison the paper makes against MoveIt: one process filters all cameras one
after the other (:class:`depthguard.fusion.voxels.VoxelFilter` per camera, R16–R19)
and merges the voxels; optionally the multi-camera vote (:func:`~depthguard.fusion.voxels.vote`),
which only this mode can do since it has every image.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from depthguard.camera import Camera
from depthguard.fusion.voxels import VoxelFilter, VoxelSet, union, vote

__all__ = ["CentralisedPipeline"]


class CentralisedPipeline:
    """All cameras in one process.

    cameras : list of Camera. workspace : (lo, hi). static_meshes, robot : the known scene.
    learned : camera id -> (H, W) float32 m learned static scene (issue 31; 0 = unknown), or None.
    """

    def __init__(self, cameras: Sequence[Camera], workspace, *, voxel_size: float = 0.02,
                 threshold: float = 0.55, static_meshes: Sequence = (), robot=None, offset=None, learned=None):
        self.cameras = list(cameras)
        learned = learned or {}
        self.filters = {c.id: VoxelFilter(c, workspace, voxel_size=voxel_size, threshold=threshold,
                                          static_meshes=static_meshes, robot=robot, offset=offset,
                                          learned=learned.get(c.id))
                        for c in self.cameras}

    def configure(self, voxel_size: float | None = None, threshold: float | None = None) -> None:
        for f in self.filters.values():
            f.configure(voxel_size=voxel_size, threshold=threshold)

    @property
    def voxel_size(self) -> float:
        return next(iter(self.filters.values())).voxel_size

    def per_camera(self, depths: Mapping[str, np.ndarray], q=None) -> dict[str, VoxelSet]:
        """``{camera id: VoxelSet}`` for the cameras whose image is given."""
        unknown = set(depths) - set(self.filters)
        if unknown:
            raise ValueError(f"images for unknown cameras {sorted(unknown)}; cameras: {sorted(self.filters)}")
        return {cid: self.filters[cid].filter(d, q=q) for cid, d in depths.items()}

    def refresh(self, depths: Mapping[str, np.ndarray], q=None, voting: bool = False,
                min_free: int = 2) -> tuple[np.ndarray, float]:
        """One scene refresh: (M, 3) int64 global voxel keys and the voxel size (m)."""
        sets = self.per_camera(depths, q)
        if voting:
            sets = vote(sets, self.cameras, depths, min_free=min_free)
        return union(list(sets.values()), self.voxel_size), self.voxel_size
