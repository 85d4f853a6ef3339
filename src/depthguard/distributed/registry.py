"""The server's camera → unit id registry, kept across restarts (R20, R35).

A small JSON file ``{"version": 1, "units": {"camA": 1, "camB": 2}}``. A camera keeps
its id for the life of the file; a new camera gets the next id. Every change is
written atomically (a temporary file in the same directory, ``fsync``, ``os.replace``),
so a server killed at any moment leaves either the old or the new file, never a
half-written one. A file that cannot be read is an error naming it (the server does
not start and the file is left as it is); without a path the registry lives in memory.
"""

from __future__ import annotations

import json
import os
import tempfile
import threading
from pathlib import Path

__all__ = ["Registry"]

_MAX_ID = 2 ** 32 - 1


class Registry:
    """Camera id → unit id (int ≥ 1); persisted to ``path`` when given."""

    def __init__(self, path: str | os.PathLike | None = None):
        self.path = None if path is None else Path(path)
        self._ids: dict[str, int] = {}
        self._lock = threading.Lock()
        if self.path is not None and self.path.exists():
            self._ids = self._read(self.path)

    @staticmethod
    def _read(path: Path) -> dict[str, int]:
        from depthguard.config import check_camera_id

        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise ValueError(f"registry {path}: cannot read it as JSON ({exc}); fix or move the file") from None
        if not isinstance(data, dict) or data.get("version") != 1 or not isinstance(data.get("units"), dict):
            raise ValueError(f"registry {path}: expected {{\"version\": 1, \"units\": {{camera: id}}}}")
        ids: dict[str, int] = {}
        for cam, uid in data["units"].items():
            try:
                check_camera_id(cam)
            except ValueError as exc:
                raise ValueError(f"registry {path}: {exc}") from None
            if isinstance(uid, bool) or not isinstance(uid, int) or not (1 <= uid <= _MAX_ID):
                raise ValueError(f"registry {path}: unit id of camera {cam!r} must be an integer in 1..{_MAX_ID}")
            ids[cam] = uid
        if len(set(ids.values())) != len(ids):
            raise ValueError(f"registry {path}: two cameras share a unit id")
        return ids

    def _write(self) -> None:
        assert self.path is not None
        self.path.parent.mkdir(parents=True, exist_ok=True)
        text = json.dumps({"version": 1, "units": self._ids}, indent=1, sort_keys=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", dir=self.path.parent)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(text)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.path)
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise

    def get(self, camera: str) -> int | None:
        with self._lock:
            return self._ids.get(camera)

    def assign(self, camera: str) -> int:
        """The camera's id: the one recorded, or the next free one (written before it is returned)."""
        with self._lock:
            uid = self._ids.get(camera)
            if uid is not None:
                return uid
            uid = max(self._ids.values(), default=0) + 1
            if uid > _MAX_ID:
                raise ValueError("registry: no unit id left")
            self._ids[camera] = uid
            if self.path is not None:
                try:
                    self._write()
                except BaseException:
                    del self._ids[camera]
                    raise
            return uid

    def as_dict(self) -> dict[str, int]:
        with self._lock:
            return dict(self._ids)
