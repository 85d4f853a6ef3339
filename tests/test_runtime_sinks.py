"""Reaction sinks (R31): JSON-lines log, zenoh topics, the non-blocking fan-out.

Truth: the Reaction objects built here, read back with the stdlib ``json``
module or received by a real zenoh subscriber session on 127.0.0.1; wall-clock
bounds for "never blocks".
"""

import json
import math
import threading
import time

import numpy as np
import pytest

from depthguard.runtime.result import CameraStatus, Reaction
from depthguard.runtime.sinks import CallbackSink, JsonlLog, SinkError, SinkFanout, ZenohPublisher
from depthguard.transport.settings import zenoh_config
from loopback import free_port, wait_until


def reaction(t=1.0, override=1.0, reasons=None, distance=(0.42, math.inf, 0.9), observed=(True, True, False)):
    """Control points ee, elbow and a watch point; elbow has nothing within rho, the watch point cannot be judged."""
    m = len(distance)
    direction = np.zeros((m, 3))
    direction[0] = [0.0, 0.6, 0.8]
    direction[2] = [1.0, 0.0, 0.0]
    return Reaction(
        t=t, override=override, repulsion=np.array([0.0, -0.05, 0.01]),
        qd_min=-np.ones(7), qd_max=np.ones(7), names=("ee", "elbow", "watch0"),
        distance=np.array(distance, float), direction=direction, observed=np.array(observed, bool),
        is_watch=np.array([False, False, True]), reasons=dict(reasons or {}),
        cameras={"cam0": CameraStatus(0.012, "fresh", frames=30, refused=1, stamp=0.98),
                 "cam1": CameraStatus(math.inf, "waiting")},
        joints_age_s=0.002, q=np.zeros(7), frame_stamps={"cam0": 0.98})


# --------------------------------------------------------------------------- JsonlLog
def test_jsonl_lines_read_back_with_json_keep_null_and_unobserved_apart(tmp_path):
    path = tmp_path / "log.jsonl"
    log = JsonlLog(path, flush_every=2)
    log(reaction(t=0.002))
    log(reaction(t=0.004, override=0.0, reasons={"stale:cam1": "camera cam1 has sent no frame"}))
    log(reaction(t=0.006))
    assert len(path.read_text().splitlines()) == 2             # flushed every 2 lines
    log.close()
    recs = [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines()]
    assert [r["t"] for r in recs] == [0.002, 0.004, 0.006]
    ee, elbow, watch = recs[0]["points"]
    assert ee == {"name": "ee", "watch": False, "distance": 0.42, "direction": [0.0, 0.6, 0.8], "observed": True}
    assert elbow["distance"] is None and elbow["direction"] is None and elbow["observed"] is True
    assert watch["observed"] is False and watch["watch"] is True      # cannot judge: distinct from null
    assert recs[0]["cameras"]["cam1"] == {"age_s": None, "state": "waiting", "frames": 0, "refused": 0}
    assert recs[0]["cameras"]["cam0"]["age_s"] == 0.012 and recs[0]["joints_age_s"] == 0.002
    assert recs[1]["override"] == 0.0 and recs[1]["reasons"] == {"stale:cam1": "camera cam1 has sent no frame"}
    assert recs[0]["repulsion"] == [0.0, -0.05, 0.01]


def test_jsonl_refuses_an_existing_file_and_never_writes_nan(tmp_path):
    path = tmp_path / "log.jsonl"
    path.write_text("old\n")
    with pytest.raises(SinkError, match="exists already"):
        JsonlLog(path)
    assert path.read_text() == "old\n"
    log = JsonlLog(tmp_path / "new.jsonl")
    with pytest.raises(ValueError):
        log(reaction(override=math.nan))
    log.close()
    assert (tmp_path / "new.jsonl").read_text() == ""


