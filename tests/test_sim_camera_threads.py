"""The simulated cameras of a real-time run, each on its own thread (issue 29, R29): the same frames,
bit for bit, as one thread rendering them all; each camera woken when its next frame can be made."""

import threading

import numpy as np
import pytest

from depthguard.sources.sim_source import SimFrames, SimWorld


def _times(end: float, step: float) -> list[float]:
    out, t, k = [], 0.0, 0
    while t <= end:
        out.append(t)
        k += 1
        t = k * step + (0.0007 if k % 3 else 0.0)       # irregular: captures due one or two at a time
    return out


@pytest.mark.parametrize("situation", [None, "arm_reaching"])
def test_cameras_on_their_own_threads_give_the_frames_of_one_thread_bit_for_bit(situation):
    """Four ur3-cell cameras, each stream on its own thread (the world advanced by whichever asks,
    the exact noise draws): per camera the frames of ``frames_until`` on one thread, in order, the
    same stamps and the same depth bytes; the people are in view (``arm_reaching``: 12 parts)."""
    times = _times(0.45, 0.0131)
    one = SimFrames(SimWorld("ur3-cell", situation=situation, seed=3))
    want = {c: [] for c in one.camera_ids}
    for t in times:
        for f in one.frames_until(t):
            want[f.camera_id].append((f.stamp, f.depth.tobytes()))

    many = SimFrames(SimWorld("ur3-cell", situation=situation, seed=3))
    streams = many.camera_streams()
    assert [s.camera_id for s in streams] == many.camera_ids
    got = {c: [] for c in many.camera_ids}
    errors = []
    go = threading.Barrier(len(streams))

    def camera(stream):
        try:
            go.wait()
            for t in times:
                for f in stream.frames_each(t):
                    assert f.camera_id == stream.camera_id
                    got[f.camera_id].append((f.stamp, f.depth.tobytes()))
        except BaseException as exc:           # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=camera, args=(s,)) for s in streams]
    for th in threads:
        th.start()
    for th in threads:
        th.join(120)
    assert not errors, errors
    if situation:
        assert len(many.world.dynamic(times[-1])) == 12     # the person's parts in the frames
    for c in one.camera_ids:
        assert len(want[c]) >= 12
        assert [s for s, _ in got[c]] == [s for s, _ in want[c]], c
        assert all(a == b for (_, a), (_, b) in zip(got[c], want[c])), c
    assert many.counters() == one.counters() == {"skipped_behind_real_time": 0}


def test_a_stream_wakes_at_its_capture_rounded_up_to_the_joint_tick():
    """``wake_at``: the camera's next capture on the run's clock, up to the first joint tick at or
    after it (the pose at a capture is interpolated, never extrapolated, R30); woken then, the
    frame of that capture is made, and not a moment before that tick."""
    for index in range(2):                            # a world per camera: only this one moves it
        frames = SimFrames(SimWorld("flacco-cell", alone=True))
        frames.start_clock(100.0)
        dt = 1.0 / frames.world.joint_hz
        stream = frames.camera_streams()[index]
        for _ in range(6):
            tc = frames.world.origin + frames.schedule.next[stream.index]
            wake = stream.wake_at()
            k = round((wake - frames.world.origin) / dt)
            assert wake == pytest.approx(frames.world.origin + k * dt, abs=1e-9)     # on the tick grid
            assert tc - 1e-9 <= wake < tc + dt                                      # the first at or after
            if wake - tc > 1e-6:                      # before that tick: no pose, no frame yet
                assert list(stream.frames_each(wake - dt / 2)) == []
            got = list(stream.frames_each(wake))
            assert [(f.camera_id, f.stamp) for f in got] == [(stream.camera_id, pytest.approx(tc, abs=1e-12))]


def test_streams_behind_real_time_skip_and_the_source_counts_them_all():
    """``skip_behind`` per stream: a camera woken more than a period late renders the newest capture
    due only; the source's counter is the sum over its cameras (what the monitor reports)."""
    frames = SimFrames(SimWorld("flacco-cell", alone=True, noiseless=True))
    frames.skip_behind = True
    streams = frames.camera_streams()
    period = 1.0 / frames.world.camera_hz
    for s in streams:
        assert [f.stamp for f in s.frames_each(0.0)] == [0.0]
    late = [list(s.frames_each(0.25)) for s in streams]
    assert all(len(fs) == 1 and 0.25 - period < fs[0].stamp <= 0.25 for fs in late)
    skipped = sum(s.counts.skipped for s in streams)
    # each camera's captures in (0, 0.25] on its phase: all but the newest were skipped
    caps = [[ph + k * period for k in range(100) if 0 < ph + k * period <= 0.25 + 1e-12]
            for ph in frames.schedule.phase]
    want = sum(len(c) - 1 for c in caps)
    assert skipped == want > 0
    assert frames.counters()["skipped_behind_real_time"] == frames.skipped == skipped


def test_each_camera_poses_the_robot_into_its_own_buffer():
    """After ``own_robot_buffers`` no two cameras share the posed robot's vertices (a camera thread
    never reads what another is writing); before, the cameras of a time step share one."""
    frames = SimFrames(SimWorld("ur3-cell"))
    q = frames.world.robot_sim.q
    cids = frames.camera_ids
    shared = {id(frames.sim._robot_vertices(q, c)) for c in cids}
    assert len(shared) == 1
    frames.camera_streams()
    own = [frames.sim._robot_vertices(q, c) for c in cids]
    assert len({id(v) for v in own}) == len(cids)
    assert all(np.array_equal(v, own[0]) for v in own)
    assert not any(np.shares_memory(a, b) for i, a in enumerate(own) for b in own[i + 1:])


def test_a_real_time_run_renders_each_simulated_camera_on_its_own_thread():
    """``run`` in real time with a ``sim:`` source: every camera's frames are pushed by that
    camera's own thread (``depthguard-source-0-CAM``), in capture order on the camera's own phase;
    the captures missing from a camera's sequence are the source's skipped count."""
    from depthguard.runtime.monitor import Monitor, warm_up
    from depthguard.runtime.runner import run
    from depthguard.sim import load_cell
    from depthguard.sources.base import open_joints, open_source

    rig = load_cell("flacco-cell").rig
    cfg = rig.monitor.with_changes(invalid="free")
    warm_up(rig, cfg)
    ctx = {}
    src = open_source("sim:flacco-cell:alone:noiseless", rig, ctx)
    joints = open_joints("sim", rig, ctx)
    pushed = []
    with Monitor(rig, cfg) as mon:
        push = mon.push_frame

        def recording_push(frame, *a, **k):
            pushed.append((threading.current_thread().name, frame.camera_id, frame.stamp))
            return push(frame, *a, **k)

        mon.push_frame = recording_push
        run(mon, [src], joints, duration=0.4)
    period = 1.0 / src.world.camera_hz
    missing = 0
    for i, cid in enumerate(src.camera_ids):
        mine = [(name, s) for name, c, s in pushed if c == cid]
        assert {name for name, _ in mine} == {f"depthguard-source-0-{cid}"}
        k = [round((s - src.schedule.phase[i]) / period) if s > 0 else None for _, s in mine]
        assert all(abs(src.schedule.phase[i] + n * period - s) < 1e-9 for n, (_, s) in zip(k, mine) if n is not None)
        stamps = [s for _, s in mine]
        assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps) and len(stamps) >= 4
        grid = [n for n in k if n is not None]
        missing += (grid[-1] - grid[0] + 1 - len(grid)) + (grid[0] - (1 if src.schedule.phase[i] == 0 else 0))
    assert src.counters()["skipped_behind_real_time"] == missing
