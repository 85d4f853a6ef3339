"""`depthguard scenes list|render` and the demo's contact sheets."""

import subprocess
import sys

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from depthguard.cli import app
from depthguard.depth_io import read_depth
from depthguard.render import render_depth
from depthguard.sim import load_cell


def test_scenes_list_names_every_cell():
    res = CliRunner().invoke(app, ["scenes", "list"])
    assert res.exit_code == 0, res.output
    for name in ("flacco-walls", "flacco-cell", "ur3-cell", "c-arm-room"):
        assert name in res.output
    assert "lwr4" in res.output and "ur3" in res.output and "21 x tof" in res.output


def test_scenes_render_writes_depth_pngs_and_a_contact_sheet(tmp_path):
    res = CliRunner().invoke(app, ["scenes", "render", "flacco-walls", "--time", "0", "--out", str(tmp_path),
                                   "--noiseless"])
    assert res.exit_code == 0, res.output
    d = read_depth(tmp_path / "cam0.png")
    cell = load_cell("flacco-walls")
    ideal = render_depth(cell.rig.camera("cam0"), cell.scene.meshes_at(0.0)[0])
    ideal[(ideal < 0.4) | (ideal > 4.0)] = 0
    assert np.abs(d - ideal).max() <= 0.0005 + 1e-6  # millimetre PNG
    with Image.open(tmp_path / "contact_sheet.png") as im:
        assert im.size[0] > 200 and im.mode in ("RGBA", "RGB")


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "depthguard.cli.__main__", *args], capture_output=True, text=True)


@pytest.mark.slow  # three interpreter start-ups
def test_scenes_render_bad_input_is_one_clear_error(tmp_path):
    r = run_cli("scenes", "render", "no-such-cell", "--out", str(tmp_path))
    assert r.returncode == 2 and "unknown cell 'no-such-cell'" in r.stderr
    r = run_cli("scenes", "render", "flacco-cell", "--situation", "nope", "--out", str(tmp_path))
    assert r.returncode == 2 and "situations: robot_alone" in r.stderr
    r = run_cli("scenes", "render", "flacco-walls", "--time", "-1", "--out", str(tmp_path))
    assert r.returncode == 2 and "time" in r.stderr


def test_demo_contact_sheets_function(tmp_path):
    from depthguard.cli.demo import render_contact_sheets

    sheets = render_contact_sheets(tmp_path, cells=["flacco-walls"], noiseless=True)
    assert [p.name for p in sheets] == ["contact_sheet.png"]
    assert (tmp_path / "flacco-walls" / "static" / "cam0.png").is_file()


def test_colorize_depth_marks_invalid_black_and_orders_near_far():
    from depthguard.viz import colorize_depth

    d = np.array([[0.0, 1.0, 2.0, np.nan]], np.float32)
    rgb = colorize_depth(d, 1.0, 2.0)
    assert rgb.shape == (1, 4, 3)
    assert (rgb[0, 0] == 0).all() and (rgb[0, 3] == 0).all()
    near, far = rgb[0, 1], rgb[0, 2]
    assert near[0] > near[2] and far[2] > far[0]  # near is warm (red), far is cold (blue)


def test_demo_summary_table_flags_collisions_and_missing_rms():
    """The demo's table says YES for a collision and n/a where the EE was never clear."""
    from rich.console import Console

    from depthguard.cli.demo import summary_table

    base = dict(min_true_distance_m=0.05, ee_tracking_rms_all_m=0.01, ee_max_repulsion_m_s=0.5,
                min_task_scale=1.0, safe_stops=[], avoidance_rate_hz=300.0, real_time_factor=0.4,
                real_time_factor_system=0.7)
    rows = [dict(base, scenario="ok", collision=False, ee_tracking_rms_m=0.0042, min_true_distance_dynamic_m=0.154),
            dict(base, scenario="bad", collision=True, ee_tracking_rms_m=None,
                 safe_stops=[{"reason": "stale"}])]
    con = Console(width=120, record=True, force_terminal=False)
    con.print(summary_table(rows))
    text = con.export_text()
    ok_line = next(l for l in text.splitlines() if "│ ok" in l)
    bad_line = next(l for l in text.splitlines() if "│ bad" in l)
    assert "15.4" in ok_line and "4.20" in ok_line and " no " in ok_line
    assert "YES" in bad_line and "n/a" in bad_line and "5.0" in bad_line
