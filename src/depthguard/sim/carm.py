"""A ceiling-suspended C-arm (Hamersma 2011, fig. 6), as exact primitives for a given pose.

The machine of the ``c-arm-room`` cell: the robot whose intended motions
the free-space map checks (R22). Its four degrees of freedom, the paper's
movement directions:

- ``longitudinal`` (m): the ceiling carriage runs along the rail (world x);
- ``larm`` (rad): the L-arm turns about the vertical axis through the isocentre;
- ``propeller`` (rad): the C-arc support turns about the horizontal axis from
  the L-arm to the isocentre (LAO/RAO);
- ``carc`` (rad): the C-arc slides along its own circle about the axis through
  the isocentre normal to the C plane (orbital, cranial/caudal).

All rotation axes meet at the isocentre ``iso = rail_origin + (longitudinal,
0, 0)`` at height ``iso_height``. Geometry (metres): carriage under the
ceiling; L-arm = horizontal member from the pivot to ``larm_reach`` plus a
vertical member down to the isocentre height; propeller bearing along the
L-arm's radial axis; C-arc of radius ``arc_radius`` (capsule chords) with the
X-ray detector above and the source below the isocentre (at zero pose the
beam is vertical, the C plane is the vertical plane through the L-arm).

``CArm`` quacks like a robot where the scene needs it (``dof``,
``joint_names``, ``q_min``, ``q_max``, ``q_home``, ``qd_max``,
``link_meshes(q)``, ``render_link_meshes(q, cell)``, ``link_mesh_names``,
``collision_primitives(q)``), with
``q = CArmPose.as_array()``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from depthguard.geometry.mesh import Mesh
from depthguard.geometry.primitives import Box, Capsule, Cylinder, Primitive
from depthguard.transforms import pose, rot_x, rot_y, rot_z

__all__ = ["CArmPose", "CArm", "CARM_LIMITS", "CARM_SPEEDS"]

# Limits of a ceiling C-arm of the Allura kind (rad, rad, rad, m).
CARM_LIMITS: dict[str, tuple[float, float]] = {
    "larm": (math.radians(-100.0), math.radians(100.0)),
    "propeller": (math.radians(-120.0), math.radians(120.0)),
    "carc": (math.radians(-50.0), math.radians(50.0)),
    "longitudinal": (-1.2, 0.8),
}
# Top speeds (rad/s, rad/s, rad/s, m/s), typical of motorised C-arms.
CARM_SPEEDS: dict[str, float] = {"larm": math.radians(15.0), "propeller": math.radians(25.0),
                                 "carc": math.radians(18.0), "longitudinal": 0.15}


@dataclass(frozen=True)
class CArmPose:
    """A C-arm pose: ``larm``, ``propeller``, ``carc`` in radians, ``longitudinal`` in metres."""
    larm: float = 0.0
    propeller: float = 0.0
    carc: float = 0.0
    longitudinal: float = 0.0

    NAMES = ("larm", "propeller", "carc", "longitudinal")

    def as_array(self) -> np.ndarray:
        return np.array([self.larm, self.propeller, self.carc, self.longitudinal], dtype=np.float64)

    @classmethod
    def from_array(cls, q) -> "CArmPose":
        q = np.asarray(q, dtype=np.float64).reshape(-1)
        if q.shape != (4,):
            raise ValueError(f"a C-arm pose has 4 values (larm, propeller, carc, longitudinal), got {q.shape}")
        return cls(*map(float, q))

    @classmethod
    def degrees(cls, larm=0.0, propeller=0.0, carc=0.0, longitudinal=0.0) -> "CArmPose":
        """Pose from angles in degrees (and metres)."""
        return cls(math.radians(larm), math.radians(propeller), math.radians(carc), float(longitudinal))

    def check(self) -> "CArmPose":
        """The pose itself; ``ValueError`` naming the axis if a value is outside :data:`CARM_LIMITS`."""
        for f in fields(self):
            v = getattr(self, f.name)
            lo, hi = CARM_LIMITS[f.name]
            if not (lo - 1e-9 <= v <= hi + 1e-9) or not math.isfinite(v):
                raise ValueError(f"C-arm {f.name} = {v:.4g} outside its limits [{lo:.4g}, {hi:.4g}]")
        return self


class CArm:
    """A ceiling-suspended C-arm model (module docstring). All lengths in metres."""

    dof = 4
    joint_names = CArmPose.NAMES

    def __init__(self, rail_origin=(0.0, 0.0), iso_height: float = 1.05, ceiling: float = 2.5,
                 arc_radius: float = 0.85, arc_tube: float = 0.06, larm_reach: float = 1.15,
                 arc_half_span_deg: float = 95.0, arc_segments: int = 10, name: str = "carm"):
        self.rail_origin = np.asarray(rail_origin, dtype=np.float64).reshape(2)
        self.iso_height = float(iso_height)
        self.ceiling = float(ceiling)
        self.arc_radius = float(arc_radius)
        self.arc_tube = float(arc_tube)
        self.larm_reach = float(larm_reach)
        self.arc_half_span = math.radians(arc_half_span_deg)
        self.arc_segments = int(arc_segments)
        self.name = name
        if not (0 < self.arc_radius + 0.25 < self.larm_reach):
            raise ValueError("C-arm: larm_reach must exceed arc_radius + 0.25 m (room for the support)")
        if not (self.iso_height + 0.5 < self.ceiling):
            raise ValueError("C-arm: the ceiling must be at least 0.5 m above the isocentre")
        self.q_min = np.array([CARM_LIMITS[n][0] for n in self.joint_names])
        self.q_max = np.array([CARM_LIMITS[n][1] for n in self.joint_names])
        self.qd_max = np.array([CARM_SPEEDS[n] for n in self.joint_names])
        self.q_home = np.zeros(4)
        self.link_mesh_names = tuple(p.name for p in self.primitives(CArmPose()))

    # ------------------------------------------------------------ geometry
    @staticmethod
    def _pose(p) -> CArmPose:
        return p if isinstance(p, CArmPose) else CArmPose.from_array(p)

    def isocentre(self, p) -> np.ndarray:
        """(3,) world isocentre of pose ``p``."""
        p = self._pose(p)
        return np.array([self.rail_origin[0] + p.longitudinal, self.rail_origin[1], self.iso_height])

    def frames(self, p) -> dict[str, np.ndarray]:
        """World 4x4 frames: ``larm`` (at the isocentre, z up, x towards the L-arm's vertical
        member), ``propeller`` (x along the propeller axis), ``c`` (the C plane is its x-z plane,
        z along the beam from source to detector)."""
        p = self._pose(p)
        iso = self.isocentre(p)
        T_l = pose(rot_z(p.larm), iso)
        T_p = T_l @ pose(rot_x(p.propeller))
        T_c = T_p @ pose(rot_y(p.carc))   # positive: detector towards +x of the L-arm frame (cranial)
        return {"larm": T_l, "propeller": T_p, "c": T_c}

    def primitives(self, p) -> list[Primitive]:
        """The machine at pose ``p`` (a :class:`CArmPose` or (4,) array) as named exact primitives."""
        p = self._pose(p)
        F = self.frames(p)
        T_l, T_p, T_c = F["larm"], F["propeller"], F["c"]
        n = self.name
        zi = self.iso_height
        top = self.ceiling - zi          # ceiling height above the isocentre (larm frame)
        out: list[Primitive] = []
        # carriage under the ceiling rails (follows longitudinal, not the L-arm rotation)
        car = pose(t=self.isocentre(p) + [0.0, 0.0, top - 0.10])
        out.append(Box(size=(0.50, 0.70, 0.16), world_from_local=car, name=f"{n}/carriage"))
        # L-arm: horizontal member and vertical member (larm frame)
        hz = top - 0.27
        out.append(Box(size=(self.larm_reach + 0.30, 0.30, 0.16),
                       world_from_local=T_l @ pose(t=[self.larm_reach / 2, 0.0, hz]), name=f"{n}/larm_top"))
        vlen = hz + 0.08 + 0.20
        out.append(Box(size=(0.30, 0.30, vlen),
                       world_from_local=T_l @ pose(t=[self.larm_reach, 0.0, hz + 0.08 - vlen / 2]),
                       name=f"{n}/larm_column"))
        # propeller bearing and the C-arc support (propeller frame)
        r0 = self.arc_radius + self.arc_tube + 0.12
        out.append(Cylinder.between(T_p[:3, :3] @ [r0, 0, 0] + T_p[:3, 3],
                                    T_p[:3, :3] @ [self.larm_reach - 0.15, 0, 0] + T_p[:3, 3], 0.13,
                                    name=f"{n}/propeller"))
        out.append(Box(size=(0.22, 0.30, 0.45),
                       world_from_local=T_p @ pose(t=[self.arc_radius + self.arc_tube + 0.01, 0.0, 0.0]),
                       name=f"{n}/support"))
        # C-arc chords (C frame, x-z plane), detector above, source below
        R = self.arc_radius
        angles = np.linspace(-self.arc_half_span, self.arc_half_span, self.arc_segments + 1)
        pts = [T_c[:3, :3] @ [R * math.cos(a), 0.0, R * math.sin(a)] + T_c[:3, 3] for a in angles]
        for i in range(self.arc_segments):
            out.append(Capsule.between(pts[i], pts[i + 1], self.arc_tube, name=f"{n}/arc{i}"))
        det_c, src_c = 0.50, -0.55
        out.append(Box(size=(0.45, 0.45, 0.22), world_from_local=T_c @ pose(t=[0, 0, det_c]), name=f"{n}/detector"))
        out.append(Capsule.between(pts[-1], T_c[:3, :3] @ [0, 0, det_c + 0.11] + T_c[:3, 3], self.arc_tube,
                                   name=f"{n}/detector_arm"))
        out.append(Box(size=(0.30, 0.30, 0.30), world_from_local=T_c @ pose(t=[0, 0, src_c]), name=f"{n}/source"))
        out.append(Capsule.between(pts[0], T_c[:3, :3] @ [0, 0, src_c - 0.15] + T_c[:3, 3], self.arc_tube,
                                   name=f"{n}/source_arm"))
        return out

    # ----------------------------------------------------- robot-like API
    def collision_primitives(self, q, padding: float = 0.0) -> list[Primitive]:
        """The machine's volume at ``q``, grown by ``padding`` metres (>= 0).

        Capsules grow exactly (radius + padding); boxes and cylinders grow by
        ``padding`` on every face, a superset of the exact offset volume.
        """
        import dataclasses

        padding = float(padding)
        if not (padding >= 0.0 and math.isfinite(padding)):
            raise ValueError(f"CArm.collision_primitives: padding must be >= 0 (got {padding})")
        prims = self.primitives(q)
        if padding == 0.0:
            return prims
        out = []
        for p in prims:
            if isinstance(p, Box):
                out.append(dataclasses.replace(p, size=tuple(np.asarray(p.size) + 2 * padding)))
            elif isinstance(p, (Capsule,)):
                out.append(dataclasses.replace(p, radius=p.radius + padding))
            elif isinstance(p, Cylinder):
                out.append(dataclasses.replace(p, radius=p.radius + padding, length=p.length + 2 * padding))
            else:  # pragma: no cover - the model uses only the three kinds
                raise ValueError(f"CArm: cannot pad {type(p).__name__}")
        return out

    def link_meshes(self, q) -> list[Mesh]:
        """World meshes of the machine's parts at ``q`` (order of :attr:`link_mesh_names`)."""
        prims = self.primitives(q)
        if not hasattr(self, "_local_meshes"):  # part shapes never change: build their meshes once
            self._local_meshes = [prim.local_mesh() for prim in prims]
        return [m.transformed(prim.world_from_local) for m, prim in zip(self._local_meshes, prims)]

    def render_link_meshes(self, q, cell: float | None = None) -> list[Mesh]:
        """What a camera renders of the machine at ``q``: :meth:`link_meshes` (its parts are
        primitives of a few hundred triangles: nothing to cluster, ``cell`` is not used)."""
        return self.link_meshes(q)
