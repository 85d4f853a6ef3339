"""``depthguard warm-up``: compile the package's numba kernels into their disk cache, in parallel (R29).

A fresh install has an empty cache: the first monitor, run or test then compiles for minutes
(about 170 CPU-seconds for the monitor's path alone, two kernels of the lazy depth grid 120 of
them). This command runs the real entry points on small inputs (:data:`JOBS`: the monitor's
warm-up on the built-in cells, one-thread grid queries, a short closed-loop run...) in
``--jobs`` processes that take the jobs in turn from one queue, so that the two large kernels
compile side by side. :func:`depthguard.runtime.warm_up.compile_locks` keeps two processes
from compiling one kernel twice. Which kernels and signatures are compiled is whatever the code
calls; nothing here names a kernel. ``make test`` runs it before the tests.

Measured 2026-11-26 from an empty cache (2 cores shared with other work, load 6-9): the two
processes 127 and 121 CPU-seconds (255 CPU-s user + sys in all), where the monitor's warm-up
alone takes 170 CPU-s in one process; again with the cache warm (loads only): 23 CPU-s in all.
With the bag replay and the scenes' render added (9 jobs; load 5-12): 330 CPU-s, 601 s; the two
new jobs 11 CPU-s, taken by the process that finished first while the other still compiled.
With the grid job given its frames' states and the jobs in :data:`JOBS`' order (empty cache,
load 1.3): 126.9 s, the processes' jobs 121 and 124 s end to end with as many CPU-s (nothing
waited for the other). Before (the grid job classified its own frames first; load 4-6): 576 s,
the monitor's job 418 s for 93 CPU-s (it waited for the grid job's two kernels), the run's ssm
twin 87 s for 7 CPU-s (it waited for the run's).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Optional

import numpy as np
import typer

from depthguard.cli.app import app

__all__ = ["warm_up_cmd", "JOBS"]


def _monitor(cell: str) -> None:
    """The monitor's own warm-up (R29) on a built-in cell: every kernel of its path."""
    from depthguard.runtime.warm_up import warm_up
    from depthguard.sim import load_cell

    rig = load_cell(cell).rig
    if rig.robot is not None:                    # a cell without a robot has no monitor
        # its fusion may wait for a kernel another process compiles (measured: 14 min for the two
        # grid kernels at load 10 on 2 cores, past the monitor's own 600 s)
        # with the cameras' shares on (off by default): their kernels too, for a rig that turns
        # them on; the build's own kernels are the same either way
        warm_up(rig, rig.monitor.with_changes(camera_shares=True), timeout=3600.0)


def _flat_states(grid, depth: float, options) -> dict:
    """Per-pixel states (:class:`~depthguard.fusion.depth_grid_state.CameraState`) of flat frames at
    ``depth`` m for every camera of ``grid``, as the monitor's camera workers hand them to
    ``set_frames(states=...)``: every ray a surface at ``depth`` (a valid return within range, no
    robot pixel), the principal at the grid's ``principal_bin``. With them ``set_frames`` classifies
    no pixel, so this job does not compile the frame classification (R29)."""
    from depthguard.fusion.depth_grid_kernels import KIND_SURFACE
    from depthguard.fusion.depth_grid_state import CameraState
    from depthguard.fusion.free32 import FREE_DTYPE

    def state(cam, b: int, robot_free: bool, dtype) -> CameraState:
        return CameraState(np.full(cam.shape, depth, dtype), np.full(cam.shape, KIND_SURFACE, np.int8),
                           options, robot_free, bin=b)

    states = {grid.principal.id: state(grid.principal, grid.principal_bin, False, np.float64)}
    for cam in grid.others:            # another camera's free depths: float32, as its worker makes them
        states[cam.id] = state(cam, 1, options.robot_in_others == "free", FREE_DTYPE)
    return states


