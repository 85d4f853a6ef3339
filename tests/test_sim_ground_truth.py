"""Ground truth of simulated scenes: distances and occupancy against analytic geometry."""

import math
from importlib import resources

import numpy as np
import pytest

from depthguard.geometry.mesh import load_mesh
from depthguard.geometry.primitives import Box, Capsule, Sphere
from depthguard.sim.ground_truth import MeshSolid, occupancy, true_distance
from depthguard.transforms import pose, rot_x, rot_z


def test_sphere_distance_is_analytic(rng):
    c, r = np.array([0.2, -0.1, 0.5]), 0.3
    p = rng.uniform(-1, 1, (2000, 3))
    d = true_distance([Sphere(radius=r, world_from_local=pose(t=c))], p)
    np.testing.assert_allclose(d, np.maximum(np.linalg.norm(p - c, axis=1) - r, 0.0), atol=1e-12)


def test_axis_aligned_box_distance_is_analytic(rng):
    lo, hi = np.array([-0.3, 0.1, 0.0]), np.array([0.2, 0.5, 0.8])
    p = rng.uniform(-1, 1.5, (2000, 3))
    d = true_distance([Box.from_bounds(lo, hi)], p)
    # distance to an AABB: norm of the per-axis excess
    excess = np.maximum(np.maximum(lo - p, p - hi), 0.0)
    np.testing.assert_allclose(d, np.linalg.norm(excess, axis=1), atol=1e-12)
    inside = np.all((p > lo) & (p < hi), axis=1)
    assert inside.any() and (d[inside] == 0).all()


def test_rotated_box_distance_matches_trimesh_closest_point(rng):
    import trimesh

    T = pose(rot_z(0.7) @ rot_x(0.3), [0.1, 0.2, 0.3])
    b = Box(size=(0.4, 0.2, 0.6), world_from_local=T)
    m = b.mesh()
    tm = trimesh.Trimesh(m.vertices, m.faces, process=False)
    p = rng.uniform(-1, 1, (500, 3))
    _, dist, _ = tm.nearest.on_surface(p)
    inside = tm.contains(p)
    ref = np.where(inside, 0.0, dist)
    np.testing.assert_allclose(true_distance([b], p), ref, atol=1e-9)


def test_distance_to_union_is_the_nearest_obstacle(rng):
    a = Sphere(radius=0.2, world_from_local=pose(t=[0.5, 0, 0]))
    b = Capsule.between([-0.5, 0, -0.3], [-0.5, 0, 0.3], 0.1)
    p = rng.uniform(-1, 1, (500, 3))
    da = np.maximum(np.linalg.norm(p - [0.5, 0, 0], axis=1) - 0.2, 0)
    z = np.clip(p[:, 2], -0.3, 0.3)
    db = np.maximum(np.linalg.norm(p - np.c_[np.full(len(p), -0.5), np.zeros(len(p)), z], axis=1) - 0.1, 0)
    np.testing.assert_allclose(true_distance([a, b], p), np.minimum(da, db), atol=1e-12)
    assert np.isinf(true_distance([], p)).all()


def test_sphere_occupancy_volume_and_any_mode():
    c, r, s = np.array([0.013, -0.021, 0.507]), 0.3, 0.02
    sph = Sphere(radius=r, world_from_local=pose(t=c))
    lo, hi = np.array([-0.5, -0.5, 0.0]), np.array([0.5, 0.5, 1.0])
    occ = occupancy([sph], lo, hi, s, mode="centre")
    assert occ.shape == (50, 50, 50)
    vol = occ.sum() * s ** 3
    assert vol == pytest.approx(4 / 3 * math.pi * r ** 3, rel=0.01)
    # independent exact tests per voxel: centre inside; AABB of the voxel meets the ball
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in occ.shape], indexing="ij"), -1).reshape(-1, 3)
    vlo = lo + idx * s
    centre_in = np.linalg.norm(vlo + s / 2 - c, axis=1) <= r
    np.testing.assert_array_equal(occ.reshape(-1), centre_in)
    aabb_dist = np.linalg.norm(np.maximum(np.maximum(vlo - c, c - (vlo + s)), 0), axis=1)
    anyocc = occupancy([sph], lo, hi, s, mode="any", refine=2).reshape(-1)
    touches = aabb_dist <= r
    assert (anyocc[touches]).all(), "every voxel meeting the sphere must be occupied in 'any' mode"
    margin = s * math.sqrt(3) / 2 / 4
    assert not anyocc[aabb_dist > r + margin].any(), "'any' adds only voxels within its documented margin"
    assert anyocc.sum() < touches.sum() * 1.15


