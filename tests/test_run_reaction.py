"""``run --rig`` takes the rig's ``monitor: reaction`` unless ``--reaction`` is given, and says
which it used (issue 33 item 6, R33)."""

import json

import pytest
import yaml
from typer.testing import CliRunner

from depthguard.cli import app


def _ur3_rig(path, reaction=None):
    rig = {
        "name": "my-ur3",
        "workspace": {"min": [-1.0, -1.0, 0.0], "max": [1.0, 1.0, 1.6]},
        "cameras": [{"id": "cam0", "width": 160, "height": 120, "fx": 140.0, "fy": 140.0, "cx": 79.5, "cy": 59.5,
                     "range": [0.3, 5.0], "pose": {"look_at": {"eye": [1.6, -1.3, 1.7], "target": [0.0, 0.0, 0.9]}}}],
        "robot": {"name": "ur3", "base": {"translation": [0.0, 0.0, 0.8]},
                  "joints": [0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0]},
        "objects": [{"name": "table", "box": {"size": [1.2, 0.8, 0.04]}, "pose": {"translation": [0.0, 0.0, 0.78]}}],
    }
    if reaction is not None:
        rig["monitor"] = {"reaction": reaction}
    path.write_text(yaml.safe_dump(rig, sort_keys=False))
    return path


@pytest.mark.parametrize("in_rig, option, used, source", [
    ("ssm", None, "ssm", "the rig's monitor: reaction"),
    ("ssm", "repulsion", "repulsion", "--reaction"),
    (None, None, "repulsion", "the rig's monitor: reaction"),
    (None, "both", "both", "--reaction"),
])
def test_the_rigs_reaction_is_used_unless_the_option_is_given(tmp_path, in_rig, option, used, source):
    f = _ur3_rig(tmp_path / "rig.yaml", in_rig)
    out = tmp_path / "run"
    args = ["run", "--rig", str(f), "-s", "empty", "--duration", "0.2", "-o", str(out), "--no-noise"]
    res = CliRunner().invoke(app, args + ([] if option is None else ["--reaction", option]))
    assert res.exit_code == 0, res.output
    s = json.loads((out / "summary.json").read_text())
    assert (s["reaction"], s["reaction_from"]) == (used, source)
    assert f"run: reaction {used} (from {source})" in res.output
    assert ("SSM: task progress" in res.output) == (used != "repulsion")      # the SSM's figures were computed
    assert ("ssm_compare" in s) == (used != "repulsion")
