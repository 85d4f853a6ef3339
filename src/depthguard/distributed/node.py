"""A camera node (processing unit) of the distributed camera subsystem (Oščádal 2022, R20).

One node per camera: it holds a liveliness token ``<prefix>/alive/<camera>``,
initialises with the server (camera id + address → unit id + settings), then for
every frame filters locally (:class:`depthguard.fusion.voxels.VoxelFilter`,
R16–R19) and sends only its voxels (UPDATE_REQ); every reply carries the current
settings (voxel size, threshold, robot joints), applied from the next frame on.

Robot joints (R30). With a joint stream (``joint_source``, e.g. ``zenoh:KEY`` — the
payload of ``docs/MONITOR.md`` "Joint states over Zenoh", the same stream the monitor
reads) every frame is filtered with the robot at the joints interpolated at the
frame's **capture stamp** (:class:`depthguard.robot.joint_history.JointHistory`, never
extrapolated). A frame whose stamp lies outside the joint history (before the
oldest state kept, in a gap of the stream, or after the newest state once
``joint_wait_s`` has passed) is **skipped**: nothing is sent for it (the unit goes
stale at the server and at the monitor if that lasts, R27), it is counted in
``skipped`` by reason (the monitor's names for refused frames: ``too_old``, ``future``,
``joint_gap``, ``no_joints``; :meth:`~depthguard.robot.joint_history.JointHistory.wait_at`
is the wait both use) and the first skip of each reason is logged. The frame stamps
and the joint stamps must then be on one clock (the monitor's). The joints in the
server's settings are ignored in that case.

Without a joint stream the robot is removed at the joints of the server's settings
(``depthguard server --sim-time`` / ``joints`` setting, else the rig's starting
joints): a **fixed pose** — a robot that moves away from it leaves voxels of
itself in the node's output, and the space it moved into is not filtered.

States (issue 29, ``states=True``, ``depthguard node --states``): instead of voxels the node
publishes each frame's depth grid state on ``<prefix>/states/<camera>``, made with the monitor's
options from the server's settings (:mod:`depthguard.distributed.unit_state`, wire format
:mod:`depthguard.transport.state_wire`; signed with ``identity``); a frame is skipped (counted in
``skipped["no_options"]``) while the server's settings carry none. Its update to the server
then carries no voxels (freshness and settings only).

Sources (``frame_source``): any callable returning ``(depth (H, W) float32 m, stamp s)``;
:func:`pattern_source` (a synthetic patch, for tests) and :func:`sim_source`
(the simulated camera of a built-in cell) are provided.

Trust (R35): with an ``identity`` (``--keys NODEDIR``, a certificate naming this
camera) the node connects over ``tls/`` with mutual certificates, has no listener of
its own, signs every request and accepts only replies signed by the cell's server.

Server gone (restart, network): the node keeps its frame rate, logs the outage once
and retries; when the server is back its first update is refused as an unknown unit
(the server's state is new), the node initialises again and gets its id back from the
server's registry (:mod:`depthguard.distributed.registry`).

``python -m depthguard.distributed.node`` is the process entry used by tests and
benchmarks (the user command is ``depthguard node``).
"""

from __future__ import annotations

import argparse
import math
import os
import socket
import sys
import threading
import time
from typing import Callable, Sequence

import numpy as np

from depthguard.camera import Camera
from depthguard.config import PRODUCT_JOINT_WAIT_S
from depthguard.distributed.node_sources import FrameSource, pattern_source, sim_source, with_resolution  # noqa: F401 (re-exported)
from depthguard.fusion.voxels import FilterOffset, VoxelFilter, regrid
from depthguard.transport import wire
from depthguard.transport.client import ServerClient, ServerRefused, ServerUnavailable
from depthguard.transport.settings import DEFAULT_ENDPOINT, DEFAULT_LEASE_MS

__all__ = ["CameraNode", "pattern_source", "sim_source", "with_resolution", "build_node", "fit_to_wire", "main"]


def fit_to_wire(keys: np.ndarray, counts: np.ndarray, voxel_size: float):
    """Make a voxel set fit one message: while it has more than ``wire.MAX_VOXELS``,
    coarsen the voxel size (×2) conservatively (:func:`regrid`; counts become 1)."""
    s = voxel_size
    while len(keys) > wire.MAX_VOXELS:
        keys = regrid(keys, s, 2 * s)
        s *= 2
        counts = np.ones(len(keys), np.int32)
    return keys, counts, s


