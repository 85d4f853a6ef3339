"""``MonitorConfig``: every product default of the runtime, defined once (R27–R30, R32).

A rig file may carry a ``monitor:`` section with any of these fields; it is
validated when the rig loads (:meth:`depthguard.rig.Rig.load`), and a bad
value gives a :class:`~depthguard.rig.RigError` naming the file, the field
and the problem, like the rest of the rig. The runtime
(:class:`depthguard.runtime.Monitor`) reads nothing else.

The model sits beside ``rig.py`` rather than in ``runtime/`` because the rig
validates it when it loads, and ``rig.py`` is imported by everything above it.

Units: metres, seconds, hertz. ``None`` means "derived": the text of each
field says from what.
"""

from __future__ import annotations

import math
import re
from typing import Annotated, Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from depthguard.control.ssm_config import SSMConfig

__all__ = ["MonitorConfig", "WatchPoint", "CAMERA_ID_PATTERN", "check_camera_id", "PRODUCT_RHO", "PRODUCT_ROBOT_OFFSET",
           "PRODUCT_METHOD", "PRODUCT_INVALID", "PRODUCT_ROBOT_IN_OTHERS", "PRODUCT_DELTA_D", "PRODUCT_ROBOT_PADDING",
           "PRODUCT_CAMERA_HZ", "PRODUCT_JOINT_WAIT_S"]

_Vec3 = tuple[float, float, float]

#: camera ids must name a Zenoh key chunk and a file: letters, digits, ``_ - .``
CAMERA_ID_PATTERN = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\-]*$")


def check_camera_id(cid: str) -> str:
    """``cid`` if it can name a Zenoh key chunk (no ``/ * $ #`` or spaces), else ``ValueError``."""
    if not isinstance(cid, str) or not CAMERA_ID_PATTERN.match(cid):
        raise ValueError(f"camera id {cid!r} cannot name a Zenoh key: use letters, digits, '_', '-' or '.'")
    return cid


class WatchPoint(BaseModel):
    """A fixed point of the cell watched like a control point (a door, a hand-over spot)."""
    model_config = ConfigDict(extra="forbid", frozen=True)
    name: str = Field(min_length=1)
    position: _Vec3


#: R9 self removal: a pixel is the robot's where ``measured >= robot_depth - offset`` (m); the offset
#: "covers sensor noise" (SPEC R9, R17). For the Kinect v1 of the papers' cells (sigma_z = 1.2 mm z^2,
#: disparity quantised to 1/8 px, f = 585 px, baseline 7.5 cm) at 3 m: 3 sigma = 3.2 cm plus one
#: disparity step 2.6 cm, and the robot's motion during the exposure: 8 cm. (The library's distance
#: functions once said 3 cm, 1 sigma at 5 m: too small for a noisy far pixel, which then showed the
#: robot as its own obstacle.) The default of MonitorConfig and of every library function, once.
PRODUCT_ROBOT_OFFSET: float = 0.08


