"""The package's rooms in import order, bottom first: a room imports only rooms before it.

A *room* is a top-level module (``camera.py``) or a sub-package (``fusion/``) of
``depthguard``; modules inside one room import each other freely. The order is
read from what the code needs, not from the flow of a frame: ``control`` (the
reaction kernels: distances and Jacobians in, joint velocities out) sits below
``config`` because ``MonitorConfig`` holds ``control.ssm_config.SSMConfig``;
``sim`` (scenes and cells, built from the rig) below ``sources`` because the
simulator is a source; ``calibration`` below ``runtime`` because the runtime's
drift watch (R34) uses its residuals; ``viz`` below ``evaluation`` because the
benchmarks time the live view.

``tests/test_layers.py`` parses every module (imports at module level and inside
functions alike) and fails on an import of a room later in :data:`LAYERS`, and
on a room missing from it. ``docs/ARCHITECTURE.md`` ("Import graph") states the
same order.
"""

from __future__ import annotations

__all__ = ["LAYERS"]

#: bottom first; the package root (``depthguard/__init__.py``: lazy re-exports) is no room
LAYERS: tuple[str, ...] = (
    "layers",         # this order; imports nothing
    "kernel_cache",   # numba's disk cache kept to the package's sources (run by the package root's import)
    "progress",       # log lines and progress bars; imports nothing of the package
    "numba_threads",  # numba's per-thread settings made without giving the GIL away (issue 29)
    "frame_pool",     # frame-sized buffers reused once nobody holds them (the camera workers, the simulator)
    "transforms",
    "camera",
    "geometry",       # primitives, meshes, the voxel grid
    "robot",          # models, kinematics, the joint history (R30), the padded volume (R9, R12)
    "render",
    "sensors",        # depth sensor presets (R1)
    "depth_io",
    "learned_scene",  # the static scene learned from the cameras: model, storage, the per-pixel median (issue 31)
    "control",        # reaction kernels and their settings (R13-R15, R22, R27, R33)
    "config",         # MonitorConfig (R26-R32)
    "rig_checks",     # sanity checks of a rig's numbers (a mesh's unit, a robot inside its table)
    "rig_schema",     # the rig file's pydantic models (R2)
    "grid_budget",    # the depth grid's column size from a budget, chosen when a rig loads (issue 29)
    "rig",
    "transport",      # Zenoh settings, the fusion server's wire format and client, ROS 2 over Zenoh
    "filtering",
    "sim",
    "sources",
    "calibration",
    "distance",
    "fusion",
    "runtime",
    "distributed",
    "viz",
    "evaluation",
    "cli",
    "__main__",
)