class CameraNode:
    """One processing unit: filter locally, send voxels, obey the server's settings.

    Parameters
    ----------
    cam : the node's Camera (from the rig). workspace : (lo, hi) box.
    source : ``() -> (depth, stamp)``.
    static_meshes, robot, robot_q0 : the known scene for the expected depth (R16).
    learned : (H, W) float32 m, the camera's learned static scene (issue 31, ``scene: {learned: DIR}``;
        0 = unknown) or None; with the CAD the nearer surface wins, as in the monitor's filter.
    connect : server endpoint(s). fps : frame rate limit (0 = as fast as possible).
    trigger : wait for a message on ``<prefix>/trigger`` before each frame (benchmarks).
    joint_source : a joint source (``states_until(t) -> [(stamp, q)]``, e.g.
        :class:`depthguard.sources.joints.ZenohJointSource`) or None. Given: the robot is
        removed at the joints interpolated at each frame's capture stamp; the server's
        settings joints are ignored (module docstring). ``joint_span_s`` seconds of states
        are kept; two states further apart than ``joint_gap_s`` are not interpolated
        between; a frame stamped after the newest state waits up to ``joint_wait_s``.
    """

    def __init__(self, cam: Camera, workspace, source: FrameSource, *, static_meshes: Sequence = (),
                 robot=None, robot_q0=None, learned=None, connect: Sequence[str] = (DEFAULT_ENDPOINT,),
                 listen: Sequence[str] | None = None, prefix: str = "depthguard",
                 fps: float = 15.0, trigger: bool = False, multicast: bool = False,
                 lease_ms: int = DEFAULT_LEASE_MS, log: Callable[[str], None] | None = None,
                 joint_source=None, joint_span_s: float = 1.0, joint_gap_s: float = math.inf,
                 joint_wait_s: float = PRODUCT_JOINT_WAIT_S, identity=None, insecure: bool = False,
                 init_timeout_s: float = 30.0, states: bool = False):
        from depthguard.transport.keys import ROLE_NODE
        from depthguard.transport.settings import check_exposure

        if identity is not None and (identity.role != ROLE_NODE or identity.name != cam.id):
            raise ValueError(f"--keys {identity.directory}: a certificate of {identity.role}/{identity.name}, "
                             f"not of camera {cam.id!r} (make one with `depthguard keys node {cam.id} ...`)")
        check_exposure(listen or [], connect, identity, insecure)
        self.init_timeout_s = float(init_timeout_s)
        self._outage: float | None = None
        self.cam = cam
        self.source = source
        self.filter = VoxelFilter(cam, workspace, static_meshes=static_meshes, robot=robot, learned=learned)
        self._default_offset = self.filter.offset
        self.robot = robot
        self.q = None if robot_q0 is None else np.asarray(robot_q0, dtype=float)
        self.fps = float(fps)
        self.trigger = trigger
        self._log = log or (lambda m: None)
        self.client = ServerClient(connect, listen, prefix, multicast, lease_ms, identity=identity)
        self.keys = self.client.keys
        self.unit_id: int | None = None
        self.settings: wire.Settings | None = None
        self.seq = 0
        self._token = None
        self._trigger_ev = threading.Event()
        self._trigger_seq = 0
        self._sub = None
        self.sent_bytes = 0
        self.joint_source = None
        self.history = None                    # JointHistory of the joint stream (attach_joints)
        self.joint_wait_s = float(joint_wait_s)
        self.skipped: dict[str, int] = {}      # frames not sent: stamp outside the joint history, by reason
        self.last_skip: str | None = None
        self.q_used: np.ndarray | None = None  # the joints the last frame was filtered with
        self.state_unit = None                 # states=True: the camera's share of the grid build
        if states:
            from depthguard.distributed.unit_state import StateUnit
            self.state_unit = StateUnit(cam, robot)
        if joint_source is not None:
            self.attach_joints(joint_source, span_s=joint_span_s, max_gap_s=joint_gap_s)

    # -------------------------------------------------------------- joints
    def attach_joints(self, source, span_s: float = 1.0, max_gap_s: float = math.inf) -> None:
        """Use the joint stream ``source`` from now on (module docstring; R30)."""
        from depthguard.robot.joint_history import JointHistory

        if self.robot is None:
            raise ValueError(f"camera {self.cam.id}: a joint stream needs the rig's robot (the rig has none)")
        self.joint_source = source
        self.history = JointHistory(self.robot.dof, span_s, q_min=self.robot.q_min, q_max=self.robot.q_max,
                                    max_gap_s=max_gap_s)

    def _drain_joints(self) -> None:
        for stamp, q in self.joint_source.states_until(math.inf):
            if not self.history.push(stamp, q):
                self._log(f"camera {self.cam.id}: joint state refused: {self.history.last_refusal}")

    def joints_at(self, stamp: float) -> np.ndarray | None:
        """The joints at capture ``stamp`` from the joint stream (waiting up to ``joint_wait_s``
        for states that lag the frame), or None — the frame is then skipped and counted."""
        from depthguard.robot.joint_history import OutsideHistory

        try:
            return self.history.wait_at(stamp, self.joint_wait_s, feed=self._drain_joints, poll_s=0.001,
                                        arrived=getattr(self.joint_source, "wait_for_states", None))
        except OutsideHistory as exc:
            first = exc.kind not in self.skipped
            self.skipped[exc.kind] = self.skipped.get(exc.kind, 0) + 1
            self.last_skip = f"frame at {stamp:.6f} s skipped: {exc} (R30)"
            if first:
                self._log(f"camera {self.cam.id}: {self.last_skip}; nothing is sent for such frames "
                          f"(counted in skipped, logged once)")
            return None

    @property
    def address(self) -> str:
        return f"{socket.gethostname()}/pid{os.getpid()}/zid{self.client.session.info.zid()}"

    # -------------------------------------------------------------- protocol
    def _apply(self, s: wire.Settings) -> None:
        """Adopt the server's settings (cheap when nothing changed: the filter keeps its
        buffers for an unchanged voxel size and its robot render for unchanged joints).
        No epoch shortcut: a restarted server counts its epochs from 0 again."""
        self.filter.configure(voxel_size=s.voxel_size, threshold=s.threshold)
        if math.isnan(s.offset_const) or math.isnan(s.offset_k):
            self.filter.offset = self._default_offset
        else:
            self.filter.offset = FilterOffset(s.offset_const, s.offset_k)
        if s.joints and self.robot is not None and self.joint_source is None:   # fixed pose: fallback only
            if len(s.joints) != self.robot.dof:
                self._log(f"ignoring {len(s.joints)} joints from the server (robot has {self.robot.dof})")
            else:
                self.q = np.asarray(s.joints, dtype=float)
        self.settings = s

    def declare_token(self) -> None:
        if self._token is not None:
            try:
                self._token.undeclare()
            except Exception:  # noqa: BLE001
                pass
        self._token = self.client.session.liveliness().declare_token(self.keys.alive(self.cam.id))

    def initialize(self, timeout: float | None = None) -> int:
        """INIT until the server answers; the unit id. ``ServerRefused`` if refused,
        ``ServerUnavailable`` (a sentence saying what to do) after ``timeout`` s (default
        ``init_timeout_s``) without an answer."""
        timeout = self.init_timeout_s if timeout is None else float(timeout)
        t_end = time.monotonic() + timeout
        said = False
        while True:
            try:
                m = self.client.request(self.keys.init, wire.init_request(self.cam.id, self.address), 0.5,
                                        wire.MsgType.INIT_REP)
                break
            except ServerUnavailable as exc:
                if not said:
                    self._log(f"camera {self.cam.id}: waiting for the fusion server on "
                              f"{', '.join(self.client.connect)} (up to {timeout:g} s)")
                    said = True
                if time.monotonic() > t_end:
                    raise ServerUnavailable(
                        f"no fusion server answered on {', '.join(self.client.connect)} within {timeout:g} s: "
                        f"start `depthguard server` first, or check --connect"
                        + (" and --keys" if self.client.identity is not None else "")
                        + (f" ({exc})" if "refused" in str(exc) else "")) from None
                time.sleep(0.05)
        self.unit_id = m.unit_id
        self._apply(m.settings)
        self._log(f"camera {self.cam.id}: unit id {self.unit_id}, voxel size {m.settings.voxel_size} m")
        return self.unit_id

    def step(self) -> int | None:
        """Capture, filter, send one update; the number of voxels sent, or None when the frame
        was skipped (joint stream given and its stamp outside the joint history)."""
        depth, stamp = self.source()
        if self.joint_source is not None:
            q = self.joints_at(float(stamp))
            if q is None:
                return None
        else:
            q = self.q
        self.q_used = None if q is None else np.array(q, dtype=float)
        self.seq = self._trigger_seq if self.trigger else self.seq + 1
        if self.state_unit is not None:
            if not self._send_state(depth, stamp, q):
                return None
            keys, counts, s = np.zeros((0, 3), np.int32), np.zeros(0, np.int32), self.settings.voxel_size
            invalid = float(np.count_nonzero(~(depth > 0))) / depth.size
        else:
            vs = self.filter.filter(depth, q=q)
            keys, counts, s = fit_to_wire(vs.keys, vs.counts, vs.voxel_size)
            invalid = vs.n_invalid / (self.cam.width * self.cam.height)
        msg = wire.update_request(self.unit_id, self.seq, stamp, s, keys, counts, invalid)
        self.sent_bytes += len(msg)
        try:
            rep = self.client.request(self.keys.update, msg, 1.0, wire.MsgType.UPDATE_REP)
        except ServerRefused as exc:
            if exc.code == 3:                  # server restarted: unknown unit → initialise again
                self._log(f"camera {self.cam.id}: {exc}; re-initialising")
                self.initialize(timeout=1.0)
                return len(keys)
            raise
        if rep.flags & 1:                       # the server does not see our token: declare again
            self.declare_token()
        self._apply(rep.settings)
        return len(keys)

    def _send_state(self, depth, stamp: float, q) -> bool:
        from depthguard.distributed.unit_state import publish_state
        return publish_state(self, depth, stamp, q)

    def run(self, stop: threading.Event | None = None, max_updates: int | None = None) -> None:
        """Token, initialise, then update at ``fps`` (or on each trigger) until ``stop``."""
        stop = stop or threading.Event()
        self.declare_token()
        self.initialize()
        if self.trigger:
            self._sub = self.client.session.declare_subscriber(self.keys.trigger, self._on_trigger)
        n = 0
        period = 1.0 / self.fps if self.fps > 0 else 0.0
        next_t = time.monotonic()
        while not stop.is_set() and (max_updates is None or n < max_updates):
            if self.trigger:
                if not self._trigger_ev.wait(0.2):
                    continue
                self._trigger_ev.clear()
            try:
                if self.step() is not None:
                    n += 1
                if self._outage is not None:
                    self._log(f"camera {self.cam.id}: server back after {time.monotonic() - self._outage:.1f} s")
                    self._outage = None
            except ServerUnavailable as exc:
                if self._outage is None:
                    self._outage = time.monotonic()
                    self._log(f"camera {self.cam.id}: {exc}; retrying every frame (logged once)")
            if period and not self.trigger:
                next_t += period
                delay = next_t - time.monotonic()
                if delay > 0:
                    stop.wait(delay)
                else:
                    next_t = time.monotonic()

    def _on_trigger(self, sample) -> None:
        try:
            self._trigger_seq = int.from_bytes(sample.payload.to_bytes()[:4], "little")
        except Exception:  # noqa: BLE001 - a bad trigger still triggers
            self._trigger_seq += 1
        self._trigger_ev.set()

    def close(self) -> None:
        try:
            if self._token is not None:
                self._token.undeclare()
        except Exception:  # noqa: BLE001
            pass
        if self.joint_source is not None:
            try:
                self.joint_source.close()
            except Exception:  # noqa: BLE001 - closing anyway
                pass
        self.client.close()


