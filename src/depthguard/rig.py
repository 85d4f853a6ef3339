"""Rig files: cameras, workspace, robot and static CAD of a cell (R2).

A rig is YAML (format in ``docs/ARCHITECTURE.md``). It is validated once, on
load, with pydantic; every problem becomes a :class:`RigError` whose message
names the file, the field (``cameras[1].fx``) and what is wrong. After
loading, a :class:`Rig` holds only validated, immutable objects.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Union

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, ValidationInfo, field_validator, model_validator

from depthguard.camera import Camera, CameraError
from depthguard.config import MonitorConfig
from depthguard.geometry.mesh import Mesh, load_mesh
from depthguard.rig_checks import mesh_extent_problem, robot_inside_objects
from depthguard.geometry.primitives import Box, Capsule, Cylinder, Primitive, Sphere
from depthguard.transforms import as_rigid, look_at, pose, quat_to_matrix

__all__ = ["Rig", "RigError", "Workspace", "StaticObject", "RIG_SCHEMA_VERSION", "joint_limits_problem"]

RIG_SCHEMA_VERSION = 1


class RigError(ValueError):
    """A rig file is missing, unreadable or invalid; the message names file and field."""


# --------------------------------------------------------------------- schema
_Vec3 = tuple[float, float, float]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class LookAtSpec(_Strict):
    """A camera at ``eye`` looking at ``target`` (m, world); ``up`` sets the roll: the image's
    y axis points against it, so it must not lie along the view direction."""
    eye: _Vec3
    target: _Vec3
    up: _Vec3 = (0.0, 0.0, 1.0)

    @field_validator("up")
    @classmethod
    def _roll_defined(cls, up: _Vec3, info: ValidationInfo) -> _Vec3:
        if "eye" not in info.data or "target" not in info.data:
            return up                     # eye or target is wrong: that error is reported
        view = np.subtract(info.data["target"], info.data["eye"])
        u = np.asarray(up, dtype=float)
        n_view, n_up = float(np.linalg.norm(view)), float(np.linalg.norm(u))
        if n_up == 0 or not np.isfinite(n_up):
            raise ValueError(f"up must be a finite non-zero vector (got {list(up)})")
        if n_view > 0 and np.linalg.norm(np.cross(view / n_view, u / n_up)) < 1e-3:
            # within 0.06 deg: the roll would be a fallback's guess, not the user's choice
            raise ValueError(f"up {list(up)} lies along the view direction eye -> target "
                             f"{[round(float(a), 6) for a in view]}: the camera's roll is undefined; give an up "
                             f"across the view (e.g. [0, 1, 0] for a camera looking straight down)")
        return up


class PoseSpec(_Strict):
    """One of: ``translation`` (+ ``quaternion`` xyzw), ``matrix`` (4x4), ``look_at``."""

    translation: Optional[_Vec3] = None
    quaternion: Optional[tuple[float, float, float, float]] = None
    matrix: Optional[list[list[float]]] = None
    look_at: Optional[LookAtSpec] = None

    @model_validator(mode="after")
    def _one_form(self) -> "PoseSpec":
        forms = [self.matrix is not None, self.look_at is not None,
                 self.translation is not None or self.quaternion is not None]
        if sum(forms) > 1:
            raise ValueError("give exactly one of translation/quaternion, matrix or look_at")
        if self.quaternion is not None:
            quat_to_matrix(np.asarray(self.quaternion))  # raises on a non-unit quaternion
        if self.matrix is not None:
            as_rigid(np.asarray(self.matrix, dtype=float))  # raises: shape, orthonormality, bottom row
        if self.look_at is not None:
            e, t = np.asarray(self.look_at.eye), np.asarray(self.look_at.target)
            if np.allclose(e, t):
                raise ValueError("look_at: eye and target coincide")
        return self

    def matrix4(self) -> np.ndarray:
        if self.matrix is not None:
            return as_rigid(np.asarray(self.matrix, dtype=float))
        if self.look_at is not None:
            return look_at(self.look_at.eye, self.look_at.target, self.look_at.up)
        R = quat_to_matrix(np.asarray(self.quaternion)) if self.quaternion is not None else None
        return pose(R, self.translation)


class CameraSpec(_Strict):
    id: str = Field(min_length=1)
    sensor: Optional[str] = None
    width: Optional[int] = None
    height: Optional[int] = None
    fx: Optional[float] = None
    fy: Optional[float] = None
    cx: Optional[float] = None
    cy: Optional[float] = None
    range: Optional[tuple[float, float]] = None
    topic: Optional[str] = None          # its depth Image topic in a ROS 2 bag (R31, docs/BAGS.md)
    depth_scale: Optional[float] = None  # m per 16-bit unit, bag / images: PNG (0.001; D405 0.0001; TUM 0.0002)
    pose: PoseSpec

    @field_validator("id")
    @classmethod
    def _key_safe_id(cls, v: str) -> str:
        from depthguard.config import check_camera_id
        return check_camera_id(v)        # it names Zenoh keys and files (R31)

    @field_validator("sensor")
    @classmethod
    def _known_sensor(cls, v: Optional[str]) -> Optional[str]:
        if v is not None:
            from depthguard.sensors import sensor_model
            sensor_model(v)  # raises with the list of known models
        return v

    @field_validator("fx", "fy")
    @classmethod
    def _positive_focal(cls, v: Optional[float]) -> Optional[float]:
        if v is not None and not v > 0:
            raise ValueError(f"focal length must be > 0 (got {v})")
        return v

    @field_validator("width", "height")
    @classmethod
    def _positive_size(cls, v: Optional[int]) -> Optional[int]:
        if v is not None and v <= 0:
            raise ValueError(f"image size must be > 0 (got {v})")
        return v

    @field_validator("depth_scale")
    @classmethod
    def _depth_scale(cls, v: Optional[float]) -> Optional[float]:
        # the span RealSense devices accept for their depth units (1 um .. 1 cm per unit)
        if v is not None and not (math.isfinite(v) and 1e-6 <= v <= 1e-2):
            raise ValueError(f"depth_scale is metres per unit of 16-bit depth, 1e-6..0.01 "
                             f"(0.001 = millimetres, 0.0001 = a RealSense D405's 0.1 mm); got {v}")
        return v

    @field_validator("range")
    @classmethod
    def _range(cls, v):
        if v is not None and not (0 <= v[0] < v[1]):
            raise ValueError(f"range must be [min, max] with 0 <= min < max (got {list(v)})")
        return v

    @model_validator(mode="after")
    def _intrinsics(self) -> "CameraSpec":
        given = {k: getattr(self, k) for k in ("fx", "fy", "cx", "cy")}
        if any(v is not None for v in given.values()):
            missing = [k for k, v in given.items() if v is None]
            if self.width is None or self.height is None:
                missing = ["width/height"] + missing
            if missing:
                raise ValueError(f"intrinsics incomplete: missing {', '.join(missing)}")
            if not (-0.5 <= self.cx <= self.width - 0.5 and -0.5 <= self.cy <= self.height - 0.5):
                raise ValueError(f"principal point ({self.cx}, {self.cy}) lies outside the "
                                 f"{self.width}x{self.height} image")
        elif self.sensor is None:
            raise ValueError("give the intrinsics (width, height, fx, fy, cx, cy) or a sensor preset")
        elif (self.width is None) != (self.height is None):
            raise ValueError("give both width and height, or neither")
        return self

    def to_camera(self) -> Camera:
        from depthguard.sensors import intrinsics_for

        if self.fx is not None:
            intr = dict(width=self.width, height=self.height, fx=self.fx, fy=self.fy, cx=self.cx, cy=self.cy)
            rng = (0.4, 6.0)
            if self.sensor is not None:                  # its range, whatever the mode of the intrinsics
                from depthguard.sensors import sensor_model
                m = sensor_model(self.sensor)
                rng = (m.min_range, m.max_range)
        else:
            p = intrinsics_for(self.sensor, self.width, self.height)
            intr = {k: p[k] for k in ("width", "height", "fx", "fy", "cx", "cy")}
            rng = (p["min_range"], p["max_range"])
        if self.range is not None:
            rng = self.range
        return Camera(id=self.id, world_from_camera=self.pose.matrix4(), min_range=rng[0],
                      max_range=rng[1], sensor=self.sensor, **intr)


class WorkspaceSpec(_Strict):
    min: _Vec3
    max: _Vec3

    @model_validator(mode="after")
    def _ordered(self) -> "WorkspaceSpec":
        if not all(a < b for a, b in zip(self.min, self.max)):
            raise ValueError(f"workspace min must be < max on every axis (got min={list(self.min)}, max={list(self.max)})")
        return self


class ControlPointSpec(_Strict):
    name: str
    link: Union[str, int]
    offset: _Vec3 = (0.0, 0.0, 0.0)
    radius: float = Field(default=0.0, ge=0.0)


class RobotSpec(_Strict):
    name: Optional[str] = None
    urdf: Optional[str] = None
    base: Optional[PoseSpec] = None
    joints: Optional[list[float]] = None
    control_points: Optional[list[ControlPointSpec]] = None

    @model_validator(mode="after")
    def _one_source(self) -> "RobotSpec":
        if (self.name is None) == (self.urdf is None):
            raise ValueError("give exactly one of name (a built-in robot) or urdf (a file)")
        return self


class _Shape(_Strict):
    pass


class BoxShape(_Shape):
    size: _Vec3

    @field_validator("size")
    @classmethod
    def _pos(cls, v):
        if min(v) <= 0:
            raise ValueError(f"box size must be > 0 on every axis (got {list(v)})")
        return v


class SphereShape(_Shape):
    radius: float = Field(gt=0)


class CylinderShape(_Shape):
    radius: float = Field(gt=0)
    length: float = Field(gt=0)


class ObjectSpec(_Strict):
    name: str = Field(min_length=1)
    pose: Optional[PoseSpec] = None
    mesh: Optional[str] = None
    scale: Union[float, _Vec3] = 1.0
    box: Optional[BoxShape] = None
    sphere: Optional[SphereShape] = None
    cylinder: Optional[CylinderShape] = None
    capsule: Optional[CylinderShape] = None

    @field_validator("scale")
    @classmethod
    def _positive_scale(cls, v):
        values = [v] if isinstance(v, (int, float)) else list(v)
        if not all(np.isfinite(a) and a > 0 for a in values):
            raise ValueError(f"scale must be > 0 on every axis (got {v}): a negative scale mirrors the mesh, "
                             f"0 flattens it")
        return v

    @model_validator(mode="after")
    def _one_shape(self) -> "ObjectSpec":
        shapes = [k for k in ("mesh", "box", "sphere", "cylinder", "capsule") if getattr(self, k) is not None]
        if len(shapes) != 1:
            raise ValueError(f"give exactly one shape of mesh, box, sphere, cylinder, capsule (got {shapes or 'none'})")
        return self


class SceneSpec(_Strict):
    """``scene: {learned: DIR}``: the static scene learned from the cameras (issue 31,
    :mod:`depthguard.learned_scene`), beside or instead of the CAD objects; DIR is relative
    to the rig file."""
    learned: Optional[str] = Field(default=None, min_length=1)


class RigSpec(_Strict):
    version: int = RIG_SCHEMA_VERSION
    name: str = "rig"
    description: str = ""
    workspace: WorkspaceSpec
    cameras: list[CameraSpec] = Field(min_length=1)
    robot: Optional[RobotSpec] = None
    objects: list[ObjectSpec] = Field(default_factory=list)
    scene: Optional[SceneSpec] = None
    monitor: Optional[MonitorConfig] = None

    @field_validator("version")
    @classmethod
    def _version(cls, v: int) -> int:
        if v != RIG_SCHEMA_VERSION:
            raise ValueError(f"unsupported rig version {v} (this depthguard reads version {RIG_SCHEMA_VERSION})")
        return v

    @field_validator("cameras")
    @classmethod
    def _unique_ids(cls, v: list[CameraSpec]) -> list[CameraSpec]:
        ids = [c.id for c in v]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ValueError(f"camera ids must be unique (repeated: {', '.join(dup)})")
        return v


# ------------------------------------------------------------------ the rig
def _vec(v) -> str:
    return "(" + ", ".join(f"{float(a):.3g}" for a in np.asarray(v).ravel()) + ")"


@dataclass(frozen=True)
class Workspace:
    """Axis-aligned box of interest, world frame, metres."""
    lo: np.ndarray
    hi: np.ndarray

    def __repr__(self) -> str:
        return f"Workspace({_vec(self.lo)}..{_vec(self.hi)} m)"

    def contains(self, points: np.ndarray) -> np.ndarray:
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        return np.all((p >= self.lo) & (p <= self.hi), axis=1)

    def depth_span(self, cam: Camera) -> tuple[float, float]:
        """``(d_min, d_max)`` m: the box's depth range in ``cam``, clipped to the camera's range
        (the depth grid's span, R10); ``ValueError`` when the box lies outside that range."""
        corners = np.array([[x, y, z] for x in (self.lo[0], self.hi[0]) for y in (self.lo[1], self.hi[1])
                            for z in (self.lo[2], self.hi[2])])
        d = corners @ np.asarray(cam.R).T[:, 2] + cam.t[2]
        d_min = max(float(cam.min_range), float(d.min()))
        d_max = min(float(cam.max_range), float(d.max()))
        if d_max <= d_min:
            raise ValueError(f"camera {cam.id}: the workspace lies outside its depth range")
        return d_min, d_max


@dataclass(frozen=True, eq=False)
class StaticObject:
    """A piece of known CAD: its world mesh, and its primitive when it is one (exact ground truth)."""
    name: str
    mesh: Mesh
    primitive: Optional[Primitive] = None

    def __repr__(self) -> str:
        kind = type(self.primitive).__name__.lower() if self.primitive is not None else "mesh"
        lo, hi = self.mesh.bounds
        return (f"StaticObject({self.name!r}, {kind}, {len(self.mesh.vertices)} vertices, "
                f"{len(self.mesh.faces)} faces, bounds {_vec(lo)}..{_vec(hi)} m)")


@dataclass(frozen=True, eq=False)
class Rig:
    """A validated cell description (R2). Build with :meth:`load` or :meth:`from_dict`."""

    name: str
    cameras: list[Camera]
    workspace: Workspace
    robot: Any = None                  # depthguard.robot.RobotModel or None
    robot_q0: Optional[np.ndarray] = None
    objects: list[StaticObject] = field(default_factory=list)
    path: Optional[Path] = None
    description: str = ""
    monitor: MonitorConfig = field(default_factory=MonitorConfig)   # the rig's ``monitor:`` section
    topics: dict = field(default_factory=dict)   # camera id -> depth Image topic (``topic:``, R31)
    depth_scales: dict = field(default_factory=dict)   # camera id -> m per 16-bit unit (``depth_scale:``, R31)
    learned: dict = field(default_factory=dict)   # camera id -> LearnedScene (``scene: {learned: DIR}``, issue 31)
    learned_dir: Optional[Path] = None            # that DIR, resolved

    def __repr__(self) -> str:
        """One line: the name, file, camera ids, workspace, robot and object names (no mesh arrays)."""
        robot = "none" if self.robot is None else getattr(self.robot, "name", type(self.robot).__name__)
        names = [o.name for o in self.objects]
        shown = ", ".join(names[:8]) + (f", ... ({len(names)} in all)" if len(names) > 8 else "")
        where = f", path={str(self.path)!r}" if self.path is not None else ""
        return (f"Rig({self.name!r}{where}, cameras=[{', '.join(self.camera_ids)}], "
                f"workspace={_vec(self.workspace.lo)}..{_vec(self.workspace.hi)} m, robot={robot}, "
                f"objects=[{shown}])")

    def camera(self, camera_id: str) -> Camera:
        for c in self.cameras:
            if c.id == camera_id:
                return c
        raise ValueError(f"rig {self.name!r} has no camera {camera_id!r}; cameras: "
                         f"{', '.join(c.id for c in self.cameras)}")

    @property
    def camera_ids(self) -> list[str]:
        return [c.id for c in self.cameras]

    def static_meshes(self) -> list[Mesh]:
        return [o.mesh for o in self.objects]

    def learned_depth(self, camera_id: str) -> Optional[np.ndarray]:
        """(H, W) float32 m: camera ``camera_id``'s learned static scene (0 = unknown), or None
        when the rig has none for it (:mod:`depthguard.learned_scene`)."""
        sc = self.learned.get(camera_id)
        return None if sc is None else sc.depth

    def without_cad(self) -> "Rig":
        """This rig with its static CAD objects taken out (the learned scene, if any, stays): what a
        cell without CAD sees, for comparing the two."""
        import dataclasses
        return dataclasses.replace(self, objects=[])

    def with_learned(self, folder) -> "Rig":
        """This rig with the learned scene in ``folder`` (:func:`depthguard.learned_scene.load`;
        a scene learned at another camera pose or size raises its one-sentence error)."""
        import dataclasses

        from depthguard.learned_scene import load
        return dataclasses.replace(self, learned=load(folder, self.cameras), learned_dir=Path(folder))

    def key(self) -> str:
        """Hash of every camera (for caches keyed by the rig's geometry)."""
        import hashlib
        return hashlib.sha256("".join(c.key() for c in self.cameras).encode()).hexdigest()[:16]

    # ---------------------------------------------------------------- load
    @classmethod
    def load(cls, path: str | Path) -> "Rig":
        """Load and validate a rig YAML file; :class:`RigError` names the file, field and problem."""
        p = Path(path)
        if not p.is_file():
            raise RigError(f"{p}: rig file not found")
        try:
            data = yaml.safe_load(p.read_text())
        except yaml.YAMLError as exc:
            raise RigError(f"{p}: not valid YAML: {exc}") from None
        except UnicodeDecodeError:
            raise RigError(f"{p}: not a text file") from None
        return cls.from_dict(data, source=p)

    @classmethod
    def from_dict(cls, data: Any, source: str | Path = "<rig>") -> "Rig":
        src = str(source)
        base_dir = Path(source).parent if isinstance(source, Path) else Path.cwd()
        if not isinstance(data, dict):
            raise RigError(f"{src}: a rig must be a mapping with workspace and cameras (got {type(data).__name__})")
        try:
            spec = RigSpec.model_validate(data)
        except ValidationError as exc:
            raise RigError(_format_errors(src, exc)) from None

        cameras = []
        for i, cs in enumerate(spec.cameras):
            try:
                cameras.append(cs.to_camera())
            except (CameraError, ValueError) as exc:
                raise RigError(f"{src}: cameras[{i}] ({cs.id}): {exc}") from None
        ws = Workspace(np.asarray(spec.workspace.min, float), np.asarray(spec.workspace.max, float))

        objects = []
        for i, o in enumerate(spec.objects):
            try:
                objects.append(_make_object(o, base_dir))
            except (FileNotFoundError, ValueError) as exc:
                field_name = "mesh" if o.mesh is not None else "pose"
                raise RigError(f"{src}: objects[{i}].{field_name} ({o.name}): {exc}") from None

        learned, learned_dir = {}, None
        if spec.scene is not None and spec.scene.learned:
            from depthguard.learned_scene import LearnedSceneError, load
            learned_dir = (base_dir / spec.scene.learned).resolve()
            try:
                learned = load(learned_dir, cameras)
            except LearnedSceneError as exc:
                raise RigError(f"{src}: scene.learned: {exc}") from None

        robot, q0 = None, None
        if spec.robot is not None:
            robot, q0 = _make_robot(spec.robot, base_dir, src)
            inside = robot_inside_objects(robot, q0, objects)     # mounted 20 cm inside its table
            if inside:
                raise RigError(f"{src}: robot: {inside}")
        return cls(name=spec.name, cameras=cameras, workspace=ws, robot=robot, robot_q0=q0,
                   objects=objects, path=Path(source) if isinstance(source, Path) else None,
                   description=spec.description, monitor=spec.monitor or MonitorConfig(),
                   topics={c.id: c.topic for c in spec.cameras if c.topic},
                   depth_scales={c.id: c.depth_scale for c in spec.cameras if c.depth_scale is not None},
                   learned=learned, learned_dir=learned_dir)


def _make_object(o: ObjectSpec, base_dir: Path) -> StaticObject:
    T = o.pose.matrix4() if o.pose is not None else np.eye(4)
    prim: Optional[Primitive] = None
    if o.box is not None:
        prim = Box(size=o.box.size, world_from_local=T, name=o.name)
    elif o.sphere is not None:
        prim = Sphere(radius=o.sphere.radius, world_from_local=T, name=o.name)
    elif o.cylinder is not None:
        prim = Cylinder(radius=o.cylinder.radius, length=o.cylinder.length, world_from_local=T, name=o.name)
    elif o.capsule is not None:
        prim = Capsule(radius=o.capsule.radius, length=o.capsule.length, world_from_local=T, name=o.name)
    if prim is not None:
        return StaticObject(o.name, prim.mesh(), prim)
    mpath = Path(o.mesh)
    if not mpath.is_absolute():
        mpath = base_dir / mpath
    if not mpath.is_file():
        raise FileNotFoundError(f"mesh file not found: {mpath}")
    mesh = load_mesh(mpath, scale=o.scale)
    problem = mesh_extent_problem(*mesh.bounds, o.scale)     # millimetres without scale: 1000 x too large
    if problem:
        raise ValueError(f"{mpath.name}: {problem}")
    return StaticObject(o.name, mesh.transformed(T), None)


def _make_robot(rs: RobotSpec, base_dir: Path, src: str):
    from depthguard.robot import load_robot

    base = rs.base.matrix4() if rs.base is not None else np.eye(4)
    target = rs.name
    if rs.urdf is not None and rs.urdf.startswith("package://"):
        from depthguard.robot.urdf import resolve_uri
        try:                                     # a ROS package's URDF (example-robot-data, ROS_PACKAGE_PATH)
            target = str(resolve_uri(rs.urdf, base_dir))
        except FileNotFoundError as exc:
            raise RigError(f"{src}: robot.urdf: {str(exc).replace('cannot resolve mesh', 'cannot find')} (package:// "
                           f"looks in example-robot-data's share folder, then $ROS_PACKAGE_PATH)") from None
    elif rs.urdf is not None:
        up = Path(rs.urdf)
        target = str(up if up.is_absolute() else base_dir / up)
        if not Path(target).is_file():
            raise RigError(f"{src}: robot.urdf: file not found: {target}")
    try:
        robot = load_robot(target, base=base)
    except (ValueError, FileNotFoundError) as exc:
        fld = "robot.name" if rs.name is not None else "robot.urdf"
        raise RigError(f"{src}: {fld}: {exc}") from None
    if rs.control_points is not None:
        from depthguard.robot import ControlPoint
        cps = []
        for i, c in enumerate(rs.control_points):
            link = c.link
            if isinstance(link, str) and link not in robot.link_names:
                raise RigError(f"{src}: robot.control_points[{i}].link: unknown link {link!r}; "
                               f"links: {', '.join(robot.link_names)}")
            if isinstance(link, int) and not (0 <= link < len(robot.link_names)):
                raise RigError(f"{src}: robot.control_points[{i}].link: index {link} out of range "
                               f"[0, {len(robot.link_names)})")
            cps.append(ControlPoint(c.name, link, np.asarray(c.offset, float), c.radius))
        robot = robot.with_control_points(cps)
    q0 = np.asarray(robot.q_home, dtype=float).copy()
    if rs.joints is not None:
        q = np.asarray(rs.joints, dtype=float)
        if q.shape != (robot.dof,):
            raise RigError(f"{src}: robot.joints: expected {robot.dof} joint values for {robot.name}, got {q.size}")
        problem = joint_limits_problem(robot, q)
        if problem:
            raise RigError(f"{src}: robot.joints{problem}")
        q0 = q
    return robot, q0


def joint_limits_problem(robot, q: np.ndarray) -> Optional[str]:
    """``"[j]: v rad is outside the joint limits [lo, hi]"`` for the first joint of ``q`` (dof,)
    rad outside ``robot.q_min``/``q_max``, else None; callers prefix the field (``robot.joints``)."""
    q = np.asarray(q, dtype=float)
    bad = np.nonzero((q < robot.q_min - 1e-9) | (q > robot.q_max + 1e-9))[0]
    if not bad.size:
        return None
    j = int(bad[0])
    return (f"[{j}]: {q[j]:.4f} rad is outside the joint limits [{robot.q_min[j]:.4f}, {robot.q_max[j]:.4f}]"
            f" of {robot.name}")


def _format_errors(src: str, exc: ValidationError) -> str:
    lines = []
    for err in exc.errors():
        loc = ""
        for part in err["loc"]:
            if isinstance(part, int):
                loc += f"[{part}]"
            else:
                loc += ("." if loc else "") + str(part)
        msg = err["msg"]
        if msg.startswith("Value error, "):
            msg = msg[len("Value error, "):]
        if err["type"] == "extra_forbidden":
            msg = "unknown field (check the spelling)"
        if err["type"] == "missing":
            msg = "required field is missing"
        lines.append(f"{src}: {loc or '<top>'}: {msg}")
    return "\n".join(lines)
