"""The moving meshes posed in place (``sim/posed.py``) and the renderer that draws them where they
lie, with its rows' spans (``Renderer.render_arrays``, ``Renderer.spans``; issue 29).

Truths: each primitive's own ``mesh()`` (a second implementation of the posed vertices), the
plain-numpy twin of the rasteriser (``render_depth_numpy``: per-pixel edge tests), and the
spans read off the depth image with numpy (first and last nonzero pixel of each row).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import depthguard as dg
from depthguard.geometry import Box, Sphere
from depthguard.geometry.primitives import Capsule
from depthguard.render import Renderer
from depthguard.render.raster_ref import render_depth_numpy
from depthguard.sim import load_cell
from depthguard.sim.posed import PosedMeshes, pack_primitives
from depthguard.sim.scene import Scene
from depthguard.transforms import look_at, pose, rot_z


def _rounding(got, want, *context) -> None:
    """``got`` is ``want`` to the rounding of the few floating-point operations between them:
    within 1e-14 m, or 8 eps relative. numpy's small products may use a fused multiply-add where
    the compiled posing does not, or the other way round, by the CPU: on an AVX-512 Xeon
    (2026-11-27) the posed vertices differed from each primitive's ``mesh()`` in the last bit of
    about 9k coordinates, the part poses by up to 1.4e-15, where the earlier machines gave the
    same bits. A wrong posing is off by millimetres and more."""
    np.testing.assert_allclose(np.asarray(got, dtype=np.float64), np.asarray(want, dtype=np.float64),
                               rtol=8 * np.finfo(np.float64).eps, atol=1e-14, err_msg=repr(context))


def _spans_of(depth: np.ndarray) -> np.ndarray:
    """(H, 2) ``[a, b)`` of each row's nonzero pixels, ``(0, 0)`` when none (numpy)."""
    out = np.zeros((depth.shape[0], 2), np.int32)
    for v, row in enumerate(depth):
        nz = np.flatnonzero(row)
        if len(nz):
            out[v] = (nz[0], nz[-1] + 1)
    return out


@pytest.mark.parametrize("name", ["flacco-cell", "ur3-cell", "c-arm-room"])
def test_posed_meshes_are_the_primitives_meshes(name):
    """Over the whole script (people walking, reaching, carrying, entering and leaving; the
    c-arm room's step-posed staff): the packed vertices are each primitive's ``mesh()``, to the
    rounding (:func:`_rounding`), the faces the same; one topology while the parts stay, another when they change."""
    scene = load_cell(name).scene
    posed = PosedMeshes(load_cell(name).scene)          # its own people: no memo shared with the truth
    assert posed.posed_as_arrays                          # the built-in cells take the arrays' path
    topologies = set()
    n_parts = 0
    for t in np.linspace(0.0, scene.duration, 48, endpoint=False):
        t = float(t)
        got = posed.at(t)
        ref = [p.mesh() for p in scene.dynamic_at(t)]
        if got is None:
            assert not ref
            continue
        assert posed.at(t) is got                         # one posing per time step
        meshes = got.meshes()
        assert len(meshes) == len(ref)
        for a, b in zip(meshes, ref):
            _rounding(a.vertices, b.vertices, t)
            np.testing.assert_array_equal(a.faces, b.faces)
        topologies.add((got.topology, len(ref)))
        n_parts += len(ref)
    assert n_parts > 20
    counts = {}
    for topo, n in topologies:                            # a topology number means one set of parts
        counts.setdefault(topo, set()).add(n)
    assert all(len(v) == 1 for v in counts.values())


def test_posed_meshes_alone_and_empty():
    scene = load_cell("ur3-cell").scene
    assert PosedMeshes(scene, alone=True).at(6.5) is None
    assert PosedMeshes(Scene(duration=1.0)).at(0.5) is None             # nothing moves
    packed = pack_primitives([Box(size=(0.1, 0.2, 0.3)), Sphere(radius=0.1)])
    assert packed.mesh_off[-1].tolist() == [8 + len(Sphere(radius=0.1).mesh().vertices),
                                            12 + len(Sphere(radius=0.1).mesh().faces)]


