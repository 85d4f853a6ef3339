"""Processes warming one numba cache together (``depthguard warm-up``, R29): no kernel compiled
twice, no overload lost from the cache's index.

Truth: numba's own compile events (:class:`~depthguard.runtime.warm_up.CompileCount`, counted in
each process) and what a later process finds in the cache — it compiles nothing when every
overload was saved. The kernel is a small ``cache=True`` function written to a temporary module,
so the cache is this test's own (``NUMBA_CACHE_DIR``).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from depthguard.cli import app

pytestmark = [pytest.mark.multiprocess, pytest.mark.slow]

KERNEL = textwrap.dedent("""
    import numba
    import numpy as np

    @numba.njit(cache=True)
    def weighted(a):
        s = 0.0
        for i in range(a.shape[0]):
            s += (i % 7) * a[i] + np.sqrt(abs(a[i]))
        return s
""")

# argv: work folder, dtypes (comma-separated), lock folder ('' = no locks); waits for the file
# 'go', then calls the kernel once per dtype and prints {"compiled": n, "values": [v, ...]}
WORKER = textwrap.dedent("""
    import json, sys, time
    from pathlib import Path
    import numpy as np
    from depthguard.runtime.warm_up import CompileCount, compile_locks
    work, dtype, locks = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
    sys.path.insert(0, str(work))
    import kern
    (work / f"ready-{dtype}-{time.monotonic_ns()}").touch()
    while not (work / "go").exists():
        time.sleep(0.005)
    values = []
    with CompileCount() as cc:
        for d in dtype.split(","):
            a = np.arange(50).astype(d)
            if locks:
                with compile_locks(locks):
                    values.append(float(kern.weighted(a)))
            else:
                values.append(float(kern.weighted(a)))
    print(json.dumps({"compiled": len(cc.kernels), "values": values}))
""")


def _start(work: Path, dtype: str, locks: str, env: dict) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(work / "worker.py"), str(work), dtype, locks], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _together(work: Path, dtypes: list[str], locks: str, env: dict) -> list[dict]:
    """Start one worker per dtype, let them call the kernel at the same moment; their reports."""
    for f in work.glob("ready-*"):
        f.unlink()
    (work / "go").unlink(missing_ok=True)
    procs = [_start(work, d, locks, env) for d in dtypes]
    import time

    t0 = time.monotonic()
    while len(list(work.glob("ready-*"))) < len(procs):
        assert time.monotonic() - t0 < 120, "workers did not start"
        assert all(p.poll() is None for p in procs), [p.communicate() for p in procs]
        time.sleep(0.01)
    (work / "go").touch()
    outs = []
    for p in procs:
        out, err = p.communicate(timeout=180)
        assert p.returncode == 0, err
        outs.append(json.loads(out.strip().splitlines()[-1]))
    return outs


@pytest.fixture
def work(tmp_path):
    (tmp_path / "kern.py").write_text(KERNEL)
    (tmp_path / "worker.py").write_text(WORKER)
    env = os.environ.copy()
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "cache")
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).parents[1] / "src"), env.get("PYTHONPATH", "")])
    return tmp_path, env


def _expected(dtype: str) -> float:
    import numpy as np

    a = np.arange(50).astype(dtype)
    return float(sum((i % 7) * float(a[i]) + np.sqrt(abs(float(a[i]))) for i in range(50)))


def test_processes_warming_one_cache_compile_each_overload_once_and_keep_all(work):
    """Two processes reach one kernel at once: one compiles it, the other waits and loads it.
    Two compile two overloads of one kernel at once: a third process finds both in the cache
    (numba rewrites a kernel's index on each save; two saves at once could lose one)."""
    path, env = work
    locks = str(path / "locks")
    outs = _together(path, ["float64", "float64"], locks, env)
    assert sorted(o["compiled"] for o in outs) == [0, 1], outs
    outs = _together(path, ["int64", "float32"], locks, env)
    assert [o["compiled"] for o in outs] == [1, 1], outs
    again = _together(path, ["float64,int64,float32"], "", env)[0]
    assert again["compiled"] == 0, again
    assert again["values"] == pytest.approx([_expected(d) for d in ("float64", "int64", "float32")], rel=1e-6)


def test_warm_up_rejects_a_bad_number_of_processes():
    from typer.testing import CliRunner

    r = CliRunner().invoke(app, ["warm-up", "--jobs", "0"])
    assert r.exit_code == 2 and "--jobs" in r.output
