"""Recorded depth images as a frame source: the scheme ``images:DIR`` (R31, SPEC §1).

``DIR/index.csv`` lists the frames, one a line, under the header ``stamp,camera,file``
(without it, a TUM RGB-D ``DIR/depth.txt``: below):

- ``stamp``: capture time, seconds (float, finite), used as it is: the monitor's
  clock in ``--fast`` replay starts at the first stamp (:attr:`ImageSource.first_stamp`);
- ``camera``: a camera id of the rig; per camera the stamps never decrease;
- ``file``: the image, relative to DIR: ``.png`` 16-bit millimetres or ``.npy``
  float32 metres (read with :func:`depthguard.depth_io.read_depth`).

A 16-bit PNG counts the rig camera's ``depth_scale`` metres per unit (default
0.001, millimetres; a TUM RGB-D sequence: 0.0002, 5000 per metre).

``DIR/depth.txt`` (TUM RGB-D): ``timestamp filename`` lines (seconds, a path
relative to DIR), ``#`` comments and blank lines skipped, for one camera: the
rig's only camera, or the one named as ``images:CAMERA=DIR``. Used only when
there is no ``index.csv``.

The index is checked whole when the source opens (every problem names the
line), and each listed file must exist then. Images are read only when due; a
file that cannot be decoded then, or whose shape is not the camera's, is
skipped and :attr:`ImageSource.lost` says why (the runtime treats the source
as failed, R27), without an exception in ``frames_until``.

:func:`write_image_dir` records frames in this format (``.npy``).
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from depthguard.camera import check_depth_image
from depthguard.depth_io import read_depth, write_depth
from depthguard.sources.base import register_source
from depthguard.sources.frame import Frame

__all__ = ["ImageSource", "ImageSourceError", "write_image_dir", "INDEX_NAME", "INDEX_HEADER"]

INDEX_NAME = "index.csv"
TUM_INDEX_NAME = "depth.txt"
INDEX_HEADER = ["stamp", "camera", "file"]
_SAFE_ID = re.compile(r"^[A-Za-z0-9_\-.]+$")


class ImageSourceError(ValueError):
    """An image directory or its index is not usable (the message names the file and line)."""


@dataclass(frozen=True)
class _Entry:
    stamp: float
    camera: str
    path: Path
    line: int


def _parse_index(index: Path, rig) -> list[_Entry]:
    """The index lines as entries in file order; :class:`ImageSourceError` names the first bad line."""
    known = set(rig.camera_ids)
    last: dict[str, float] = {}
    entries: list[_Entry] = []
    with open(index, newline="", encoding="utf-8") as fh:
        rows = csv.reader(fh)
        header = next(rows, None)
        if header is None or [h.strip() for h in header] != INDEX_HEADER:
            raise ImageSourceError(f"{index}:1: the header must be exactly {','.join(INDEX_HEADER)} (got {header})")
        for row in rows:
            line = rows.line_num
            if not row or all(not c.strip() for c in row):
                continue
            where = f"{index}:{line}"
            if len(row) != 3:
                raise ImageSourceError(f"{where}: expected 3 columns stamp,camera,file (got {len(row)})")
            s, cam, name = (c.strip() for c in row)
            try:
                stamp = float(s)
            except ValueError:
                raise ImageSourceError(f"{where}: stamp {s!r} is not a number") from None
            if not math.isfinite(stamp):
                raise ImageSourceError(f"{where}: stamp {s!r} is not finite")
            if cam not in known:
                raise ImageSourceError(f"{where}: camera {cam!r} is not in rig {rig.name!r} "
                                       f"(cameras: {', '.join(rig.camera_ids)})")
            entries.append(_entry(index, line, stamp, cam, name, last))
    return entries


def _entry(index: Path, line: int, stamp: float, cam: str, name: str, last: dict) -> _Entry:
    """One checked line of an index (either format); :class:`ImageSourceError` names the line."""
    where = f"{index}:{line}"
    if cam in last and stamp < last[cam]:
        raise ImageSourceError(f"{where}: stamp {stamp!r} of camera {cam!r} is before its previous "
                               f"stamp {last[cam]!r} (stamps per camera must not decrease)")
    last[cam] = stamp
    if not name or Path(name).is_absolute():
        raise ImageSourceError(f"{where}: file {name!r} must be a path relative to {index.parent}")
    path = index.parent / name
    if path.suffix.lower() not in (".png", ".npy"):
        raise ImageSourceError(f"{where}: file {name!r} is neither .png nor .npy")
    if not path.is_file():
        raise ImageSourceError(f"{where}: file {name!r} does not exist ({path})")
    return _Entry(stamp, cam, path, line)


def _parse_tum(index: Path, camera: str) -> list[_Entry]:
    """A TUM RGB-D ``depth.txt`` (module docstring) as entries of ``camera``; :class:`ImageSourceError`
    names the first bad line."""
    entries: list[_Entry] = []
    last: dict[str, float] = {}
    with open(index, encoding="utf-8") as fh:
        for line, text in enumerate(fh, start=1):
            text = text.strip()
            if not text or text.startswith("#"):
                continue
            fields = text.split()
            if len(fields) != 2:
                raise ImageSourceError(f"{index}:{line}: expected 'timestamp filename' (got {text!r})")
            try:
                stamp = float(fields[0])
            except ValueError:
                raise ImageSourceError(f"{index}:{line}: timestamp {fields[0]!r} is not a number") from None
            if not math.isfinite(stamp):
                raise ImageSourceError(f"{index}:{line}: timestamp {fields[0]!r} is not finite")
            entries.append(_entry(index, line, stamp, camera, fields[1], last))
    return entries


class ImageSource:
    """Frames of a recorded image directory (module docstring), served in stamp order.

    ``camera_ids``: the cameras named in the index, in rig order. ``first_stamp``:
    the smallest stamp (s), ``None`` for an empty index. ``skipped``: frames not
    served because their image was unreadable or of the wrong shape.
    """

    def __init__(self, directory: str | Path, rig, camera: str | None = None):
        self.directory = Path(directory)
        if not self.directory.is_dir():
            raise ImageSourceError(f"images source: {self.directory} is not a directory")
        index, tum = self.directory / INDEX_NAME, self.directory / TUM_INDEX_NAME
        if camera is not None and camera not in rig.camera_ids:
            raise ImageSourceError(f"images source: the rig {rig.name!r} has no camera {camera!r} "
                                   f"(cameras: {', '.join(rig.camera_ids)})")
        if not index.is_file() and not tum.is_file():
            raise ImageSourceError(f"images source: {index} does not exist (header {','.join(INDEX_HEADER)}), "
                                   f"nor a TUM {tum}")
        self._rig = rig
        self.index = index if index.is_file() else tum
        if index.is_file():
            if camera is not None:
                raise ImageSourceError(f"images source: {index} names the camera of each frame; give images:DIR "
                                       f"(CAMERA=DIR is for a TUM {TUM_INDEX_NAME})")
            entries = _parse_index(index, rig)
        else:
            if camera is None and len(rig.camera_ids) != 1:
                raise ImageSourceError(f"images source: {tum} is one camera's and the rig {rig.name!r} has "
                                       f"{len(rig.camera_ids)} ({', '.join(rig.camera_ids)}): name it, "
                                       f"images:CAMERA={self.directory}")
            entries = _parse_tum(tum, camera or rig.camera_ids[0])
        # stable sort: frames with equal stamps keep the order of the index
        self._entries = sorted(entries, key=lambda e: e.stamp)
        named = {e.camera for e in entries}
        self.camera_ids = [c for c in rig.camera_ids if c in named]
        self.first_stamp = self._entries[0].stamp if self._entries else None
        self.skipped = 0
        self._next = 0
        self._lost: str | None = None
        self._closed = False

    @property
    def done(self) -> bool:
        """True once every frame of the index has been given (or the source is closed)."""
        return self._closed or self._next >= len(self._entries)

    @property
    def lost(self) -> str | None:
        """``None``, or a sentence naming the first image that could not be used."""
        return self._lost

    def frames_until(self, t: float) -> list[Frame]:
        """The frames with stamp <= ``t`` (s) not given yet, in stamp order; each image is read now."""
        out: list[Frame] = []
        while not self._closed and self._next < len(self._entries) and self._entries[self._next].stamp <= t:
            e = self._entries[self._next]
            self._next += 1
            frame = self._read(e)
            if frame is not None:
                out.append(frame)
        return out

    def _read(self, e: _Entry) -> Frame | None:
        where = f"{self.index}:{e.line}"
        units = self._rig.depth_scales.get(e.camera, 0.001)
        try:
            depth = check_depth_image(self._rig.camera(e.camera), read_depth(e.path, png_units_m=units),
                                      name=str(e.path.name))
        except ValueError as exc:
            self.skipped += 1
            if self._lost is None:
                self._lost = f"image {e.path} ({where}) cannot be used: {exc}"
            return None
        return Frame(e.camera, depth.astype(np.float32, copy=False), e.stamp)

    def close(self) -> None:
        self._closed = True


@register_source("images")
def open_images(argument: str, rig, context: dict) -> ImageSource:
    """Factory of ``images:DIR`` or ``images:CAMERA=DIR`` (a TUM ``depth.txt``, module docstring)."""
    if not argument:
        raise ImageSourceError("the images source needs a directory: images:DIR")
    camera, sep, directory = argument.partition("=")
    if sep and camera.strip() in rig.camera_ids and not Path(argument).is_dir():
        return ImageSource(directory.strip(), rig, camera=camera.strip())
    return ImageSource(argument, rig)


def write_image_dir(directory: str | Path, frames: list[Frame]) -> Path:
    """Record ``frames`` as ``DIR/<camera>_<n>.npy`` (float32 metres) plus ``DIR/index.csv``.

    Refuses an existing index or image file (nothing is overwritten), a camera id
    that cannot name a file, a non-finite stamp, and stamps that decrease for one
    camera (the reader would refuse them). Returns the path of the index.
    """
    d = Path(directory)
    index = d / INDEX_NAME
    if index.exists():
        raise ImageSourceError(f"{index} exists already; record into a new directory")
    last: dict[str, float] = {}
    for i, f in enumerate(frames):
        if not _SAFE_ID.match(f.camera_id):
            raise ImageSourceError(f"frame {i}: camera id {f.camera_id!r} cannot name a file "
                                   "(use letters, digits, '_', '-', '.')")
        if not math.isfinite(f.stamp):
            raise ImageSourceError(f"frame {i}: stamp {f.stamp!r} is not finite")
        if f.stamp < last.get(f.camera_id, -math.inf):
            raise ImageSourceError(f"frame {i}: stamp {f.stamp!r} of camera {f.camera_id!r} is before "
                                   f"its previous stamp {last[f.camera_id]!r}")
        last[f.camera_id] = f.stamp
    d.mkdir(parents=True, exist_ok=True)
    rows = []
    for i, f in enumerate(frames):
        name = f"{f.camera_id}_{i:06d}.npy"
        if (d / name).exists():
            raise ImageSourceError(f"{d / name} exists already; record into a new directory")
        write_depth(d / name, f.depth)
        rows.append([repr(float(f.stamp)), f.camera_id, name])
    with open(index, "x", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(INDEX_HEADER)
        w.writerows(rows)
    return index
