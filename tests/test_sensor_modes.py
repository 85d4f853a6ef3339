"""The D435's depth modes as its data sheet lists them (issue 33 item 9, R1): a rig may name any,
each with the field of view of its family; a mode that does not exist says that explicit
intrinsics are accepted, and explicit intrinsics keep the sensor's range."""

import math

import pytest
import yaml

import depthguard as dg
from depthguard.rig import RigError
from depthguard.sensors import intrinsics_for


def _rig(tmp_path, camera):
    data = {"name": "own-cell", "workspace": {"min": [-1, -1, 0], "max": [1, 1, 2]},
            "cameras": [dict({"id": "front", "pose": {"look_at": {"eye": [2, 0, 1.5], "target": [0, 0, 0.5]}}},
                             **camera)]}
    p = tmp_path / "cell.yaml"
    p.write_text(yaml.safe_dump(data))
    return dg.Rig.load(p)


@pytest.mark.parametrize("w, h", [(1280, 720), (848, 480), (640, 360), (480, 270), (424, 240), (256, 144)])
def test_every_16_9_mode_of_the_d435_loads_with_the_field_of_view_of_1280x720(tmp_path, w, h):
    """The 16:9 modes are the 1280x720 image scaled: 2 atan(W / 2f) is the same 90 deg for each."""
    cam = _rig(tmp_path, {"sensor": "realsense_d435", "width": w, "height": h}).camera("front")
    assert (cam.width, cam.height) == (w, h) and cam.fx == cam.fy
    assert math.degrees(2 * math.atan(w / 2 / cam.fx)) == pytest.approx(90.0, abs=0.01)
    # vertically the same 59 deg, up to the rounding of 848 and 424 to a multiple of 8 (58.7 vs 59.0 deg)
    assert math.degrees(2 * math.atan(h / 2 / cam.fy)) == pytest.approx(2 * math.degrees(math.atan(360 / 640)),
                                                                        abs=0.35)
    assert (cam.cx, cam.cy) == ((w - 1) / 2, (h - 1) / 2) and (cam.min_range, cam.max_range) == (0.2, 6.0)


def test_the_848x100_band_has_the_focal_length_of_848x480():
    band, full = intrinsics_for("realsense_d435", 848, 100), intrinsics_for("realsense_d435", 848, 480)
    assert band["fx"] == full["fx"] == 424.0 and band["cy"] == 49.5


def test_the_640x480_default_is_unchanged():
    assert intrinsics_for("realsense_d435")["fx"] == 385.0


def test_a_mode_the_sensor_does_not_have_names_its_modes_and_the_explicit_intrinsics(tmp_path):
    with pytest.raises(RigError) as err:
        _rig(tmp_path, {"sensor": "realsense_d435", "width": 1024, "height": 768})
    msg = str(err.value)
    assert "has no 1024x768 mode" in msg and "848x480" in msg and "fx, fy, cx, cy" in msg


def test_explicit_intrinsics_of_another_mode_keep_the_sensors_range(tmp_path):
    cam = _rig(tmp_path, {"sensor": "realsense_d435", "width": 1024, "height": 768, "fx": 500.0, "fy": 500.0,
                          "cx": 511.5, "cy": 383.5}).camera("front")
    assert (cam.fx, cam.width) == (500.0, 1024) and (cam.min_range, cam.max_range) == (0.2, 6.0)
