"""``depthguard reproduce ssm``: repulsion vs speed and separation monitoring on every built-in
scenario (R33): a markdown table of productivity, true separation, stops and SSM violations."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from depthguard.cli.reproduce import reproduce_app


@reproduce_app.command("ssm")
def ssm_cmd(
    out: Path = typer.Option(Path("out/ssm"), "--out", help="Folder for table.md, ssm_compare.json and each run's summary.json."),
    scenario: Optional[list[str]] = typer.Option(None, "--scenario", "-s", help="A scenario (repeatable; default: every built-in one)."),
    reaction: Optional[list[str]] = typer.Option(None, "--reaction", help="repulsion, ssm or both (repeatable; default: all three)."),
    ssm_range: float = typer.Option(0.8, "--range", help="How far (m) the distances are looked for in ssm and both modes (ssm.range)."),
    known_scene: str = typer.Option("obstacle", "--known-scene", help="obstacle (default) or muted: SSM measures the separation from what is not the known static scene (ssm.known_scene, docs/SSM.md)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the cameras' noise."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress output."),
) -> None:
    """Run every closed-loop scenario on flacco-cell with the repulsion (R13, R14), speed and
    separation monitoring (ISO/TS 15066 formula 1, R33) and both, and write OUT/table.md:
    task progress (productivity), minimum true separation, protective stops, time stopped and
    the ground truth's SSM violations (0 expected). Not a safety-rated function: docs/SSM.md.
    """
    from depthguard.control.ssm_config import SSMConfig
    from depthguard.evaluation.ssm_compare import MODES, compare, table
    from depthguard.progress import track

    modes = tuple(reaction) if reaction else MODES
    for md in modes:
        if md not in MODES:
            raise typer.BadParameter(f"must be one of {', '.join(MODES)} (got {md!r})", param_hint="--reaction")
    if known_scene not in ("obstacle", "muted"):
        raise typer.BadParameter(f"must be obstacle or muted (got {known_scene!r})", param_hint="--known-scene")
    if not (0.0 < ssm_range <= 10.0):
        raise typer.BadParameter("must be > 0 and <= 10 m", param_hint="--range")
    if out.exists() and not out.is_dir():
        raise typer.BadParameter(f"{out} exists and is not a folder", param_hint="--out")

    def progress(it, total, label):
        return track(it, label, total=total, quiet=quiet)

    rows = compare(scenarios=scenario or None, modes=modes, ssm=SSMConfig(range=ssm_range, known_scene=known_scene), progress=progress,
                   seed=seed, out=out)
    md_text = table(rows)
    (out / "table.md").write_text(md_text)
    typer.echo(md_text)
    bad = [r for r in rows if r["ssm_violations"]]
    typer.echo(f"wrote {out}/table.md; SSM violations: " +
               ("none" if not bad else ", ".join(f"{r['scenario']}/{r['reaction']} {r['ssm_violations']}" for r in bad)))
