"""Depth images on disk (SPEC §1).

- ``.png``: 16-bit single channel, millimetres, 0 = no measurement.
- ``.npy``: float32 metres, 0 or NaN = no measurement.

In memory a depth image is ``(H, W) float32`` metres with 0 = no measurement.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["read_depth", "write_depth", "DepthFileError"]

_MAX_MM = 65535


class DepthFileError(ValueError):
    """A depth file is missing, of an unknown kind, or does not hold a depth image."""


def read_depth(path: str | Path) -> np.ndarray:
    """Read a depth image as ``(H, W) float32`` metres, 0 where there is no measurement."""
    p = Path(path)
    if not p.is_file():
        raise DepthFileError(f"{p}: no such depth file")
    suffix = p.suffix.lower()
    if suffix == ".png":
        from PIL import Image

        try:
            with Image.open(p) as im:
                mode = im.mode
                arr = np.asarray(im)
        except Exception as exc:
            raise DepthFileError(f"{p}: not a readable PNG ({exc})") from None
        if arr.ndim != 2 or arr.dtype not in (np.uint16, np.int32, np.uint8) or mode not in ("I;16", "I;16B", "I", "L"):
            raise DepthFileError(
                f"{p}: a depth PNG must be 16-bit single-channel millimetres (got mode {mode}, shape {arr.shape})"
            )
        if mode == "L":
            raise DepthFileError(f"{p}: 8-bit PNG is not a depth image; expected 16-bit millimetres")
        if arr.dtype == np.int32 and (arr.min() < 0 or arr.max() > _MAX_MM):
            raise DepthFileError(f"{p}: values outside the 16-bit range")
        return (arr.astype(np.float32) / np.float32(1000.0)).astype(np.float32)
    if suffix == ".npy":
        try:
            arr = np.load(p, allow_pickle=False)
        except Exception as exc:
            raise DepthFileError(f"{p}: not a readable .npy array ({exc})") from None
        if arr.ndim != 2:
            raise DepthFileError(f"{p}: a depth image must be 2-D (got shape {arr.shape})")
        if not np.issubdtype(arr.dtype, np.floating):
            raise DepthFileError(f"{p}: a .npy depth image must be float metres (got dtype {arr.dtype})")
        out = arr.astype(np.float32)
        out[~np.isfinite(out)] = 0.0
        if (out < 0).any():
            raise DepthFileError(f"{p}: negative depths ({int((out < 0).sum())} pixels)")
        return out
    raise DepthFileError(f"{p}: unknown depth file type {suffix!r} (use .png or .npy)")


def write_depth(path: str | Path, depth: np.ndarray) -> Path:
    """Write ``(H, W)`` metres as 16-bit millimetre PNG or float32 ``.npy``.

    PNG rounds to the nearest millimetre; depths beyond 65.535 m cannot be
    stored and raise ``ValueError`` rather than being clipped silently.
    """
    p = Path(path)
    d = np.asarray(depth)
    if d.ndim != 2:
        raise ValueError(f"depth must be a 2-D image (got shape {d.shape})")
    d = d.astype(np.float64)
    d[~np.isfinite(d)] = 0.0
    if (d < 0).any():
        raise ValueError("depth has negative values")
    suffix = p.suffix.lower()
    p.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".png":
        from PIL import Image

        mm = np.rint(d * 1000.0)
        if mm.max(initial=0) > _MAX_MM:
            raise ValueError(f"depth up to {d.max():.3f} m does not fit a 16-bit millimetre PNG")
        Image.fromarray(mm.astype(np.uint16)).save(p)
    elif suffix == ".npy":
        np.save(p, d.astype(np.float32))
    else:
        raise ValueError(f"unknown depth file type {suffix!r} (use .png or .npy)")
    return p