def _flat_grid(cell: str, states: bool = True):
    """``(grid, points, config)``: the lazy depth grid of a built-in cell (None where it has fewer
    than two cameras) loaded with flat frames halfway through its depth span, and points to query
    (the ends of the robot's first capsule at its start joints). ``states``: hand the frames'
    per-pixel states in (:func:`_flat_states`) rather than let ``set_frames`` work them out."""
    from depthguard.fusion.depth_grid import DepthGridMap
    from depthguard.fusion.depth_grid_state import StateOptions
    from depthguard.sim import load_cell

    rig = load_cell(cell).rig
    cfg = rig.monitor
    cams = [rig.camera(c) for c in rig.camera_ids]
    if len(cams) < 2:
        return None, None, cfg
    d_min, d_max = rig.workspace.depth_span(cams[0])
    grid = DepthGridMap(cams, principal=cams[0].id, d_min=d_min, d_max=d_max, delta_d=cfg.delta_d,
                        principal_bin=cfg.principal_bin)
    q0 = np.asarray(rig.robot_q0, dtype=np.float64)
    d = float(np.float32(0.5 * (d_min + d_max)))          # as the float32 frames hold it
    depths = {c.id: np.full((c.height, c.width), d, np.float32) for c in cams}
    caps = rig.robot.collision_segments(q0, 0.05)
    o = StateOptions.of(cfg)
    grid.set_frames(depths, robot_capsules=caps, robot_offset=o.robot_offset, invalid=o.invalid,
                    robot_in_others=o.robot_in_others, silhouette_px=o.silhouette_px, gap_px=o.gap_px,
                    states=_flat_states(grid, d, o) if states else None)
    return grid, np.asarray(caps[0][:4], dtype=np.float64).reshape(-1, 3), cfg


def _grid_one_thread(cell: str) -> None:
    """The lazy depth grid of a built-in cell queried from one thread on flat frames, as the
    monitor's distance thread queries a frame the fusion has already classified (the lookup
    classifies what is still missing): the largest kernel of the monitor's path, compiled first
    thing while :func:`_monitor` compiles the frame classification and the cells' classification.
    The frames' states are handed in (:func:`_flat_states`), so this job waits for no kernel the
    other process compiles (measured from an empty cache: with ``set_frames`` working them out it
    compiled the frame classification first, 53 CPU-s, while the monitor's job waited for it).
    (The first query of a frame classifies first; marking the frame queried skips that for the
    first query, so that the lookup compiles first; a second query of the frame marked unqueried
    then compiles the classification of the frame's cells, which the monitor's job loads. The
    only uses of the grid's insides: were they renamed, this job would compile both kernels, the
    classification first, and nothing else change.)"""
    import numba

    grid, points, cfg = _flat_grid(cell)
    if grid is None:
        return
    if hasattr(grid, "_queried") and hasattr(grid, "_frame"):
        grid._queried = grid._frame
    prev = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        grid.query(points, rho=cfg.query_rho, method=cfg.method, threads=1)
        # then the frame's classification (the first query of a frame classifies first): compiled
        # here, after the lookup, while the other process is still in the monitor's frame state
        # (its largest kernel); the monitor's first query then loads it instead of compiling it
        # after the frame state, where the run's job (next in this process) waited for it
        if hasattr(grid, "_queried"):
            grid._queried = -1
        grid.query(points, rho=cfg.query_rho, method=cfg.method, threads=1)
    finally:
        numba.set_num_threads(prev)


def _cli(*args: str) -> None:
    """A ``depthguard`` command on a small input, its files in a temporary folder (``{tmp}``)."""
    import contextlib
    import io

    from depthguard.cli import app as the_app

    with tempfile.TemporaryDirectory(prefix="depthguard-warm-up-") as tmp:
        argv = [a.replace("{tmp}", tmp) for a in args]
        with contextlib.redirect_stdout(io.StringIO()):     # the command's report: not wanted here
            the_app(argv, standalone_mode=False)


