"""The depthguard command: --help everywhere, clear errors for bad arguments."""

import json
import subprocess
import sys

from typer.testing import CliRunner

from depthguard.cli import app


def _commands(typer_app, prefix=()):
    import typer.main
    click_cmd = typer.main.get_command(typer_app)
    out = []

    def walk(cmd, path):
        out.append(path)
        for name, sub in getattr(cmd, "commands", {}).items():
            walk(sub, path + (name,))

    walk(click_cmd, prefix)
    return out


def test_every_command_has_help():
    runner = CliRunner()
    cmds = _commands(app)
    assert len(cmds) > 3
    for path in cmds:
        res = runner.invoke(app, list(path) + ["--help"], env={"COLUMNS": "80"})
        assert res.exit_code == 0, (path, res.output)
        assert "Usage" in res.output
        # nothing cut short at 80 columns (rich ends a word wider than its column with "…")
        assert "…" not in res.output, (path, [ln for ln in res.output.splitlines() if "…" in ln])


def test_bench_rejects_unknown_group():
    res = subprocess.run([sys.executable, "-m", "depthguard.cli.__main__", "bench", "--only", "nosuchgroup"],
                         capture_output=True, text=True)
    assert res.returncode == 2
    assert "nosuchgroup" in (res.stderr + res.stdout)


def test_bench_only_picks_the_group_that_owns_a_prefix():
    """``--only monitor.build`` runs the ``monitor.build`` group alone (it once ran the whole
    ``monitor`` group too, minutes of work whose rows were then dropped); a prefix inside a
    group's rows (``monitor.step_p99_ms``) runs the group that owns them."""
    from depthguard.evaluation.bench import load_groups, selected_groups

    names = list(load_groups())
    assert selected_groups(["monitor.build"], names) == ["monitor.build"]
    assert selected_groups(["monitor.step_p99_ms"], names) == ["monitor"]
    assert set(selected_groups(["monitor"], names)) == {n for n in names if n.startswith("monitor")}
    assert selected_groups(["units.combine_ms"], names) == ["units"]
    assert selected_groups(["nosuchgroup"], names) == []


def test_bench_names_its_machine():
    """The table says what it was measured on (the same code's figures differ by machine): the CPU
    as /proc/cpuinfo names it, the cores this process may use, Python's and numba's versions."""
    import os
    import platform

    import numba

    from depthguard.evaluation.bench import machine

    line = machine()
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    assert f", {cores} cores," in line
    assert f"Python {platform.python_version()}" in line and f"numba {numba.__version__}" in line
    if os.path.exists("/proc/cpuinfo"):
        with open("/proc/cpuinfo") as fh:
            name = next((ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name")), None)
        assert name is None or line.startswith(name)


def test_run_rejects_bad_camera_latency_and_records_the_latency(tmp_path):
    runner = CliRunner()
    res = runner.invoke(app, ["run", "-s", "empty", "-o", str(tmp_path / "x"), "--camera-latency", "-0.1"])
    assert res.exit_code == 2 and "--camera-latency" in res.output
    out = tmp_path / "r"
    res = runner.invoke(app, ["run", "-s", "empty", "-o", str(out), "--duration", "0.2", "--camera-latency", "0.05",
                              "--quiet"])
    assert res.exit_code == 0, res.output
    s = json.loads((out / "summary.json").read_text())
    assert s["params"]["camera_latency_s"] == 0.05


def test_numbas_openmp_threads_sleep_between_parallel_regions_unless_the_user_says_otherwise():
    """``import depthguard`` sets OMP_WAIT_POLICY=PASSIVE before numba starts its OpenMP threads
    (spinning after each parallel region took a core's half from the simulator and the camera
    workers of a real-time run); a policy the user set is kept."""
    import os

    code = "import os, depthguard; print(os.environ['OMP_WAIT_POLICY'])"
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "PASSIVE"
    out = subprocess.run([sys.executable, "-c", code], env={**env, "OMP_WAIT_POLICY": "ACTIVE"},
                         capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "ACTIVE"


def test_the_overview_lists_every_command_once_by_panel_on_one_line():
    """``depthguard --help`` groups the commands by what they are for, each with one line of
    at most 56 characters (one row at 80 columns); a command added without a place in
    ``OVERVIEW`` fails here."""
    import typer.main

    from depthguard.cli.app import OVERVIEW

    names = set(typer.main.get_command(app).commands)
    assert names == set(OVERVIEW), names ^ set(OVERVIEW)
    assert all(len(line) <= 56 for _, line in OVERVIEW.values())
    out = CliRunner().invoke(app, ["--help"], env={"COLUMNS": "80"}).output
    panels = list(dict.fromkeys(panel for panel, _ in OVERVIEW.values()))
    at = [out.index(f"─ {p} ") for p in panels]
    assert at == sorted(at)
    for name, (panel, line) in OVERVIEW.items():
        row = next(r for r in out.splitlines() if r.startswith(f"│ {name} "))
        assert line in row, (name, row)
        start = out.index(f"─ {panel} ")
        assert start < out.index(row) < start + out[start:].index("╰")


def test_a_commands_text_reads_as_paragraphs_not_as_its_docstrings_lines():
    """typer keeps the docstring's line breaks; the help reflows each paragraph, and leaves a
    paragraph with a list or an indented example as written."""
    from depthguard.cli.app import _reflow

    text = "First line\n    goes on.\n\n    Second paragraph\n    over two lines.\n\n    - one\n    - two\n"
    assert _reflow(text) == "First line goes on.\n\nSecond paragraph over two lines.\n\n- one\n- two"
    out = CliRunner().invoke(app, ["view", "--help"], env={"COLUMNS": "200"}).output
    assert "so that the view shows its decisions and reasons, not only the depth." in out


def test_ports_and_the_ros2_domain_outside_their_range_are_usage_errors_naming_the_option():
    runner = CliRunner()
    for args, opt, rng in ((["monitor", "--ros2-domain", "233"], "--ros2-domain", "0 to 232"),
                           (["monitor", "--sink", "view:-1"], "--sink", "0 to 65535"),
                           (["view", "--port", "65536"], "--port", "0 to 65535")):
        res = runner.invoke(app, args, env={"COLUMNS": "200"})
        assert res.exit_code == 2 and opt in res.output and rng in res.output, (args, res.output)
