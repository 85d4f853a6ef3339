"""The rig file's schema (R2): pydantic models of every section, validated once when a rig loads.

:mod:`depthguard.rig` turns a validated :class:`RigSpec` into a :class:`~depthguard.rig.Rig`
(and every validation error into a ``RigError`` naming the file and the field); apart to keep
each file short.
"""

from __future__ import annotations

import math
from typing import Optional, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

from depthguard.camera import Camera
from depthguard.config import MonitorConfig
from depthguard.transforms import as_rigid, look_at, pose, quat_to_matrix

__all__ = ["RIG_SCHEMA_VERSION", "RigSpec", "CameraSpec", "LookAtSpec", "PoseSpec", "WorkspaceSpec",
           "ControlPointSpec", "RobotSpec", "BoxShape", "SphereShape", "CylinderShape", "ObjectSpec"]

RIG_SCHEMA_VERSION = 1


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
