"""A ROS 2 bag round trip (R31): simulator -> ``record`` -> bag -> monitor gives the log of
simulator -> monitor, and two ``--fast`` replays of a bag give the same log byte for byte.

The truth for the bag run is the simulator's own frames quantised to whole millimetres (the
16UC1 encoding every ROS depth driver uses), computed here with numpy, not by the bag code.
Both runs are open loop: the simulated robot follows its path and does not obey the monitor
(a recording cannot obey anybody), so the two runs see the same robot.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from depthguard.runtime.monitor import Monitor
from depthguard.runtime.runner import run
from depthguard.sim import load_cell
from depthguard.sources.base import open_joints, open_source
from depthguard.sources.frame import Frame

DG = [sys.executable, "-m", "depthguard.cli"]
DURATION = 0.5


class MillimetreFrames:
    """A frame source that hands on another's frames with depths rounded to whole millimetres."""

    def __init__(self, inner):
        self.inner = inner
        self.camera_ids = inner.camera_ids

    def frames_until(self, t):
        return [Frame(f.camera_id, (np.rint(f.depth.astype(np.float64) * 1000.0) / 1000.0).astype(np.float32), f.stamp)
                for f in self.inner.frames_until(t)]

    done = property(lambda self: self.inner.done)
    lost = property(lambda self: self.inner.lost)

    def close(self):
        self.inner.close()


def _log(rig, frame_sources, joint_source) -> list[dict]:
    records = []
    mon = Monitor(rig, rig.monitor, sinks=[lambda r: records.append(r.to_dict())])
    try:
        run(mon, frame_sources, joint_source, duration=DURATION, fast=True)
    finally:
        mon.close()
    return records


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("bag") / "reach"
    res = subprocess.run(DG + ["record", "--cell", "flacco-cell", "--source", "sim:flacco-cell:reach",
                               "--duration", str(DURATION), "--out", str(out)],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    return out


def _compare(a: list[dict], b: list[dict]) -> None:
    assert len(a) == len(b) > 0
    for ra, rb in zip(a, b):
        assert ra["t"] == rb["t"]
        assert ra["override"] == pytest.approx(rb["override"], abs=1e-6)
        assert ra["reasons"].keys() == rb["reasons"].keys(), (ra["t"], ra["cameras"], rb["cameras"])
        assert {c: s["state"] for c, s in ra["cameras"].items()} == {c: s["state"] for c, s in rb["cameras"].items()}
        for pa, pb in zip(ra["points"], rb["points"]):
            assert pa["name"] == pb["name"] and pa["observed"] == pb["observed"]
            assert (pa["distance"] is None) == (pb["distance"] is None), (ra["t"], pa, pb)
            if pa["distance"] is not None:
                assert pa["distance"] == pytest.approx(pb["distance"], abs=2e-6)


def test_simulator_record_replay_gives_the_log_of_the_simulator(recorded):
    rig = load_cell("flacco-cell").rig
    ctx: dict = {}
    direct = _log(rig, [MillimetreFrames(open_source("sim:flacco-cell:reach", rig, ctx))], open_joints("sim", rig, ctx))
    ctx = {}
    replay = _log(rig, [open_source(f"bag:{recorded}", rig, ctx)], open_joints(f"bag:{recorded}", rig, ctx))
    _compare(direct, replay)
    # the run saw something: frames in use and a distance reported
    assert direct[-1]["cameras"]["cam0"]["frames"] > 5 and direct[-1]["cameras"]["cam1"]["frames"] > 5
    assert any(p["distance"] is not None for p in direct[-1]["points"])


@pytest.fixture(scope="module")
def replays(recorded, tmp_path_factory):
    """Two ``monitor --fast`` runs of the recorded bag, from the command line."""
    outs = []
    for k in range(2):
        out = tmp_path_factory.mktemp("replay") / f"run{k}"
        res = subprocess.run(DG + ["monitor", "--cell", "flacco-cell", "--source", f"bag:{recorded}",
                                   "--joints", f"bag:{recorded}", "--fast", "--out", str(out), "--quiet"],
                             capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr
        outs.append(out)
    return outs


def test_two_fast_replays_are_byte_identical_and_the_bag_counts_nothing_bad(recorded, replays):
    logs = [(out / "log.jsonl").read_bytes() for out in replays]
    assert logs[0] == logs[1]
    summary = json.loads((replays[0] / "summary.json").read_text())
    assert summary["cycles"] == int(round(DURATION / 0.002)) + 1
    assert summary["source_counts"] == {f"bag:{recorded}": {}}


def test_results_mcap_holds_every_cycle_of_the_log_for_an_independent_reader(replays):
    mcap_reader = pytest.importorskip("mcap.reader", reason="the mcap package (test extra) is the independent reader")
    mcap_decoder = pytest.importorskip("mcap_ros2.decoder", reason="mcap-ros2-support (test extra) decodes CDR")
    log = [json.loads(x) for x in (replays[0] / "log.jsonl").read_text().splitlines()]
    topics: dict[str, list] = {}
    with open(replays[0] / "results.mcap", "rb") as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[mcap_decoder.DecoderFactory()])
        for schema, channel, message, msg in reader.iter_decoded_messages():
            topics.setdefault(channel.topic, []).append((schema.name, message.log_time, msg))
    reactions, overrides, markers = (topics[t] for t in ("/depthguard/reaction", "/depthguard/override", "/depthguard/markers"))
    assert len(reactions) == len(overrides) == len(log)
    assert 15 <= len(markers) <= 16                                   # 30 Hz over 0.5 s
    assert {r[0] for r in reactions} == {"depthguard_msgs/msg/Reaction"} and overrides[0][0] == "std_msgs/msg/Float64"
    for (_n, lt, r), (_m, _lt, o), rec in zip(reactions, overrides, log):
        assert lt == round(rec["t"] * 1e9) and r.header.stamp.sec + r.header.stamp.nanosec * 1e-9 == pytest.approx(rec["t"])
        assert o.data == pytest.approx(rec["override"], abs=1e-6) and r.override == pytest.approx(rec["override"], abs=1e-6)
        assert list(r.reason_keys) == list(rec["reasons"])
        for i, p in enumerate(rec["points"]):
            assert r.names[i] == p["name"] and r.observed[i] == p["observed"]
            assert r.within_rho[i] == (p["distance"] is not None)      # "nothing within rho" is not a number
            if p["distance"] is not None:
                assert r.distance[i] == pytest.approx(p["distance"], abs=1e-6)
    # the arrows go from a control point to its nearest obstacle: their length is the distance
    by_t = {rec["t"]: rec for rec in log}
    arrows = 0
    for _n, lt, ma in markers:
        rec = by_t[round(lt * 1e-9, 6)]
        assert ma.markers[0].action == 3                                 # DELETEALL, then this cycle's markers
        for m in ma.markers[1:]:
            p = rec["points"][m.id]
            if m.ns == "distance":
                a, b = (np.array([q.x, q.y, q.z]) for q in m.points)
                assert np.linalg.norm(b - a) == pytest.approx(p["distance"], abs=1e-5)
                arrows += 1
    assert arrows > 0
