"""Sinks by scheme (runtime.sink_specs): a sink added as one module (tests/example_sink.py) runs in
``depthguard monitor --sink`` beside the built-in ones without an edit of the runtime or the CLI.

Truth: the run's own log.jsonl, written by the built-in jsonl sink from the same reactions.
"""

from __future__ import annotations

import json

from typer.testing import CliRunner

import example_sink  # noqa: F401  (registers csv-scale)
from depthguard.cli import app


def test_a_sink_module_receives_every_reaction_of_a_monitor_run(tmp_path):
    out, csv = tmp_path / "run", tmp_path / "scale.csv"
    res = CliRunner().invoke(app, ["monitor", "--fast", "--duration", "0.3", "-q", "--out", str(out),
                                   "--sink", f"csv-scale:{csv}"])
    assert res.exit_code == 0, res.output
    log = [json.loads(x) for x in (out / "log.jsonl").read_text().splitlines()]
    rows = csv.read_text().splitlines()
    assert rows[0] == "t,speed_scale,override" and len(rows) - 1 == len(log) > 100
    for row, rec in zip(rows[1:], log):
        t, s, k = (float(x) for x in row.split(","))
        assert abs(t - rec["t"]) < 1e-6 and abs(s - rec["speed_scale"]) < 1e-6 and abs(k - rec["override"]) < 1e-6


def test_bad_sink_specs_are_usage_errors_before_anything_opens(tmp_path):
    runner = CliRunner()
    for spec, words in (("nope:x", "unknown scheme 'nope'"), ("view:99999", "0 to 65535"),
                        ("view:host:port", "must be a number")):
        res = runner.invoke(app, ["monitor", "--fast", "--duration", "0.1", "-q", "--out", str(tmp_path / spec[:4]),
                                  "--sink", spec], env={"COLUMNS": "200"})
        assert res.exit_code == 2 and words in res.output and "Traceback" not in res.output, (spec, res.output)
