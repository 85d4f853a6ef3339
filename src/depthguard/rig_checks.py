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

__all__ = ["MESH_MIN_EXTENT_M", "MESH_MAX_EXTENT_M", "mesh_extent_problem"]

#: a static object's largest extent (m) below which its mesh is taken to be in the wrong unit
MESH_MIN_EXTENT_M = 0.01
#: ... and above which (a cell is a few metres; 50 m is no robot's workspace)
MESH_MAX_EXTENT_M = 50.0

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
