"""``realsense-file:`` against the RealSense SDK itself, without hardware (issue 15).

Simulated depth of ``flacco-cell`` (its person reaching, the cameras' noise) is
streamed by an SDK ``software_device`` and written by the SDK's own recorder
(raw ``mono16``); the source plays the recording back through the SDK. The
truth is the simulated frames: the played-back depth equals them to one depth
unit, the intrinsics and stamps are those injected, and a monitor fed from the
recording gives the same distances as one fed the simulated frames directly.
Skipped, with the reason, when ``import pyrealsense2`` fails (no SDK, no libusb).
"""

import dataclasses
import math

import numpy as np
import pytest

from depthguard.sources.realsense_device import RealSenseUnavailable, import_sdk

try:
    rs = import_sdk()
except RealSenseUnavailable as _exc:
    pytest.skip(f"RealSense SDK not importable here: {_exc}", allow_module_level=True)

from depthguard.runtime.monitor import Monitor  # noqa: E402
from depthguard.sources.base import open_source  # noqa: E402
from depthguard.sources.frame import Frame  # noqa: E402
from depthguard.sources.realsense_device import intrinsics_of, record_depth  # noqa: E402
from depthguard.sources.sim_source import SimFrames, SimWorld  # noqa: E402

UNITS = 0.001          # m per z16 unit, as a D400 by default
T_END = 0.2            # s of simulated cell recorded


@pytest.fixture(scope="module")
def sim():
    """flacco-cell, situation reach: every camera's frames up to T_END and the robot's joint states."""
    world = SimWorld("flacco-cell", situation="reach", seed=3)
    frames = SimFrames(world).frames_until(T_END)
    states = list(world.states)
    return world.rig, frames, states


@pytest.fixture(scope="module")
def recordings(sim, tmp_path_factory):
    rig, frames, _ = sim
    d = tmp_path_factory.mktemp("rs")
    out = {}
    for i, cid in enumerate(rig.camera_ids):
        own = [(f.depth, f.stamp) for f in frames if f.camera_id == cid]
        path = d / f"{cid}.db3"
        rec = record_depth(path, own, rig.camera(cid), serial=f"10{i}", units=UNITS, period_s=0.01)
        out[cid] = {"path": path, "frames": [f for f in frames if f.camera_id == cid], "z16": rec["z16"]}
    return out


def _drain(src, limit_s=30.0, dt=1 / 90):
    """Every frame, taken as a fast run does: frames_until(t) for t every ``dt`` s of recording time."""
    import time

    got, end, t = [], time.monotonic() + limit_s, src.first_stamp
    while not src.done and time.monotonic() < end:
        got.extend(src.frames_until(t))
        t += dt
    got.extend(src.frames_until(math.inf))
    assert src.done, "the recording did not end"
    return got


def test_playback_equals_the_simulated_frames(sim, recordings):
    rig, _, _ = sim
    cam = rig.camera("cam0")
    rec = recordings["cam0"]
    src = open_source(f"realsense-file:cam0={rec['path']}", rig)
    try:
        assert src.camera_ids == ["cam0"]
        assert src.first_stamp == pytest.approx(rec["frames"][0].stamp, abs=1e-9)
        got = _drain(src)
        stats = src.stats()["cam0"]
    finally:
        src.close()
    assert len(got) == len(rec["frames"]) >= 5
    assert stats["dropped"] == 0 and stats["overflow"] == 0 and stats["received"] == len(got)
    for f, truth in zip(got, rec["frames"]):
        assert f.camera_id == "cam0"
        assert f.stamp == pytest.approx(truth.stamp, abs=1e-9)          # injected ms -> s
        assert f.depth.dtype == np.float32 and f.depth.shape == (cam.height, cam.width)
        t = np.asarray(truth.depth, dtype=np.float64)
        valid = (t > 0) & np.isfinite(t)
        assert valid.mean() > 0.5
        assert np.all(f.depth[~valid] == 0)                              # no measurement stays none
        assert np.max(np.abs(f.depth[valid] - t[valid])) <= UNITS * 0.5 + 1e-6    # one depth unit (rounded)


def test_the_sdk_reports_the_injected_intrinsics(sim, recordings):
    """Read with the SDK alone (not through the source): size, focal lengths, principal point, rate."""
    rig, _, _ = sim
    cam = rig.camera("cam1")
    ctx = rs.context()
    dev = ctx.load_device(str(recordings["cam1"]["path"]))
    sensor = dev.first_depth_sensor()
    assert sensor.get_depth_scale() == pytest.approx(UNITS)
    assert dev.get_info(rs.camera_info.serial_number) == "101"
    (profile,) = sensor.get_stream_profiles()
    intr = intrinsics_of(profile)
    assert (intr["width"], intr["height"], intr["fps"]) == (cam.width, cam.height, 30)
    for k in ("fx", "fy", "cx", "cy"):
        assert intr[k] == pytest.approx(getattr(cam, k), abs=1e-4)
    ctx.unload_device(str(recordings["cam1"]["path"]))


def _run_monitor(rig, states, frames):
    """Distances of every control point after each frame, frames pushed in stamp order."""
    out = []
    with Monitor(rig) as mon:
        for ts, q in states:
            mon.push_joints(ts, q)
        for f in sorted(frames, key=lambda f: (f.stamp, f.camera_id)):
            mon.push_frame(f)
            mon.flush()
            r = mon.step(f.stamp + 0.002)
            out.append((r.distance.copy(), r.observed.copy(), r.override))
    return out


