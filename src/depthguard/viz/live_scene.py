"""What the live view draws, as plain arrays (R29, R31): no viser here, so it is testable alone.

The view (:mod:`depthguard.viz.live`) turns one moment of the monitor into
a :class:`Snapshot` and the cameras' newest frames into coloured points:

- :func:`snapshot_of_reaction` / :func:`snapshot_of_record` — the same
  fields from a live :class:`~depthguard.runtime.result.Reaction` or from a
  line of ``log.jsonl`` (``docs/MONITOR.md``). ``distance`` is ``inf`` for
  "nothing within rho" (``null`` in the log) and ``observed`` False for
  "cannot judge": the two stay apart (R26).
- :func:`pixel_labels` — each pixel of a frame as invalid, the robot (within
  ``robot_offset`` in front of the robot's rendered depth, or behind it),
  the known scene (within ``tolerance`` of the static CAD's depth) or other
  (what may be an obstacle).
- :func:`frame_points` — the labelled pixels, subsampled, as world points.
- :func:`distance_colours` — control/watch points by distance, unobserved apart.
- :func:`map_points` — the free-space map's occupied and unknown voxel centres (R37), coloured
  by state (:data:`MAP_COLOURS`).

Colours are RGB uint8; distances metres; points (N, 3) float world metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["map_points", "MAP_COLOURS", "Snapshot", "snapshot_of_reaction", "snapshot_of_record", "pixel_labels", "frame_points",
           "distance_colours", "state_colour", "LABEL_COLOURS", "STATE_COLOURS", "ROBOT_COLOUR",
           "UNOBSERVED_COLOUR", "INVALID", "ROBOT", "KNOWN", "OTHER"]

INVALID, ROBOT, KNOWN, OTHER = 0, 1, 2, 3

#: the robot's meshes (orange: no other layer uses this hue)
ROBOT_COLOUR = (255, 110, 0)
#: the points of a frame by label: removed as robot (violet), as the known scene (grey), other (blue)
LABEL_COLOURS = {ROBOT: (170, 90, 230), KNOWN: (150, 150, 150), OTHER: (30, 90, 255)}
#: points of "other" within rho of a control point: what the robot is near
NEAR_COLOUR = (230, 0, 40)
#: a camera frustum by its state (``CameraStatus.state``); an unknown state is drawn as untrusted
STATE_COLOURS = {"fresh": (20, 170, 60), "stale": (235, 200, 0), "waiting": (140, 140, 140),
                 "untrusted": (220, 20, 20)}
#: a control or watch point no camera can judge (R26): never drawn like "nothing near"
UNOBSERVED_COLOUR = (230, 0, 230)
#: a point with nothing within rho
CLEAR_COLOUR = (0, 200, 120)
#: the free-space map's voxels by state (R37): 1 unknown (pale grey-blue: no camera could judge
#: it), 2 occupied (brown: a camera saw a surface in it, or the known scene)
MAP_COLOURS = {1: (185, 190, 215), 2: (120, 60, 20)}


def map_points(snapshot) -> tuple[np.ndarray, np.ndarray]:
    """R37: the free-space map ``snapshot`` (:class:`~depthguard.runtime.free_space_map.FreeSpaceSnapshot`)
    as the view's layer: centres (N, 3) float32 world m of the voxels that are neither free nor
    the robot's body — the points of ``/depthguard/obstacles``
    (:func:`~depthguard.runtime.map_cloud.obstacle_points`) — and their colours (N, 3) uint8."""
    from depthguard.runtime.map_cloud import obstacle_points

    pts = obstacle_points(snapshot)
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float32)
    table = np.zeros((256, 3), np.uint8)
    for k, c in MAP_COLOURS.items():
        table[k] = c
    return xyz, table[pts["state"]]


def state_colour(state: str) -> tuple[int, int, int]:
    """The frustum colour of a camera state; anything not fresh/stale/waiting is ``untrusted``."""
    return STATE_COLOURS.get(state, STATE_COLOURS["untrusted"])


@dataclass
class Snapshot:
    """One moment of the monitor as the view draws it.

    t : s, the monitor's clock.  override : [0, 1].  reasons : key -> sentence.
    names : m point names; distance (m,) m, ``inf`` = nothing within rho;
    direction (m, 3) unit, world; observed (m,) bool; is_watch (m,) bool.
    cameras : id -> ``{"age_s": float (inf before a frame), "state", "frames", "refused"}``.
    q : (dof,) rad or None (a log without joints).  step_s : s of the cycle.
    """
    t: float
    override: float
    reasons: dict
    names: tuple
    distance: np.ndarray
    direction: np.ndarray
    observed: np.ndarray
    is_watch: np.ndarray
    cameras: dict
    q: np.ndarray | None = None
    step_s: float = math.nan
    extra: dict = field(default_factory=dict)


def snapshot_of_reaction(r) -> Snapshot:
    """A :class:`Snapshot` of a live reaction (its arrays are already the reaction's own copies)."""
    cams = {c: {"age_s": s.age_s, "state": s.state, "frames": s.frames, "refused": s.refused}
            for c, s in r.cameras.items()}
    return Snapshot(r.t, r.override, dict(r.reasons), tuple(r.names), np.asarray(r.distance, dtype=float),
                    np.asarray(r.direction, dtype=float), np.asarray(r.observed, dtype=bool),
                    np.asarray(r.is_watch, dtype=bool), cams, np.asarray(r.q, dtype=float), float(r.step_s))


def snapshot_of_record(rec: dict, where: str = "record") -> Snapshot:
    """A :class:`Snapshot` of one ``log.jsonl`` line; ``ValueError`` naming ``where`` and the
    field when a field is missing or of the wrong kind. ``distance: null`` -> ``inf``."""
    try:
        pts = rec["points"]
        names = tuple(str(p["name"]) for p in pts)
        dist = np.array([math.inf if p["distance"] is None else float(p["distance"]) for p in pts])
        direc = np.array([[0.0, 0.0, 0.0] if p.get("direction") is None else [float(x) for x in p["direction"]]
                          for p in pts]).reshape(-1, 3)
        obs = np.array([bool(p["observed"]) for p in pts], dtype=bool)
        watch = np.array([bool(p.get("watch", False)) for p in pts], dtype=bool)
        cams = {str(c): {"age_s": math.inf if s.get("age_s") is None else float(s["age_s"]),
                         "state": str(s["state"]), "frames": int(s.get("frames", 0)),
                         "refused": int(s.get("refused", 0))} for c, s in rec["cameras"].items()}
        q = rec.get("q")
        return Snapshot(float(rec["t"]), float(rec["override"]), dict(rec.get("reasons") or {}), names, dist,
                        direc, obs, watch, cams, None if q is None else np.asarray(q, dtype=float),
                        float(rec["step_s"]) if rec.get("step_s") is not None else math.nan)
    except KeyError as exc:
        raise ValueError(f"{where}: field {exc.args[0]!r} is missing (schema in docs/MONITOR.md)") from None
    except (TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"{where}: not a monitor record ({exc})") from None


def pixel_labels(depth: np.ndarray, robot_depth: np.ndarray, static_depth: np.ndarray,
                 robot_offset: float, tolerance: float = 0.04, tolerance_per_m2: float = 0.012) -> np.ndarray:
    """(H, W) int8 labels of a frame: :data:`INVALID` (no measurement), :data:`ROBOT` (on or
    behind the robot's rendered depth, within ``robot_offset`` m in front of it, as R9 removes
    it), :data:`KNOWN` (at or behind the static CAD's depth ``s`` minus ``tolerance +
    tolerance_per_m2 * s**2`` m: a structured-light sensor's noise grows with the square of the
    depth), :data:`OTHER`. All images (H, W) metres, 0 = nothing rendered. For looking only:
    the monitor's own classification is its depth grid's (R10-R12)."""
    d = np.asarray(depth, dtype=np.float32)
    rd = np.asarray(robot_depth, dtype=np.float32)
    sd = np.asarray(static_depth, dtype=np.float32)
    if d.shape != rd.shape or d.shape != sd.shape:
        raise ValueError(f"depth {d.shape}, robot depth {rd.shape} and static depth {sd.shape} differ in shape")
    lab = np.full(d.shape, OTHER, dtype=np.int8)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(d) & (d > 0)
        lab[(sd > 0) & (d >= sd - (tolerance + tolerance_per_m2 * sd * sd))] = KNOWN
        lab[(rd > 0) & (d >= rd - robot_offset)] = ROBOT
    lab[~valid] = INVALID
    return lab


def frame_points(cam, depth: np.ndarray, robot_depth: np.ndarray, static_depth: np.ndarray,
                 robot_offset: float, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """Every ``stride``-th pixel (both axes) with a measurement, labelled (:func:`pixel_labels`),
    as world points: ``(points (N, 3) float32 m, labels (N,) int8)``, back-projected by the
    camera's own :meth:`~depthguard.camera.Camera.depth_to_points` (R1)."""
    s = max(1, int(stride))
    d = np.asarray(depth)
    lab = pixel_labels(d[::s, ::s], np.asarray(robot_depth)[::s, ::s], np.asarray(static_depth)[::s, ::s],
                       robot_offset)
    keep = lab != INVALID
    mask = np.zeros(d.shape, dtype=bool)
    mask[::s, ::s] = keep
    pts = cam.depth_to_points(d, "world", mask)         # row-major, as lab[keep]
    return pts.astype(np.float32), lab[keep]


def near_mask(points: np.ndarray, centres: np.ndarray, radius: float) -> np.ndarray:
    """(N,) bool: points within ``radius`` m of any of ``centres`` (M, 3)."""
    if len(points) == 0 or len(centres) == 0:
        return np.zeros(len(points), dtype=bool)
    p = np.asarray(points, dtype=np.float32)
    c = np.asarray(centres, dtype=np.float32)
    d2 = (p * p).sum(axis=1)[:, None] - 2.0 * p @ c.T + (c * c).sum(axis=1)[None, :]
    return (d2 <= float(radius) ** 2).any(axis=1)


def point_colours(labels: np.ndarray, near: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) uint8 colours of frame points by label (:data:`LABEL_COLOURS`); ``near`` points red."""
    out = np.zeros((len(labels), 3), dtype=np.uint8)
    for lab, col in LABEL_COLOURS.items():
        out[labels == lab] = col
    if near is not None:
        out[near] = NEAR_COLOUR
    return out


def distance_colours(distance: np.ndarray, observed: np.ndarray, rho: float) -> np.ndarray:
    """(m, 3) uint8: unobserved -> magenta (cannot judge, R26), nothing within rho -> green,
    else from red (0 m) through yellow (rho / 2) to green (rho)."""
    d = np.asarray(distance, dtype=float)
    out = np.tile(np.array(CLEAR_COLOUR, dtype=np.uint8), (len(d), 1))
    fin = np.isfinite(d)
    x = np.clip(d[fin] / max(float(rho), 1e-9), 0.0, 1.0)
    red = np.where(x < 0.5, 230, 230 * (1 - (x - 0.5) * 2)).astype(np.uint8)
    green = np.where(x < 0.5, 200 * x * 2, 200).astype(np.uint8)
    out[fin] = np.stack([red, green, np.zeros_like(red)], axis=1)
    out[~np.asarray(observed, dtype=bool)] = UNOBSERVED_COLOUR
    return out


def panel_markdown(snap: Snapshot, rates: dict, step_ms: dict, rho: float, note: str = "") -> str:
    """The panel's text: override and reasons, per camera state / rate / age, step time, points."""
    state = "STOPPED" if snap.override <= 0 else ("slowing" if snap.override < 1 else "running")
    lines = [f"**t = {snap.t:.2f} s — override {snap.override:.2f} ({state})**", ""]
    if snap.reasons:
        lines += [f"- {v}" for v in snap.reasons.values()]
    else:
        lines.append("- no reason to slow down")
    lines += ["", "| camera | state | rate | age |", "|---|---|---|---|"]
    for c, s in snap.cameras.items():
        age = "-" if not math.isfinite(s["age_s"]) else f"{s['age_s'] * 1e3:.0f} ms"
        rate = rates.get(c)
        lines.append(f"| {c} | {s['state']} | {'-' if rate is None else f'{rate:.1f} Hz'} | {age} |")
    if step_ms:
        lines += ["", "step " + ", ".join(f"{k} {v:.3f} ms" for k, v in step_ms.items())]
    unobs = [n for n, o in zip(snap.names, snap.observed) if not o]
    near = [(n, d) for n, d, o in zip(snap.names, snap.distance, snap.observed) if o and math.isfinite(d)]
    lines.append("")
    lines.append(f"rho {rho:.2f} m; nearest: " + (", ".join(f"{n} {d * 100:.0f} cm" for n, d in
                                                        sorted(near, key=lambda x: x[1])[:3]) or "nothing within rho"))
    if unobs:
        lines += ["", f"cannot judge: {', '.join(unobs)}"]
    if note:
        lines += ["", note]
    return "\n".join(lines)
