"""Under pytest-xdist (`make test`: two workers) a test marked ``realtime`` or ``multiprocess``
runs alone, every other test beside any other (tests/conftest.py's turn locks). The suite's own
``conftest.py`` runs in pytest itself on small test files in a scratch folder; the truth is the
tests' own wall-clock intervals, written by each test as it starts and ends."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

CONFTEST = Path(__file__).with_name("conftest.py")

TIMED = """import json, os, time
import pytest

def _record(name, fn):
    t0 = time.time()
    fn()
    with open(os.environ["TURNS_LOG"], "a") as f:
        f.write(json.dumps([name, t0, time.time()]) + "\\n")

{tests}
"""


def _tests(prefix: str, n: int, mark: str = "") -> str:
    return "\n".join(f"{mark}\ndef test_{prefix}{k}():\n    _record('{prefix}{k}', lambda: time.sleep(0.4))\n"
                     for k in range(n))


def test_a_timed_test_runs_alone_and_the_others_side_by_side(tmp_path):
    pytest.importorskip("xdist", reason="pytest-xdist is not installed (the test extra has it)")
    shutil.copy(CONFTEST, tmp_path / "conftest.py")
    for f in range(4):
        (tmp_path / f"test_plain{f}.py").write_text(TIMED.format(tests=_tests(f"plain{f}_", 4)))
    (tmp_path / "test_timed.py").write_text(TIMED.format(
        tests=_tests("timed_rt", 2, "@pytest.mark.realtime") + _tests("timed_mp", 2, "@pytest.mark.multiprocess")))
    log = tmp_path / "turns.jsonl"
    env = {**os.environ, "TURNS_LOG": str(log)}
    env.pop("DEPTHGUARD_CI_REQUIRES", None)
    res = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "2", "--dist", "load",
                          str(tmp_path)], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    runs = [json.loads(line) for line in log.read_text().splitlines()]
    assert len(runs) == 20
    alone = [r for r in runs if r[0].startswith("timed")]
    assert len(alone) == 4
    for name, t0, t1 in alone:
        for other, s0, s1 in runs:
            if other != name:
                assert s1 <= t0 or t1 <= s0, f"{other} ran while {name} ran alone"
    plain = [r for r in runs if r[0].startswith("plain")]
    side_by_side = sum(1 for i, a in enumerate(plain) for b in plain[i + 1:] if a[1] < b[2] and b[1] < a[2])
    assert side_by_side > 0, "the plain tests never ran side by side"


def test_the_longest_files_go_first_and_each_file_keeps_its_order(tmp_path):
    """`make test` (``--dist loadfile --no-loadscope-reorder``): the two files that conftest.py's
    FILE_SECONDS names longest start first, one on each worker, although they hold the fewest
    tests (xdist's own order, by number of tests per file, would start them last); a file's tests
    run in their order. Truth: the tests' own wall-clock starts."""
    pytest.importorskip("xdist", reason="pytest-xdist is not installed (the test extra has it)")
    import importlib.util

    spec = importlib.util.spec_from_file_location("suite_conftest", CONFTEST)
    conf = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(conf)
    longest = sorted(conf.FILE_SECONDS, key=lambda f: -conf.FILE_SECONDS[f])[:2]
    shutil.copy(CONFTEST, tmp_path / "conftest.py")
    for name in longest:                          # 1.5 s: ended only after the other worker's has started
        long_test = _tests(name[:-3] + "_", 1).replace("sleep(0.4)", "sleep(1.5)")
        (tmp_path / name).write_text(TIMED.format(tests=long_test))
    for f in range(3):                            # names xdist's collection puts before test_[l-z]...
        (tmp_path / f"test_a_plain{f}.py").write_text(TIMED.format(tests=_tests(f"plain{f}_", 5)))
    log = tmp_path / "turns.jsonl"
    env = {**os.environ, "TURNS_LOG": str(log)}
    env.pop("DEPTHGUARD_CI_REQUIRES", None)
    res = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "2",
                          "--dist", "loadfile", "--no-loadscope-reorder", str(tmp_path)],
                         capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    runs = {name: t0 for name, t0, _ in (json.loads(line) for line in log.read_text().splitlines())}
    assert len(runs) == 17
    heavy = [t0 for name, t0 in runs.items() if not name.startswith("plain")]
    plain = [t0 for name, t0 in runs.items() if name.startswith("plain")]
    assert len(heavy) == 2 and max(heavy) < min(plain), sorted(runs.items(), key=lambda r: r[1])
    for f in range(3):
        starts = [runs[f"plain{f}_{k}"] for k in range(5)]
        assert starts == sorted(starts)


def test_files_with_a_test_that_runs_alone_come_first_then_the_longest(tmp_path):
    """The collection's order (what `make test` hands the workers, file by file): the files that
    hold a test marked realtime or multiprocess first, then FILE_SECONDS' files longest first, then
    the rest in name order; each file's tests in their own order. Truth: pytest's own list."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("suite_conftest", CONFTEST)
    conf = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(conf)
    longest = sorted(conf.FILE_SECONDS, key=lambda f: -conf.FILE_SECONDS[f])[:2]
    shutil.copy(CONFTEST, tmp_path / "conftest.py")
    files = {"test_a_plain.py": _tests("p", 3),
             "test_zz_alone.py": _tests("z", 1) + _tests("y", 1, "@pytest.mark.realtime"),
             longest[1]: _tests("l", 2), longest[0]: _tests("k", 2)}
    for name, tests in files.items():
        (tmp_path / name).write_text(TIMED.format(tests=tests))
    env = {k: v for k, v in os.environ.items() if k not in ("DEPTHGUARD_CI_REQUIRES", "PYTEST_ADDOPTS")}
    res = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--collect-only",
                          str(tmp_path)], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    got = [ln.split("/")[-1] for ln in res.stdout.splitlines() if "::" in ln]
    assert got == ["test_zz_alone.py::test_z0", "test_zz_alone.py::test_y0", f"{longest[0]}::test_k0",
                   f"{longest[0]}::test_k1", f"{longest[1]}::test_l0", f"{longest[1]}::test_l1",
                   "test_a_plain.py::test_p0", "test_a_plain.py::test_p1", "test_a_plain.py::test_p2"], got