def _scene_meshes(rng, cam):
    meshes = []
    for _ in range(8):                                     # large triangles: rows of many pixels
        c = np.array([0.0, 0.0, 0.0]) + rng.normal(size=3) * 0.5
        meshes.append((c + rng.normal(size=(3, 3)) * 0.7, np.array([[0, 1, 2]], np.int32)))
    axis = rng.normal(size=3)
    meshes.append(Box(size=(0.6, 0.3, 0.4)).moved(look_at(rng.uniform(-0.3, 0.3, 3), axis,
                                                          np.array([0, 0, 1.0]))).mesh())
    meshes.append(Sphere(radius=0.3, segments=16).moved(look_at(rng.uniform(-0.5, 0.5, 3), axis,
                                                               np.array([0, 0, 1.0]))).mesh())
    return [dg.geometry.mesh.as_mesh(m) for m in meshes]


def _pack(meshes):
    off = np.zeros((len(meshes) + 1, 2), np.int64)
    np.cumsum([len(m.vertices) for m in meshes], out=off[1:, 0])
    np.cumsum([len(m.faces) for m in meshes], out=off[1:, 1])
    return (np.ascontiguousarray(np.concatenate([m.vertices for m in meshes])),
            np.ascontiguousarray(np.concatenate([m.faces for m in meshes]), dtype=np.int32), off)


@pytest.mark.parametrize("parallel", [False, True])
def test_render_arrays_equals_the_twin_and_its_spans_are_the_images(parallel):
    """Meshes that move from call to call (rows that empty, spans that shrink and grow), some
    crossing the near plane: each call's image equals the numpy twin's (the covered pixels
    exactly: labels equal), ``render`` of the same meshes gives the same bits, and ``spans``
    are the rows' nonzero pixels of the image (outside them every pixel is 0 / -1)."""
    rng = np.random.default_rng(5)
    T = look_at(np.array([0.0, -2.2, 0.8]), np.zeros(3), np.array([0, 0, 1.0]))
    cam = dg.Camera("cam", 96, 72, 70.0, 70.0, 47.5, 35.5, T)
    ra = Renderer(cam, near=0.3, parallel=parallel)
    rb = Renderer(cam, near=0.3, parallel=parallel)
    covered = 0
    for k in range(5):
        meshes = _scene_meshes(rng, cam) if k != 3 else _scene_meshes(rng, cam)[:1]
        vw, faces, off = _pack(meshes)
        d, lab = ra.render_arrays(vw, faces, off)
        d2, lab2, f2 = render_depth_numpy(cam, meshes, near=0.3)
        np.testing.assert_allclose(d, d2, rtol=0, atol=1e-6)
        np.testing.assert_array_equal(lab, lab2)
        np.testing.assert_array_equal(ra.face_index(), f2)
        db, _ = rb.render(meshes)
        assert d.tobytes() == db.tobytes()
        np.testing.assert_array_equal(ra.spans, _spans_of(d))
        np.testing.assert_array_equal(rb.spans, _spans_of(d))
        covered += int((d > 0).sum())
    assert covered > 3000


def test_render_arrays_rejects_bad_buffers():
    cam = dg.Camera("cam", 32, 24, 30.0, 30.0, 15.5, 11.5, np.eye(4))
    r = Renderer(cam)
    vw, faces, off = _pack([Box(size=(0.2, 0.2, 0.2)).moved(np.eye(4)).mesh()])
    vw = vw + [0.0, 0.0, 1.0]
    with pytest.raises(ValueError, match="vertices"):
        r.render_arrays(vw.astype(np.float32), faces, off)
    with pytest.raises(ValueError, match="faces"):
        r.render_arrays(vw, faces.astype(np.int64), off)
    bad = off.copy()
    bad[-1, 0] = len(vw) + 1                                # more vertices than given
    with pytest.raises(ValueError, match="mesh_off"):
        r.render_arrays(vw, faces, bad)
    wrong = faces.copy()
    wrong[0, 0] = 99                                       # outside its mesh: nothing drawn
    with pytest.raises(ValueError, match="outside its mesh"):
        r.render_arrays(vw, wrong, off)
    assert not r.depth.any() and not r.spans.any()
    d, _ = r.render_arrays(vw, faces, off)
    assert d.any()