class MonitorConfig(BaseModel):
    """Settings of :class:`depthguard.runtime.Monitor` (the ``monitor:`` section of a rig).

    Distances (R3–R12): ``rho`` radius of surveillance; ``method`` R7
    aggregation; ``delta_d`` depth slice of the grid (R10); ``principal`` the
    grid's principal camera (default: the rig's first camera); ``principal_bin`` the
    principal's pixels per grid column side (2: one column per 2x2 pixels, a quarter of
    the columns to classify and look up; distances can only come out smaller, by at most
    a block's width at its depth, 1.1 cm for a 640x480 Kinect at 3 m; 1: the paper's grid).
    A rig with a robot that does not set it gets the finest column that keeps a point's
    region of surveillance at the robot within 64 columns across
    (:func:`depthguard.grid_budget.auto_principal_bin`: the build's cost bounded by design,
    issue 29; ``Rig.principal_bin_why`` says what was chosen); 2 here otherwise.
    ``fusion_duty`` the share of a core the fusion thread may take (R36): a build of b
    seconds on n numba threads rests b (n / duty - 1) before the next, frames that come
    meanwhile going into that one, so the fusion cannot starve the cameras' workers however
    many frames come (1: build whenever a frame comes); ``fusion_threads`` its numba threads
    (0: all). ``camera_shares``: each other camera's worker also works out which of the grid's
    cells its frame clears, for the fusion's build to install
    (:mod:`~depthguard.runtime.camera_shares`; the same distances, bit for bit). Off by
    default: it takes 0.2-0.5 ms off the fusion's serial build, but costs more CPU on the
    workers than it saves in the build — on the project's 2-core machine 0.004-0.009 of a core
    more per camera at every count from 2 to 16 cameras, with the same frame-to-reaction p99
    (``depthguard bench --only monitor``, issue 29). On for a machine with cores to spare
    whose fusion thread is what holds the frames back.

    Self removal (R9, R30): ``robot_offset`` a pixel is the robot's where
    ``measured >= robot_depth - robot_offset`` (covers the sensor's noise and
    the robot's motion during the exposure); ``robot_padding`` grid cells
    whose centre lies within this of the robot's capsules are its own (7 cm:
    two cameras see a link of radius r, with the dropout band of
    ``silhouette_px`` around its outline of width w, as a prism whose edges
    lie up to sqrt(2) (r + w) - r beyond its surface — 5.7 cm for the LWR's
    7 cm links and w = 2 cm; with 5 cm the robot alone saw its own shadow);
    ``robot_in_others`` what a robot pixel of a non-principal camera says
    (``"unknown"``: free up to the robot, unknown behind it).

    Invalid pixels (R28, R32): ``invalid = "unknown"`` (the safe default: the
    ray is unknown from the near range on) or ``"free"`` (simulated cells
    without walls only). ``silhouette_px``: invalid pixels within this many
    pixels of the robot's rendered silhouette take the robot's meaning
    (free up to the robot, unknown behind it) instead of "unknown from the
    near range" — the dropout at the robot's own depth edges is not an
    obstacle in front of the robot (0 turns the rule off). ``gap_px``: an
    invalid run of at most this many pixels along a row or column, between
    returns, is unknown from the nearer return's depth (the fixed scene's
    edge dropout; a dark object narrower than this can be missed: 3 px is
    2.1 cm at 4 m for a Kinect v1). A finite measurement beyond the camera's
    rated range is free up to that range and unknown behind (R28).

    Supervision (R26, R27): ``camera_stale_s`` a camera whose newest frame
    is older than this is stale (default: 3 periods of ``camera_hz``);
    ``joints_stale_s`` likewise for the joint stream; ``joint_history_s``
    how far back joint states are kept for capture-time self removal (a
    frame stamped before the oldest kept state is refused, R30);
    ``joint_wait_s`` how long a frame stamped after the newest joint state
    waits for the joints to catch up before it is refused.

    Drift watch (R34, :mod:`depthguard.runtime.drift`): ``drift_watch`` turns it on; a camera
    whose frames show more than ``drift_share`` of the known static scene farther than expected
    (by ``drift_sigma`` times its noise + 1 cm) in ``drift_frames`` consecutive frames is
    untrusted (stop reason ``untrusted:<camera>``) until recalibrated or accepted
    (``Monitor.accept_camera``).

    Change watch (issue 31, R38; :mod:`depthguard.runtime.scene_change`), on every camera with a
    learned scene (``scene: {learned: DIR}``): a sample nearer than the learned surface by more
    than its band for ``scene_change_new_s`` seconds without a break is *new* (a person walking
    through is not; one standing still is reported and stays an obstacle: never learned), one
    farther for ``scene_change_gone_s`` is *gone*; the image is cut into
    ``scene_change_regions`` (rows, columns) tiles and a tile with at least
    ``scene_change_min_share`` of its judged samples changed is reported (``Monitor.scene_changes``,
    the log and ``summary.json``).

    Reaction (R13, R14): ``v_max``, ``alpha`` of the repulsion and the
    limits; ``stop_time`` / ``resume_time`` the override's ramps from 1 to 0
    and back; ``control_hz`` the rate ``step`` is called at (its ``dt``);
    ``control_priority`` the SCHED_FIFO priority of the control thread in a
    real-time run (1–99, as ros2_control's ``thread_priority``; 0 = normal
    scheduling; where the system does not permit it the run goes on with
    normal scheduling and its summary says so, :mod:`depthguard.runtime.realtime`).
    ``distance_hz``: in a real-time run the grid is queried on a thread of its own at this
    rate and each cycle bounds the newest answer at its own joints (a point that moved by
    Δ is reported ``Δ`` nearer); ``distance_margin`` the band beyond ``rho`` that the thread
    queries: a point that moved farther since is queried by the cycle itself
    (:mod:`depthguard.runtime.distances`); 0 Hz = every cycle queries (as fast runs do).

    ``remote_cameras``: rig cameras served by distributed camera units (R20):
    their voxels, not their frames, reach the monitor (``push_voxels``); the
    distance to a voxel's box counts (R25) and a unit's staleness is its
    camera's (R27). A unit drops invalid pixels (R17), so its camera clears
    nothing and judges nothing: only cameras with frames make a point observed.
    ``state_cameras``: rig cameras whose units send their frames' depth grid state instead
    (issue 29, ``depthguard node --states``, ``Monitor.push_state``): they join the depth grid like
    cameras with frames and the distances are those of the centralised fusion; the monitor
    renders nothing for them (:mod:`depthguard.runtime.unit_states`).

    ``reaction`` (R33): ``"repulsion"`` (R13, R14, the default), ``"ssm"`` speed and separation
    monitoring (ISO/TS 15066: a speed scale and a protective stop, no repulsion, the joint
    box from the joint limits only), ``"both"``; ``ssm`` its settings
    (:class:`~depthguard.control.ssm_config.SSMConfig`, docs/SSM.md). ``reactions``: the
    reaction policies by registered name (:mod:`depthguard.control.policy`, e.g.
    ``[repulsion, ssm]``: the most restrictive wins); when given it replaces ``reaction``,
    which is the shorthand for ``[repulsion]``, ``[ssm]``, ``[repulsion, ssm]``.

    ``watch_points``: fixed points reported like control points (distance,
    direction, observed); they do not change the reaction. ``cell``: the
    name under ``depthguard/<cell>/...`` of the Zenoh publications;
    ``zenoh_listen``: where the monitor's Zenoh session listens (loopback
    unless told otherwise).

    Free space (R21, R37; :mod:`depthguard.runtime.free_space_map`): ``free_space`` keeps the
    voxel map of free, unknown and occupied space of the workspace on its own thread (off by
    default), rebuilt at ``free_space_hz`` from the newest frames, voxels of ``free_space_voxel``
    m; :meth:`~depthguard.runtime.Monitor.check_path` judges planned paths in it, with the
    robot's capsules padded by ``robot_padding`` against what the cameras saw and by
    ``free_space_scene_padding`` (2 cm) against the known CAD scene (exact and static).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    def scene_change_settings(self) -> dict:
        """The change watch's keywords (:class:`~depthguard.runtime.scene_change.SceneChangeWatch`)
        from the ``scene_change_*`` fields (issue 31)."""
        return dict(new_after_s=self.scene_change_new_s, gone_after_s=self.scene_change_gone_s,
                    regions=tuple(self.scene_change_regions), min_share=self.scene_change_min_share)

    rho: float = Field(0.4, gt=0.0, le=5.0)
    method: Literal["min", "mean", "hybrid"] = "hybrid"
    delta_d: float = Field(0.01, gt=0.0, le=0.5)
    principal: Optional[str] = None
    principal_bin: int = Field(2, ge=1, le=8)
    fusion_duty: float = Field(1.0, gt=0.0, le=1.0)
    fusion_threads: int = Field(0, ge=0, le=256)
    camera_shares: bool = False
    cameras: Optional[tuple[str, ...]] = None
    robot_offset: float = Field(PRODUCT_ROBOT_OFFSET, ge=0.0, le=1.0)
    robot_padding: float = Field(0.07, ge=0.0, le=0.5)
    robot_in_others: Literal["unknown", "free"] = "unknown"
    invalid: Literal["unknown", "free"] = "unknown"
    silhouette_px: int = Field(4, ge=0, le=64)
    gap_px: int = Field(3, ge=0, le=16)
    camera_hz: float = Field(30.0, gt=0.0, le=1000.0)
    camera_stale_s: Optional[float] = Field(None, gt=0.0, le=10.0)
    joints_stale_s: float = Field(0.05, gt=0.0, le=10.0)
    joint_history_s: float = Field(1.0, gt=0.0, le=60.0)
    joint_wait_s: float = Field(0.05, ge=0.0, le=1.0)
    drift_watch: bool = True
    drift_share: float = Field(0.02, gt=0.0, le=1.0)
    drift_sigma: float = Field(3.0, gt=0.0, le=20.0)
    drift_frames: int = Field(3, ge=1, le=300)
    scene_change_new_s: float = Field(10.0, gt=0.0, le=3600.0)
    scene_change_gone_s: float = Field(1.0, gt=0.0, le=3600.0)
    scene_change_regions: tuple[Annotated[int, Field(ge=1, le=64)], Annotated[int, Field(ge=1, le=64)]] = (3, 4)
    scene_change_min_share: float = Field(0.05, gt=0.0, le=1.0)
    control_hz: float = Field(500.0, gt=0.0, le=10000.0)
    control_priority: int = Field(50, ge=0, le=99)
    distance_hz: float = Field(250.0, ge=0.0, le=10000.0)
    distance_margin: float = Field(0.02, gt=0.0, le=0.5)
    v_max: float = Field(1.5, gt=0.0, le=10.0)
    alpha: float = Field(5.0, gt=0.0, le=100.0)
    stop_time: float = Field(0.5, gt=0.0, le=10.0)
    resume_time: float = Field(1.0, gt=0.0, le=60.0)
    remote_cameras: tuple[str, ...] = ()
    state_cameras: tuple[str, ...] = ()
    watch_points: tuple[WatchPoint, ...] = ()
    cell: Optional[str] = None
    zenoh_listen: str = "tcp/127.0.0.1:0"
    reaction: Literal["repulsion", "ssm", "both"] = "repulsion"
    ssm: SSMConfig = Field(default_factory=SSMConfig)
    free_space: bool = False
    free_space_hz: float = Field(10.0, gt=0.0, le=100.0)
    free_space_voxel: float = Field(0.05, ge=0.01, le=0.5)
    free_space_scene_padding: float = Field(0.02, ge=0.0, le=0.5)
    reactions: Optional[tuple[str, ...]] = None

    @field_validator("reactions")
    @classmethod
    def _reactions(cls, v):
        if v is not None:
            from depthguard.control.policy import reaction_names

            if not v:
                raise ValueError("reactions must name at least one reaction policy (or be left out: reaction)")
            unknown = [n for n in v if n not in reaction_names()]
            if unknown:
                raise ValueError(f"unknown reaction {unknown[0]!r}; known: {', '.join(reaction_names())}")
            if len(set(v)) != len(v):
                raise ValueError(f"reactions repeats a name: {list(v)}")
        return v

    @field_validator("cameras")
    @classmethod
    def _ids(cls, v):
        if v is not None:
            if not v:
                raise ValueError("cameras must name at least one camera (or be left out: all)")
            for c in v:
                check_camera_id(c)
            if len(set(v)) != len(v):
                raise ValueError(f"cameras repeats an id: {list(v)}")
        return v

    @field_validator("remote_cameras", "state_cameras")
    @classmethod
    def _remote(cls, v):
        for c in v:
            check_camera_id(c)
        if len(set(v)) != len(v):
            raise ValueError(f"a camera list repeats an id: {list(v)}")
        return v

    @field_validator("zenoh_listen")
    @classmethod
    def _endpoint(cls, v):
        if not re.match(r"^(tcp|udp|quic|tls|unixsock-stream)/\S+$", v):
            raise ValueError(f"zenoh_listen {v!r} is not a Zenoh endpoint like 'tcp/127.0.0.1:7447'")
        return v

    @field_validator("cell")
    @classmethod
    def _cell(cls, v):
        if v is not None:
            check_camera_id(v)
        return v

    @model_validator(mode="after")
    def _finite(self) -> "MonitorConfig":
        for name, value in self:
            if isinstance(value, float) and not math.isfinite(value):
                raise ValueError(f"{name} must be finite (got {value})")
        if self.cameras is not None and set(self.cameras) & set(self.remote_cameras):
            raise ValueError(f"cameras and remote_cameras share {sorted(set(self.cameras) & set(self.remote_cameras))}: "
                             f"a camera sends frames or voxels, not both")
        names = [w.name for w in self.watch_points]
        if len(set(names)) != len(names):
            raise ValueError(f"watch point names must be unique (got {names})")
        return self

    # ------------------------------------------------------------- derived
    @property
    def dt(self) -> float:
        """Seconds between two control cycles (1 / ``control_hz``)."""
        return 1.0 / self.control_hz

    @property
    def policies(self) -> tuple[str, ...]:
        """The reaction policies that run (:mod:`depthguard.control.policy`): ``reactions``, else
        the ``reaction`` shorthand's."""
        from depthguard.control.policy import LEGACY_MODES

        return self.reactions if self.reactions is not None else LEGACY_MODES[self.reaction]

    @property
    def reaction_mode(self) -> str:
        """The result's ``reaction`` field: ``repulsion``, ``ssm``, ``both``, or the names joined by '+'."""
        from depthguard.control.policy import mode_name

        return mode_name(self.policies)

    @property
    def query_rho(self) -> float:
        """Radius (m) the distances are looked for in: the largest reach of the policies that run
        (``rho``; ``max(rho, ssm.range)`` with speed and separation monitoring, R33)."""
        from depthguard.control.policy import policy_reach

        return max([self.rho] + [policy_reach(n, self) for n in self.policies])

    @property
    def camera_stale_limit(self) -> float:
        """Seconds after which a camera's newest frame is stale (R27)."""
        return 3.0 / self.camera_hz if self.camera_stale_s is None else float(self.camera_stale_s)

    def with_changes(self, **changes) -> "MonitorConfig":
        """A validated copy with ``changes`` applied (``ValueError`` naming the field on a bad value)."""
        from pydantic import ValidationError

        data = self.model_dump()
        data.update(changes)
        try:
            return MonitorConfig.model_validate(data)
        except ValidationError as exc:
            raise ValueError("; ".join(f"{'.'.join(str(p) for p in e['loc']) or 'monitor'}: "
                                       f"{e['msg'].removeprefix('Value error, ')}" for e in exc.errors())) from None


#: the product's radius of surveillance (m): the default of the library's distance queries too
PRODUCT_RHO: float = MonitorConfig.model_fields["rho"].default
#: the other product defaults that library signatures take (each defined once, in MonitorConfig above)
PRODUCT_METHOD: str = MonitorConfig.model_fields["method"].default                  # R7 aggregation
PRODUCT_INVALID: str = MonitorConfig.model_fields["invalid"].default                # R28
PRODUCT_ROBOT_IN_OTHERS: str = MonitorConfig.model_fields["robot_in_others"].default  # R12
PRODUCT_DELTA_D: float = MonitorConfig.model_fields["delta_d"].default              # m, R10
PRODUCT_ROBOT_PADDING: float = MonitorConfig.model_fields["robot_padding"].default  # m, R12
PRODUCT_CAMERA_HZ: float = MonitorConfig.model_fields["camera_hz"].default          # Hz
PRODUCT_JOINT_WAIT_S: float = MonitorConfig.model_fields["joint_wait_s"].default    # s, R30
