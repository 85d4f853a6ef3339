"""Reproduction of Flacco & De Luca 2015 (figs. 8/12, 9/13) on the built-in ``flacco-cell``.

Three situations of the cell's scene, the LWR's 9 control points, ``rho = 0.4``:

* ``shadow`` — a person between the principal camera (cam0) and the robot.
  One camera (the paper's one-camera method, :func:`depthguard.distance.depth_space_distance`,
  robot pixels dropped): small distances to the person's gray area. Two
  cameras (depth grid): the shadow is cleared by cam1.
* ``hidden_hand`` — a hand right behind the robot as seen from cam0. One
  camera: missed. Two cameras: found, near the ground truth.
* ``robot_alone`` — no obstacle but the static table: no self distance.

Two-camera rows are given for both treatments of robot pixels in cam1
(``robot_in_others``): ``"unknown"`` (SPEC R9, default: unknown behind the
robot, so space hidden by the robot from cam1 *and* by the person from cam0
stays obstacle) and ``"free"`` (the paper's removal). The simulated cell has
no walls: rays that leave it read 0, taken as free (``invalid="free"``, R28).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["SITUATIONS", "SituationResult", "run_flacco2015", "grid_for_rig", "write_outputs"]

SITUATIONS = ("shadow", "hidden_hand", "robot_alone")
#: the paper's settings (Flacco 2015 §VIII), which this reproduction keeps whatever the product's
#: defaults (MonitorConfig) become
PAPER_RHO = 0.4            # m, radius of surveillance
PAPER_DELTA_D = 0.01       # m, the grid's depth slice


@dataclass
class SituationResult:
    name: str
    description: str
    points: np.ndarray            # (9, 3) control points, world
    names: list[str]
    truth: np.ndarray             # (9,) exact distance to the nearest non-robot surface
    one: np.ndarray               # (9,) one camera (cam0), paper's method
    one_dir: np.ndarray
    two: np.ndarray               # (9,) depth grid, robot_in_others="unknown" (R9)
    two_dir: np.ndarray
    two_paper: np.ndarray         # (9,) depth grid, robot_in_others="free" (paper)
    two_paper_dir: np.ndarray
    depth0: np.ndarray = field(repr=False)
    eps: np.ndarray = field(repr=False, default=None)   # (9,) discretisation bound


def grid_for_rig(rig, principal: str = "cam0", delta_d: float = PAPER_DELTA_D, cache_dir=None, quiet=True):
    """A :class:`DepthGridMap` whose slices span the workspace box as seen by the principal."""
    from depthguard.fusion.depth_grid import DepthGridMap

    cam = rig.camera(principal)
    lo, hi = np.asarray(rig.workspace.lo), np.asarray(rig.workspace.hi)
    C = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    z = cam.world_to_camera(C)[:, 2]
    d_min = max(cam.min_range, float(np.floor(z.min() / delta_d) * delta_d))
    d_max = min(cam.max_range, float(np.ceil(z.max() / delta_d) * delta_d))
    return DepthGridMap(rig.cameras, principal, d_min, d_max, delta_d, cache_dir, quiet=quiet)


def discretisation_bound(cam, points, rho: float, delta_d: float) -> np.ndarray:
    """(N,) metres: 2 pixel-footprint diagonals plus a cell diagonal at depth ``dp + rho``
    (the tolerance of reported vs true distance, R25)."""
    d = cam.world_to_camera(points)[:, 2] + rho
    pix = d * np.hypot(1 / cam.fx, 1 / cam.fy)
    return 2 * pix + np.sqrt(pix ** 2 + delta_d ** 2)


def run_flacco2015(rho: float = PAPER_RHO, padding: float = 0.05, delta_d: float = PAPER_DELTA_D, cache_dir=None,
                   situations=SITUATIONS, quiet: bool = True) -> dict[str, SituationResult]:
    """Run the three situations; returns ``{name: SituationResult}``."""
    from depthguard.distance import depth_space_distance
    from depthguard.distance.self_removal import robot_depth
    from depthguard.progress import track
    from depthguard.render import render_depth
    from depthguard.sim import load_cell

    cell = load_cell("flacco-cell")
    rig, robot = cell.rig, cell.robot
    cams = rig.cameras
    grid = grid_for_rig(rig, "cam0", delta_d, cache_dir, quiet)
    out = {}
    for name in track(list(situations), "flacco2015 situations", quiet=quiet):
        scene, t = cell.scene_for(name)
        q = scene.robot_q(t)
        meshes, _ = scene.meshes_at(t, robot=True)
        depths = {c.id: render_depth(c, meshes) for c in cams}
        rds = {c.id: robot_depth(c, robot, q) for c in cams}
        P = robot.control_point_positions(q)
        caps = robot.collision_capsules(q, padding)
        one = depth_space_distance(cams[0], depths["cam0"], P, rho, "min", robot_depth=rds["cam0"],
                                   invalid="free")
        reach = grid.robot_reach(caps, rho, 0.05)      # the control points lie in the capsules
        two = grid.distance(depths, P, rho, "min", rds, robot_capsules=caps, invalid="free", reach=reach)
        twop = grid.distance(depths, P, rho, "min", rds, robot_capsules=caps, invalid="free",
                             robot_in_others="free", reach=reach)
        out[name] = SituationResult(
            name, cell.situations[name].description, P, [c.name for c in robot.control_points],
            scene.true_distance(P, t), one.distance, one.direction, two.distance, two.direction,
            twop.distance, twop.direction, depths["cam0"],
            discretisation_bound(cams[0], P, rho, delta_d))
    return out


def table(results: dict[str, SituationResult], rho: float = PAPER_RHO) -> str:
    """Markdown table: per situation and control point, truth and the three estimates."""
    def f(x):
        return "—" if not np.isfinite(x) else f"{x:.3f}"
    lines = ["| situation | point | truth (m) | 1 camera | 2 cameras (R9) | 2 cameras (paper) |",
             "|---|---|---|---|---|---|"]
    for r in results.values():
        for i, n in enumerate(r.names):
            lines.append(f"| {r.name} | {n} | {f(r.truth[i])} | {f(r.one[i])} | {f(r.two[i])} | "
                         f"{f(r.two_paper[i])} |")
    lines.append(f"\n— = no obstacle within rho = {rho} m. 1 camera: cam0 alone, the paper's one-camera "
                 "method (robot pixels dropped). 2 cameras: depth grid, principal cam0; (R9) robot "
                 "pixels of cam1 are unknown behind the robot, (paper) they confirm nothing. Rays that "
                 "leave the wall-less cell (depth 0) count as free (R28 policy 'free').")
    return "\n".join(lines)


def write_outputs(results: dict[str, SituationResult], out: Path, rig=None) -> list[Path]:
    """Plots (cam0 view with distance lines; distances per control point) and ``table.md``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from depthguard.sim import load_cell

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cam = (rig or load_cell("flacco-cell").rig).camera("cam0")
    files = []
    for r in results.values():
        fig, axes = plt.subplots(1, 2, figsize=(13, 4.8))
        ax = axes[0]
        img = np.where(r.depth0 > 0, r.depth0, np.nan)
        ax.imshow(img, cmap="gray_r")
        for D, V, col, lab in ((r.one, r.one_dir, "tab:red", "1 camera"),
                               (r.two, r.two_dir, "tab:blue", "2 cameras (R9)"),
                               (r.two_paper, r.two_paper_dir, "tab:green", "2 cameras (paper)")):
            first = True
            for p, d, v in zip(r.points, D, V):
                if not np.isfinite(d):
                    continue
                a = cam.world_to_depth_space(p)[0]
                b = cam.world_to_depth_space(p + d * v)[0]
                ax.plot([a[0], b[0]], [a[1], b[1]], color=col, lw=1.5, label=lab if first else None)
                first = False
        uv = cam.world_to_depth_space(r.points)
        ax.plot(uv[:, 0], uv[:, 1], "o", color="orange", ms=4, label="control points")
        ax.set_title(f"{r.name}: cam0 view, distance lines")
        ax.legend(loc="lower right", fontsize=7)
        ax.set_axis_off()
        ax = axes[1]
        x = np.arange(len(r.names))
        cap = 0.45
        for D, mk, lab in ((r.truth, "k_", "truth"), (r.one, "rv", "1 camera"),
                           (r.two, "bs", "2 cameras (R9)"), (r.two_paper, "g^", "2 cameras (paper)")):
            ax.plot(x, np.where(np.isfinite(D), np.minimum(D, cap), cap), mk, ms=9, label=lab)
        ax.axhline(0.4, color="gray", ls=":", lw=1)
        ax.text(0, 0.405, "rho (nothing within rho plotted at the top)", fontsize=7, color="gray")
        ax.set_xticks(x, r.names, rotation=45, ha="right", fontsize=7)
        ax.set_ylabel("distance (m)")
        ax.set_ylim(0, cap + 0.02)
        ax.set_title(f"{r.name}: distance per control point")
        ax.legend(fontsize=7)
        fig.tight_layout()
        p = out / f"flacco2015_{r.name}.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        files.append(p)
    p = out / "table.md"
    p.write_text(table(results) + "\n")
    files.append(p)
    return files
