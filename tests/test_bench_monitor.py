"""The ``monitor`` bench group runs in quick mode and reports its rows (speed is not asserted)."""

import math
import re

import depthguard.evaluation.bench.fusion_cells  # noqa: F401  (registers the group)
import depthguard.evaluation.bench.monitor  # noqa: F401  (registers the group)
from depthguard.evaluation.bench import GROUPS, BenchContext, load_groups


def test_monitor_group_is_listed():
    assert "monitor" in load_groups() and "monitor.build" in load_groups()


def test_monitor_bench_quick_rows():
    rows = GROUPS["monitor"](BenchContext(quick=True))
    by = {r.name: r for r in rows}
    assert list(by) == ["monitor.step_p99_ms", "monitor.frame_to_reaction_p99_ms",
                        "monitor.fusion_build_p50_ms", "monitor.step_p99_ms.map_on", "monitor.cameras_at_30hz",
                        "monitor.cpu_per_camera"]
    for name in ("monitor.step_p99_ms", "monitor.fusion_build_p50_ms", "monitor.step_p99_ms.map_on"):
        r = by[name]
        assert r.unit == "ms" and math.isfinite(r.value) and r.value > 0, r
        assert r.peer and math.isfinite(r.peer_value) and r.peer_value > 0, r
    f2r = by["monitor.frame_to_reaction_p99_ms"]       # inf when no frame reached a reaction (a starved machine)
    assert f2r.value > 0 and f2r.peer_value > 0 and not math.isnan(f2r.value + f2r.peer_value), f2r
    assert by["monitor.step_p99_ms"].paper == 3.3
    on = by["monitor.step_p99_ms.map_on"]               # the map on beside the map off of the same run
    assert on.peer_value == by["monitor.step_p99_ms"].value and "map builds" in on.note, on
    builds = re.search(r": (\d+) map builds in [\d.]+ s \((\d+) failed\)", on.note)
    assert builds and int(builds.group(1)) > 0 and builds.group(2) == "0", on.note
    cams = by["monitor.cameras_at_30hz"]
    assert cams.unit == "cameras" and cams.value in (0.0, 2.0, 4.0) and cams.peer_value in (0.0, 2.0, 4.0)
    assert "2:" in cams.note and "33.3 ms" in cams.note     # 4 is tried only when 2 held
    assert ("4:" in cams.note) == (cams.value >= 2.0)
    cpu = by["monitor.cpu_per_camera"]                  # cores per camera: measured, never judged here
    assert cpu.unit == "cores" and math.isfinite(cpu.value) and cpu.value > 0, cpu
    assert math.isfinite(cpu.peer_value) and cpu.peer_value > 0, cpu


def test_the_monitor_bench_robot_moves_between_any_two_frames():
    """The bench's path is one of robot motion (its rows claim robot removal at every frame's joints):
    the capture joints differ between any two consecutive frames of a camera, in full and quick
    runs, and the arm travels. Truth: the cell's own scripted joints (the simulator's)."""
    import numpy as np

    from depthguard.evaluation.bench import monitor as bench_monitor
    from depthguard.sim import load_cell

    scene = load_cell("flacco-cell").scene
    for n in (bench_monitor.PATH_FRAMES, 10):
        t = bench_monitor.PATH_END - np.arange(n)[::-1] / bench_monitor.CAMERA_HZ
        q = np.array([scene.robot_q(x) for x in t])
        steps = np.abs(np.diff(q, axis=0)).max(axis=1)
        assert steps.min() > 0.0, (n, steps)
        assert np.abs(q[-1] - q[0]).max() > 0.05 or n == 10, (n, q[0], q[-1])


def test_every_built_in_cell_window_is_one_of_robot_motion():
    """The per-cell rows (``monitor.build``) and the ``share`` group's worker and build rows are of a
    moving robot: on each built-in cell's window the scripted joints differ between any two frames
    1/30 s apart, over its second (the robot's image rendered at every frame, its capsules moving)."""
    import numpy as np

    from depthguard.evaluation.bench import fusion_cells
    from depthguard.sim import load_cell

    from depthguard.evaluation.bench import camera_share

    windows = [(name, start) for name, start, _ in fusion_cells.BUILTIN_WINDOWS + fusion_cells.FULL_ONLY_WINDOWS]
    for name, start in windows + list(camera_share.CELLS):        # and the share group's frames
        scene = load_cell(name).scene
        q = np.array([scene.robot_q(start + k / 30.0) for k in range(31)])
        assert np.abs(np.diff(q, axis=0)).max(axis=1).min() > 0.0, (name, start)


def test_build_per_cell_quick_rows():
    """A p50 and a p99 row per cell with a robot, without and with a person; each measured, with its peer."""
    rows = GROUPS["monitor.build"](BenchContext(quick=True))
    cases = ("flacco-cell", "ur3-cell", "ur5-urdf-posts")
    names = [f"monitor.build_p{q}_ms.{c}{p}" for c in cases for p in ("", "+person") for q in (50, 99)]
    assert [r.name for r in rows] == names
    for r in rows:
        assert r.unit == "ms" and math.isfinite(r.value) and r.value > 0, r
        assert r.peer and math.isfinite(r.peer_value) and r.peer_value > 0, r
    assert "flacco-walls" in rows[0].note and "c-arm-room" in rows[0].note     # the cells without a robot, named