# --------------------------------------------------------------------------- SinkFanout
def test_fanout_delivers_in_order_to_every_sink_and_closes_them(tmp_path):
    got, closed = [], []
    log = JsonlLog(tmp_path / "log.jsonl")
    fan = SinkFanout([CallbackSink(got.append, on_close=lambda: closed.append(True)), log])
    for i in range(200):
        fan(reaction(t=i * 0.002))
    fan.close()
    assert [r.t for r in got] == [i * 0.002 for i in range(200)] and closed == [True]
    lines = (tmp_path / "log.jsonl").read_text().splitlines()
    assert len(lines) == 200 and json.loads(lines[-1])["t"] == round(199 * 0.002, 6)
    assert fan.dropped == 0 and fan.errors == [] and fan.delivered == 200
    with pytest.raises(SinkError, match="closed"):
        fan(reaction())


def test_fanout_never_blocks_on_a_slow_sink_and_reports_dropped():
    release = threading.Event()
    seen = []

    def slow(r):
        release.wait(5.0)
        seen.append(r.t)

    items = [reaction(t=float(i)) for i in range(1000)]
    fan = SinkFanout([slow], maxsize=100)
    for r in items:
        fan(r)
    # every call returned while the sink was still held (it waits for `release`): had one call
    # waited for the sink, the sink would have timed out and appended before the loop ended
    assert seen == []
    release.set()
    fan.close()
    # the sink held at most one reaction while the queue kept the newest 100: the oldest went
    assert fan.dropped == 1000 - len(seen) and 899 <= fan.dropped <= 900
    assert seen[-100:] == [float(i) for i in range(900, 1000)] and seen == sorted(seen)


def test_fanout_wakes_per_period_not_per_reaction_but_at_once_for_a_slowing_or_a_stop():
    """issue 29: steady reactions are delivered in batches (the thread wakes every period_s), while
    a lower override or another set of reasons is delivered without waiting for the period."""
    got = []
    fan = SinkFanout([got.append], period_s=30.0)
    fan(reaction(t=0.0, override=1.0))                  # the first: at once
    assert wait_until(lambda: len(got) == 1, 5.0)
    for i in range(1, 6):
        fan(reaction(t=i * 0.002, override=1.0))        # the same override and reasons: they wait
    time.sleep(0.3)
    assert len(got) == 1
    fan(reaction(t=0.012, override=0.5))                # slowing: everything queued goes at once
    assert wait_until(lambda: len(got) == 7, 5.0)
    fan(reaction(t=0.014, override=0.8))                # faster again: waits
    fan(reaction(t=0.016, override=0.8, reasons={"stale:cam1": "camera cam1: stale"}))   # a new reason: at once
    assert wait_until(lambda: len(got) == 9, 5.0)
    assert [r.t for r in got] == [i * 0.002 for i in range(9)] and fan.wakes == 3
    fan(reaction(t=0.018, override=0.8, reasons={"stale:cam1": "camera cam1: stale"}))
    fan.close()                                         # close delivers what waits
    assert len(got) == 10 and fan.dropped == 0
    # at 500 Hz with the default period the thread wakes about every 20 ms, not every 2 ms
    fan = SinkFanout([got.append])
    t0 = time.monotonic()
    for i in range(150):
        fan(reaction(t=i * 0.002))
        time.sleep(0.002)
    elapsed = time.monotonic() - t0
    fan.close()
    assert len(got) == 160 and fan.wakes <= elapsed / fan.period_s + 3, (fan.wakes, elapsed)


def test_a_failing_sink_is_disabled_and_counted_the_others_go_on():
    good = []
    calls = []

    def bad(r):
        calls.append(r.t)
        raise RuntimeError("disk full")

    bad.name = "broken-sink"
    fan = SinkFanout([bad, good.append])
    for i in range(10):
        fan(reaction(t=float(i)))
    fan.close()
    assert calls == [0.0] and len(good) == 10
    assert fan.errors == ["broken-sink: RuntimeError: disk full"] and fan.disabled == ["broken-sink"]


# --------------------------------------------------------------------------- ZenohPublisher




class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


