"""Joint-state sources ``csv:FILE`` and ``zenoh:KEY`` (R27, R31).

Truth: the states the test writes or publishes itself, the robot's joint limits
read from the rig, and the stated rules (strictly increasing stamps, payload schema).
The zenoh source is fed by a real publisher session on 127.0.0.1.
"""

import json
from pathlib import Path

import numpy as np
import pytest

import depthguard
from depthguard.rig import Rig
from depthguard.sources.base import JointSource
from depthguard.transport.settings import zenoh_config
from depthguard.sources.joints import (CsvJointSource, JointSourceError, ZenohJointSource, open_csv_joints,
                                       open_zenoh_joints)
from loopback import free_port, wait_until

CELL = Path(depthguard.__file__).parent / "data" / "cells" / "flacco-cell.yaml"


@pytest.fixture(scope="module")
def rig():
    return Rig.load(CELL)          # lwr4: 7 joints, limits +-2.967 / +-2.094 rad


def states(rig, rng, n=5):
    lo, hi = rig.robot.q_min, rig.robot.q_max
    return [(0.1 * i + 3.0, rng.uniform(lo, hi)) for i in range(n)]


def write_csv(path: Path, header: str, rows: list[str]) -> Path:
    path.write_text("\n".join([header, *rows]) + "\n", encoding="utf-8")
    return path


HEADER = "stamp,a1,a2,a3,a4,a5,a6,a7"


# --------------------------------------------------------------------------- csv
def test_csv_round_trip_gives_the_written_states(tmp_path, rig, rng):
    truth = states(rig, rng)
    path = write_csv(tmp_path / "j.csv", HEADER, [",".join(repr(float(v)) for v in [s, *q]) for s, q in truth])
    src = open_csv_joints(str(path), rig, {})
    assert isinstance(src, JointSource) and src.first_stamp == truth[0][0] and not src.done
    assert src.states_until(2.9) == []
    got = src.states_until(truth[2][0]) + src.states_until(truth[2][0]) + src.states_until(1e9)
    assert [s for s, _ in got] == [s for s, _ in truth]
    for (_, q), (_, qt) in zip(got, truth):
        assert q.dtype == np.float64 and q.shape == (7,)
        np.testing.assert_array_equal(q, qt)
    assert src.done and src.lost is None
    got[0][1][:] = 99.0                                      # callers get copies
    src.close()


def test_csv_values_at_the_joint_limits_are_accepted(tmp_path, rig):
    lo, hi = rig.robot.q_min, rig.robot.q_max
    rows = [",".join(map(repr, [0.0, *map(float, lo)])), ",".join(map(repr, [1.0, *map(float, hi)]))]
    src = CsvJointSource(write_csv(tmp_path / "j.csv", HEADER, rows), rig)
    assert len(src.states_until(1.0)) == 2


@pytest.mark.parametrize("header, rows, line, words", [
    ("stamp,a1,a2,a3,a4,a5,a6", ["0,0,0,0,0,0,0"], 1, "7 joint names"),
    ("time,a1,a2,a3,a4,a5,a6,a7", ["0,0,0,0,0,0,0,0"], 1, "header"),
    (HEADER, ["0,0,0,0,0,0,0,0", "1,0,0,0,0,0,0"], 3, "expected 8 columns"),
    (HEADER, ["0,0,0,0,x,0,0,0"], 2, "not a number"),
    (HEADER, ["0,0,0,0,nan,0,0,0"], 2, "non-finite"),
    (HEADER, ["inf,0,0,0,0,0,0,0"], 2, "stamp inf is not a finite"),
    (HEADER, ["0,0,0,0,0,0,0,0", "0,0,0,0,0,0,0,0"], 3, "strictly increase"),
    (HEADER, ["1,0,0,0,0,0,0,0", "0.5,0,0,0,0,0,0,0"], 3, "strictly increase"),
    (HEADER, ["0,0,2.5,0,0,0,0,0"], 2, "joint 2 = 2.5 is outside its limits"),
    (HEADER, ["0,0,0,0,0,0,0,-3.0"], 2, "joint 7 = -3 is outside its limits"),
])
def test_csv_bad_cases_name_file_and_line(tmp_path, rig, header, rows, line, words):
    path = write_csv(tmp_path / "j.csv", header, rows)
    with pytest.raises(JointSourceError) as err:
        CsvJointSource(path, rig)
    assert f"j.csv:{line}" in str(err.value) and words in str(err.value)


