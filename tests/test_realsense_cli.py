"""``depthguard rig from-realsense``, the missing-SDK sentence, the import rule and the bench row (issue 15).

- The import rule: loading every RealSense module (source, CLI, bench) and the
  source registry does not import ``pyrealsense2`` (a fresh interpreter says).
- A missing SDK, or an SDK whose libusb is missing, is one line naming what to
  install, exit status 2, no traceback: a fresh interpreter whose
  ``pyrealsense2`` raises the SDK's own ImportError text.
- ``rig from-realsense --file``: the blocks carry the intrinsics the SDK reports
  for a recording made by the SDK's recorder (with known, injected numbers); with
  the pose written they load as a rig that the ``realsense-file`` source accepts;
  with ``pose: null`` they do not load; ``--out`` is never overwritten.
"""

import math
import os
import subprocess
import sys

import pytest
import yaml

from depthguard.sources.realsense_device import RealSenseUnavailable, import_sdk

PY = sys.executable


def _run(args, env_extra=None, cwd=None):
    env = dict(os.environ, **(env_extra or {}))
    return subprocess.run([PY, *args], capture_output=True, text=True, env=env, cwd=cwd, timeout=120)


def test_importing_the_realsense_modules_does_not_import_the_sdk():
    code = ("import sys; import depthguard.sources.realsense, depthguard.sources.realsense_device, "
            "depthguard.evaluation.bench.realsense; import depthguard.cli; "
            "from depthguard.sources.base import source_schemes; s = source_schemes(); "
            "assert 'realsense' in s and 'realsense-file' in s, s; "
            "print('pyrealsense2' in sys.modules)")
    r = _run(["-c", code])
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "False"


@pytest.mark.parametrize("error, expect", [
    ("ImportError('libusb-1.0.so.0: cannot open shared object file: No such file or directory')",
     "apt install libusb-1.0-0"),
    ("ModuleNotFoundError(\"No module named 'pyrealsense2'\")", "pip install 'depthguard[realsense]'"),
])
def test_a_missing_sdk_is_one_line_saying_what_to_install(tmp_path, error, expect):
    fake = tmp_path / "fake"
    (fake / "pyrealsense2").mkdir(parents=True)
    (fake / "pyrealsense2" / "__init__.py").write_text(f"raise {error}\n")
    out = tmp_path / "cams.yaml"
    env = {"PYTHONPATH": os.pathsep.join([str(fake), os.environ.get("PYTHONPATH", "")])}
    r = _run(["-m", "depthguard", "rig", "from-realsense", "--out", str(out)], env)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("depthguard: error: ") and expect in lines[0], r.stderr
    assert not out.exists()
    r = _run(["-c", "from depthguard.sim.cells import load_cell; from depthguard.sources.base import open_source\n"
                    "open_source('realsense:123', load_cell('flacco-cell').rig)"], env)
    assert r.returncode != 0 and expect in r.stderr and "RealSenseUnavailable" in r.stderr
    r = _run(["-c", "from depthguard.evaluation.bench import BenchContext\n"
                    "from depthguard.evaluation.bench.realsense import bench_realsense\n"
                    "(row,) = bench_realsense(BenchContext(quick=True)); print(row.value, row.note)"], env)
    assert r.returncode == 0 and r.stdout.startswith("nan") and expect in r.stdout


# ---------------------------------------------------------------- with the SDK
def _sdk():
    try:
        return import_sdk()
    except RealSenseUnavailable as exc:
        pytest.skip(f"RealSense SDK not importable here: {exc}")


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    _sdk()
    import numpy as np

    from depthguard.camera import Camera
    from depthguard.sources.realsense_device import record_depth

    cam = Camera(id="x", width=848, height=480, fx=421.25, fy=420.75, cx=425.1, cy=238.6)
    path = tmp_path_factory.mktemp("rscli") / "d435.db3"
    depth = np.full((480, 848), 1.5, dtype=np.float32)
    record_depth(path, [(depth, 100.0 + i / 30) for i in range(3)], cam, serial="832112070255",
                 name="Intel RealSense D435", period_s=0.01)
    return path, cam


def test_rig_from_realsense_writes_the_sdk_intrinsics(recording, tmp_path):
    path, cam = recording
    out = tmp_path / "cams.yaml"
    r = _run(["-m", "depthguard", "rig", "from-realsense", "--file", str(path), "--id", "front", "--out", str(out)])
    assert r.returncode == 0, r.stderr
    text = out.read_text()
    assert "POSE IS NOT KNOWN" in text and "832112070255" in text
    (block,) = yaml.safe_load(text)["cameras"]
    assert block["id"] == "front" and block["sensor"] == "realsense_d435" and block["pose"] is None
    assert (block["width"], block["height"]) == (848, 480)
    for k in ("fx", "fy", "cx", "cy"):
        assert block[k] == pytest.approx(getattr(cam, k), abs=1e-4)
    assert block["range"] == [0.2, 6.0]

    from depthguard.rig import Rig, RigError
    from depthguard.sources.base import open_source

    base = {"name": "mine", "workspace": {"min": [-1, -1, 0], "max": [1, 1, 2]},
            "robot": {"name": "lwr4"}, "cameras": [block]}
    with pytest.raises(RigError, match="pose"):
        Rig.from_dict(base)                                        # the pose must be written first
    block = dict(block, pose={"look_at": {"eye": [2, 0, 1.5], "target": [0, 0, 0.5]}})
    rig = Rig.from_dict(dict(base, cameras=[block]))
    src = open_source(f"realsense-file:{path}", rig)                # the intrinsics check passes
    try:
        got = []
        t = src.first_stamp
        while not src.done:
            got.extend(src.frames_until(t))
            t += 0.01
        got.extend(src.frames_until(math.inf))
    finally:
        src.close()
    assert [f.stamp for f in got] == pytest.approx([100.0 + i / 30 for i in range(3)], abs=1e-9)
    assert all(float(f.depth[240, 424]) == pytest.approx(1.5, abs=0.0005) for f in got)

    before = out.read_text()
    r = _run(["-m", "depthguard", "rig", "from-realsense", "--file", str(path), "--out", str(out)])
    assert r.returncode == 2 and "exists already" in r.stderr and out.read_text() == before


def test_rig_from_realsense_refuses_bad_arguments(recording, tmp_path):
    path, _ = recording
    r = _run(["-m", "depthguard", "rig", "from-realsense", "--file", str(tmp_path / "none.db3"),
              "--out", str(tmp_path / "a.yaml")])
    assert r.returncode == 2 and "recording not found" in r.stderr
    r = _run(["-m", "depthguard", "rig", "from-realsense", "--file", str(path), "--id", "a", "--id", "b",
              "--out", str(tmp_path / "b.yaml")])
    assert r.returncode == 2 and "--id given 2 times for 1 camera" in r.stderr
    assert not (tmp_path / "a.yaml").exists() and not (tmp_path / "b.yaml").exists()


def test_bench_row_is_measured(recording):
    from depthguard.evaluation.bench import BenchContext
    from depthguard.evaluation.bench.realsense import bench_realsense

    (row,) = bench_realsense(BenchContext(quick=True))
    assert row.name == "realsense.ingest_ms" and math.isfinite(row.value) and row.value > 0
    assert "848x480" in row.note


def test_docs_name_every_scheme_and_command():
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[1] / "docs" / "REALSENSE.md").read_text()
    for word in ("realsense:", "realsense-file:", "rig from-realsense", "libusb-1.0-0",
                 "pip install 'depthguard[realsense]'", "realsense.ingest_ms"):
        assert word in doc, word