@pytest.mark.multiprocess
def test_zenoh_publisher_is_received_rate_limited_and_never_skips_a_change():
    import zenoh

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    sub_session = zenoh.open(zenoh_config(listen=[endpoint]))
    received = {"reaction": [], "distances": [], "health": []}
    lock = threading.Lock()

    def on_sample(sample):
        with lock:
            received[str(sample.key_expr).rsplit("/", 1)[-1]].append(json.loads(sample.payload.to_bytes().decode()))

    sub = sub_session.declare_subscriber("depthguard/cellA/*", on_sample)
    clock = FakeClock()
    pub = ZenohPublisher("cellA", listen="tcp/127.0.0.1:0", connect=[endpoint], rate_hz=50.0, clock=clock)
    try:
        assert wait_until(lambda: all(p.matching_status.matching for p in pub._pubs.values()), 10.0)
        sent = []
        for i in range(100):                                   # 0.2 s at 500 Hz
            reasons = {"stale:cam1": "camera cam1 is stale"} if 40 <= i < 43 else {}
            r = reaction(t=i * 0.002, override=0.5 if i == 70 else 1.0, reasons=reasons)
            pub(r)
            sent.append(r)
            clock.now += 0.002
        changes = {40, 43, 70, 71}                             # reasons set, cleared; override 0.5, back to 1
        assert wait_until(lambda: len(received["health"]) >= pub.published, 5.0)
        time.sleep(0.05)                                       # nothing more may come
        with lock:
            got = [round(r["t"] / 0.002) for r in received["reaction"]]
            assert len(got) == pub.published and pub.published + pub.skipped == 100
            assert [round(r["t"] / 0.002) for r in received["health"]] == got
            assert [round(r["t"] / 0.002) for r in received["distances"]] == got
            assert got[0] == 0 and changes <= set(got)             # a change is never skipped
            for a, b in zip(got, got[1:]):                         # otherwise about every 0.02 s = 10 cycles
                assert b in changes or 10 <= b - a <= 11, (a, b)
            assert 99 - got[-1] <= 10
            assert received["reaction"][0] == sent[0].to_dict()
            assert received["distances"][0] == {"t": 0.0, "points": sent[0].to_dict()["points"]}
            assert received["distances"][0]["points"][1]["distance"] is None
            h = {r["t"]: r for r in received["health"]}
            assert h[0.08]["reasons"] == {"stale:cam1": "camera cam1 is stale"} and h[0.086]["reasons"] == {}
            assert h[0.14]["override"] == 0.5 and h[0.142]["override"] == 1.0
            assert set(h[0.0]) == {"t", "override", "reasons", "cameras", "joints_age_s"}
            assert h[0.0]["cameras"]["cam1"]["state"] == "waiting"
    finally:
        pub.close()
        sub.undeclare()
        sub_session.close()


def test_zenoh_publisher_refuses_a_bad_cell_name():
    with pytest.raises(SinkError, match="cell name"):
        ZenohPublisher("a/b")
    with pytest.raises(SinkError, match="cell name"):
        ZenohPublisher("*")


# --------------------------------------------------------------------------- results.mcap's writes
def test_results_mcap_appender_writes_the_file_rosbags_writes(tmp_path):
    """issue 29: McapResults appends its messages without Writer.write (runtime.mcap_results._Appender);
    the file is byte for byte the one rosbags' own Writer.write makes of the same messages, over
    several chunks (messages of random sizes and channels, equal and decreasing stamps)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

    from depthguard.runtime.mcap_results import _Appender
    from depthguard.transport import ros_messages as rosmsg

    rng = np.random.default_rng(13)
    msgs = []
    ns = 10**9
    for _ in range(3000):
        ns += int(rng.choice([0, 1, 2_000_000, -5]))
        msgs.append((int(rng.integers(0, 3)), ns, rng.bytes(int(rng.integers(0, 1500)))))
    out = []
    for fast in (False, True):
        d = tmp_path / f"{int(fast)}" / "bag"           # the same name: the metadata names the file
        w = Writer(d, version=9, storage_plugin=StoragePlugin.MCAP)
        w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        w.open()
        cons = [w.add_connection(f"/t{i}", rosmsg.MSG["Float64"], typestore=rosmsg.TYPESTORE) for i in range(3)]
        app = _Appender(w)
        assert app.fast
        for c, t, data in msgs:
            (app.append if fast else w.write)(cons[c], t, data)
        w.close()
        out.append((d / "bag.mcap").read_bytes())
    assert len(out[0]) > 2**21 and out[0] == out[1]
