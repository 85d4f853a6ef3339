"""Plots: contact sheets of depth images (more to come: distances, voxels, free space)."""

from depthguard.viz.contact_sheet import colorize_depth, contact_sheet

__all__ = ["contact_sheet", "colorize_depth"]
