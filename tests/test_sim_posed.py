"""The moving meshes posed in place (``sim/posed.py``) and the renderer that draws them where they
lie, with its rows' spans (``Renderer.render_arrays``, ``Renderer.spans``; issue 29).

Truths: each primitive's own ``mesh()`` (a second implementation of the posed vertices), the
plain-numpy twin of the rasteriser (``render_depth_numpy``: per-pixel edge tests), and the
spans read off the depth image with numpy (first and last nonzero pixel of each row).
"""

from __future__ import annotations

import numpy as np
import pytest

import depthguard as dg
from depthguard.geometry import Box, Sphere
from depthguard.render import Renderer
from depthguard.render.raster_ref import render_depth_numpy
from depthguard.sim import load_cell
from depthguard.sim.posed import PosedMeshes, pack_primitives
from depthguard.sim.scene import Scene
from depthguard.transforms import look_at


def _spans_of(depth: np.ndarray) -> np.ndarray:
    """(H, 2) ``[a, b)`` of each row's nonzero pixels, ``(0, 0)`` when none (numpy)."""
    out = np.zeros((depth.shape[0], 2), np.int32)
    for v, row in enumerate(depth):
        nz = np.flatnonzero(row)
        if len(nz):
            out[v] = (nz[0], nz[-1] + 1)
    return out


@pytest.mark.parametrize("name", ["flacco-cell", "ur3-cell", "c-arm-room"])
def test_posed_meshes_are_the_primitives_meshes_bit_for_bit(name):
    """Over the whole script (people walking, reaching, carrying, entering and leaving; the
    c-arm room's step-posed staff): the packed vertices are each primitive's ``mesh()``, to the
    bit, the faces the same; one topology while the parts stay, another when they change."""
    scene = load_cell(name).scene
    posed = PosedMeshes(scene)
    topologies = set()
    n_parts = 0
    for t in np.linspace(0.0, scene.duration, 24, endpoint=False):
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
            assert a.vertices.tobytes() == b.vertices.tobytes()
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
