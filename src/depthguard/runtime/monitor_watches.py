"""The monitor's watches on its cameras, as a mixin of :class:`depthguard.runtime.Monitor`:
the drift watch (R34: ``drift``, ``accept_camera``) and the learned scene's change watch
(issue 31: ``scene_changes``). Each reads the camera workers' own watches
(:mod:`depthguard.runtime.drift`, :mod:`depthguard.runtime.scene_change`); the monitor
holds ``_workers`` (camera id -> worker) and ``_camera_ids``."""

from __future__ import annotations

__all__ = ["MonitorWatches"]


class MonitorWatches:
    """Mixin of :class:`~depthguard.runtime.Monitor` (module docstring)."""

    def accept_camera(self, camera_id: str) -> None:
        """The user trusts camera ``camera_id`` as it is now (R34): its drift flag is cleared and its
        current residual level becomes the baseline — a further growth is flagged again. (A moved
        camera is better recalibrated: ``depthguard calibrate``, then run with the corrected rig.)"""
        w = self._workers.get(camera_id)
        if w is None:
            raise ValueError(f"camera {camera_id!r} is not monitored; monitored: {', '.join(self._camera_ids)}")
        if w.drift is not None:
            w.drift.accept()

    def drift(self) -> dict:
        """Per monitored camera: ``untrusted``, the last judged ``share`` farther than the static
        scene, its ``baseline``, the ``flagged_at`` stamp and the ``message`` (R34); {} when off."""
        out = {}
        for c, w in list(self._workers.items()):
            d = w.drift
            if d is not None:
                out[c] = {"untrusted": d.untrusted, "share": d.share, "baseline": d.baseline,
                          "flagged_at": d.flagged_at, "judged": d.judged, "samples": d.samples,
                          "message": d.message}
        return out

    def scene_changes(self) -> list[dict]:
        """Where the cell no longer matches its learned scene (issue 31): per camera and region,
        ``kind`` new (something stayed in front of it) or gone, the tile's ``box`` (u0, v0, u1, v1 px),
        ``share`` and ``since`` (s); [] without a learned scene
        (:class:`~depthguard.runtime.scene_change.SceneChangeWatch`). Never learned into the scene."""
        out = []
        for w in list(self._workers.values()):
            if getattr(w, "scene_change", None) is not None:
                out.extend(w.scene_change.changes())
        return out
