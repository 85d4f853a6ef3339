"""``depthguard monitor`` on SDK recordings, end to end (issue 15).

Two recordings of simulated ``flacco-cell`` depth, written by the RealSense
SDK's recorder, and the simulated robot's joint states as a CSV, are run by
the command a user types (``--source realsense-file:... --joints csv:... --fast``),
twice: every frame is used and none refused, the cameras are fresh at the end,
and the two logs are the same byte for byte (a ``--fast`` replay is a pure
function of its inputs). Skipped, with the reason, when ``import pyrealsense2`` fails.
"""

import pytest

from depthguard.sources.realsense_device import RealSenseUnavailable, import_sdk

try:
    import_sdk()
except RealSenseUnavailable as _exc:
    pytest.skip(f"RealSense SDK not importable here: {_exc}", allow_module_level=True)

from depthguard.sources.realsense_device import record_depth  # noqa: E402
from depthguard.sources.sim_source import SimFrames, SimWorld  # noqa: E402

T_END = 0.2


@pytest.fixture(scope="module")
def sim():
    world = SimWorld("flacco-cell", situation="reach", seed=3)
    frames = SimFrames(world).frames_until(T_END)
    return world.rig, frames, list(world.states)


@pytest.fixture(scope="module")
def recordings(sim, tmp_path_factory):
    rig, frames, _ = sim
    d = tmp_path_factory.mktemp("rsmon")
    out = {}
    for i, cid in enumerate(rig.camera_ids):
        own = [f for f in frames if f.camera_id == cid]
        path = d / f"{cid}.db3"
        record_depth(path, [(f.depth, f.stamp) for f in own], rig.camera(cid), serial=f"10{i}", period_s=0.01)
        out[cid] = {"path": path, "frames": own}
    return out


def test_depthguard_monitor_runs_a_recording_fast_and_deterministically(sim, recordings, tmp_path):
    """The user's path: ``depthguard monitor --source realsense-file:... --joints csv:... --fast``, twice."""
    import json

    from typer.testing import CliRunner

    from depthguard.cli import app

    rig, frames, states = sim
    joints = tmp_path / "joints.csv"
    dof = len(states[0][1])
    joints.write_text("stamp," + ",".join(f"j{i}" for i in range(dof)) + "\n"
                      + "".join(f"{ts!r}," + ",".join(repr(float(v)) for v in q) + "\n" for ts, q in states))
    spec = "realsense-file:" + ",".join(f"{c}={recordings[c]['path']}" for c in rig.camera_ids)
    logs = []
    for run in ("a", "b"):
        out = tmp_path / run
        r = CliRunner().invoke(app, ["monitor", "--cell", "flacco-cell", "--source", spec, "--joints", f"csv:{joints}",
                                     "--fast", "--duration", str(T_END - 0.01), "--out", str(out), "--quiet"])
        assert r.exit_code == 0, r.output
        summary = json.loads((out / "summary.json").read_text())
        assert summary["source_errors"] == [] and summary["cycles"] >= 90
        for c in rig.camera_ids:
            st = summary["stats"]["cameras"][c]
            assert st["frames"] >= len(recordings[c]["frames"]) - 1 and st["refused"] == {}
        logs.append((out / "log.jsonl").read_bytes())
    assert logs[0] == logs[1]
    last = json.loads(logs[0].splitlines()[-1])
    assert all(s["state"] == "fresh" for s in last["cameras"].values())
