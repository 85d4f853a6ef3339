"""Embree ray casting of the same expected-depth image: the renderer's test oracle and
benchmark peer (R16). Needs the optional ``embreex`` package (extras ``test`` / ``bench``).

One ray per pixel centre from the optical centre, with the camera-frame
direction ``((u - cx)/fx, (v - cy)/fy, 1)`` turned into the world; the hit
parameter ``t`` along that unnormalised direction is then the camera-frame
depth ``z`` itself. Embree works in float32, does not cull back faces and
has no near plane (every hit at ``t > 0`` counts).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from depthguard.geometry.mesh import as_mesh

__all__ = ["EmbreeCaster"]


class EmbreeCaster:
    """Ray caster for one camera: rays are made once, the scene (BVH) on every :meth:`cast`.

    A moving robot changes the scene every frame, so the BVH build is part of
    each frame's cost, as it would be in a real expected-depth loop.
    """

    def __init__(self, cam):
        try:
            from embreex import mesh_construction, rtcore_scene  # noqa: F401
        except ImportError as exc:  # pragma: no cover - depends on the environment
            raise ImportError("Embree ray casting needs the 'embreex' package "
                              "(pip install 'depthguard[test]')") from exc
        self.cam = cam
        dc = cam.ray_directions().reshape(-1, 3)                 # camera frame, z = 1
        self._dirs = np.ascontiguousarray(dc @ cam.R, dtype=np.float32)   # R^T d for each row d
        self._orig = np.ascontiguousarray(np.broadcast_to(cam.position, dc.shape), dtype=np.float32)

    def cast(self, meshes: Sequence) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cast every pixel's ray into ``meshes`` (world coordinates).

        Returns ``depth`` (H, W) float32 metres (camera-frame z, 0 = no hit),
        ``labels`` (H, W) int32 index into ``meshes`` (-1 = no hit) and
        ``faces`` (H, W) int32 face index within that mesh (-1 = no hit).
        """
        from embreex import mesh_construction, rtcore_scene

        ms = [as_mesh(m, name=f"meshes[{k}]") for k, m in enumerate(meshes)]
        H, W = self.cam.shape
        if not ms or sum(len(m.faces) for m in ms) == 0:
            return (np.zeros((H, W), np.float32), np.full((H, W), -1, np.int32),
                    np.full((H, W), -1, np.int32))
        v_off = np.cumsum([0] + [len(m.vertices) for m in ms])
        f_off = np.cumsum([0] + [len(m.faces) for m in ms])
        V = np.concatenate([m.vertices for m in ms]).astype(np.float32)
        F = np.concatenate([m.faces + o for m, o in zip(ms, v_off)]).astype(np.int32)
        scene = rtcore_scene.EmbreeScene()
        mesh_construction.TriangleMesh(scene, V, F)
        res = scene.run(self._orig, self._dirs, output=1)
        prim = res["primID"]
        hit = prim >= 0
        depth = np.where(hit, res["tfar"], 0.0).astype(np.float32).reshape(H, W)
        label = np.full(prim.shape, -1, dtype=np.int32)
        face = np.full(prim.shape, -1, dtype=np.int32)
        label[hit] = np.searchsorted(f_off, prim[hit], side="right") - 1
        face[hit] = prim[hit] - f_off[label[hit]]
        return depth, label.reshape(H, W), face.reshape(H, W)
