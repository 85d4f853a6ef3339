"""The SDK's own post-processing filters as source options: ``:spatial``, ``:temporal`` (issue 15).

Simulated ``flacco-cell`` depth in which a block of pixels stops returning in
the last frames (a person in dark clothes walking in) is recorded by the SDK's
recorder. Truths: the source's filtered frames equal the SDK's filters applied
to the same recording outside depthguard (they are the SDK's, not rewritten);
the pixels with no measurement stay without one (unknown stays unknown, R28),
where the SDK's default temporal filter would have shown the old background —
checked here too, so that the test would see a filter left at its default.
Skipped, with the reason, when ``import pyrealsense2`` fails.
"""

import math
import threading

import numpy as np
import pytest

from depthguard.sources.realsense_device import RealSenseUnavailable, import_sdk

try:
    rs = import_sdk()
except RealSenseUnavailable as _exc:
    pytest.skip(f"RealSense SDK not importable here: {_exc}", allow_module_level=True)

from depthguard.sources.base import open_source  # noqa: E402
from depthguard.sources.realsense_device import record_depth  # noqa: E402
from depthguard.sources.sim_source import SimFrames, SimWorld  # noqa: E402

HOLE = (slice(150, 260), slice(250, 380))
DARK_FROM = 4                    # frames 4 and 5 have no return in HOLE


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    world = SimWorld("flacco-cell", situation="reach", seed=7)
    frames = SimFrames(world, cameras=["cam0"]).frames_until(0.17)[:6]
    seq = []
    for i, f in enumerate(frames):
        d = np.array(f.depth, copy=True)
        if i >= DARK_FROM:
            d[HOLE] = 0.0
        seq.append((d, f.stamp))
    path = tmp_path_factory.mktemp("rsfilt") / "cam0.db3"
    rec = record_depth(path, seq, world.rig.camera("cam0"), period_s=0.01)
    assert all(np.all(rec["z16"][i][HOLE] == 0) for i in range(DARK_FROM, len(seq)))
    assert np.mean(rec["z16"][DARK_FROM - 1][HOLE] > 0) > 0.9    # the background returned before
    return world.rig, path, rec["z16"]


def _through_source(rig, spec):
    src = open_source(spec, rig)
    got, t = [], src.first_stamp
    try:
        while not src.done:
            got.extend(src.frames_until(t))
            t += 0.01
        got.extend(src.frames_until(math.inf))
    finally:
        src.close()
    return [f.depth for f in got]


def _sdk_alone(path, make):
    """The recording played by the SDK, each frame through ``make()``'s filter, to metres."""
    ctx = rs.context()
    dev = ctx.load_device(str(path))
    pb = dev.as_playback()
    pb.set_real_time(False)
    sensor = dev.first_depth_sensor()
    flt = make()
    out, done = [], threading.Event()

    def on_frame(frame):
        f = flt.process(frame)
        out.append(np.asanyarray(f.get_data()).astype(np.float32) * np.float32(f.as_depth_frame().get_units()))
    sensor.open(sensor.get_stream_profiles()[0])
    sensor.start(on_frame)
    pb.set_status_changed_callback(lambda s: done.set() if s == rs.playback_status.stopped else None)
    done.wait(20.0)
    sensor.stop()
    sensor.close()
    ctx.unload_device(str(path))
    return out


def _temporal(holes_fill):
    def make():
        f = rs.temporal_filter()
        f.set_option(rs.option.holes_fill, holes_fill)
        return f
    return make


def test_temporal_filter_is_the_sdks_and_keeps_no_measurement(recording):
    rig, path, z16 = recording
    got = _through_source(rig, f"realsense-file:cam0={path}:temporal")
    assert len(got) == len(z16)
    sdk = _sdk_alone(path, _temporal(0))
    for a, b in zip(got, sdk):
        np.testing.assert_array_equal(a, b)
    raw = [z.astype(np.float32) * np.float32(0.001) for z in z16]
    assert any(np.any(a != r) for a, r in zip(got[1:], raw[1:])), "the filter changed nothing"
    for i in range(DARK_FROM, len(got)):
        assert np.all(got[i][HOLE] == 0)
    default = _sdk_alone(path, _temporal(3))                   # the SDK's default persistence
    assert np.mean(default[DARK_FROM][HOLE] > 0) > 0.5         # would have shown the old background


def test_spatial_filter_is_the_sdks_and_keeps_no_measurement(recording):
    rig, path, z16 = recording
    got = _through_source(rig, f"realsense-file:{path}:spatial")
    sdk = _sdk_alone(path, rs.spatial_filter)                  # the SDK's defaults: hole filling off
    assert len(got) == len(sdk) == len(z16)
    for a, b in zip(got, sdk):
        np.testing.assert_array_equal(a, b)
    raw = [z.astype(np.float32) * np.float32(0.001) for z in z16]
    assert any(np.any(a != r) for a, r in zip(got, raw)), "the filter changed nothing"
    for i in range(DARK_FROM, len(got)):
        assert np.all(got[i][HOLE] == 0)


def test_unsafe_filters_are_refused_with_the_reason(recording):
    rig, path, _ = recording
    with pytest.raises(ValueError, match="hole_filling.*refused.*unknown space"):
        open_source(f"realsense-file:{path}:hole_filling", rig)
    with pytest.raises(ValueError, match="decimation.*image size"):
        open_source("realsense:123:decimation", rig, {"realsense_devices": lambda: {}})
