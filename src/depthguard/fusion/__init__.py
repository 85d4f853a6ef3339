"""Fusion of several cameras: depth grid (R10–R12), voxels (R17–R19), free space (R21).

Modules are imported directly (``depthguard.fusion.voxels`` ...); this package
file stays empty so that importing one of them does not compile the others.
"""
