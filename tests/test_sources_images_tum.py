"""``images:`` reads a TUM RGB-D sequence: ``depth.txt`` and 16-bit PNGs at 5000 per metre (issue 31).

The truth is what the test writes: integer PNG units whose depth is ``units /
5000`` m (the TUM RGB-D format), read through PIL by ``images:`` with the rig
camera's ``depth_scale: 0.0002``; the stamps of ``depth.txt``, its ``#``
comments skipped. A multi-camera rig must be told which camera the sequence is.
"""

import dataclasses

import numpy as np
import pytest
from PIL import Image

from depthguard.rig import Rig
from depthguard.sources.base import open_source
from depthguard.sources.images import ImageSourceError

from test_sources_images import CELL

TUM_HEADER = "# depth maps\n# file: 'rgbd_dataset_freiburg1_xyz.bag'\n# timestamp filename\n"


@pytest.fixture(scope="module")
def rig():
    base = Rig.load(CELL)                     # cam0, cam1: 480 x 640
    return dataclasses.replace(base, depth_scales={**base.depth_scales, "cam0": 0.0002})


def write_tum(directory, stamps, rng):
    """``depth/<stamp>.png`` (uint16, 5000 per metre, 0 = none) and ``depth.txt``; the unit images."""
    (directory / "depth").mkdir(parents=True)
    units, lines = [], []
    for s in stamps:
        u = rng.integers(1500, 30000, size=(480, 640)).astype(np.uint16)     # 0.3 .. 6 m
        u[rng.random(u.shape) < 0.1] = 0
        name = f"depth/{s:.6f}.png"
        Image.fromarray(u).save(directory / name)
        units.append(u)
        lines.append(f"{s:.6f} {name}")
    (directory / "depth.txt").write_text(TUM_HEADER + "\n".join(lines) + "\n\n")
    return units


def drain(src):
    got = []
    while not src.done:
        got.extend(src.frames_until(float("inf")))
    assert src.lost is None, src.lost
    return got


def test_a_tum_sequence_plays_at_5000_units_per_metre(tmp_path, rig, rng):
    stamps = [1305031102.160407, 1305031102.194330, 1305031102.226738]
    units = write_tum(tmp_path / "seq", stamps, rng)
    src = open_source(f"images:cam0={tmp_path / 'seq'}", rig)
    try:
        got = drain(src)
    finally:
        src.close()
    assert [f.camera_id for f in got] == ["cam0"] * 3
    assert [f.stamp for f in got] == stamps
    for f, u in zip(got, units):
        np.testing.assert_allclose(f.depth, u.astype(np.float64) / 5000.0, rtol=1e-6)
        assert np.all((f.depth == 0) == (u == 0))


def test_a_one_camera_rig_needs_no_name_and_a_bad_line_is_named(tmp_path, rig, rng):
    one = dataclasses.replace(rig, cameras=[rig.camera("cam0")])
    write_tum(tmp_path / "seq", [1.0, 2.0], rng)
    src = open_source(f"images:{tmp_path / 'seq'}", one)
    try:
        assert [f.stamp for f in drain(src)] == [1.0, 2.0]
    finally:
        src.close()
    with open(tmp_path / "seq" / "depth.txt", "a") as fh:
        fh.write("3.0\n")
    with pytest.raises(ImageSourceError, match=r"depth.txt:7: expected 'timestamp filename'"):
        open_source(f"images:{tmp_path / 'seq'}", one)


def test_a_tum_sequence_for_a_rig_of_several_cameras_must_name_its_camera(tmp_path, rig, rng):
    write_tum(tmp_path / "seq", [1.0], rng)
    with pytest.raises(ImageSourceError, match=r"name it, images:CAMERA="):
        open_source(f"images:{tmp_path / 'seq'}", rig)


def test_the_rig_cameras_depth_scale_applies_to_index_csv_pngs_too(tmp_path, rig):
    u = np.full((480, 640), 6172, dtype=np.uint16)
    d = tmp_path / "imgs"
    d.mkdir()
    Image.fromarray(u).save(d / "a.png")
    Image.fromarray(u).save(d / "b.png")
    (d / "index.csv").write_text("stamp,camera,file\n0.0,cam0,a.png\n0.0,cam1,b.png\n")
    src = open_source(f"images:{d}", rig)
    try:
        got = {f.camera_id: f.depth for f in drain(src)}
    finally:
        src.close()
    assert np.allclose(got["cam0"], 6172 / 5000.0) and np.allclose(got["cam1"], 6.172)   # cam1: millimetres
