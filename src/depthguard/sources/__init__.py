"""Depth sources: frames, noise models, simulated cameras, recordings, devices and live topics
(the sensor presets they use are :mod:`depthguard.sensors`)."""

from depthguard.sources.frame import Frame
from depthguard.sources.simulated import SimSource, SimulatedCamera

__all__ = ["Frame", "SimSource", "SimulatedCamera"]
