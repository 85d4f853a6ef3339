"""Robot meshes clustered for rendering (geometry.decimate, R9): against analytic geometry (a
sphere's radius) and against the full meshes rendered by the same renderer."""

from __future__ import annotations

import math

import numpy as np
import pytest

from depthguard.geometry.decimate import RENDER_CELL, SIM_CELL, cluster_decimate
from depthguard.geometry.primitives import Sphere
from depthguard.render import render_depth
from depthguard.sim import load_cell


@pytest.mark.parametrize("cell", [0.004, 0.01, 0.03])
def test_sphere_stays_within_the_cell_diagonal(cell):
    """Every vertex of the clustered sphere lies within sqrt(3) cell of the sphere's surface,
    fewer triangles remain, and each is a proper triangle (three distinct vertices)."""
    mesh = Sphere(radius=0.2).mesh()
    out = cluster_decimate(mesh, cell)
    r = np.linalg.norm(out.vertices, axis=1)
    assert np.all(np.abs(r - 0.2) <= math.sqrt(3) * cell + 1e-12)
    assert 0 < len(out.faces) < len(mesh.faces)
    f = out.faces
    assert np.all((f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2]))
    assert f.min() >= 0 and f.max() < len(out.vertices)


def test_bad_cell_is_refused():
    with pytest.raises(ValueError, match="cell"):
        cluster_decimate(Sphere(radius=0.1).mesh(), 0.0)


@pytest.mark.parametrize("cell", [SIM_CELL, RENDER_CELL])
def test_clustered_robot_renders_as_the_full_one(cell):
    """The UR3 of ur3-cell (37,657 triangles) at three poses in every camera: the clustered
    robot covers the same pixels (IoU >= 0.97) at the same depth (99 % of the shared pixels within
    sqrt(3) cell), with at most 60 % of the triangles."""
    rig = load_cell("ur3-cell").rig
    robot = rig.robot
    rng = np.random.default_rng(3)
    q0 = np.asarray(rig.robot_q0, dtype=np.float64)
    n_full = sum(len(m.faces) for m in robot.local_link_meshes().values())
    for k in range(3):
        q = q0 + rng.uniform(-0.5, 0.5, q0.shape)
        mine = robot.render_link_meshes(q, cell)
        assert sum(len(m.faces) for m in mine) <= 0.6 * n_full
        for cam in rig.cameras:
            full = render_depth(cam, robot.link_meshes(q))
            fewer = render_depth(cam, mine)
            a, b = full > 0, fewer > 0
            if a.sum() < 200:
                continue
            assert (a & b).sum() / (a | b).sum() >= 0.97, (k, cam.id)
            d = np.abs(full[a & b] - fewer[a & b])
            assert np.percentile(d, 99) <= math.sqrt(3) * cell, (k, cam.id)
