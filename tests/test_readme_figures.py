"""A speed the README states is one a user can reproduce (issue 33 item 11: "bags replay at about
11x real time" was the reader alone, the monitor's replay of a 10 s bag took 26 s).

Speed is never asserted in tests (it is measured by ``depthguard bench``); what is checked here is
the README's text against the program: each "N× real time" figure names the ``depthguard bench
--only GROUP`` that measures it, GROUP is a benchmark group the program has, and the bag replay a
user runs (``monitor --fast`` on a bag) has its own figure beside the reader's.
"""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def _sentences(text: str) -> list[str]:
    flat = " ".join(text.split())
    return re.split(r"(?<=[.;:])\s+(?=[A-Z(`])", flat)


def test_every_times_real_time_figure_names_the_bench_group_that_measures_it():
    from depthguard.evaluation.bench import load_groups

    groups = set(load_groups())
    figures = [s for s in _sentences(README.read_text()) if re.search(r"\d+(\.\d+)?\s*[×x] real time", s)]
    assert figures, "the README states no replay speed: this test has nothing to check"
    for s in figures:
        named = re.findall(r"depthguard bench --only (\w+)", s)
        assert named, f"README: a speed without the command that measures it: {s!r}"
        assert set(named) <= groups, (named, sorted(groups))


def test_the_bag_replay_a_user_runs_has_its_own_figure_beside_the_readers():
    text = " ".join(README.read_text().split())
    reader = text.index("the reader alone")
    part = text[reader:reader + 600]
    assert "--fast" in part and re.search(r"\d+(\.\d+)? s of CPU", part) and "of real time" in part, part
