"""The soak harness (R35): a short run of the ``soak`` bench group, quick mode (2 units, 10 s).

Truth: the units count what they sent and the server process counts what it stored (two
processes, two counters); the refresh interval is compared with the 30 Hz period."""

import math

import pytest


@pytest.mark.multiprocess
@pytest.mark.slow
@pytest.mark.timeout(120)
def test_short_soak_row():
    from depthguard.evaluation.bench import BenchContext, load_groups

    rows = {r.name: r for r in load_groups()["soak"](BenchContext(quick=True))}
    assert set(rows) == {"soak.2units.lost_pct", "soak.2units.refresh_p99_ms", "soak.2units.server_rss_mb"}
    assert rows["soak.2units.lost_pct"].value == 0.0, rows["soak.2units.lost_pct"].note
    # the median interval between two stored updates of a unit is the 30 Hz period
    p50 = float(rows["soak.2units.refresh_p99_ms"].note.split("p50 ")[1].split(" ms")[0])
    assert abs(p50 - 1000 / 30) < 5.0
    assert 10.0 < rows["soak.2units.server_rss_mb"].value < 2000.0 and math.isfinite(rows["soak.2units.refresh_p99_ms"].value)