def _bag_replay(cell: str) -> None:
    """``depthguard record`` of the cell's simulator for 0.2 s, then ``depthguard monitor`` on that
    bag (``--fast``): the simulator's noise (R25), the bag's reading and the monitor on joints as a
    recording or a driver decodes them from a message (read-only arrays: kernels of their own
    signature, which the monitor's warm-up on its own arrays does not compile)."""
    with tempfile.TemporaryDirectory(prefix="depthguard-warm-up-") as tmp:
        bag = str(Path(tmp) / "bag")
        # from the `reach` situation: a person in view, whose posing (the simulator's, 2-5 CPU-s)
        # compiles here, not in the first test that shows one (measured: 19 s wall inside the fr3
        # cell's 18 s real-time run, tests/test_fr3_cell.py, which runs alone, its cameras stale)
        _cli("record", "--cell", cell, "--source", f"sim:{cell}:reach", "--duration", "0.2", "--out", bag)
        _cli("monitor", "--cell", cell, "--source", f"bag:{bag}", "--fast", "--quiet", "--out", str(Path(tmp) / "run"))


def _check_path(cell: str) -> None:
    """``depthguard check-path`` of a two-waypoint path from the cell's joints (free space, R22)."""
    from depthguard.sim import load_cell

    rig = load_cell(cell).rig
    q0 = np.asarray(rig.robot_q0, dtype=np.float64)
    with tempfile.TemporaryDirectory(prefix="depthguard-warm-up-") as tmp:
        path = Path(tmp) / "path.csv"
        rows = [[0.0, *q0], [0.5, *(q0 + 0.05)]]
        path.write_text(",".join(["stamp", *rig.robot.joint_names]) + "\n"
                        + "\n".join(",".join(f"{v:.6f}" for v in r) for r in rows) + "\n")
        _cli("check-path", "--cell", cell, "--path", str(path), "--settle", "0.2")   # any verdict will do


#: (name, callable, args), in the order the processes take them. The first two hold the large
#: kernels of the monitor's path and wait for nothing the other compiles (the monitor's job: the
#: frame state, fused, the largest of all; the grid job: the lookup, then the frame's
#: classification, which the monitor's job then loads where it used to compile it after the frame
#: state). The grid job ends first: then the closed-loop run, whose simulator compiles its own
#: render and edges (about 60 CPU-s) before it reaches the monitor's kernels, in the cache by
#: then; the monitor's job is followed by the jobs that need its kernels (check-path, the bag's
#: monitor) and the small ones. (Measured 2026-11-27 from an empty cache at load 5-7: the
#: monitor's job 162 CPU-s, the grid's 81, the run's 91 and check-path's 55, of which the
#: rasteriser's second signatures for a writable ``mesh_off``, 57 CPU-s, are gone since the
#: renderer passes it read-only; with check-path after the small jobs the process that took it
#: ended last.)
#: A process that reaches a kernel the other one is compiling waits for it (compile_locks): a
#: core idle. Measured from an empty cache (2 cores, load 4-8 from other work): with the grid
#: job classifying its own frames the monitor's job waited 250 of its 418 s for it; with the run
#: after the small jobs it started only once the monitor's job ended and ran alone at the end.
#: With the classification compiled by the monitor's job after the frame state, the run (after
#: the grid job) reached it while the monitor's job compiled it and waited 28 s (fresh clone,
#: 2026-11-27: run 101.9 s for 73.6 CPU-s; 194.7 s in all), or compiled it itself while the
#: monitor's job waited for it.
JOBS: list[tuple[str, object, tuple]] = [
    ("monitor flacco-cell", _monitor, ("flacco-cell",)),
    ("grid query on one thread and its classification, flacco-cell", _grid_one_thread, ("flacco-cell",)),
    ("run reach 0.3 s", _cli, ("run", "-s", "reach", "--duration", "0.3", "-o", "{tmp}/run", "--quiet")),
    ("check-path flacco-cell", _check_path, ("flacco-cell",)),
    ("record 0.2 s with a person in view and monitor the bag, flacco-cell", _bag_replay, ("flacco-cell",)),
    ("placement c-arm-room", _cli, ("placement", "--cell", "c-arm-room", "--no-improve")),
    ("scenes render flacco-cell", _cli, ("scenes", "render", "flacco-cell", "--out", "{tmp}/render")),
    ("run reach ssm 0.3 s", _cli, ("run", "-s", "reach", "--reaction", "ssm", "--duration", "0.3", "-o", "{tmp}/run",
                                   "--quiet")),
    ("monitor ur3-cell", _monitor, ("ur3-cell",)),
    # SSM with the known scene muted: the cameras' voxel filter (1-2 CPU-s), which the monitors
    # above do not compile and the first tests that need it compiled on their clocks (the fr3
    # cell's 18 s real-time run, the distributed tests' nodes, which run alone)
    ("monitor fr3-cell", _monitor, ("fr3-cell",)),
]


