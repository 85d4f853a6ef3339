"""``depthguard rig learn-scene``: a cell without CAD learns its static scene from its cameras (issue 31).

The frames come from any frame source of ``depthguard monitor`` (default: the
simulator of the cell with no person, ``sim:CELL:alone``), the joints from its
joint source (the robot may move: it is removed at each frame's capture joints).
The result is a folder (``scene.json`` and one ``.npz`` per camera,
:mod:`depthguard.learned_scene`) that a rig names with ``scene: {learned: DIR}``.
Learning again is this command again, with ``--replace``: a scene is never
updated behind the user's back (the monitor reports a changed cell instead).
"""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from depthguard.cli.app import rig_app
from depthguard.cli.common import check_output_dir, load_rig_or_cell


@rig_app.command("learn-scene")
def learn_scene(
    out: Path = typer.Option(..., "--out", "-o", help="Folder to write the learned scene to (scene.json, <camera>.npz)."),
    rig: Optional[Path] = typer.Option(None, "--rig", help="Rig file of the cell."),
    cell: Optional[str] = typer.Option(None, "--cell", help="A built-in cell instead of --rig."),
    source: List[str] = typer.Option([], "--source", help="Frame source SCHEME:ARG as for depthguard monitor (default: the simulator of the cell with nobody in it, sim:CELL:alone)."),
    joints: Optional[str] = typer.Option(None, "--joints", help="Joint source as for depthguard monitor (default: sim with a sim source, the bag with a bag: source)."),
    duration: float = typer.Option(10.0, "--duration", help="Seconds of frames to learn from (the sources' own clock)."),
    max_frames: int = typer.Option(64, "--max-frames", help="Frames kept per camera for the median (spread over the whole duration)."),
    replace: bool = typer.Option(False, "--replace", help="Relearn: overwrite a learned scene already in --out."),
) -> None:
    """Learn the cell's static scene from its cameras, with nobody in the cell (the robot may move).

    Per camera and pixel: the median depth over the frames where the robot was not in front of it
    and its noise band (sensor model and observed spread); pixels that never returned or that the
    robot always hid stay unknown. With CAD objects in the rig, the learned scene is compared with
    the CAD's expected depth (share of the CAD's pixels within the band).
    """
    from depthguard.filtering.scene_learner import base_silhouette, compare_with_cad, learn_from_sources
    from depthguard.learned_scene import save
    from depthguard.progress import log, track
    from depthguard.sources.base import check_source_spec, open_joints, open_source

    if not duration > 0:
        raise typer.BadParameter("must be > 0 seconds", param_hint="--duration")
    if max_frames < 4:
        raise typer.BadParameter("must be >= 4", param_hint="--max-frames")
    the_rig, the_cell = load_rig_or_cell(rig, cell)
    if (Path(out) / "scene.json").exists() and not replace:
        raise ValueError(f"--out {out}: holds a learned scene already; relearning is explicit: add --replace")
    check_output_dir(out)
    name = the_cell.name if the_cell is not None else ""
    specs = list(source) or [f"sim:{name}:alone" if name else "sim::alone"]
    schemes = [check_source_spec(s)[0] for s in specs]
    if len(specs) != 1:
        raise typer.BadParameter("give one --source (it delivers every camera's frames)", param_hint="--source")
    joint_spec = joints or ("sim" if "sim" in schemes else None) or next((s for s in specs if s.startswith("bag:")), None)
    if joint_spec is None and the_rig.robot is not None:
        raise typer.BadParameter("a non-simulated source needs --joints (the robot is removed at the frames' joints)",
                                 param_hint="--joints")
    context: dict = {}
    frames = joint_source = None
    try:
        frames = open_source(specs[0], the_rig, context)
        joint_source = open_joints(joint_spec, the_rig, context) if joint_spec else None
        log(f"learn-scene: {duration:g} s of {specs[0]} (joints {joint_spec}), cameras {', '.join(the_rig.camera_ids)}")
        scenes, info = learn_from_sources(the_rig, frames, joint_source, duration, max_frames=max_frames,
                                          progress=lambda it, total: track(it, "learning the scene", total))
    finally:
        for s in (frames, joint_source):
            if s is not None and hasattr(s, "close"):
                s.close()
    save(out, scenes, {"source": specs[0], "joints": joint_spec, "duration_s": duration,
                       "rig": str(rig) if rig else name, "frames": info["frames"]})
    cad = the_rig.static_meshes()
    for cid, sc in scenes.items():
        line = (f"{cid}: {info['frames'][cid]} frames ({info['frames_kept'][cid]} kept), "
                f"{100 * sc.known.mean():.1f} % of the pixels learned")
        if cad:
            from depthguard.filtering.expected import ExpectedDepth
            cam = the_rig.camera(cid)
            r = compare_with_cad(cam, sc, ExpectedDepth(cam, None, cad).static, info["hidden"][cid],
                                 base_silhouette(cam, the_rig.robot))
            line += (f"; CAD reproduced within the band on {100 * r['share']:.2f} % of its {r['cad_pixels']} "
                     f"pixels in range, {100 * r['share_outside_base']:.2f} % of the "
                     f"{r['cad_pixels'] - r['base_pixels']} outside the robot's base (rest: "
                     f"{r['behind_base']} behind the base, never observable; {r['behind_arm']} behind the moving "
                     f"arm in every kept frame; {r['no_return']} too few returns; {r['edge']} on depth edges; "
                     f"{r['off']} off)")
        typer.echo(line)
    if info["skipped_without_joints"]:
        typer.echo(f"{info['skipped_without_joints']} frames skipped: no joint states at their capture")
    typer.echo(f"wrote {out}: name it in the rig as  scene: {{learned: {out}}}")


