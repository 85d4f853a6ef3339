"""Depth sources: sensor presets, noise models, simulated cameras (later recordings, RealSense)."""

from depthguard.sources.frame import Frame
from depthguard.sources.sensors import SENSOR_MODELS, SensorModel, intrinsics_for, sensor_model
from depthguard.sources.simulated import SimSource, SimulatedCamera

__all__ = ["Frame", "SENSOR_MODELS", "SensorModel", "intrinsics_for", "sensor_model",
           "SimSource", "SimulatedCamera"]
