"""Sanity checks of a rig where a number is almost certainly a mistake (R28, issue 33).

A rig file's lengths are metres. Two mistakes pass every type check and then
give silently wrong answers:

- a mesh in millimetres (most STL exports) without ``scale: 0.001``: the
  object is 1000 times too large (or, scaled twice, too small) and the
  known scene is wrong everywhere; :func:`mesh_extent_problem` refuses a mesh
  whose largest extent is under :data:`MESH_MIN_EXTENT_M` or over
  :data:`MESH_MAX_EXTENT_M` and suggests the ``scale`` that brings it in range;
- a robot mounted inside a static object (its table 20 cm too high):
  :func:`robot_inside_objects` (see there).
"""

from __future__ import annotations

import numpy as np

__all__ = ["MESH_MIN_EXTENT_M", "MESH_MAX_EXTENT_M", "MOUNT_CONTACT_M", "mesh_extent_problem",
           "robot_inside_objects"]

#: a static object's largest extent (m) below which its mesh is taken to be in the wrong unit
MESH_MIN_EXTENT_M = 0.01
#: ... and above which (a cell is a few metres; 50 m is no robot's workspace)
MESH_MAX_EXTENT_M = 50.0

#: how deep (m) a robot link may reach into a static object: a base standing on its table touches it,
#: and a mesh's tessellation or a mount's chamfer is a few millimetres
MOUNT_CONTACT_M = 0.01

# unit factors tried for the suggestion, most common first: mm, cm, inch, and their inverses
_FACTORS = (0.001, 0.01, 0.0254, 1000.0, 100.0, 1 / 0.0254)


def _fmt_scale(scale) -> str:
    s = np.atleast_1d(np.asarray(scale, dtype=float))
    return f"{s[0]:g}" if s.size == 1 or np.all(s == s[0]) else "[" + ", ".join(f"{v:g}" for v in s) + "]"


def mesh_extent_problem(bounds_min, bounds_max, scale) -> str | None:
    """A sentence when a mesh's largest extent (its bounds (3,) m after ``scale``, before its
    pose) is under 1 cm or over 50 m, suggesting the ``scale`` that gives it a plausible size;
    None otherwise."""
    extent = float(np.max(np.asarray(bounds_max, float) - np.asarray(bounds_min, float)))
    if MESH_MIN_EXTENT_M <= extent <= MESH_MAX_EXTENT_M:
        return None
    if not extent > 0:
        return "the mesh has no extent (all its vertices coincide)"
    where = (f"under {MESH_MIN_EXTENT_M * 100:g} cm" if extent < MESH_MIN_EXTENT_M
             else f"over {MESH_MAX_EXTENT_M:g} m")
    current = np.asarray(scale, dtype=float)
    hint = ""
    for f in _FACTORS:
        if (f < 1) == (extent > MESH_MAX_EXTENT_M) and 0.05 <= extent * f <= 20.0:
            unit = {0.001: "millimetres", 0.01: "centimetres", 0.0254: "inches"}.get(f)
            why = f" (the file is in {unit})" if unit else ""
            hint = f": give scale: {_fmt_scale(current * f)}{why}, which makes it {extent * f:.3g} m across"
            break
    return (f"the mesh is {extent:.4g} m across with scale {_fmt_scale(current)}, {where}: a rig's lengths are "
            f"metres{hint or ' - check the scale'}")


def _surface_samples(mesh, per_link: int, rng) -> np.ndarray:
    """(n, 3) points on ``mesh``'s surface: ``per_link`` of its vertices (all when fewer) and
    ``per_link`` area-weighted samples."""
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    corners = v if len(v) <= per_link else v[rng.choice(len(v), size=per_link, replace=False)]
    if not len(f):
        return corners
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if not area.sum() > 0:
        return corners
    k = rng.choice(len(f), size=per_link, p=area / area.sum())
    u, w = rng.random(per_link), rng.random(per_link)
    flip = u + w > 1.0
    u[flip], w[flip] = 1.0 - u[flip], 1.0 - w[flip]
    pts = tri[k, 0] + u[:, None] * (tri[k, 1] - tri[k, 0]) + w[:, None] * (tri[k, 2] - tri[k, 0])
    return np.concatenate([corners, pts])


def _depth_inside(obj, points: np.ndarray) -> np.ndarray:
    """(n,) m how deep each point lies inside static object ``obj`` (<= 0: outside): the exact
    distance for a primitive, the mesh's signed distance for a mesh (points in its bounds only)."""
    if obj.primitive is not None:
        return -obj.primitive.sdf(points)
    lo, hi = obj.mesh.bounds
    depth = np.full(len(points), -np.inf)
    near = np.all((points >= lo) & (points <= hi), axis=1)
    if near.any():
        import trimesh

        tm = trimesh.Trimesh(obj.mesh.vertices, obj.mesh.faces, process=False)
        depth[near] = trimesh.proximity.signed_distance(tm, points[near])     # > 0 inside
    return depth


def robot_inside_objects(robot, q, objects, contact: float = MOUNT_CONTACT_M, per_link: int = 400) -> str | None:
    """A sentence naming the deepest robot link inside a static object at joints ``q`` (dof,),
    when it reaches more than ``contact`` m into it (a robot mounted inside its table); None
    otherwise. The links' surfaces are sampled (``per_link`` of their meshes' vertices and as many
    area-weighted points each, a fixed seed); a robot without link meshes uses its capsules' axes
    widened by their radii."""
    rng = np.random.default_rng(0)
    names = list(robot.link_mesh_names)
    if names:
        clouds = [_surface_samples(m, per_link, rng) for m in robot.link_meshes(q)]
        radii = [0.0] * len(clouds)
    else:
        ab, r = robot.collision_segments(q)
        s = np.linspace(0.0, 1.0, 33)[:, None]
        clouds = [a + s * (b - a) for a, b in ab]
        radii = list(r)
        names = [c.name or c.link for c in robot.capsules]
    worst = (contact, None, None)
    for name, pts, rad in zip(names, clouds, radii):
        for obj in objects:
            d = float(np.max(_depth_inside(obj, pts))) + rad if len(pts) else -np.inf
            if d > worst[0]:
                worst = (d, name, obj.name)
    if worst[1] is None:
        return None
    return (f"link {worst[1]} of {robot.name} reaches {worst[0] * 100:.1f} cm into the static object "
            f"{worst[2]!r} at the rig's joints: check robot.base and the pose of {worst[2]!r} (a robot stands on "
            f"its table, it is not mounted in it; contact up to {contact * 100:g} cm is allowed)")
