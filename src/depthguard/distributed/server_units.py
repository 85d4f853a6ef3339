"""The fusion server's pieces without a network (R20): a unit's storage, the error codes of its
replies, the settings a request may change, and the coarsening of a set too large for one reply.
:mod:`depthguard.distributed.server` serves them over Zenoh."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from depthguard.fusion.voxels import regrid
from depthguard.transport import wire

__all__ = ["Unit", "ERR_MALFORMED", "ERR_REFUSED", "ERR_UNKNOWN_UNIT", "ERR_BAD_SETTINGS", "ERR_AUTH",
           "RATE_WINDOW_S", "SETTABLE", "clean_setting_changes", "fit_one_reply"]

ERR_MALFORMED = 1
ERR_REFUSED = 2
ERR_UNKNOWN_UNIT = 3
ERR_BAD_SETTINGS = 4
ERR_AUTH = 5
RATE_WINDOW_S = 5.0             # s, the window of the server's bytes per second


@dataclass
class Unit:
    """Storage of one processing unit (one camera)."""
    id: int
    camera: str
    address: str
    alive: bool = False
    keys: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int32))
    counts: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    voxel_size: float = 0.02
    stamp: float = float("nan")      # capture time sent by the node (its clock)
    t_update: float | None = None    # server monotonic receive time
    seq: int = 0
    invalid_frac: float = float("nan")   # share of the node's pixels without a valid measurement (R28)
    updates: int = 0
    inits: int = 1
    lost: int = 0            # updates missing from the node's sequence numbers (gaps), since the first


#: the settings a SETTINGS request (or ``FusionServer.set_settings``) may change
SETTABLE = frozenset({"voxel_size", "threshold", "stale_s", "offset_const", "offset_k", "joints"})


def clean_setting_changes(changes: dict) -> dict:
    """``{name: value}`` checked and made plain: floats, and ``joints`` a tuple of floats; raises
    ``ValueError`` naming an unknown setting or a value of the wrong kind (the ranges are
    ``wire.Settings.check``'s)."""
    bad = set(changes) - SETTABLE
    if bad:
        raise ValueError(f"unknown settings {sorted(bad)}; allowed: {sorted(SETTABLE)}")
    clean = {}
    for name, v in changes.items():
        if name == "joints":
            if isinstance(v, np.ndarray) and v.ndim == 1 and v.dtype.kind in "fiu":
                v = v.tolist()                 # a joint vector from Python code
            if not isinstance(v, (list, tuple)) or not all(
                    isinstance(q, (int, float)) and not isinstance(q, bool) for q in v):
                raise ValueError(f"setting joints must be a list of numbers (got {str(v)[:60]})")
            clean[name] = tuple(float(q) for q in v)
        else:
            if isinstance(v, np.generic) and v.dtype.kind in "fiu":
                v = v.item()
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ValueError(f"setting {name} must be a number (got {v!r})")
            clean[name] = float(v)
    return clean


def fit_one_reply(keys: np.ndarray, voxel_size: float) -> tuple[np.ndarray, float]:
    """A unit's voxel keys (N, 3) at ``voxel_size`` m coarsened (doubling the size) until one
    UNITS_REP holds them (``wire.MAX_UNIT_VOXELS``): conservative, every old voxel covered."""
    while len(keys) > wire.MAX_UNIT_VOXELS:
        keys = regrid(keys, voxel_size, 2 * voxel_size)
        voxel_size *= 2
    return keys, voxel_size
