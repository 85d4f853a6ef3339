"""The cameras' part of a control cycle's supervision (R26, R27, R34): one pass over the monitored
cameras that makes each one's :class:`~depthguard.runtime.result.CameraStatus` and the stale-data
stop reasons of :func:`depthguard.control.supervisor.stop_reasons`, in its order (issue 29: the
monitor's cycle no longer walks the cameras twice). A part of
:meth:`depthguard.runtime.monitor.Monitor.step`, apart to keep that file short.
"""

from __future__ import annotations

import math

from depthguard.control.supervisor import stale_reason
from depthguard.runtime.result import CameraStatus

__all__ = ["camera_pass"]


def camera_pass(t: float, ids, stamps: dict, workers: dict, added: dict, limit: float):
    """``(cameras, reasons, untrusted)`` of the cycle at ``t`` (s).

    ids : the supervised cameras (monitored, then remote), in the reasons' order.
    stamps : camera id -> capture stamp (s) of its frame in use this cycle (absent: none yet).
    workers : camera id -> its worker (``frames``, ``refused``, ``drift``); a remote camera has none.
    added : camera id -> when it was added while running: not awaited before its first frame
        while another supervised camera has a frame in use.
    limit : s, the cameras' stale limit (R27): a frame older than ``limit + 1e-9`` s is stale.

    cameras : id -> :class:`CameraStatus` (age s, ``fresh`` / ``stale`` / ``waiting`` / ``untrusted``).
    reasons : ``stale:<id>`` -> sentence for each awaited camera without a frame younger than the
        limit — ``stop_reasons``' camera reasons, key for key and in its order.
    untrusted : id -> the drift watch's message for each camera found moved (R34), or None.
    """
    cams: dict[str, CameraStatus] = {}
    reasons: dict[str, str] = {}
    made = CameraStatus.made
    stale_at = limit + 1e-9
    # an added camera is not awaited before its first frame only while some supervised camera
    # has a frame in use: a grid made of removed cameras' frames alone must not run unsupervised
    in_use = any(c in stamps for c in ids) if added else False
    untrusted = None
    for c in ids:
        w = workers.get(c)
        st = stamps.get(c)
        if st is None:
            age = math.inf
            state = "waiting"
            if not (c in added and in_use):          # added, no frame yet: not awaited
                key, msg = stale_reason(c, limit, True)
                reasons[key] = msg
        else:
            age = t - st
            if age > stale_at:
                state = "stale"
                key, msg = stale_reason(c, limit, age == math.inf)
                reasons[key] = msg
            else:
                state = "fresh"
        if w is None:
            cams[c] = made(age, state, 0, 0, -math.inf if st is None else st)
            continue
        dw = w.drift
        if dw is not None and dw.untrusted:           # R34: moved; latched until recalibrated or accepted
            state = "untrusted"
            if untrusted is None:
                untrusted = {}
            untrusted[c] = dw.message
        cams[c] = made(age, state, w.frames, w.refused, -math.inf if st is None else st)
    return cams, reasons, untrusted
