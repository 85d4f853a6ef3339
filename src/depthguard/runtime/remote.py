"""Changing a running monitor over Zenoh: the settings key (R29).

``SettingsListener(monitor, session, cell)`` subscribes to
``depthguard/<cell>/settings``. A message is UTF-8 JSON with any of:

- ``rho``, ``camera_stale_s``, ``joints_stale_s``, ``stop_time``,
  ``resume_time``, ``v_max``, ``alpha``, ``method``, ``camera_hz``
  (the :class:`~depthguard.config.MonitorConfig` fields that may change
  while running);
- ``cameras``: the list of camera ids to monitor (the rig's cameras; those
  added are used from their first frame, those removed are no longer awaited).

A message is applied whole or not at all. The outcome is published on
``depthguard/<cell>/settings/result``: ``{"ok": true, "config": {...},
"cameras": [...]}`` or ``{"ok": false, "error": "<what is wrong>"}``. The
listener binds where its session does (loopback unless told otherwise);
authentication of who may change settings is the trusted-network issue's
(R35) and not provided here.
"""

from __future__ import annotations

import json

__all__ = ["SettingsListener", "settings_keys"]


def settings_keys(cell: str) -> tuple[str, str]:
    """``(settings key, result key)`` of ``cell``."""
    from depthguard.config import check_camera_id

    check_camera_id(cell)
    return f"depthguard/{cell}/settings", f"depthguard/{cell}/settings/result"


class SettingsListener:
    """Applies settings messages to ``monitor`` (module docstring). ``applied`` / ``rejected``
    count messages; ``last_error`` keeps the last rejection's sentence."""

    def __init__(self, monitor, session, cell: str):
        self.monitor = monitor
        key, result = settings_keys(cell)
        self.applied = 0
        self.rejected = 0
        self.last_error: str | None = None
        self._pub = session.declare_publisher(result)
        self._sub = session.declare_subscriber(key, self._on_sample)

    def apply(self, message: bytes | str) -> dict:
        """Apply one message; returns the result record (also published)."""
        try:
            data = json.loads(message)
            if not isinstance(data, dict) or not data:
                raise ValueError("a settings message is a non-empty JSON object")
            cams = data.pop("cameras", None)
            if cams is not None:
                if not (isinstance(cams, list) and cams and all(isinstance(c, str) for c in cams)):
                    raise ValueError("cameras must be a non-empty list of camera ids")
                unknown = [c for c in cams if c not in self.monitor.rig.camera_ids]
                if unknown:
                    raise ValueError(f"cameras: the rig has no camera {', '.join(map(repr, unknown))}")
            if data:
                self.monitor.config.with_changes(**data)          # validate before changing anything
                self.monitor.update_config(**data)
            if cams is not None:
                for c in cams:
                    self.monitor.add_camera(c)
                for c in [c for c in self.monitor.camera_ids if c not in cams]:
                    self.monitor.remove_camera(c)
            out = {"ok": True, "config": self.monitor.config.model_dump(mode="json"),
                   "cameras": list(self.monitor.camera_ids)}
            self.applied += 1
        except (ValueError, TypeError) as exc:
            self.rejected += 1
            self.last_error = str(exc)
            out = {"ok": False, "error": str(exc)}
        self._pub.put(json.dumps(out).encode("utf-8"))
        return out

    def _on_sample(self, sample) -> None:
        self.apply(bytes(sample.payload.to_bytes()))

    def close(self) -> None:
        for h in (self._sub, self._pub):
            try:
                h.undeclare()
            except Exception:  # noqa: BLE001 - closing anyway
                pass