def test_box_occupancy_counts_voxel_centres_exactly():
    lo_b, hi_b = np.array([0.111, 0.203, 0.05]), np.array([0.487, 0.352, 0.301])
    s = 0.01
    occ = occupancy([Box.from_bounds(lo_b, hi_b)], [0, 0, 0], [0.6, 0.4, 0.4], s)
    # per axis: number of centres (i + 1/2)·s inside [lo, hi]
    n = [int(np.sum(((np.arange(m) + 0.5) * s >= a) & ((np.arange(m) + 0.5) * s <= b)))
         for a, b, m in zip(lo_b, hi_b, occ.shape)]
    assert occ.sum() == n[0] * n[1] * n[2]
    assert occ.sum() * s ** 3 == pytest.approx(np.prod(hi_b - lo_b), rel=0.06)


def test_occupancy_rejects_bad_grids():
    b = [Sphere(radius=0.1)]
    with pytest.raises(ValueError, match="voxel_size"):
        occupancy(b, [0, 0, 0], [1, 1, 1], 0.0)
    with pytest.raises(ValueError, match="lo < hi"):
        occupancy(b, [0, 0, 0], [1, -1, 1], 0.1)
    with pytest.raises(ValueError, match="mode"):
        occupancy(b, [0, 0, 0], [1, 1, 1], 0.1, mode="some")


def annulus_distance(p, r_in, r_out, z0, z1):
    """Exact distance to a solid annulus (ring) around the z axis: 2-D distance in (r, z) to a rectangle."""
    r = np.hypot(p[:, 0], p[:, 1])
    dr = np.maximum(np.maximum(r_in - r, r - r_out), 0)
    dz = np.maximum(np.maximum(z0 - p[:, 2], p[:, 2] - z1), 0)
    return np.hypot(dr, dz)


def test_mesh_solid_distance_matches_the_analytic_ring(rng):
    path = resources.files("depthguard") / "data" / "cells" / "meshes" / "ring_fixture.stl"
    mesh = load_mesh(str(path), scale=0.001)  # a ring: r 30..60 mm, z 0..40 mm, 48 sections
    solid = MeshSolid(local=mesh, name="ring")
    assert solid.watertight
    p = rng.uniform([-0.1, -0.1, -0.05], [0.1, 0.1, 0.09], (1500, 3))
    ref = annulus_distance(p, 0.03, 0.06, 0.0, 0.04)
    got = true_distance([solid], p)
    # the 48-gon differs from the circle by r (1 - cos(pi/48)) <= 0.13 mm
    np.testing.assert_allclose(got, ref, atol=2e-4)
    assert ((ref == 0) == (got <= 2e-4)).mean() > 0.98


def test_shipped_stl_is_the_generated_fixture(tmp_path):
    from depthguard.sim.cells import write_fixture_meshes

    shipped = load_mesh(str(resources.files("depthguard") / "data" / "cells" / "meshes" / "ring_fixture.stl"))
    made = load_mesh(write_fixture_meshes(tmp_path)[0])
    np.testing.assert_allclose(shipped.vertices, made.vertices, atol=1e-4)
    np.testing.assert_array_equal(shipped.faces, made.faces)
