"""CI fails when a test it is meant to run skips (issue 33: ``.ci/run`` stayed green when the apt
install of Chromium or libusb failed and their tests skipped). The suite's own ``conftest.py`` is
run by pytest itself on small test files in a scratch folder: a skip for a requirement named in
``DEPTHGUARD_CI_REQUIRES`` fails the run — a test's own ``pytest.skip`` and a module's skip at
import alike (every RealSense test file skips at module level; collection-time skips once went
unnoticed) — and elsewhere the same skips leave the run green."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

CONFTEST = Path(__file__).with_name("conftest.py")
PASSING = "def test_fine():\n    assert 1 + 1 == 2\n"
SKIPS = {
    "module": "import pytest\npytest.skip('RealSense SDK not importable here: no libusb', allow_module_level=True)\n",
    "function": "import pytest\n\ndef test_view():\n    pytest.skip('no Chromium on this machine')\n",
}


def _pytest(folder: Path, required: str | None, *args: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "DEPTHGUARD_CI_REQUIRES"}
    if required is not None:
        env["DEPTHGUARD_CI_REQUIRES"] = required
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *args, str(folder)],
                          capture_output=True, text=True, env=env, cwd=folder, timeout=300)


def test_a_required_skip_fails_the_run_and_an_optional_one_does_not(tmp_path):
    shutil.copy(CONFTEST, tmp_path / "conftest.py")
    (tmp_path / "test_fine.py").write_text(PASSING)
    for kind, text in SKIPS.items():
        (tmp_path / f"test_skips_{kind}.py").write_text(text)
    res = _pytest(tmp_path, "chromium realsense")
    assert res.returncode == 1, res.stdout
    assert "FAILED: 2 test(s) that this run requires (DEPTHGUARD_CI_REQUIRES) skipped" in res.stdout, res.stdout
    for kind in SKIPS:
        assert f"test_skips_{kind}.py" in res.stdout, (kind, res.stdout)
    res = _pytest(tmp_path, None)
    assert res.returncode == 0 and "1 passed, 2 skipped" in res.stdout, res.stdout


def test_a_required_skip_fails_the_run_in_two_xdist_workers_too(tmp_path):
    """`make test` runs the tests in two pytest-xdist workers: the skips happen there (a module's
    at its collection in a worker) and the run's status is the controller's."""
    pytest.importorskip("xdist", reason="pytest-xdist is not installed (the test extra has it)")
    shutil.copy(CONFTEST, tmp_path / "conftest.py")
    (tmp_path / "test_fine.py").write_text(PASSING)
    for kind, text in SKIPS.items():
        (tmp_path / f"test_skips_{kind}.py").write_text(text)
    res = _pytest(tmp_path, "chromium realsense", "-n", "2")
    assert res.returncode == 1, res.stdout
    assert "FAILED: 2 test(s) that this run requires (DEPTHGUARD_CI_REQUIRES) skipped" in res.stdout, res.stdout
    for kind in SKIPS:
        assert f"test_skips_{kind}.py" in res.stdout, (kind, res.stdout)
    res = _pytest(tmp_path, None, "-n", "2")
    assert res.returncode == 0 and "1 passed, 2 skipped" in res.stdout, res.stdout
