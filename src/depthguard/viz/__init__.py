"""Plots: contact sheets of depth images (more to come: distances, voxels, free space)."""

from depthguard.viz import sinks as _sinks  # noqa: F401  (registers the view: sink, viz/sinks.py)
from depthguard.viz.contact_sheet import colorize_depth, contact_sheet

__all__ = ["contact_sheet", "colorize_depth"]
