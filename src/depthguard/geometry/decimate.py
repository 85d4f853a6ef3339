"""Fewer triangles for rendering a robot's depth: vertex clustering (R9, R16).

The robot is rendered into every camera at every frame's capture joints (the monitor's robot
removal, R9, and the simulator's robot layer), and a robot description's visual meshes are made
for looks: the UR3 of ``ur3-cell`` has 37,657 triangles, which cost 5.7 ms per 640x480 frame
for 4,600 robot pixels. :func:`cluster_decimate` snaps every vertex to the mean of the vertices
in its cell of a grid of side ``cell`` and drops the triangles that collapse: each output vertex
lies in the cell of the vertices it replaces, so every point of the result lies within the cell's
diagonal ``sqrt(3) cell`` of the original surface and back (what
``robot_offset``, several centimetres, already covers). Parts thinner than a cell may collapse to
nothing; their pixels then read as a surface close to the robot, inside its padded volume.
"""

from __future__ import annotations

import numpy as np

from depthguard.geometry.mesh import Mesh

__all__ = ["cluster_decimate", "RENDER_CELL", "SIM_CELL"]

#: grid side (m) of the robot meshes the monitor renders each camera's robot depth from (R9): every
#: point within 10.4 mm of the model's surface, a sixth of the product's robot_offset (8 cm);
#: ur3-cell's UR3: 37,657 -> ~8,500 triangles, 5.7 -> 1.3 ms per 640x480 frame
RENDER_CELL = 0.006
#: ... and the simulator its robot layer: the same meshes, as before with the full ones (the
#: simulated cameras see the robot the monitor removes; a model that does not match the real robot
#: is not simulated — with 3 mm here, the robot's outline alone made the closed loop react)
SIM_CELL = RENDER_CELL


def cluster_decimate(mesh: Mesh, cell: float) -> Mesh:
    """``mesh`` with its vertices clustered on a grid of side ``cell`` (m, > 0): module
    docstring. Faces keep their orientation; the result's vertices are float64, faces int32."""
    cell = float(cell)
    if not cell > 0.0:
        raise ValueError(f"cluster_decimate: cell must be > 0 metres (got {cell!r})")
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    if len(v) == 0 or len(f) == 0:
        return Mesh(v.copy(), f.astype(np.int32))
    key = np.floor(v / cell).astype(np.int64)
    _, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    n = int(inverse.max()) + 1
    sums = np.zeros((n, 3))
    np.add.at(sums, inverse, v)
    out_v = sums / np.bincount(inverse, minlength=n)[:, None]
    nf = inverse[f]
    keep = (nf[:, 0] != nf[:, 1]) & (nf[:, 1] != nf[:, 2]) & (nf[:, 0] != nf[:, 2])
    nf = nf[keep]
    # the same triangle with the same orientation from several originals: once
    start = np.argmin(nf, axis=1)
    rolled = np.stack([nf[np.arange(len(nf)), (start + k) % 3] for k in range(3)], axis=1)
    _, first = np.unique(rolled, axis=0, return_index=True)
    nf = nf[np.sort(first)]
    used = np.unique(nf)
    remap = np.full(n, -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return Mesh(out_v[used], remap[nf].astype(np.int32))