def _take(queue: Path) -> int:
    """The next job's index from the counter file ``queue`` shared by the processes (flock)."""
    import fcntl

    with open(queue, "r+") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        i = int(f.read() or 0)
        f.seek(0)
        f.truncate()
        f.write(str(i + 1))
        return i


def _part(work: Path, part: int) -> int:
    """One process: jobs from the queue until none is left; a line per job. Returns how many
    failed (a failed job is named with its error; the others run all the same)."""
    from depthguard.runtime.warm_up import CompileCount, compile_locks

    failed = 0
    with compile_locks(work / "locks"):
        while (i := _take(work / "queue")) < len(JOBS):
            name, fn, args = JOBS[i]
            t0, c0 = time.perf_counter(), time.process_time()
            with CompileCount() as cc:
                try:
                    fn(*args)
                except Exception as exc:          # noqa: BLE001 - one line, and the next job
                    failed += 1
                    typer.echo(f"warm-up [{part}] {name}: failed: {type(exc).__name__}: {exc}", err=True)
                    continue
            typer.echo(f"warm-up [{part}] {name}: {time.perf_counter() - t0:.1f} s "
                       f"({time.process_time() - c0:.1f} CPU-s), {len(cc.kernels)} kernels compiled "
                       f"in {cc.seconds:.1f} s")
    return failed


@app.command("warm-up")
def warm_up_cmd(
    jobs: int = typer.Option(2, "--jobs", "-j", min=1, max=64, help="Processes compiling side by side (the machine's cores)."),
    part: int = typer.Option(0, "--part", hidden=True, help="Internal: this process's number."),
    work: Optional[Path] = typer.Option(None, "--work", hidden=True, help="Internal: the queue's folder."),
) -> None:
    """Compile the numba kernels of the monitor, the grid and a closed-loop run into numba's disk
    cache (R29), in JOBS processes sharing the work, so that the first run (or test) loads them
    instead of compiling for minutes. With a warm cache it only loads them (seconds per process).
    The cache is numba's: next to the package's sources, or NUMBA_CACHE_DIR."""
    if work is not None:
        if _part(Path(work), part):
            raise typer.Exit(1)
        return
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="depthguard-warm-up-") as tmp:
        (Path(tmp) / "queue").write_text("0")
        procs = [subprocess.Popen([sys.executable, "-m", "depthguard", "warm-up", "--part", str(k + 1),
                                   "--work", tmp], env=os.environ.copy()) for k in range(jobs)]
        codes = [p.wait() for p in procs]
    if any(codes):
        typer.echo(f"depthguard: warm-up: {sum(1 for c in codes if c)} of {jobs} processes had a job fail "
                   f"(above); what the others compiled is in the cache", err=True)
        raise typer.Exit(1)
    typer.echo(f"warm-up: {len(JOBS)} jobs in {jobs} processes, {time.perf_counter() - t0:.1f} s")