def test_monitor_from_the_recording_equals_the_simulated_frames(sim, recordings):
    rig, frames, states = sim
    spec = "realsense-file:" + ",".join(str(recordings[c]["path"]) for c in rig.camera_ids)
    src = open_source(spec, rig)
    try:
        played = _drain(src)
    finally:
        src.close()
    # the same bits the SDK was given: the simulated frames quantised to depth units
    direct = [Frame(c, (recordings[c]["z16"][i].astype(np.float32) * np.float32(UNITS)), recordings[c]["frames"][i].stamp)
              for c in rig.camera_ids for i in range(len(recordings[c]["frames"]))]
    assert len(played) == len(direct) == len(frames)
    a = _run_monitor(rig, states, direct)
    b = _run_monitor(rig, states, played)
    c = _run_monitor(rig, states, frames)       # unquantised: within the quantisation's effect
    near = 0
    for (da, oa, ka), (db, ob, kb), (dc, oc, _) in zip(a, b, c):
        np.testing.assert_array_equal(oa, ob)
        np.testing.assert_array_equal(da, db)
        # the override ramps with the time between steps: the recording's stamps carry the SDK's
        # rounding (below a microsecond), so the ramp agrees to far better than a step's share
        assert ka == pytest.approx(kb, abs=1e-6)
        both = oa & oc & np.isfinite(da) & np.isfinite(dc)
        assert np.all(np.abs(da[both] - dc[both]) <= 0.015)
        near += int(np.isfinite(da[oa]).sum())
    assert near > 0, "no obstacle within rho: the comparison would say nothing"


def test_several_devices_in_stamp_order(sim, recordings):
    rig, _, _ = sim
    src = open_source(f"realsense-file:cam1={recordings['cam1']['path']},cam0={recordings['cam0']['path']}", rig)
    try:
        assert sorted(src.camera_ids) == ["cam0", "cam1"]
        got = _drain(src)
    finally:
        src.close()
    stamps = [f.stamp for f in got]
    assert stamps == sorted(stamps)
    for cid in ("cam0", "cam1"):
        mine = [f for f in got if f.camera_id == cid]
        assert [f.stamp for f in mine] == pytest.approx([f.stamp for f in recordings[cid]["frames"]], abs=1e-9)


def test_dropped_frames_are_counted_from_the_frame_numbers(sim, tmp_path):
    rig, frames, _ = sim
    own = [(f.depth, f.stamp) for f in frames if f.camera_id == "cam0"][:6]
    numbers = [1, 2, 5, 6, 7, 11]                          # 2 lost after 2, 3 lost after 7
    path = tmp_path / "gaps.db3"
    record_depth(path, own, rig.camera("cam0"), numbers=numbers, period_s=0.01)
    src = open_source(f"realsense-file:{path}", rig)
    try:
        got = _drain(src)
        st = src.stats()["cam0"]
    finally:
        src.close()
    assert len(got) == 6
    assert st["received"] == 6 and st["dropped"] == 5


def test_intrinsics_mismatch_is_an_error_with_both_sets(sim, tmp_path):
    rig, frames, _ = sim
    cam = rig.camera("cam0")
    other = dataclasses.replace(cam, fx=cam.fx + 4.0)
    path = tmp_path / "other.db3"
    record_depth(path, [(frames[0].depth, frames[0].stamp)], other, period_s=0.01)
    with pytest.raises(ValueError) as err:
        open_source(f"realsense-file:{path}", rig)
    msg = str(err.value)
    assert f"fx={cam.fx + 4.0:.3f}" in msg and f"fx={cam.fx:.3f}" in msg and "cam0" in msg


def test_bad_specs_are_one_clear_error(sim, tmp_path):
    rig, _, _ = sim
    with pytest.raises(FileNotFoundError, match="not found"):
        open_source(f"realsense-file:{tmp_path / 'none.db3'}", rig)
    with pytest.raises(ValueError, match="no camera 'cam9'"):
        open_source(f"realsense-file:cam9={tmp_path / 'x.db3'}", rig)
    with pytest.raises(ValueError, match="has 2 camera"):
        open_source("realsense-file:a.db3,b.db3,c.db3", rig)
    junk = tmp_path / "junk.db3"
    junk.write_bytes(b"not a recording")
    with pytest.raises(ValueError, match="cannot read it as a recording"):
        open_source(f"realsense-file:{junk}", rig)



def test_images_are_reused_only_when_no_consumer_holds_them(sim, recordings):
    """The stream writes a new frame into an image of an earlier one only when nothing holds that
    image any more: a frame kept by a consumer never changes; frames let go are recycled."""
    rig, _, _ = sim
    rec = recordings["cam0"]
    src = open_source(f"realsense-file:cam0={rec['path']}", rig)
    import weakref

    kept = None
    seen, reused, copies, t = [], 0, [], src.first_stamp
    try:
        while not src.done:
            for f in src.frames_until(t):
                reused += any(w() is f.depth for w in seen)       # the same image object, alive in the pool
                seen.append(weakref.ref(f.depth))
                copies.append(np.array(f.depth, copy=True))
                if kept is None:
                    kept = f                                  # held to the end
            t += 1 / 90
    finally:
        src.close()
    assert len(copies) == len(rec["frames"])
    np.testing.assert_array_equal(kept.depth, copies[0])     # never written over
    assert reused > 0, "no image was reused"
    for got, z16 in zip(copies, rec["z16"]):                 # and every frame was right when given
        np.testing.assert_array_equal(got, z16.astype(np.float32) * np.float32(UNITS))
