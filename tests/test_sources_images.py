"""The ``images:DIR`` frame source (R31): recorded frames come back exactly, bad indexes name the line.

Truth: the arrays and stamps written by the test itself (``write_image_dir``,
``write_depth``), and the stated format rules of ``sources/images.py``.
"""

from pathlib import Path

import numpy as np
import pytest

import depthguard
from depthguard.depth_io import write_depth
from depthguard.rig import Rig
from depthguard.sources import Frame
from depthguard.sources.base import FrameSource
from depthguard.sources.images import ImageSource, ImageSourceError, open_images, write_image_dir

CELL = Path(depthguard.__file__).parent / "data" / "cells" / "flacco-cell.yaml"


@pytest.fixture(scope="module")
def rig():
    return Rig.load(CELL)          # cameras cam0, cam1, both (480, 640)


def depth_image(rng, shape=(480, 640)):
    d = rng.uniform(0.3, 6.0, shape).astype(np.float32)
    d[rng.random(shape) < 0.1] = 0.0                     # holes: no measurement
    return d


def write_index(directory: Path, lines: list[str]) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "index.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    return directory


def test_round_trip_gives_the_written_arrays_and_stamps_in_stamp_order(tmp_path, rig, rng):
    frames = [Frame("cam0", depth_image(rng), 10.0), Frame("cam1", depth_image(rng), 10.01),
              Frame("cam0", depth_image(rng), 10.033), Frame("cam1", depth_image(rng), 10.02)]
    write_image_dir(tmp_path / "rec", frames)
    src = ImageSource(tmp_path / "rec", rig)
    assert isinstance(src, FrameSource)
    assert src.camera_ids == ["cam0", "cam1"] and src.first_stamp == 10.0 and not src.done
    assert src.frames_until(9.99) == []
    got = src.frames_until(10.02)
    assert [(f.camera_id, f.stamp) for f in got] == [("cam0", 10.0), ("cam1", 10.01), ("cam1", 10.02)]
    for f, truth in zip(got, [frames[0], frames[1], frames[3]]):
        assert f.depth.dtype == np.float32 and f.depth.shape == (480, 640)
        np.testing.assert_array_equal(f.depth, truth.depth)
    assert src.frames_until(10.02) == [] and not src.done     # nothing given twice
    last = src.frames_until(1e9)
    assert [(f.camera_id, f.stamp) for f in last] == [("cam0", 10.033)]
    np.testing.assert_array_equal(last[0].depth, frames[2].depth)
    assert src.done and src.lost is None and src.skipped == 0
    src.close()


def test_images_are_read_only_when_due(tmp_path, rig, rng):
    write_image_dir(tmp_path, [Frame("cam0", depth_image(rng), 0.0), Frame("cam0", depth_image(rng), 1.0)])
    src = ImageSource(tmp_path, rig)
    replacement = depth_image(rng)
    np.save(tmp_path / "cam0_000001.npy", replacement)       # changed after open, before due
    src.frames_until(0.5)
    np.testing.assert_array_equal(src.frames_until(1.0)[0].depth, replacement)


def test_png_millimetres_are_read_as_metres(tmp_path, rig, rng):
    truth = np.rint(depth_image(rng) * 1000.0) / 1000.0        # a PNG holds whole millimetres
    write_depth(tmp_path / "a.png", truth)
    write_index(tmp_path, ["stamp,camera,file", "0.5,cam1,a.png"])
    src = open_images(str(tmp_path), rig, {})
    (f,) = src.frames_until(0.5)
    assert f.camera_id == "cam1" and f.stamp == 0.5
    np.testing.assert_allclose(f.depth, truth, atol=1e-6)
    assert (f.depth[truth == 0] == 0).all()


def test_empty_index_is_done_with_no_first_stamp(tmp_path, rig):
    src = ImageSource(write_index(tmp_path, ["stamp,camera,file"]), rig)
    assert src.done and src.first_stamp is None and src.camera_ids == [] and src.frames_until(1e9) == []