def _reproduce_app():
    from depthguard.cli.reproduce import reproduce_app
    return reproduce_app


@_reproduce_app().command("learned-scene")
def learned_scene_cmd(
    cell: List[str] = typer.Option([], "--cell", help="A built-in cell (repeatable; default: flacco-cell and ur3-cell)."),
    duration: float = typer.Option(10.0, "--duration", help="Seconds of simulated frames to learn from (nobody in the cell, the robot moving)."),
    scale: int = typer.Option(1, "--scale", help="Cameras at 1/SCALE of their pixels per side (1: full resolution)."),
    scenario: List[str] = typer.Option([], "--scenario", "-s", help="A closed-loop scenario for the SSM table (repeatable; flacco-cell only; none: no SSM runs, they take minutes each)."),
    out: Optional[Path] = typer.Option(None, "--out", help="Folder for table.md and learned_scene.json."),
) -> None:
    """The learned scene against the CAD on the built-in cells (issue 31): learn the scene from
    DURATION s of simulated frames, then ask the rig with its CAD and the rig with the learned
    scene in its place the same questions — the CAD's pixels the learned scene reproduces within
    its band (the rest named: behind the robot's base, behind the moving arm, no return, edges),
    the per-camera filter's classification, the calibration check's and the drift watch's verdicts
    (at the rig pose and bumped by 2 degrees), SSM with the known scene muted — and print the tables.
    """
    import json

    from depthguard.evaluation.learned_scene import evaluate, report
    from depthguard.progress import track
    from depthguard.sim.cells import CELL_NAMES

    cells = list(cell) or ["flacco-cell", "ur3-cell"]
    for c in cells:
        if c not in CELL_NAMES:
            raise typer.BadParameter(f"unknown cell {c!r}; built-in cells: {', '.join(CELL_NAMES)}", param_hint="--cell")
    if not duration > 0:
        raise typer.BadParameter("must be > 0 seconds", param_hint="--duration")
    if not 1 <= scale <= 8:
        raise typer.BadParameter("must be 1 to 8", param_hint="--scale")
    if scenario and cells != ["flacco-cell"]:
        raise typer.BadParameter("the closed-loop scenarios run on flacco-cell: give --cell flacco-cell",
                                 param_hint="--scenario")
    if out is not None:
        check_output_dir(out)
    results, text = [], []
    for c in cells:
        res = evaluate(c, duration=duration, scale=scale, scenarios=tuple(scenario),
                       progress=lambda it, total, label="learning the scene": track(it, label, total))
        results.append(res)
        text.append(report(res))
        typer.echo(text[-1])
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        (Path(out) / "table.md").write_text("\n".join(text))
        (Path(out) / "learned_scene.json").write_text(json.dumps(results, indent=1, default=float))
        typer.echo(f"wrote {out}/table.md, {out}/learned_scene.json")
