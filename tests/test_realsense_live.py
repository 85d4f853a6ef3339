"""``realsense:`` — live devices, unplugged and plugged back, without hardware (issue 15).

The devices are the SDK's own: recordings of simulated ``flacco-cell`` depth
(written by the SDK's recorder from a ``software_device``) loaded as playback
devices that play in real time, as a camera streams. The source lists its
devices through ``context["realsense_devices"]`` (by default the SDK
context's list); taking a device out of that list is an unplug. The truth:
frames stop, ``lost`` names the camera, the monitor's camera goes stale and
the robot stops (R27); put back, the device streams again without a restart.
Skipped, with the reason, when ``import pyrealsense2`` fails.
"""

import math
import time

import pytest

from depthguard.sources.realsense_device import RealSenseUnavailable, import_sdk

try:
    rs = import_sdk()
except RealSenseUnavailable as _exc:
    pytest.skip(f"RealSense SDK not importable here: {_exc}", allow_module_level=True)

from depthguard.runtime.monitor import Monitor  # noqa: E402
from depthguard.sources.base import open_source  # noqa: E402
from depthguard.sources.realsense_device import record_depth  # noqa: E402
from depthguard.sources.sim_source import SimFrames, SimWorld  # noqa: E402

PERIOD = 1 / 30


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    """Two recordings of cam0 (the second 5 s later), each about 0.8 s of frames at 30 Hz."""
    world = SimWorld("flacco-cell", situation="reach", seed=5)
    frames = [f for f in SimFrames(world, cameras=["cam0"]).frames_until(0.2)]
    q0 = world.states[0][1]
    d = tmp_path_factory.mktemp("rslive")
    seq = [(frames[i % len(frames)].depth, i * PERIOD) for i in range(24)]
    first, second = d / "first.db3", d / "second.db3"
    record_depth(first, seq, world.rig.camera("cam0"), serial="200")
    record_depth(second, [(dep, s + 5.0) for dep, s in seq], world.rig.camera("cam0"), serial="200",
                 numbers=range(1001, 1001 + len(seq)), period_s=0.01)
    return world.rig, q0, first, second


def _collect(src, seconds, until=None):
    got, end = [], time.monotonic() + seconds
    while time.monotonic() < end:
        got.extend(src.frames_until(math.inf))
        if until is not None and until(got):
            break
        time.sleep(0.005)
    return got


def test_unplugged_device_goes_stale_and_comes_back(cell):
    rig, q0, first, second = cell
    ctx1, ctx2 = rs.context(), rs.context()
    devices = {"200": ctx1.load_device(str(first))}
    src = open_source("realsense:cam0=200", rig, {"realsense_devices": lambda: dict(devices),
                                                  "realsense_recheck_s": 0.05, "realsense_buffer": 64})
    cfg = rig.monitor.with_changes(cameras=("cam0",))
    try:
        assert src.live and src.camera_ids == ["cam0"] and src.lost is None
        before = _collect(src, 5.0, until=lambda g: len(g) >= 6)
        assert len(before) >= 6, "the device did not stream"
        devices.clear()                                            # unplug
        after = _collect(src, 3.0, until=lambda g: src.lost is not None)
        assert src.lost is not None and "cam0" in src.lost and "unplugged" in src.lost
        later = _collect(src, 0.4)
        assert later == [], "frames after the unplug"
        frames = before + after
        stamps = [f.stamp for f in frames]
        assert stamps == sorted(stamps) and len(frames) < 24       # cut before the recording's end

        with Monitor(rig, cfg) as mon:
            t_last = stamps[-1]
            for k in range(int((t_last + 1.0) / 0.002) + 1):
                mon.push_joints(k * 0.002, q0)
            for f in frames:
                mon.push_frame(f)
            mon.flush()
            r = mon.step(t_last + 0.01)
            assert r.cameras["cam0"].state == "fresh" and not any(k.startswith("stale") for k in r.reasons)
            t = t_last + 0.01
            while t < t_last + 0.95:                                # no frame since: stale, the robot stops
                t += 0.002
                r = mon.step(t)
            assert r.cameras["cam0"].state == "stale" and "stale:cam0" in r.reasons
            assert r.override == 0.0

        devices["200"] = ctx2.load_device(str(second))            # plugged back
        back = _collect(src, 5.0, until=lambda g: len(g) >= 3 and src.lost is None)
        assert len(back) >= 3 and src.lost is None
        assert all(f.stamp >= 5.0 for f in back)
        st = src.stats()["cam0"]
        assert st["reconnects"] == 1 and st["received"] >= len(frames) + len(back)
        # the second recording ends: the device is still listed but sends nothing
        _collect(src, 4.0, until=lambda g: src.lost is not None)
        assert src.lost is not None and "no frame for" in src.lost and "still listed" in src.lost
    finally:
        src.close()


def test_device_listing_errors_are_clear(cell):
    rig, _, first, _ = cell
    with pytest.raises(ValueError, match="no RealSense device is connected"):
        open_source("realsense", rig, {"realsense_devices": lambda: {}})
    with pytest.raises(ValueError, match="999 not connected; connected: 200"):
        open_source("realsense:999", rig, {"realsense_devices": lambda: {"200": None}})
    with pytest.raises(ValueError, match="2 devices are connected"):
        open_source("realsense", rig, {"realsense_devices": lambda: {"200": None, "201": None}})
