"""``depthguard distance`` (offline depth-space distances) and ``depthguard reproduce flacco2014``."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Optional

import typer

from depthguard.cli.app import app
from depthguard.cli.reproduce import reproduce_app


def read_points_csv(path: Path) -> "np.ndarray":  # noqa: F821
    """(N, 3) world points from a CSV file: three numbers per line (x, y, z metres);
    an optional header line, blank lines and ``#`` comments are skipped."""
    import numpy as np

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"points file not found: {p}")
    rows = []
    for k, line in enumerate(p.read_text().splitlines(), start=1):
        s = line.split("#", 1)[0].strip()
        if not s:
            continue
        parts = [a.strip() for a in s.replace(";", ",").split(",") if a.strip()]
        try:
            vals = [float(a) for a in parts]
        except ValueError:
            if not rows and k == 1:           # header
                continue
            raise ValueError(f"{p}:{k}: expected three numbers x, y, z, got {line.strip()!r}") from None
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


def parse_joints(text: str, dof: int) -> "np.ndarray":  # noqa: F821
    import numpy as np

    try:
        q = np.array([float(a) for a in text.replace(" ", "").split(",") if a != ""])
    except ValueError:
        raise ValueError(f"--robot-joints must be comma-separated numbers (got {text!r})") from None
    if q.shape != (dof,) or not np.all(np.isfinite(q)):
        raise ValueError(f"--robot-joints: the robot has {dof} joints, got {q.size} finite values in {text!r}")
    return q


@app.command("distance")
def distance_cmd(
    rig: Path = typer.Option(..., "--rig", help="Rig file (YAML) with the cameras (and the robot)."),
    depth: list[str] = typer.Option(..., "--depth", help="CAMERA=FILE depth image (16-bit mm PNG or float32 m .npy); repeatable."),
    points: Path = typer.Option(..., "--points", help="CSV of control points x,y,z in world metres (optional header)."),
    robot_joints: Optional[str] = typer.Option(None, "--robot-joints", help="q1,q2,...: remove the rig's robot at these joints (R9)."),
    rho: float = typer.Option(0.4, "--rho", help="Radius of surveillance, metres."),
    method: str = typer.Option("hybrid", "--method", help="min | mean | hybrid (R7)."),
    invalid: str = typer.Option("unknown", "--invalid", help="Invalid pixels: unknown (safe, R28) | free."),
    robot_mode: str = typer.Option("drop", "--robot-mode", help="Robot pixels: drop (default) | shadow (obstacle behind the robot)."),
    json_out: bool = typer.Option(False, "--json", help="Print JSON instead of a table."),
) -> None:
    """Depth-space distance from control points to what each camera sees (Flacco 2014, R3-R9).

    One row per camera and point: distance (m; "none within rho" when no obstacle
    lies within rho), unit direction towards the obstacle (world), and whether
    the camera can judge the point at all (observed).
    """
    import numpy as np

    from depthguard.depth_io import read_depth
    from depthguard.distance import depth_space_distance
    from depthguard.distance.api import check_rho
    from depthguard.rig import Rig

    check_rho(rho)
    if method not in ("min", "mean", "hybrid"):
        raise ValueError(f"--method must be min, mean or hybrid (got {method!r})")
    r = Rig.load(rig)
    files = parse_depth_args(depth)
    P = read_points_csv(points)
    q = None
    if robot_joints is not None:
        if r.robot is None:
            raise ValueError(f"--robot-joints given but rig {rig} has no robot")
        q = parse_joints(robot_joints, r.robot.dof)
    out = []
    for cid, f in files.items():
        try:
            cam = r.camera(cid)
        except (KeyError, ValueError):
            raise ValueError(f"--depth: rig {rig} has no camera {cid!r} "
                             f"(cameras: {', '.join(c.id for c in r.cameras)})") from None
        img = read_depth(f)
        rd = None
        if q is not None:
            from depthguard.distance.self_removal import robot_depth
            rd = robot_depth(cam, r.robot, q)
        res = depth_space_distance(cam, img, P, rho=rho, method=method, robot_depth=rd,
                                   invalid=invalid, robot_mode=robot_mode)
        for i in range(len(P)):
            D = float(res.distance[i])
            out.append({"camera": cid, "point": i, "x": float(P[i, 0]), "y": float(P[i, 1]), "z": float(P[i, 2]),
                        "distance": D if math.isfinite(D) else None,
                        "obstacle_within_rho": bool(math.isfinite(D)),
                        "direction": [float(a) for a in res.direction[i]],
                        "observed": bool(res.observed[i]), "pixels": int(res.count[i])})
    if json_out:
        typer.echo(json.dumps({"rho": rho, "method": method, "invalid": invalid, "results": out}, indent=2))
        return
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"depth-space distance, {method}, rho = {rho} m")
    for c in ("camera", "point", "x", "y", "z", "distance [m]", "direction", "observed", "pixels"):
        t.add_column(c)
    for o in out:
        d = f"{o['distance']:.4f}" if o["distance"] is not None else "none within rho"
        t.add_row(o["camera"], str(o["point"]), f"{o['x']:.3f}", f"{o['y']:.3f}", f"{o['z']:.3f}", d,
                  "(" + ", ".join(f"{a:+.3f}" for a in o["direction"]) + ")",
                  "yes" if o["observed"] else "NO (cannot judge)", str(o["pixels"]))
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
    res = run_flacco2014(steps=steps, noiseless=noiseless, seed=seed, invalid=invalid, quiet=False)
    files = write_flacco2014(res, out)
    typer.echo(summary_markdown(res))
    typer.echo(f"wrote {len(files)} files to {out}")
    S = res.summary
    if not (S["claim_min"] and S["claim_cartesian"] and S["claim_continuity"]):
        typer.echo("warning: not every claim of the paper holds in this run (see summary.md)", err=True)
