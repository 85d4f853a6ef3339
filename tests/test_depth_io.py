"""Depth files (SPEC §1): 16-bit millimetre PNG and float32 .npy, and their errors."""

import numpy as np
import pytest
from PIL import Image

import depthguard as dg
from depthguard.depth_io import DepthFileError


def test_png_round_trip_millimetres(tmp_path, rng):
    d = rng.uniform(0.3, 6.0, (48, 64)).astype(np.float32)
    d[0, 0] = 0.0
    p = dg.write_depth(tmp_path / "d.png", d)
    back = dg.read_depth(p)
    assert back.dtype == np.float32 and back.shape == d.shape
    assert np.abs(back - d).max() <= 0.0005 + 1e-6        # rounded to the nearest mm
    assert back[0, 0] == 0.0
    raw = np.asarray(Image.open(p))
    assert raw.dtype == np.uint16 and raw[1, 1] == round(float(d[1, 1]) * 1000)


def test_npy_round_trip_and_nan_is_no_measurement(tmp_path, rng):
    d = rng.uniform(0.3, 6.0, (10, 12)).astype(np.float32)
    d[2, 3] = np.nan
    np.save(tmp_path / "d.npy", d)
    back = dg.read_depth(tmp_path / "d.npy")
    assert back[2, 3] == 0.0
    mask = np.isfinite(d)
    assert np.array_equal(back[mask], d[mask])


def test_errors_name_the_file(tmp_path):
    with pytest.raises(DepthFileError, match="no such depth file"):
        dg.read_depth(tmp_path / "missing.png")
    Image.fromarray(np.zeros((4, 4, 3), np.uint8)).save(tmp_path / "rgb.png")
    with pytest.raises(DepthFileError, match="rgb.png"):
        dg.read_depth(tmp_path / "rgb.png")
    np.save(tmp_path / "int.npy", np.zeros((4, 4), np.int32))
    with pytest.raises(DepthFileError, match="float"):
        dg.read_depth(tmp_path / "int.npy")
    (tmp_path / "x.txt").write_text("1")
    with pytest.raises(DepthFileError, match="unknown depth file type"):
        dg.read_depth(tmp_path / "x.txt")
    (tmp_path / "broken.png").write_bytes(b"not a png")
    with pytest.raises(DepthFileError, match="broken.png"):
        dg.read_depth(tmp_path / "broken.png")


def test_write_refuses_what_png_cannot_hold(tmp_path):
    with pytest.raises(ValueError, match="16-bit"):
        dg.write_depth(tmp_path / "far.png", np.full((2, 2), 70.0))
    with pytest.raises(ValueError, match="negative"):
        dg.write_depth(tmp_path / "neg.png", np.full((2, 2), -1.0))
