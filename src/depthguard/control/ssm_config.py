"""``SSMConfig``: the settings of speed and separation monitoring (R33), the ``monitor.ssm:`` section.

Every term of ISO/TS 15066 formula (1) is a named setting or is computed from
named settings (:mod:`depthguard.control.ssm`):

    S_p = S_h + S_r + S_s + C + Z_d + Z_r,   S_h = v_h (T_r + T_s),   S_r = v_r T_r

Units: metres, seconds, m/s, m/s². Not a safety-rated function (docs/SSM.md).
"""

from __future__ import annotations

import math
from typing import Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = ["SSMConfig", "StoppingTable", "intrusion_distance"]


def intrusion_distance(d: float) -> float:
    """ISO 13855 intrusion distance ``C`` (m) of a sensing with detection capability ``d`` (m):
    ``8 (d − 14 mm)`` for ``d ≤ 40 mm`` (0 below 14 mm), 850 mm above (reach of an arm)."""
    if not (math.isfinite(d) and d >= 0.0):
        raise ValueError(f"detection capability must be a finite length >= 0 m (got {d!r})")
    if d > 0.040:
        return 0.850
    return max(0.0, 8.0 * (d - 0.014))


class StoppingTable(BaseModel):
    """Stopping distance and time against speed, as a manufacturer publishes them (ISO 10218-1
    annex B style): ``speed`` (k,) m/s increasing from 0, ``distance`` (k,) m and ``time`` (k,) s
    non-decreasing. Linear between rows; above the last row the last segment is extended."""
    model_config = ConfigDict(extra="forbid", frozen=True)
    speed: tuple[float, ...]
    distance: tuple[float, ...]
    time: tuple[float, ...]

    @model_validator(mode="after")
    def _check(self) -> "StoppingTable":
        k = len(self.speed)
        if k < 2 or len(self.distance) != k or len(self.time) != k:
            raise ValueError(f"stop_table needs >= 2 rows with as many speeds, distances and times "
                             f"(got {len(self.speed)}, {len(self.distance)}, {len(self.time)})")
        if self.speed[0] != 0.0:
            raise ValueError(f"stop_table.speed must start at 0 m/s (got {self.speed[0]})")
        for name, vals in (("speed", self.speed), ("distance", self.distance), ("time", self.time)):
            if any(not math.isfinite(v) or v < 0 for v in vals):
                raise ValueError(f"stop_table.{name} must be finite and >= 0 (got {list(vals)})")
        if any(b <= a for a, b in zip(self.speed, self.speed[1:])):
            raise ValueError(f"stop_table.speed must increase strictly (got {list(self.speed)})")
        for name, vals in (("distance", self.distance), ("time", self.time)):
            if any(b < a for a, b in zip(vals, vals[1:])):
                raise ValueError(f"stop_table.{name} must not decrease with speed (got {list(vals)})")
        return self


class SSMConfig(BaseModel):
    """Speed and separation monitoring (R33). Read with :mod:`depthguard.control.ssm`.

    Person (S_h): ``v_h`` m/s towards the robot (ISO 13855 K = 1.6) where the
    separation exceeds ``near_limit`` (0.5 m), ``v_h_near`` (2.0) within it;
    ``v_h_mode = "measured"``: the rate at which the distance of a point shrinks
    beyond the robot's own approach, never below ``v_h_floor``.

    Reaction time T_r = ``camera_latency_s`` (exposure to the frame's stamp;
    0 when stamps are capture times) + the measured age of the oldest frame in
    use at the cycle (capture to reaction, the monitor's clock) + one control
    period + ``controller_latency_s`` (the robot controller applying the scale).

    Stopping (S_s, T_s) of a point moving towards the obstacle at v:
    ``stop_model = "deceleration"``: ``T_s = brake_delay_s + v / deceleration``,
    ``S_s = v brake_delay_s + v² / (2 deceleration)``; ``"table"``: ``stop_table``.

    C from ``detection_capability`` (m, ISO 13855; ``None`` = derived from the
    cameras: ``gap_px + 1`` pixels at the farthest camera's rated range).
    Z_d: computed per point (pixel footprint, ``delta_d``, ``noise_sigmas`` times
    the depth noise of the camera's sensor model, ``default_sigma_*`` for a camera
    without one); ``z_r`` the robot's position uncertainty.

    ``range`` m: how far the distances are looked for in ssm mode (the query
    radius is ``max(rho, range)``); nothing within it counts as an obstacle at
    ``range``. Protective stop when the largest scale is ``<= stop_scale``;
    released after the scale stayed ``>= resume_scale`` for ``resume_hold_s``;
    the scale rises at most by ``1 / ramp_up_s`` per second (falls at once).

    ``known_scene`` (issue 31): ``"obstacle"`` (default) measures the separation from
    everything the cameras see, the known static scene included; ``"muted"`` from what is
    not the known scene (CAD or learned) nor the robot: each camera's frame filtered like a
    camera unit's (R17, :class:`~depthguard.fusion.voxels.VoxelFilter`), voxels of
    ``muted_voxel_size`` m. The known scene stays an obstacle for the motion checks and the
    repulsion; ``docs/SSM.md`` says what muting trades.
    """
    model_config = ConfigDict(extra="forbid", frozen=True)

    v_h: float = Field(1.6, gt=0.0, le=10.0)
    v_h_near: float = Field(2.0, gt=0.0, le=10.0)
    near_limit: float = Field(0.5, ge=0.0, le=10.0)
    v_h_mode: Literal["fixed", "measured"] = "fixed"
    v_h_floor: float = Field(1.0, gt=0.0, le=10.0)
    camera_latency_s: float = Field(0.0, ge=0.0, le=1.0)
    controller_latency_s: float = Field(0.008, ge=0.0, le=1.0)
    stop_model: Literal["deceleration", "table"] = "deceleration"
    deceleration: float = Field(2.5, gt=0.0, le=100.0)
    brake_delay_s: float = Field(0.0, ge=0.0, le=2.0)
    stop_table: Optional[StoppingTable] = None
    detection_capability: Optional[float] = Field(None, ge=0.0, le=1.0)
    z_r: float = Field(0.01, ge=0.0, le=1.0)
    noise_sigmas: float = Field(3.0, ge=0.0, le=10.0)
    default_sigma_a: float = Field(0.005, ge=0.0, le=1.0)
    default_sigma_z2: float = Field(0.002, ge=0.0, le=1.0)
    range: float = Field(1.0, gt=0.0, le=10.0)
    stop_scale: float = Field(0.0, ge=0.0, lt=1.0)
    resume_scale: float = Field(0.1, gt=0.0, le=1.0)
    resume_hold_s: float = Field(0.2, ge=0.0, le=10.0)
    ramp_up_s: float = Field(0.5, gt=0.0, le=60.0)
    known_scene: Literal["obstacle", "muted"] = "obstacle"
    muted_voxel_size: float = Field(0.03, ge=0.01, le=0.1)

    @model_validator(mode="after")
    def _check(self) -> "SSMConfig":
        if self.stop_model == "table" and self.stop_table is None:
            raise ValueError("stop_model 'table' needs a stop_table (speed, distance, time)")
        if self.resume_scale <= self.stop_scale:
            raise ValueError(f"resume_scale ({self.resume_scale}) must exceed stop_scale ({self.stop_scale}): "
                             f"the hysteresis")
        for name, value in self:
            if isinstance(value, float) and not math.isfinite(value):
                raise ValueError(f"ssm.{name} must be finite (got {value})")
        return self
