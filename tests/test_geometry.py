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


def _random_pose(rng):
    from depthguard.transforms import quat_to_matrix
    q = rng.normal(size=4)
    return pose(quat_to_matrix(q / np.linalg.norm(q)), rng.uniform(-1.0, 1.0, 3))


def test_packed_sdf_equals_each_primitives_own_sdf():
    """The one-pass numba union (ground truth of the loop) against ``sdf_union``, the
    primitives' own numpy formulas, on random poses and sizes, inside and outside."""
    from depthguard.geometry.packed import PackedSolids
    rng = np.random.default_rng(7)
    n_inside = 0
    for trial in range(20):
        prims = []
        for _ in range(int(rng.integers(1, 8))):
            T = _random_pose(rng)
            kind = int(rng.integers(0, 4))
            if kind == 0:
                prims.append(Box(size=tuple(rng.uniform(0.05, 1.0, 3)), world_from_local=T))
            elif kind == 1:
                prims.append(Sphere(radius=float(rng.uniform(0.05, 0.5)), world_from_local=T))
            elif kind == 2:
                prims.append(Capsule.between(rng.uniform(-1, 1, 3), rng.uniform(-1, 1, 3),
                                             radius=float(rng.uniform(0.02, 0.3))))
            else:
                prims.append(Cylinder(radius=float(rng.uniform(0.05, 0.5)), length=float(rng.uniform(0.1, 1.0)),
                                      world_from_local=T))
        pts = rng.uniform(-1.5, 1.5, (500, 3))
        packed, rest = PackedSolids.split(prims)
        assert rest == [] and len(packed) == len(prims)
        want = sdf_union(prims, pts)
        n_inside += int((want < 0).sum())
        np.testing.assert_allclose(packed.sdf_min(pts), want, rtol=0, atol=1e-12)
    assert n_inside > 100          # the inside branches were exercised too


def test_packed_sdf_of_nothing_is_infinite_and_mesh_solids_are_handed_back():
    from depthguard.geometry.packed import PackedSolids
    from depthguard.sim.ground_truth import MeshSolid, true_distance

    packed, rest = PackedSolids.split([])
    assert len(packed) == 0 and np.all(np.isinf(packed.sdf_min(np.zeros((3, 3)))))
    solid = MeshSolid(local=Box(size=(0.2, 0.2, 0.2)).mesh(), world_from_local=pose(t=[1.0, 0.0, 0.0]))
    ball = Sphere(radius=0.1)
    packed, rest = PackedSolids.split([ball, solid])
    assert len(packed) == 1 and rest == [solid]
    pts = np.array([[1.3, 0.0, 0.0], [0.0, 0.0, 0.5], [1.0, 0.0, 0.0]])
    # true_distance takes both: 0.2 to the mesh box, 0.4 to the ball, 0 inside the mesh box
    np.testing.assert_allclose(true_distance([ball, solid], pts), [0.2, 0.4, 0.0], atol=1e-9)
    with pytest.raises(ValueError, match="out must be float64"):
        packed.sdf_min(np.zeros((3, 3)), out=np.zeros(2))
