"""A camera unit's share of the depth grid build (issue 29 point 3, R20, R30, R36).

With ``depthguard node --states`` the unit does, for each frame, what the monitor's camera
worker does for a camera whose frames it has (:class:`~depthguard.runtime.ingest.CameraWorker`):
renders the robot into the camera at the frame's capture joints
(:class:`~depthguard.filtering.expected.ExpectedDepth`, R9, R30) and makes the frame's
:class:`~depthguard.fusion.depth_grid_state.CameraState` with the monitor's state options
(:class:`~depthguard.fusion.depth_grid_state.StateMaker`), which reach the unit in the fusion
server's settings (``Settings.state``: the options and the principal camera, whose role decides
``robot_free``). It then encodes it (:mod:`depthguard.transport.state_wire`) for
``<prefix>/states/<camera>``; the monitor only combines
(:mod:`depthguard.runtime.unit_states`).
"""

from __future__ import annotations

import numpy as np

from depthguard.camera import check_depth_image
from depthguard.filtering.expected import ExpectedDepth
from depthguard.fusion.depth_grid_state import StateMaker, StateOptions
from depthguard.transport.state_wire import CODEC_F32, encode_state

__all__ = ["StateUnit", "options_of", "publish_state", "state_settings_of"]


def state_settings_of(rig) -> tuple:
    """The ``Settings.state`` tuple of a rig's monitor (``robot_offset, invalid, robot_in_others,
    silhouette_px, gap_px, principal``): the options its monitor builds the depth grid with and
    its principal camera (``monitor.principal``, else the first camera the monitor fuses)."""
    cfg = rig.monitor
    ids = list(cfg.cameras) if cfg.cameras is not None else \
        [c.id for c in rig.cameras if c.id not in cfg.remote_cameras]
    principal = cfg.principal if cfg.principal is not None else ids[0]
    return (float(cfg.robot_offset), cfg.invalid, cfg.robot_in_others, int(cfg.silhouette_px), int(cfg.gap_px),
            principal)


def options_of(state_settings, camera_id: str) -> tuple[StateOptions, bool]:
    """``(StateOptions, robot_free)`` of camera ``camera_id`` from the settings' ``state`` tuple
    ``(robot_offset, invalid, robot_in_others, silhouette_px, gap_px, principal)``: a camera
    other than the principal with ``robot_in_others="free"`` makes robot pixels confirm nothing."""
    off, inv, rio, sil, gap, principal = state_settings
    return StateOptions(float(off), inv, rio, int(sil), int(gap)), rio == "free" and camera_id != principal


class StateUnit:
    """Makes one camera's encoded states (module docstring). ``cam``, ``robot`` and
    ```` from the rig (the monitor's own, so the robot renders the same); ``codec``
    of :mod:`depthguard.transport.state_wire`."""

    def __init__(self, cam, robot, codec: int = CODEC_F32):
        self.camera = cam
        self.expected = ExpectedDepth(cam, robot) if robot is not None else None   # the robot alone
        self.maker = StateMaker(cam)
        self.codec = int(codec)

    def make(self, depth, q, state_settings):
        """The :class:`~depthguard.fusion.depth_grid_state.CameraState` of ``depth`` (H, W) m with
        the robot at ``q`` (dof,) rad (None: no robot removed) and the options of
        ``state_settings`` (:func:`options_of`)."""
        options, robot_free = options_of(state_settings, self.camera.id)
        d = np.array(check_depth_image(self.camera, depth), dtype=np.float32, copy=True)
        rd = None
        if q is not None and self.expected is not None:
            rd = np.array(self.expected.robot(q), copy=True)
        return self.maker.make(d, rd, options, robot_free, False)

    def encode(self, depth, stamp: float, q, seq: int, state_settings) -> bytes:
        """One state message of ``depth`` captured at ``stamp`` s (:meth:`make`, then
        :func:`~depthguard.transport.state_wire.encode_state`)."""
        st = self.make(depth, q, state_settings)
        qq = np.zeros(0) if q is None else np.asarray(q, dtype=np.float64)
        return encode_state(self.camera.id, seq, float(stamp), qq, tuple(st.options), st.robot_free, st.free,
                            st.kind, self.codec)


def publish_state(node, depth, stamp: float, q) -> bool:
    """Make, encode and publish a :class:`~depthguard.distributed.node.CameraNode`'s frame state
    on ``<prefix>/states/<camera>`` (sealed with the node's certificate when it has one); False
    when skipped (counted in ``node.skipped["no_options"]``, logged once) because the server's
    settings carry no state options."""
    st = node.settings.state if node.settings is not None else ()
    cid = node.cam.id
    if not st:
        node.skipped["no_options"] = node.skipped.get("no_options", 0) + 1
        if node.skipped["no_options"] == 1:
            node._log(f"camera {cid}: the server's settings carry no state options (start the server with "
                      f"the monitor's rig); nothing is sent (counted in skipped, logged once)")
        return False
    msg = node.state_unit.encode(depth, stamp, q, node.seq, st)
    key = node.keys.states(cid)
    signer = getattr(node.client, "_signer", None)
    if signer is not None:
        msg, _ = signer.seal(msg, key)
    import zenoh

    # BLOCK: a 1.5 MB state is many Zenoh fragments, which the default (DROP) loses under load; the
    # unit then waits for the link instead (its next frame is later, the monitor sees its age, R27)
    node.client.session.put(key, msg, congestion_control=zenoh.CongestionControl.BLOCK)
    node.sent_bytes += len(msg)
    return True
