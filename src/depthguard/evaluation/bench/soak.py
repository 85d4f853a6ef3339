"""Bench group ``soak``: a short soak of the distributed mode (R35, :mod:`depthguard.distributed.soak`).

8 simulated units at 30 Hz for 1 minute on loopback (quick mode: 2 units, 10 s), 500
voxels per update, against a server process. The long run (16 units, 10 minutes) is
``depthguard soak``; this row only keeps an eye on regressions.

Rows:

- ``soak.<n>units.lost_pct``: share of the updates sent that the server never stored
  (goal 0 where the CPU keeps up; the note says how many 30 Hz slots were late);
- ``soak.<n>units.refresh_p99_ms``: p99 of the interval between two stored updates of a
  unit (ideal 33.3 ms); the p50 is in the note;
- ``soak.<n>units.server_rss_mb``: the server's resident memory at the end, and its
  growth after the warm-up in the note (a growth over a minute is not a leak verdict:
  the long soak is).

No paper quotes a figure for these.
"""

from __future__ import annotations

from depthguard.evaluation.bench import BenchContext, BenchRow, group


@group("soak")
def soak_rows(ctx: BenchContext) -> list[BenchRow]:
    from depthguard.distributed.soak import run_soak

    units, minutes = (2, 10 / 60) if ctx.quick else (8, 1.0)
    ctx.log(f"soak: {units} units x 30 Hz for {minutes * 60:.0f} s")
    r = run_soak(units, minutes, 30.0, 500, sample_s=5.0, log=ctx.log)
    tag = f"soak.{units}units"
    lost_pct = 100.0 * r["lost"] / max(r["sent"], 1)
    rss = r["rss_mb"]
    return [
        BenchRow(f"{tag}.lost_pct", lost_pct, "%",
                 note=f"{r['lost']} of {r['sent']} updates lost; {r['late_slots']} of {r['slots']} slots late "
                      f"(CPU); {r['cpu_count']} CPUs"),
        BenchRow(f"{tag}.refresh_p99_ms", r["refresh_ms"]["p99"], "ms",
                 note=f"p50 {r['refresh_ms']['p50']:.1f} ms, ideal {r['refresh_ms']['ideal']:.1f} ms; round trip "
                      f"p50 {r['rtt_ms']['p50']:.1f} / p99 {r['rtt_ms']['p99']:.1f} ms"),
        BenchRow(f"{tag}.server_rss_mb", rss[-1][1], "MB",
                 note=f"{rss[0][1]:.1f} MB at start; growth after {r['warmup_s']:.0f} s warm-up "
                      f"{r['rss_growth_pct']:+.1f} %"),
    ]