def test_csv_missing_file_and_rig_without_robot(tmp_path, rig):
    with pytest.raises(JointSourceError, match="does not exist"):
        CsvJointSource(tmp_path / "none.csv", rig)
    no_robot = Rig(name="bare", cameras=rig.cameras, workspace=rig.workspace)
    with pytest.raises(JointSourceError, match="no robot"):
        CsvJointSource(write_csv(tmp_path / "j.csv", HEADER, []), no_robot)


# --------------------------------------------------------------------------- zenoh




@pytest.fixture
def wired(rig):
    """A ZenohJointSource listening on a loopback port and a publisher session connected to it."""
    import zenoh

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    src = open_zenoh_joints("robot/joints", rig, {"zenoh_listen": [endpoint]})
    pub_session = zenoh.open(zenoh_config(connect=[endpoint]))
    pub = pub_session.declare_publisher("robot/joints")
    assert wait_until(lambda: pub.matching_status.matching, 10.0), "publisher never matched the subscriber"
    yield src, pub
    pub.undeclare()
    pub_session.close()
    src.close()


def payload(stamp, q) -> bytes:
    return json.dumps({"stamp": stamp, "q": [float(v) for v in q]}).encode("utf-8")


@pytest.mark.multiprocess
def test_zenoh_states_arrive_in_order_and_bad_payloads_are_counted(wired, rig, rng):
    src, pub = wired
    truth = states(rig, rng, 4)
    bad = [b"not json", b"\xff\xfe", json.dumps({"stamp": 1.0, "q": [0.0] * 6}).encode(),
           json.dumps({"stamp": float("nan"), "q": [0.0] * 7}).encode(),      # NaN is not valid JSON data
           json.dumps({"stamp": 1.0, "q": [0.0] * 6 + [float("inf")]}).encode(),
           json.dumps({"stamp": 1.0, "q": ["0"] * 7}).encode(),
           json.dumps({"stamp": True, "q": [0.0] * 7}).encode(),
           json.dumps({"q": [0.0] * 7}).encode(),
           json.dumps([1.0, [0.0] * 7]).encode(),
           json.dumps({"stamp": 1.0, "q": [0.0, 2.5, 0, 0, 0, 0, 0]}).encode()]   # joint 2 beyond 2.094
    pub.put(payload(*truth[0]))
    for b in bad:
        pub.put(b)
    pub.put(payload(*truth[1]))
    pub.put(payload(truth[0][0], truth[0][1]))                 # older than the last one: dropped
    pub.put(payload(*truth[2]))
    pub.put(payload(*truth[3]))
    assert wait_until(lambda: src.rejected + src.out_of_order + len(src._queue) >= len(bad) + 5, 5.0)
    assert src.rejected == len(bad) and src.out_of_order == 1
    assert "outside its limits" in src.last_error
    got = src.states_until(truth[1][0])
    assert [s for s, _ in got] == [truth[0][0], truth[1][0]]
    for (_, q), (_, qt) in zip(got, truth):
        np.testing.assert_array_equal(q, qt)
    rest = src.states_until(1e9)
    assert [s for s, _ in rest] == [truth[2][0], truth[3][0]]
    assert src.states_until(1e9) == [] and not src.done and src.lost is None


@pytest.mark.multiprocess
def test_zenoh_source_is_done_after_close(wired):
    src, _ = wired
    src.close()
    assert src.done


def test_zenoh_bad_key_is_an_error(rig):
    import zenoh

    session = zenoh.open(zenoh_config())
    try:
        with pytest.raises(JointSourceError, match="key expression"):
            ZenohJointSource("robot//joints", rig, session=session)
        with pytest.raises(JointSourceError, match="zenoh:KEY"):
            open_zenoh_joints("", rig, {"zenoh_session": session})
    finally:
        session.close()
