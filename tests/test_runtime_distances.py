"""Distances off the control thread (R12, R29): the band query, its bound at moved points, and
the monitor's real-time mode.

Truth: the depth grid's own answer queried at the moved points (a second query of the same
frames, not the bound), the same grid queried with the min method (the band's distance), and
the plain-numpy twin of the bound kernel. Frames: flacco-cell's noisy simulated cameras with
the person of situation ``reach`` next to the robot, so that most control points have
obstacles within rho.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from depthguard.runtime.distances import (REQUERY_FRACTION, DistanceSnapshot, DistanceWorker, bound_distances,
                                          bound_distances_numpy, moved_beyond, moved_beyond_numpy)
from depthguard.runtime.monitor import Monitor, warm_up
from depthguard.sim import load_cell
from depthguard.sources.frame import Frame

RHO = 0.4
MARGIN = 0.03
TAU = 9.3                      # scene time of ``reach``: the person's hand near the end effector


@pytest.fixture(scope="module")
def setup():
    from depthguard.sources.sim_source import SimFrames, SimWorld

    cell = load_cell("flacco-cell")
    rig = cell.rig
    warm_up(rig, rig.monitor)
    q = np.asarray(cell.scene.robot_q(TAU), dtype=np.float64)
    sim = SimFrames(SimWorld("flacco-cell", seed=3))
    frames = {cid: sim.render(cid, TAU, q) for cid in rig.camera_ids}
    return rig, q, frames


def loaded(rig, q, frames, cfg=None):
    mon = Monitor(rig, cfg if cfg is not None else rig.monitor)
    mon.push_joints(0.0, q)
    mon.push_joints(0.01, q)
    for cid, d in frames.items():
        mon.push_frame(Frame(cid, d, 0.005))
    mon.flush(timeout=120.0)
    return mon


def points_near(mon, q, rng):
    """The control points at ``q`` and two clouds of points around them (m, 3)."""
    data = mon.robot.create_data()
    mon.robot.forward(q, data)
    P = data.cp_positions.copy()
    return np.concatenate([P, P + rng.normal(0, 0.1, P.shape), P + rng.normal(0, 0.25, P.shape)])


def query(grid, P, **kw):
    r = grid.query(P, threads=1, **kw)
    return r.distance.copy(), r.direction.copy(), r.observed.copy()


def discretisation(grid) -> float:
    """m: the grid's slice depth plus a pixel's diagonal at its far end (R10, R12)."""
    P = grid.principal
    return grid.delta_d + float(np.hypot(1 / P.fx, 1 / P.fy)) * grid.d_max


def test_band_query_keeps_the_rho_answer_and_adds_the_nearest_in_the_band(setup):
    rig, q, frames = setup
    with loaded(rig, q, frames) as mon:
        grid = mon.fusion.front.grid
        P = points_near(mon, q, np.random.default_rng(0))
        D, V, obs = query(grid, P, rho=RHO, method="hybrid")
        Db, Vb, obsb = query(grid, P, rho=RHO + MARGIN, method="hybrid", rho_core=RHO)
        Dm, Vm, _ = query(grid, P, rho=RHO + MARGIN, method="min")
    inside = np.isfinite(D)
    band = ~inside & np.isfinite(Db)
    assert inside.sum() >= 10, "the scene must put obstacles within rho of many points"
    # within rho: the R7 hybrid answer of radius rho, bit for bit (distance and mean direction)
    assert np.array_equal(D[inside], Db[inside]) and np.array_equal(V[inside], Vb[inside])
    # only in the band: the nearest (the min rule at rho + margin), never nearer than rho
    assert np.array_equal(Db[band], Dm[band]) and np.allclose(Vb[band], Vm[band], atol=1e-12)
    assert np.all(Db[band] >= RHO - 1e-12)
    assert np.all(np.isinf(Db[~inside & ~band])) and np.array_equal(obs, obsb)
    with pytest.raises(ValueError, match="rho_core must be <= rho"):
        grid.query(P, rho=RHO, rho_core=RHO + 0.01)


def test_bound_at_moved_points_never_exceeds_the_grids_answer_there(setup):
    rig, q, frames = setup
    rng = np.random.default_rng(1)
    with loaded(rig, q, frames) as mon:
        grid = mon.fusion.front.grid
        P0 = points_near(mon, q, rng)
        D0, V0, obs0 = query(grid, P0, rho=RHO + MARGIN, method="hybrid", rho_core=RHO)
        snap = DistanceSnapshot(P0, D0, V0, obs0, RHO, MARGIN, "hybrid", {}, {}, {}, grid.principal_view(), 0.0)
        m = len(P0)
        checked = finite = 0
        over = 0.0
        tol = discretisation(grid)
        for _ in range(25):
            step = rng.normal(size=P0.shape)
            step *= rng.uniform(0, MARGIN, (m, 1)) / np.linalg.norm(step, axis=1)[:, None]
            P = P0 + step
            D, V, obs = np.empty(m), np.empty((m, 3)), np.empty(m, dtype=bool)
            assert bound_distances(snap, P, RHO, D, V, obs)
            twin = bound_distances_numpy(snap, P, RHO)
            assert np.array_equal(twin[0], D) and np.array_equal(twin[1], V) and np.array_equal(twin[2], obs)
            Dt, _, obst = query(grid, P, rho=RHO, method="hybrid")
            # R12 kept: the bound is never farther than the grid's own answer at P by more than
            # the discretisation (the grid's distance is one to a point of each cell, not the
            # cell's nearest; measured: never farther at all); "nothing within rho" only where
            # the grid finds nothing within rho - tol; observed only where it is
            fin = np.isfinite(Dt)
            assert np.all(D[fin] <= Dt[fin] + tol)
            over = max(over, float(np.max(D[fin] - Dt[fin], initial=0.0)))
            assert np.all(Dt[np.isinf(D) & fin] >= RHO - tol)
            assert not np.any(obs & ~obst)
            checked += m
            finite += int(np.isfinite(D).sum())
        assert finite > checked // 4
        print(f"bound farther than the grid's answer at the moved points by at most {over * 1e3:.3f} mm")
        # a point that moved farther than the margin: no answer, nothing written
        P = P0.copy()
        P[3, 0] += MARGIN * 1.01
        D = np.full(m, -1.0)
        assert not bound_distances(snap, P, RHO, D, np.empty((m, 3)), np.empty(m, dtype=bool))
        assert np.all(D == -1.0) and bound_distances_numpy(snap, P, RHO) is None


def test_real_time_monitor_bounds_the_workers_answers_and_falls_back_when_it_has_none(setup):
    rig, q, frames = setup
    cfg = rig.monitor.with_changes(distance_hz=500.0)
    with loaded(rig, q, frames, cfg) as mon:
        inline = mon.step(0.011, q)
        with mon.real_time():
            deadline = time.perf_counter() + 30.0
            w = mon._dist_worker           # a robot standing still: one query, then the answer reused (issue 29)
            while (w.queries < 1 or w.queries + w.reused < 3) and time.perf_counter() < deadline:
                mon.step(0.011, q)
                time.sleep(0.002)
            assert w.queries >= 1 and w.queries + w.reused >= 3, w.last_error
            still = mon.step(0.011, q)
            # a robot that has not moved: the worker's answer itself
            assert np.array_equal(still.distance, inline.distance)
            assert np.array_equal(still.observed, inline.observed)
            assert still.frame_stamps == inline.frame_stamps
            # moved a little: never farther than the grid's answer at the new joints
            q2 = q + 0.004
            fb = sum(mon.distance_fallbacks.values())
            r2 = mon.step(0.012, q2)
            assert sum(mon.distance_fallbacks.values()) == fb, mon.distance_fallbacks    # the bound answered
        truth = mon.step(0.012, q2)                  # the worker is gone: this cycle queried
        assert sum(mon.distance_fallbacks.values()) == fb
        fin = np.isfinite(truth.distance)
        tol = discretisation(mon.fusion.front.grid)
        assert np.all(r2.distance[fin] <= truth.distance[fin] + tol)
        assert np.all(truth.distance[np.isinf(r2.distance) & fin] >= cfg.rho - tol)
        # the worker without an answer (stopped): the cycle queries the grid itself, same answer
        worker = DistanceWorker(mon.fusion, mon._points_at, mon._distance_settings, 500.0, MARGIN)
        mon._dist_worker = worker                   # never started: no answer
        r3 = mon.step(0.013, q2)
        mon._dist_worker = None
        assert mon.distance_fallbacks.get("no_answer", 0) >= 1
        assert np.array_equal(r3.distance, truth.distance)


def test_a_builds_own_query_is_the_newest_answer_at_once(setup):
    """The fusion build's classify-ahead query is the worker's query (same radius, same
    direction rule, the newest joints' points): published when the build ends, the next cycle
    uses the new frame without waiting for the worker's next period (here 1 s)."""
    rig, q, frames = setup
    cfg = rig.monitor.with_changes(distance_hz=1.0)
    cid = rig.camera_ids[0]
    with loaded(rig, q, frames, cfg) as mon:
        with mon.real_time():
            worker = mon._dist_worker
            deadline = time.perf_counter() + 30.0
            while worker.newest() is None and time.perf_counter() < deadline:
                mon.step(0.011, q)
                time.sleep(0.002)
            before = mon.step(0.011, q)
            assert before.frame_stamps[cid] == pytest.approx(0.005)
            offered = worker.offered
            mon.push_joints(0.02, q)
            mon.push_frame(Frame(cid, frames[cid], 0.015))
            mon.flush(timeout=60.0)
            assert worker.offered == offered + 1
            after = mon.step(0.021, q)
            assert after.frame_stamps[cid] == pytest.approx(0.015)       # the new frame, at once
            snap = worker.newest()
            front = mon.fusion.front
            assert snap.generation == front.generation and snap.stamps[cid] == pytest.approx(0.015)
            with front.lock:
                D, V, obs = query(front.grid, snap.P, rho=cfg.query_rho + worker.margin, method=cfg.method,
                                  rho_core=cfg.query_rho)
            assert np.array_equal(snap.D, D) and np.array_equal(snap.V, V) and np.array_equal(snap.observed, obs)
            assert np.array_equal(snap.P, mon._points_at(q))


def test_relaxed_bound_keeps_what_it_knows_and_cannot_judge_the_rest(setup):
    rig, q, frames = setup
    with loaded(rig, q, frames) as mon:
        grid = mon.fusion.front.grid
        P0 = points_near(mon, q, np.random.default_rng(2))
        D0, V0, obs0 = query(grid, P0, rho=RHO + MARGIN, method="hybrid", rho_core=RHO)
    snap = DistanceSnapshot(P0, D0, V0, obs0, RHO, MARGIN, "hybrid", {}, {}, {}, grid.principal_view(), 0.0)
    m = len(P0)
    P = P0 + np.array([0.0, 0.0, 2.5 * MARGIN])              # every point moved beyond the margin
    D, V, obs = np.empty(m), np.empty((m, 3)), np.empty(m, dtype=bool)
    assert not bound_distances(snap, P, RHO, D, V, obs)
    assert bound_distances(snap, P, RHO, D, V, obs, strict=False)
    twin = bound_distances_numpy(snap, P, RHO, strict=False)
    assert np.array_equal(twin[0], D) and np.array_equal(twin[1], V) and np.array_equal(twin[2], obs)
    had = np.isfinite(D0)
    assert had.any() and (~had).any()
    # something within rho + margin: its bound D0 - Δ (finite, nearer); nothing: cannot judge
    assert np.allclose(D[had], np.maximum(D0[had] - 2.5 * MARGIN, 0.0))
    assert not np.any(obs[~had]) and np.all(np.isinf(D[~had]))


def test_one_grid_gives_the_same_answers_with_half_the_per_camera_work(setup):
    """Cameras taking turns: two grids must each catch up with both cameras at every build,
    one grid loads only the camera whose frame is new (counted: the per-camera frame states
    computed), and every cycle's answer is the same."""
    from depthguard.fusion.depth_grid import DepthGridMap
    from depthguard.sources.sim_source import SimFrames, SimWorld

    rig, q, _ = setup
    cell = load_cell("flacco-cell")
    sim = SimFrames(SimWorld("flacco-cell", seed=4))
    taus = [9.0 + 0.033 * k for k in range(8)]
    qs = [np.asarray(cell.scene.robot_q(t), dtype=np.float64) for t in taus]
    ids = rig.camera_ids
    shots = [(ids[k % 2], sim.render(ids[k % 2], taus[k], qs[k]), 0.01 + 0.033 * k, qs[k]) for k in range(8)]

    def run(single):
        calls = []
        orig, orig_p = DepthGridMap._other_state, DepthGridMap._principal_state

        def counting(self, k, cam, *a, **kw):
            calls.append(cam.id)
            return orig(self, k, cam, *a, **kw)

        def counting_principal(self, *a, **kw):
            calls.append(self.principal.id)
            return orig_p(self, *a, **kw)
        DepthGridMap._other_state, DepthGridMap._principal_state = counting, counting_principal
        try:
            answers = []
            with Monitor(rig, rig.monitor) as mon:
                if single:
                    mon.fusion.set_single(True)
                for k, (cid, depth, stamp, qk) in enumerate(shots):
                    mon.push_joints(stamp - 0.005, qk)
                    mon.push_joints(stamp + 0.005, qk)
                    mon.push_frame(Frame(cid, depth, stamp))
                    mon.flush(timeout=120.0)
                    r = mon.step(stamp + 0.005, qk)
                    answers.append((r.distance.copy(), r.direction.copy(), r.observed.copy()))
                builds = mon.fusion.builds
        finally:
            DepthGridMap._other_state, DepthGridMap._principal_state = orig, orig_p
        return answers, calls, builds

    two, calls2, builds2 = run(False)
    one, calls1, builds1 = run(True)
    assert builds1 == builds2 == len(shots)
    for a, b in zip(two, one):
        assert all(np.array_equal(x, y) for x, y in zip(a, b))
    # build 1 has cam0 only (the one-camera map); build 2 loads both into the grid made when the
    # monitor started; from then on one grid loads the new camera only, while two grids load both
    # (the third build starts the second grid)
    n = len(shots)
    assert len(calls1) == 2 + (n - 2)
    assert len(calls2) == 2 + 2 * (n - 2)


def test_a_cycle_never_waits_for_a_build_into_the_one_grid(setup):
    import threading

    rig, q, frames = setup
    cfg = rig.monitor.with_changes(distance_hz=500.0)
    with loaded(rig, q, frames, cfg) as mon:
        with mon.real_time():
            assert mon.fusion.single
            deadline = time.perf_counter() + 30.0
            w = mon._dist_worker                  # running: it queried, then queried or republished
            while (w.queries < 1 or w.queries + w.reused < 3) and time.perf_counter() < deadline:
                mon.step(0.011, q)
                time.sleep(0.002)
            snap = mon._dist_worker.newest()
            # the worker stops with a fast last query: the cycle must try the grid (not give up
            # because the worker's queries are slow, which a busy machine can make them)
            mon._dist_worker.close()
            mon._dist_worker.last_query_s = 0.0
            buf = mon.fusion.front
            buf.lock.acquire()                   # a build in progress, for as long as the test says
            try:
                q_far = q.copy()                 # most points move beyond the margin
                q_far[:2] += (0.4, 0.3)
                done = threading.Event()
                out = {}

                def cycle():
                    out["r"] = mon.step(0.012, q_far)
                    done.set()
                th = threading.Thread(target=cycle, daemon=True)
                th.start()
                assert done.wait(10.0), "the control cycle waited for the grid"
            finally:
                buf.lock.release()
        r = out["r"]
        assert any("_grid_busy_some_points_unjudged" in k for k in mon.distance_fallbacks), mon.distance_fallbacks
        assert r.frame_stamps == dict(snap.stamps)
        m = len(r.names)
        data = mon.robot.create_data()
        mon.robot.forward(q_far, data)
        moved = np.zeros(m, dtype=bool)
        moved[: len(data.cp_positions)] = np.linalg.norm(data.cp_positions - snap.P[: len(data.cp_positions)],
                                                         axis=1) > MARGIN
        had = np.isfinite(snap.D[:m])
        assert np.any(moved & ~had), "the test needs a point with nothing near that moved beyond the margin"
        # nothing within rho + margin before a move beyond the margin: cannot judge (R26), and
        # the robot is told why; the others keep a bound
        assert not np.any(r.observed[moved & ~had])
        assert any(k.startswith("unobserved") for k in r.reasons), r.reasons
        assert np.array_equal(r.observed[~moved], snap.observed[:m][~moved])
    assert not mon.fusion.single                 # real_time() gave the two grids back


def test_a_cycle_does_not_query_itself_when_a_query_takes_more_than_half_a_period(setup):
    rig, q, frames = setup
    cfg = rig.monitor.with_changes(distance_hz=500.0)
    with loaded(rig, q, frames, cfg) as mon:
        with mon.real_time():
            deadline = time.perf_counter() + 30.0
            w = mon._dist_worker                  # running: it queried, then queried or republished
            while (w.queries < 1 or w.queries + w.reused < 3) and time.perf_counter() < deadline:
                mon.step(0.011, q)
                time.sleep(0.002)

            def forbidden(*_a, **_k):
                raise AssertionError("the control cycle queried the grid")
            mon._query_front = forbidden
            mon._dist_worker.last_query_s = 0.5 * cfg.dt + 1e-4     # as a query of a large radius takes
            q_far = q.copy()
            q_far[:2] += (0.4, 0.3)
            mon._dist_worker.request = lambda _q, _P=None: None               # keep the answer at q
            r = mon.step(0.012, q_far)
        assert any("_query_too_slow" in k for k in mon.distance_fallbacks), mon.distance_fallbacks
        assert r.frame_stamps and any(k.startswith("unobserved") for k in r.reasons)


def test_moved_beyond_kernel_equals_its_twin():
    rng = np.random.default_rng(11)
    for k in range(300):
        m = int(rng.integers(1, 12))
        P0 = rng.normal(size=(m, 3))
        P = P0 + rng.normal(0, 0.01, (m, 3)) * (rng.random((m, 1)) < 0.3)
        if k % 10 == 0:
            P[0, 1] = np.nan                      # a NaN point has moved (never "within")
        r = float(rng.choice([0.0, 0.005, 0.01, 0.02]))
        assert moved_beyond(P0, P, r) == moved_beyond_numpy(P0, P, r)
    assert moved_beyond(np.zeros((2, 3)), np.zeros((3, 3)), 1.0) and moved_beyond_numpy(np.zeros((2, 3)),
                                                                                        np.zeros((3, 3)), 1.0)


@pytest.mark.realtime     # no fallback while standing still: the worker republishes within max_age_s (26 ms),
#                            which a worker starved by another test's load did not (a fresh clone's CI, 2026-11-27)
def test_the_worker_queries_only_when_its_newest_answer_does_not_stand(setup):
    """issue 29: a robot standing still costs the worker one query, after which its answer is
    published again (same grid, same points: the same answer, young enough for the cycles); a
    move beyond the requery band, or a new frame, makes it query again."""
    rig, q, frames = setup
    cfg = rig.monitor.with_changes(distance_hz=500.0, distance_margin=MARGIN)
    with loaded(rig, q, frames, cfg) as mon:
        with mon.real_time():
            w = mon._dist_worker
            deadline = time.perf_counter() + 30.0
            while w.reused < 3 and time.perf_counter() < deadline:
                mon.step(0.011, q)
                time.sleep(0.004)
            n, fb = w.queries, dict(mon.distance_fallbacks)
            assert 1 <= n and w.reused >= 3, (w.queries, w.reused, w.last_error)
            for _ in range(30):                          # 60 ms standing still: no new query
                r = mon.step(0.011, q)
                time.sleep(0.002)
            assert w.queries == n and r.observed.all() and mon.distance_fallbacks == fb    # the bound answered
            data = mon.robot.create_data()
            # one joint turned until a control point moved past the band (and within the margin)
            for dq in np.linspace(0.001, 0.05, 50):
                q2 = q.copy()
                q2[0] += dq
                mon.robot.forward(q2, data)
                moved = np.linalg.norm(data.cp_positions - w.newest().P[:len(data.cp_positions)], axis=1).max()
                if moved > REQUERY_FRACTION * MARGIN * 1.2:
                    break
            assert REQUERY_FRACTION * MARGIN < moved < MARGIN
            deadline = time.perf_counter() + 30.0
            while w.queries == n and time.perf_counter() < deadline:
                mon.step(0.012, q2)
                time.sleep(0.002)
            assert w.queries == n + 1
            assert np.array_equal(w.newest().P[:len(data.cp_positions)], data.cp_positions)