@pytest.mark.parametrize("lines, line, words", [
    (["stamp,cam,file", "0,cam0,a.npy"], 1, "header"),
    (["camera,stamp,file", "cam0,0,a.npy"], 1, "header"),
    (["stamp,camera,file", "0,cam0,a.npy", "x,cam0,a.npy"], 3, "not a number"),
    (["stamp,camera,file", "nan,cam0,a.npy"], 2, "not finite"),
    (["stamp,camera,file", "inf,cam0,a.npy"], 2, "not finite"),
    (["stamp,camera,file", "0,cam0,a.npy", "0.1,camZ,a.npy"], 3, "'camZ' is not in rig"),
    (["stamp,camera,file", "0.2,cam0,a.npy", "0.3,cam1,a.npy", "0.1,cam0,a.npy"], 4, "before its previous"),
    (["stamp,camera,file", "0,cam0,missing.npy"], 2, "does not exist"),
    (["stamp,camera,file", "0,cam0,a.npy,extra"], 2, "3 columns"),
    (["stamp,camera,file", "0,cam0,a.tiff"], 2, "neither .png nor .npy"),
])
def test_bad_index_names_the_line(tmp_path, rig, lines, line, words):
    np.save(tmp_path / "a.npy", np.zeros((480, 640), np.float32))
    (tmp_path / "a.tiff").write_bytes(b"")
    write_index(tmp_path, lines)
    with pytest.raises(ImageSourceError) as err:
        ImageSource(tmp_path, rig)
    assert f"index.csv:{line}" in str(err.value) and words in str(err.value)


def test_missing_directory_or_index_is_an_error(tmp_path, rig):
    with pytest.raises(ImageSourceError, match="not a directory"):
        ImageSource(tmp_path / "nope", rig)
    with pytest.raises(ImageSourceError, match="index.csv does not exist"):
        ImageSource(tmp_path, rig)


def test_equal_stamps_of_one_camera_are_allowed(tmp_path, rig):
    np.save(tmp_path / "a.npy", np.ones((480, 640), np.float32))
    src = ImageSource(write_index(tmp_path, ["stamp,camera,file", "1,cam0,a.npy", "1,cam0,a.npy"]), rig)
    assert len(src.frames_until(1.0)) == 2


def test_corrupt_image_sets_lost_and_is_skipped_without_raising(tmp_path, rig, rng):
    good = depth_image(rng)
    np.save(tmp_path / "good.npy", good)
    (tmp_path / "bad.npy").write_bytes(b"not an array at all")
    np.save(tmp_path / "small.npy", np.ones((240, 320), np.float32))
    write_index(tmp_path, ["stamp,camera,file", "0,cam0,bad.npy", "1,cam0,good.npy", "2,cam1,small.npy"])
    src = ImageSource(tmp_path, rig)
    assert src.lost is None
    got = src.frames_until(1.0)
    assert [f.stamp for f in got] == [1.0] and src.skipped == 1
    np.testing.assert_array_equal(got[0].depth, good)
    assert "bad.npy" in src.lost and "index.csv:2" in src.lost
    assert src.frames_until(2.0) == [] and src.skipped == 2 and src.done
    assert "bad.npy" in src.lost                                # the first failure stays reported


def test_wrong_shape_is_lost_with_a_sentence(tmp_path, rig):
    np.save(tmp_path / "small.npy", np.ones((240, 320), np.float32))
    src = ImageSource(write_index(tmp_path, ["stamp,camera,file", "2,cam1,small.npy"]), rig)
    assert src.frames_until(5.0) == []
    assert "small.npy" in src.lost and "(480, 640)" in src.lost and "'cam1'" in src.lost


def test_write_image_dir_refuses_to_overwrite_and_bad_frames(tmp_path, rng):
    frames = [Frame("cam0", depth_image(rng, (4, 5)), 0.0)]
    write_image_dir(tmp_path, frames)
    before = (tmp_path / "index.csv").read_bytes()
    with pytest.raises(ImageSourceError, match="exists already"):
        write_image_dir(tmp_path, frames)
    assert (tmp_path / "index.csv").read_bytes() == before
    with pytest.raises(ImageSourceError, match="frame 1: stamp"):
        write_image_dir(tmp_path / "b", [Frame("cam0", frames[0].depth, 1.0), Frame("cam0", frames[0].depth, 0.5)])
    with pytest.raises(ImageSourceError, match="not finite"):
        write_image_dir(tmp_path / "c", [Frame("cam0", frames[0].depth, float("nan"))])
    with pytest.raises(ImageSourceError, match="cannot name a file"):
        write_image_dir(tmp_path / "d", [Frame("../x", frames[0].depth, 0.0)])
    assert not (tmp_path / "b" / "index.csv").exists()
