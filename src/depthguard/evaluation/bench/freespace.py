"""Bench group ``freespace``: one free-space update of the C-arm room (R21).

``freespace.21cam.5cm_ms``: the ``c-arm-room`` cell's 21 ToF cameras, the
4 x 4 x 2.5 m box at 5 cm voxels (320 000 voxels), one update
(:meth:`FreeSpaceMap.update`, numba, centre pixel as in the paper); goal
<= 50 ms (issue 7). Peers measured in the same run: the plain-numpy twin of
the same update, and OctoMap (``pyoctomap``) inserting the same depth images
as point clouds with ray casting (its standard free-space update) at the same
resolution. ``freespace.21cam.5cm_full_ms``: the conservative full-footprint
variant. ``freespace.21cam.10cm_ms``: 10 cm voxels.
"""

from __future__ import annotations

import time

import numpy as np

from depthguard.evaluation.bench import BenchContext, BenchRow, group, time_call


def _inputs(seed: int):
    from depthguard.evaluation.hamersma2011 import load_room, setup_frames

    room = load_room()
    name = room.setups[0]
    depths = setup_frames(room, name, seed=seed)
    return room, depths


@group("freespace")
def bench_freespace(ctx: BenchContext) -> list[BenchRow]:
    from depthguard.fusion.free_space import FreeSpaceMap
    from depthguard.fusion.free_space_kernels import free_space_update_numpy

    room, depths = _inputs(ctx.seed)
    cams = room.cameras
    lo, hi = room.lo, room.hi
    rows: list[BenchRow] = []
    reps = max(3, ctx.repeats // (6 if ctx.quick else 1))

    ctx.log("freespace: building the 5 cm model (21 cameras)")
    fs = FreeSpaceMap(cams, (lo, hi), 0.05, margin=room.margin)
    t = time_call(lambda: fs.update(depths), reps)
    imgs = [depths[c.id] for c in cams]
    tn = time_call(lambda: free_space_update_numpy(imgs, fs.grid.size, *fs.twin_args(), fs.margin,
                                                   fs.min_free_views),
                   1 if ctx.quick else 3, warmup=0)
    rows.append(BenchRow("freespace.21cam.5cm_ms", float(np.median(t) * 1e3), "ms", None,
                         "numpy twin", float(np.median(tn) * 1e3),
                         f"{fs.grid.size} voxels x {len(cams)} cams; goal <= 50 ms; worst {t.max() * 1e3:.1f} ms"))

    # OctoMap: the same images as point clouds, ray insertion (free along rays, hit at the end)
    try:
        import pyoctomap
    except ImportError:  # pragma: no cover - bench extra not installed
        pyoctomap = None
    if pyoctomap is not None:
        clouds = [(c.depth_to_points(depths[c.id]), c.position.copy()) for c in cams]
        if ctx.quick:
            clouds = [(p[::16], o) for p, o in clouds]

        def octo():
            tree = pyoctomap.OcTree(0.05)
            for pts, origin in clouds:
                tree.insertPointCloud(pts, origin, max_range=8.0, discretize=True)
            return tree

        t0 = time.perf_counter()
        octo()
        to = time.perf_counter() - t0
        note = "every 16th pixel (quick)" if ctx.quick else "all valid pixels, discretize=True"
        rows.append(BenchRow("freespace.21cam.5cm_octomap_ms", to * 1e3, "ms", None, "numba update (ours)",
                             float(np.median(t) * 1e3), f"OctoMap insertPointCloud, 21 clouds, {note}"))

    if not ctx.quick:
        ff = FreeSpaceMap(cams, (lo, hi), 0.05, margin=room.margin, footprint="full")
        tf = time_call(lambda: ff.update(depths), 5, warmup=1)
        rows.append(BenchRow("freespace.21cam.5cm_full_ms", float(np.median(tf) * 1e3), "ms", None,
                             "centre-pixel update", float(np.median(t) * 1e3),
                             "footprint='full': every pixel of each voxel's projection"))
    f10 = FreeSpaceMap(cams, (lo, hi), 0.10, margin=room.margin)
    t10 = time_call(lambda: f10.update(depths), reps)
    rows.append(BenchRow("freespace.21cam.10cm_ms", float(np.median(t10) * 1e3), "ms", None, None, None,
                         f"{f10.grid.size} voxels"))
    return rows