def build_node(rig_path: str | None, camera: str, source: str = "pattern", cell: str | None = None,
               sim_time: float = 0.0, seed: int = 0, resolution: tuple[int, int] | None = None,
               joints: str | None = None, joints_connect: Sequence[str] = (), **kw) -> CameraNode:
    # kw: CameraNode's keywords (states=True: send depth grid states, issue 29)
    """A node from a rig file, or from a built-in cell with ``source='sim'``.

    ``joints``: a joint source spec (``zenoh:KEY``, or ``csv:FILE`` for a recording) — the
    robot is then removed at each frame's capture joints (R30; history span, gap and wait
    from the rig's ``monitor:`` section: ``joint_history_s``, ``joints_stale_s``,
    ``joint_wait_s``). Its zenoh session is the node's own (connected to the server, listening
    on ``listen``) unless ``joints_connect`` names the publisher's endpoint(s). The built-in
    frame sources stamp frames with ``time.time()``: the joint stamps must be on that clock.
    """
    from depthguard.rig import Rig

    c = None
    if source == "sim":
        if cell is None:
            raise ValueError("--source sim needs --cell NAME (a built-in cell)")
        from depthguard.sim import load_cell
        c = load_cell(cell)
        rig = Rig.load(rig_path) if rig_path is not None else c.rig
        q0 = c.scene.robot_q(sim_time) if rig.robot is not None else None
    elif source == "pattern":
        if rig_path is None:
            raise ValueError("--rig is required with --source pattern")
        rig = Rig.load(rig_path)
        q0 = rig.robot_q0
    else:
        raise ValueError(f"unknown source {source!r}; use 'sim' or 'pattern'")
    cam = rig.camera(camera)
    learned = rig.learned_depth(cam.id)        # issue 31: the rig's learned scene (checked at the rig's size)
    if resolution is not None:
        cam = with_resolution(cam, *resolution)
        if learned is not None and tuple(learned.shape) != tuple(cam.shape):
            raise ValueError(f"--resolution {cam.width}x{cam.height}: camera {cam.id}'s learned scene "
                             f"({rig.learned_dir}) was learned at {learned.shape[1]}x{learned.shape[0]}; "
                             f"run the node at that size or learn the scene again at this one")
    ws = (rig.workspace.lo, rig.workspace.hi)
    src = sim_source(c, cam, sim_time, seed) if c is not None else pattern_source(cam, ws)
    if joints is not None and rig.robot is None:
        raise ValueError(f"--joints {joints}: the rig {rig.name!r} has no robot to remove")
    node = CameraNode(cam, ws, src, static_meshes=rig.static_meshes(), robot=rig.robot, robot_q0=q0,
                      learned=learned, **kw)
    if joints is not None:
        from depthguard.sources.base import open_joints

        ctx = ({"zenoh_connect": list(joints_connect)} if joints_connect
               else {"zenoh_session": node.client.session})
        try:
            js = open_joints(joints, rig, ctx)
            node.joint_wait_s = rig.monitor.joint_wait_s
            node.attach_joints(js, span_s=rig.monitor.joint_history_s, max_gap_s=rig.monitor.joints_stale_s)
        except BaseException:
            node.close()
            raise
    return node


