"""``depthguard distance`` (offline depth-space distances) and ``depthguard reproduce flacco2014``."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Optional

import typer

from depthguard.cli.app import app
from depthguard.config import PRODUCT_INVALID, PRODUCT_METHOD, PRODUCT_RHO
from depthguard.cli.reproduce import reproduce_app


_HEADER_FIELD = re.compile(r"^[A-Za-z_][A-Za-z0-9_ ()\[\]/-]*$")


def _is_header(fields: list[str]) -> bool:
    """A header names three columns: each field a name (starts with a letter or ``_``, no dots),
    so that no number with a typo (``1.49x``, ``O.0``) passes for one."""
    return len(fields) == 3 and all(_HEADER_FIELD.match(f) for f in fields) and not any(
        f.lower() in ("nan", "inf", "infinity") for f in fields)


def read_points_csv(path: Path) -> "np.ndarray":  # noqa: F821
    """(N, 3) world points (x, y, z metres) from a CSV file: three finite numbers per line,
    separated by ``,`` or ``;``; blank lines and ``#`` comments are skipped.

    The first line with content may be a header of three column names (``x,y,z``,
    ``x [m],y [m],z [m]``); a line with anything number-like in it is data, so a typo in the
    first point (``0.0,0.19,1.49x``) is an error naming the line, never a silently skipped
    header that would shift the indices of every other point. ``FileNotFoundError`` for a
    missing file, ``ValueError`` naming ``file:line`` for anything else.
    """
    import numpy as np

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"points file not found: {p}")
    try:
        text = p.read_text()
    except UnicodeDecodeError:
        raise ValueError(f"{p}: not a text file (expected CSV lines x,y,z in metres)") from None
    rows = []
    first = True
    for k, line in enumerate(text.splitlines(), start=1):
        s = line.split("#", 1)[0].strip()
        if not s:
            continue
        parts = [a.strip() for a in s.replace(";", ",").split(",")]
        was_first, first = first, False
        try:
            vals = [float(a) for a in parts]
        except ValueError:
            if was_first and _is_header(parts):
                continue
            raise ValueError(f"{p}:{k}: expected three numbers x, y, z (or, on the first line, a header "
                             f"of three column names), got {line.strip()!r}") from None
        if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
            raise ValueError(f"{p}:{k}: expected three finite numbers x, y, z, got {line.strip()!r}")
        rows.append(vals)
    if not rows:
        raise ValueError(f"{p}: no points")
    return np.asarray(rows, dtype=np.float64)


def parse_depth_args(items: list[str]) -> dict[str, Path]:
    out: dict[str, Path] = {}
    for it in items:
        cid, sep, f = it.partition("=")
        if not sep or not cid or not f:
            raise ValueError(f"--depth must be CAMERA=FILE (got {it!r})")
        if cid in out:
            raise ValueError(f"--depth given twice for camera {cid!r}")
        out[cid] = Path(f)
    return out


def parse_joints(text: str, robot) -> "np.ndarray":  # noqa: F821
    """``--robot-joints q1,...,qn`` (rad) for ``robot``: ``dof`` finite values inside its joint limits."""
    import numpy as np

    from depthguard.rig import joint_limits_problem

    try:
        q = np.array([float(a) for a in text.replace(" ", "").split(",") if a != ""])
    except ValueError:
        raise ValueError(f"--robot-joints must be comma-separated numbers (got {text!r})") from None
    if q.shape != (robot.dof,) or not np.all(np.isfinite(q)):
        raise ValueError(f"--robot-joints: the robot has {robot.dof} joints, got {q.size} finite values in {text!r}")
    problem = joint_limits_problem(robot, q)
    if problem:
        raise ValueError(f"--robot-joints{problem}")
    return q


#: ``verdict`` of a result row: what the camera says about the point (SPEC §7, R26)
VERDICTS = {
    "obstacle": "an obstacle lies within rho (distance, direction)",
    "clear": "the camera judges the point and sees no obstacle within rho",
    "cannot_judge": "the camera cannot judge the point (outside its image or range): not free",
}


def result_row(cid: str, i: int, point, distance: float, direction, observed: bool, pixels: int) -> dict:
    """One row of ``depthguard distance``'s JSON: "no obstacle within rho" and "cannot judge"
    are different values (SPEC §7, R26).

    ``verdict`` is ``"obstacle"`` (observed, finite distance), ``"clear"`` (observed, nothing
    within rho) or ``"cannot_judge"`` (not observed). ``obstacle_within_rho`` is ``true`` when an
    obstacle is seen within rho (for an unobserved point the distance then covers only what the
    camera sees: a nearer obstacle may hide from it), ``false`` only when the camera judges
    the point and sees none, ``null`` when it cannot judge the point and sees none.
    """
    finite = math.isfinite(distance)
    if observed:
        verdict = "obstacle" if finite else "clear"
        within = finite
    else:
        verdict = "cannot_judge"
        within = True if finite else None
    return {"camera": cid, "point": i, "x": float(point[0]), "y": float(point[1]), "z": float(point[2]),
            "verdict": verdict, "distance": distance if finite else None, "obstacle_within_rho": within,
            "direction": [float(a) for a in direction], "observed": bool(observed), "pixels": int(pixels)}


def _distance_cell(o: dict) -> str:
    if o["verdict"] == "clear":
        return "none within rho"
    if o["verdict"] == "obstacle":
        return f"{o['distance']:.4f}"
    if o["distance"] is None:
        return "cannot judge"
    return f"<= {o['distance']:.4f} (cannot judge)"


@app.command("distance")
def distance_cmd(
    rig: Path = typer.Option(..., "--rig", help="Rig file (YAML) with the cameras (and the robot)."),
    depth: list[str] = typer.Option(..., "--depth", metavar="CAMERA=FILE",
                                    help="Depth image of a rig camera (16-bit mm PNG or float32 m .npy); repeatable."),
    points: Path = typer.Option(..., "--points", help="CSV of control points x,y,z in world metres; the first line "
                                "may be a header of three column names."),
    robot_joints: Optional[str] = typer.Option(None, "--robot-joints", metavar="Q1,...,QN",
                                               help="Remove the rig's robot at these joints, rad, inside its limits (R9)."),
    rho: float = typer.Option(PRODUCT_RHO, "--rho", help="Radius of surveillance, metres."),
    method: str = typer.Option(PRODUCT_METHOD, "--method", help="min | mean | hybrid (R7)."),
    invalid: str = typer.Option(PRODUCT_INVALID, "--invalid", help="Invalid pixels: unknown (safe, R28) | free."),
    robot_mode: str = typer.Option("drop", "--robot-mode", help="Robot pixels: drop (default) | shadow (obstacle behind the robot)."),
    accept_out_of_range: bool = typer.Option(False, "--accept-out-of-range",
                                             help="Use an image whose measured pixels mostly lie outside the "
                                             "camera's range as it is (by default that is an error: wrong units)."),
    json_out: bool = typer.Option(False, "--json", help="Print JSON instead of a table."),
) -> None:
    """Depth-space distance from control points to what each camera sees (Flacco 2014, R3-R9).

    One row per camera and point, with a verdict: obstacle (distance in m and the
    unit direction towards it, world frame), clear ("none within rho": the camera
    judges the point and sees nothing within rho) or cannot judge (the point lies
    outside the camera's image or range; never read it as free, R26). JSON: "verdict"
    is "obstacle" | "clear" | "cannot_judge"; "obstacle_within_rho" is true | false | null
    (null: cannot judge). An image whose measured pixels mostly lie outside the camera's
    range (millimetres in an .npy, metres in a PNG) is refused unless
    --accept-out-of-range.
    """
    from depthguard.depth_io import depth_units_problem, read_depth
    from depthguard.distance import depth_space_distance
    from depthguard.distance.api import check_rho
    from depthguard.rig import Rig

    check_rho(rho)
    if method not in ("min", "mean", "hybrid"):
        raise ValueError(f"--method must be min, mean or hybrid (got {method!r})")
    if invalid not in ("unknown", "free"):
        raise ValueError(f"--invalid must be unknown or free (got {invalid!r})")
    if robot_mode not in ("drop", "shadow"):
        raise ValueError(f"--robot-mode must be drop or shadow (got {robot_mode!r})")
    r = Rig.load(rig)
    files = parse_depth_args(depth)
    P = read_points_csv(points)
    q = None
    if robot_joints is not None:
        if r.robot is None:
            raise ValueError(f"--robot-joints given but rig {rig} has no robot")
        q = parse_joints(robot_joints, r.robot)
    cams = {}
    for cid in files:
        try:
            cams[cid] = r.camera(cid)
        except (KeyError, ValueError):
            raise ValueError(f"--depth: rig {rig} has no camera {cid!r} "
                             f"(cameras: {', '.join(c.id for c in r.cameras)})") from None
    images = {}
    for cid, f in files.items():
        img = read_depth(f)
        cam = cams[cid]
        if img.shape != (cam.height, cam.width):
            raise ValueError(f"--depth {cid}={f}: the image is {img.shape[1]}x{img.shape[0]}, camera {cid} "
                             f"is {cam.width}x{cam.height}")
        units = depth_units_problem(img, cam)
        if units and not accept_out_of_range:
            raise ValueError(f"--depth {cid}={f}: {units} (--accept-out-of-range uses it as it is)")
        images[cid] = img
    out = []
    for cid, img in images.items():
        cam = cams[cid]
        rd = None
        if q is not None:
            from depthguard.distance.self_removal import robot_depth
            rd = robot_depth(cam, r.robot, q)
        res = depth_space_distance(cam, img, P, rho=rho, method=method, robot_depth=rd,
                                   invalid=invalid, robot_mode=robot_mode)
        for i in range(len(P)):
            out.append(result_row(cid, i, P[i], float(res.distance[i]), res.direction[i], bool(res.observed[i]),
                                  int(res.count[i])))
    if json_out:
        typer.echo(json.dumps({"rho": rho, "method": method, "invalid": invalid, "verdicts": VERDICTS,
                               "results": out}, indent=2))
        return
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"depth-space distance, {method}, rho = {rho} m",
              caption="none within rho: judged, nothing within rho; cannot judge: outside the camera's image or "
                      "range (not free, R26)")
    for c in ("camera", "point", "x", "y", "z", "distance [m]", "direction", "observed", "pixels"):
        t.add_column(c)
    for o in out:
        t.add_row(o["camera"], str(o["point"]), f"{o['x']:.3f}", f"{o['y']:.3f}", f"{o['z']:.3f}", _distance_cell(o),
                  "(" + ", ".join(f"{a:+.3f}" for a in o["direction"]) + ")",
                  "yes" if o["observed"] else "no", str(o["pixels"]))
    Console(width=140).print(t)


@reproduce_app.command("flacco2014")
def flacco2014_cmd(
    out: Path = typer.Option(Path("out/flacco2014"), "--out", help="Output directory for figures, table and summary."),
    steps: int = typer.Option(201, "--steps", min=2, help="Steps of the sweep x in [-0.5, 0.5]."),
    noiseless: bool = typer.Option(False, "--noiseless", help="Ideal depth instead of the Kinect noise model."),
    seed: int = typer.Option(0, "--seed", help="Seed of the sensor noise."),
    invalid: str = typer.Option("free", "--invalid", help="Invalid pixels: free (as the paper) | unknown (R28 default)."),
) -> None:
    """Flacco et al. 2014 sec. 4 on the flacco-walls cell: Cartesian vs depth-space min/mean/hybrid.

    Writes figs. 7-11 (distance and unit-vector components along the sweep per method,
    execution times on a log scale), table.csv, summary.json and summary.md, and prints
    whether the paper's three claims hold.
    """
    from depthguard.evaluation.flacco2014 import run_flacco2014, summary_markdown, write_flacco2014

    if invalid not in ("free", "unknown"):
        raise ValueError(f"--invalid must be free or unknown (got {invalid!r})")
    from depthguard.cli.common import check_output_dir

    check_output_dir(out)      # before any work is done
    res = run_flacco2014(steps=steps, noiseless=noiseless, seed=seed, invalid=invalid, quiet=False)
    files = write_flacco2014(res, out)
    typer.echo(summary_markdown(res))
    typer.echo(f"wrote {len(files)} files to {out}")
    S = res.summary
    if not (S["claim_min"] and S["claim_cartesian"] and S["claim_continuity"]):
        typer.echo("warning: not every claim of the paper holds in this run (see summary.md)", err=True)
