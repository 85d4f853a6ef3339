"""depthguard: safe human-robot workspace sharing from several depth cameras.

The public surface (SPEC §9)::

    import depthguard as dg
    cam = dg.Camera(...); rig = dg.Rig.load("cell.yaml")
    depth = dg.read_depth("cam0.png"); img = dg.render_depth(cam, meshes)
    res = dg.depth_space_distance(cam, depth, points, rho=0.4, method="hybrid")
    grid = dg.DepthGridMap(rig.cameras, principal="cam0", d_min=0.3, d_max=3.7, delta_d=0.01)
    fs = dg.FreeSpaceMap(rig.cameras, bounds=(lo, hi), voxel_size=0.05)
    monitor = dg.Monitor(rig)   # push_frame(dg.Frame(...)), push_joints(stamp, q), step(t) -> Reaction
    dg.warm_up(rig)             # compile the monitor's kernels before any clock (README's live loop)

Names are imported lazily so that ``import depthguard`` stays fast and the
numba kernels compile only when they are used.
"""

from __future__ import annotations

import importlib
import os

# numba's OpenMP threads sleep when a parallel region ends instead of spinning for it (libgomp
# spins up to ~0.3 M iterations by default): a monitor runs many short parallel regions beside
# threads that need the same cores (camera workers, a simulator, the sinks). Measured in
# ``depthguard monitor`` on a 2-core machine: the spinning thread took 51 % of a core for 33 % of
# work. Read by libgomp when numba first runs a parallel kernel; a value the user set is kept.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def _keep_kernel_cache() -> None:
    """numba's cached kernels deleted where the package's sources changed since they were cached
    (:mod:`depthguard.kernel_cache`: numba itself checks a kernel's own file only). Never fails
    the import: a cache that cannot be checked is numba's as before."""
    try:
        from depthguard.kernel_cache import keep_cache_to_sources

        keep_cache_to_sources()
    except Exception:
        pass


_keep_kernel_cache()

__version__ = "0.1.0"

_EXPORTS = {
    "Camera": "depthguard.camera",
    "CameraError": "depthguard.camera",
    "read_depth": "depthguard.depth_io",
    "write_depth": "depthguard.depth_io",
    "Rig": "depthguard.rig",
    "RigError": "depthguard.rig",
    "Mesh": "depthguard.geometry.mesh",
    "render_depth": "depthguard.render",
    "Renderer": "depthguard.render",
    "RobotModel": "depthguard.robot",
    "load_robot": "depthguard.robot",
    "ControlPoint": "depthguard.robot",
    "available_robots": "depthguard.robot",
    "depth_space_distance": "depthguard.distance",
    "DistanceResult": "depthguard.distance",
    "DepthGridMap": "depthguard.fusion.depth_grid",
    "FreeSpaceMap": "depthguard.fusion.free_space",
    "VoxelFilter": "depthguard.fusion.voxels",
    "Monitor": "depthguard.runtime.monitor",
    "warm_up": "depthguard.runtime.monitor",
    "MonitorConfig": "depthguard.config",
    "Reaction": "depthguard.runtime.result",
    "Frame": "depthguard.sources.frame",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    mod = _EXPORTS.get(name)
    if mod is None:
        raise AttributeError(f"module 'depthguard' has no attribute {name!r}")
    value = getattr(importlib.import_module(mod), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(list(globals()) + __all__)
