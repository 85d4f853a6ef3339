"""The runtime of a cell (R29): :class:`Monitor` — frames and joint states in, a reaction out."""

from depthguard.config import MonitorConfig, WatchPoint
from depthguard.runtime.monitor import Monitor
from depthguard.runtime.result import CameraStatus, Reaction

__all__ = ["Monitor", "MonitorConfig", "WatchPoint", "Reaction", "CameraStatus"]