def _resolution(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"resolution must look like 640x480 (got {text!r})") from None
    return w, h


def main(argv: list[str] | None = None) -> int:
    """Process entry: ``python -m depthguard.distributed.node --rig R --camera ID ...``."""
    ap = argparse.ArgumentParser(prog="depthguard-node", description="A camera node (see `depthguard node`).")
    ap.add_argument("--rig")
    ap.add_argument("--camera", required=True)
    ap.add_argument("--source", default="pattern", choices=["pattern", "sim"])
    ap.add_argument("--cell")
    ap.add_argument("--sim-time", type=float, default=0.0)
    ap.add_argument("--connect", action="append", default=None)
    ap.add_argument("--listen", action="append", default=None)
    ap.add_argument("--prefix", default="depthguard")
    ap.add_argument("--fps", type=float, default=15.0)
    ap.add_argument("--trigger", action="store_true")
    ap.add_argument("--resolution")
    ap.add_argument("--joints", help="joint stream, e.g. zenoh:KEY: remove the robot at each frame's capture joints")
    ap.add_argument("--joints-connect", action="append", default=None)
    ap.add_argument("--quiet", action="store_true")
    ap.add_argument("--keys", help="node key directory (depthguard keys node)")
    ap.add_argument("--insecure", action="store_true")
    ap.add_argument("--wait", type=float, default=30.0)
    a = ap.parse_args(argv)
    from depthguard.progress import log

    try:
        from depthguard.transport.keys import load_identity

        identity = None if a.keys is None else load_identity(a.keys)
        node = build_node(a.rig, a.camera, a.source, a.cell, a.sim_time, resolution=_resolution(a.resolution),
                          connect=a.connect or [DEFAULT_ENDPOINT], listen=a.listen, identity=identity,
                          insecure=a.insecure, init_timeout_s=a.wait,
                          prefix=a.prefix, fps=a.fps, trigger=a.trigger, log=None if a.quiet else log,
                          joints=a.joints, joints_connect=a.joints_connect or ())
    except (ValueError, FileNotFoundError) as exc:
        print(f"depthguard node: error: {exc}", file=sys.stderr)
        return 2
    try:
        node.run()
    except (ServerRefused, ServerUnavailable) as exc:
        print(f"depthguard node: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        pass
    finally:
        node.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
