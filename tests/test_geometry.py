"""Primitives: meshes are closed and outward-wound; SDFs match analytic distances."""

import numpy as np
import pytest

from depthguard.geometry import Box, Capsule, Cylinder, Sphere, merge_meshes, sdf_union
from depthguard.transforms import pose, rot_z


def _closed_outward(mesh):
    v, f = mesh
    # closed: every edge appears twice, once in each direction
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    fwd = {tuple(e) for e in edges}
    assert all((b, a) in fwd for a, b in fwd)
    # outward: signed volume positive
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0


@pytest.mark.parametrize("prim,volume", [
    (Box(size=(1.0, 2.0, 0.5)), 1.0),
    (Sphere(radius=0.5, segments=64), 4 / 3 * np.pi * 0.125),
    (Capsule(radius=0.2, length=1.0, segments=64), np.pi * 0.04 * 1.0 + 4 / 3 * np.pi * 0.008),
    (Cylinder(radius=0.3, length=0.7, segments=128), np.pi * 0.09 * 0.7),
])
def test_meshes_closed_outward_and_of_the_right_volume(prim, volume):
    vol = _closed_outward(prim.mesh())
    assert vol == pytest.approx(volume, rel=0.02)


def test_sdfs_against_analytic_values():
    T = pose(rot_z(0.3), [1.0, 2.0, 3.0])
    box = Box(size=(2.0, 1.0, 1.0), world_from_local=T)
    local = np.array([[3.0, 0.0, 0.0], [0.0, 0.0, 0.0], [2.0, 1.5, 0.0]])
    world = local @ T[:3, :3].T + T[:3, 3]
    assert np.allclose(box.sdf(world), [2.0, -0.5, np.hypot(1.0, 1.0)])
    s = Sphere(radius=0.5, world_from_local=T)
    assert np.allclose(s.sdf(world), [2.5, -0.5, np.hypot(2.0, 1.5) - 0.5])
    cap = Capsule.between([0, 0, 0], [0, 0, 1], radius=0.1)
    assert np.allclose(cap.sdf([[0.5, 0, 0.5], [0, 0, 1.5], [0, 0, 0.5]]), [0.4, 0.4, -0.1])
    cyl = Cylinder.between([0, 0, 0], [0, 0, 1], radius=0.1)
    assert np.allclose(cyl.sdf([[0.5, 0, 0.5], [0, 0, 1.5], [0.4, 0, 1.4]]), [0.4, 0.5, 0.5])
    assert np.allclose(sdf_union([box, cap], [[0.5, 0, 0.5]]), [0.4])


def test_mesh_vertices_lie_on_the_surface():
    for prim in (Sphere(radius=0.3), Capsule(radius=0.1, length=0.4), Box(size=(1, 2, 3))):
        assert np.abs(prim.sdf(prim.mesh().vertices)).max() < 1e-9


def test_merge_meshes_offsets_faces():
    a, b = Box().mesh(), Sphere().mesh()
    m = merge_meshes([a, b])
    assert len(m.vertices) == len(a.vertices) + len(b.vertices)
    assert m.faces.max() == len(m.vertices) - 1