@pytest.mark.parametrize("name", ["flacco-cell", "ur3-cell", "fr3-cell", "c-arm-room"])
def test_part_poses_are_the_primitives_poses(name):
    """``Person.part_poses`` (one numba pass) against ``Person.primitives`` (a solid per part,
    ``Capsule.between``, the arms' IK in numpy) of another instance of the same person, over the
    whole script: every part's pose and length to the rounding; the arm points it leaves for the
    carried props are ``_arm_points``' own."""
    a, b = load_cell(name).scene, load_cell(name).scene
    n = 0
    for t in np.linspace(-1.0, a.duration + 1.0, 400):
        t = float(t)
        for pa, pb in zip(a.people, b.people):
            got, ref = pa.part_poses(t), pb.primitives(t)
            if got is None:
                assert not ref
                continue
            assert len(got.kinds) == len(ref) == len(got.T) == len(got.length)
            for k, prim in enumerate(ref):
                _rounding(got.T[k], prim.world_from_local, t, prim.name)
                length = float(prim.length) if type(prim) is Capsule else 0.0
                _rounding(got.length[k], length, t, prim.name)
                assert got.kinds[k][0] == ("box" if type(prim) is Box else "capsule")
                n += 1
            p = pa.pose_at(t)
            for side in ("left", "right"):
                want = pb._arm_points(pb.pose_at(t), side)
                for x, y in zip(pa.arm_points(p, side), want):
                    _rounding(x, y, t, side)
    assert n > 500


def test_body_frame_and_leg_swing_are_the_numpy_formulas():
    """``body_frame`` is ``pose(rot_z(heading), [x, y, floor_z])``; ``leg_swing``'s walking speed
    is the numpy dot product of the velocity and the heading (its former arithmetic)."""
    person = load_cell("ur3-cell").scene.people[0]
    for t in np.linspace(0.0, 16.0, 300):
        t = float(t)
        p = person.pose_at(t)
        want = pose(rot_z(p.heading), [p.xy[0], p.xy[1], person.floor_z])
        _rounding(person.body_frame(p.xy, p.heading), want, t)
        vel = (person._xy_at(t + 0.05) - person._xy_at(t - 0.05)) / (2 * 0.05)
        v = max(float(vel @ [math.cos(p.heading), math.sin(p.heading)]), 0.0)
        want = math.radians(25.0) * min(v, 1.0) * math.sin(2 * math.pi * 0.9 * t)
        _rounding(person.leg_swing(t), want, t)


def test_posed_meshes_of_a_standing_person_are_not_posed_again():
    """A person who stands still and a prop that lies still: the same packed object, its
    vertices unchanged; a move poses again (against ``pack_primitives`` of another scene)."""
    scene, ref = load_cell("ur3-cell").scene, load_cell("ur3-cell").scene
    posed = PosedMeshes(scene)
    first = posed.at(3.2)                                   # standing (keys 3.0 .. 4.0)
    before = first.vertices.copy()
    second = posed.at(3.6)
    assert second is first and second.vertices.tobytes() == before.tobytes()
    _rounding(second.vertices, pack_primitives(ref.dynamic_at(3.6)).vertices)
    moved = posed.at(5.0)                                   # the arm reaches
    _rounding(moved.vertices, pack_primitives(ref.dynamic_at(5.0)).vertices)
    assert moved.vertices.tobytes() != before.tobytes()


def test_render_arrays_checks_a_read_only_mesh_off_once_and_always_its_totals():
    """A read-only ``mesh_off`` (a packed topology's) is checked on its first call; its totals
    against the vertices and faces at every call; the images as with a writable copy."""
    cam = dg.Camera("cam", 32, 24, 30.0, 30.0, 15.5, 11.5, np.eye(4))
    r, r2 = Renderer(cam), Renderer(cam)
    vw, faces, off = _pack([Box(size=(0.2, 0.2, 0.2)).moved(np.eye(4)).mesh()])
    vw = vw + [0.0, 0.0, 1.0]
    bad = off.copy()
    bad[0, 0] = 1                                          # not from 0: refused, read-only or not
    bad.setflags(write=False)
    with pytest.raises(ValueError, match="mesh_off"):
        r.render_arrays(vw, faces, bad)
    ro = off.copy()
    ro.setflags(write=False)
    for _ in range(2):
        d, _ = r.render_arrays(vw, faces, ro)
        assert d.tobytes() == r2.render_arrays(vw, faces, off.copy())[0].tobytes() and d.any()
    with pytest.raises(ValueError, match="mesh_off"):
        r.render_arrays(vw[:-1], faces, ro)                 # fewer vertices than its totals
