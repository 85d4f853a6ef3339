"""The known static scene as planes: what the pose refinement aligns the measured points to (R34).

:class:`StaticScene` packs the rig's static meshes (world, metres) once and
keeps, per face, its outward unit normal ``n`` (F, 3) and offset ``d`` (F,)
(the face's plane is ``n . x = d``). :meth:`StaticScene.view` renders the
scene into a camera at a given pose with the shared z-buffer renderer
(:class:`depthguard.render.Renderer`) and returns, per pixel, the expected
depth and the plane of the face that owns the pixel — the projective data
association of point-to-plane ICP: the measured point of pixel ``(u, v)``
is compared with the plane of the face the ray through ``(u, v)`` hits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["StaticScene", "SceneView"]


@dataclass
class SceneView:
    """The static scene seen from one pose: ``depth`` (H, W) float32 m (0 = nothing), ``face``
    (H, W) int32 packed face index (-1 = nothing); ``normal`` (F, 3) / ``offset`` (F,) of the
    scene's faces (shared, not copied)."""
    depth: np.ndarray
    face: np.ndarray
    normal: np.ndarray
    offset: np.ndarray


class StaticScene:
    """The rig's static meshes (list of :class:`~depthguard.geometry.mesh.Mesh`, world m)."""

    def __init__(self, meshes):
        self.meshes = list(meshes)
        if not self.meshes:
            raise ValueError("the rig has no static objects: there is no known scene to calibrate against "
                             "(add the floor, walls, tables as objects: to the rig)")
        normals, offsets = [], []
        for m in self.meshes:
            v = np.asarray(m.vertices, dtype=np.float64)
            f = np.asarray(m.faces, dtype=np.int64)
            a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
            n = np.cross(b - a, c - a)
            ln = np.linalg.norm(n, axis=1)
            good = ln > 1e-12
            n[good] /= ln[good, None]
            n[~good] = np.nan                     # a degenerate face: no plane, never used
            normals.append(n)
            offsets.append(np.einsum("ij,ij->i", n, a))
        self.normal = np.concatenate(normals)
        self.offset = np.concatenate(offsets)

    def view(self, cam) -> SceneView:
        """Render the scene into ``cam`` (its pose and intrinsics): copies, safe to keep."""
        from depthguard.render import Renderer

        r = Renderer(cam)
        depth, _ = r.render(self.meshes)
        return SceneView(np.array(depth, copy=True), np.array(r.face_ids, copy=True), self.normal, self.offset)
