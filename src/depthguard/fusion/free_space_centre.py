"""The free-space map's centre-pixel update, camera by camera from the cameras' own images (R21; issue 30).

:class:`~depthguard.fusion.free_space.FreeSpaceMap` in its centre-pixel mode (the paper's) reads one
pixel per (voxel, camera) pair. :class:`CentrePairs` keeps each camera's pairs again **in increasing
pixel order** (model, made once per camera set): the update reads the image front to back
(:func:`~depthguard.fusion.free_space_kernels.centre_counts`; in voxel order the reads jump over the
image and cost about 40 ns a pair on four 640 x 480 cameras) and adds each pair's view to the voxel's
counters, which stay in cache (one byte a voxel). The images are read where the caller holds them: a
float32 image is not copied, the robot's pixels (R9, R30) are tested per pair from the robot's
rendered depth (no mask made, nothing negated). The verdicts are bit for bit those of the flat-buffer
kernel :func:`~depthguard.fusion.free_space_kernels.free_space_update` on the same inputs.
"""

from __future__ import annotations

import numpy as np

from depthguard.camera import check_depth_image
from depthguard.fusion.free_space_kernels import centre_counts, robot_pixels

__all__ = ["CentrePairs"]

# a robot mask read as a robot depth at offset 0: "depth >= the smallest normal float32" is
# "depth > 0" (the pixels whose depth the flat buffer negates; a 0 stays 0 there) for every depth
# but a subnormal one (< 1.2e-38 m, below any camera's range); not the smallest subnormal, which a
# process flushing subnormals to zero (a library built with -ffast-math) would read as 0: no robot
_MASK_DEPTH = np.float32(np.finfo(np.float32).tiny)


class CentrePairs:
    """Each camera's pairs in pixel order (model) and the few buffers of the update (data).

    ``start`` (C+1,) int64, ``pix`` (P,) int32 flat pixel over all images (``offs[c] + v W + u``),
    ``vox`` (P,) int32, ``zc`` (P,) float32 m: the map's pairs camera by camera (voxel order);
    ``cameras`` the map's :class:`~depthguard.camera.Camera` s, ``offs`` (C,) int64.

    ``spix`` (P,) int32 pixel ``v W + u`` in the camera's own image, ``svox``, ``szc`` the pairs
    reordered (per camera, by pixel; stable); ``sbg`` (P,) float32 m the known shell's depth at each
    pair's pixel (0 = none; :meth:`set_background`).
    """

    def __init__(self, cameras, start, pix, vox, zc, offs):
        self.cameras = list(cameras)
        self.start = start
        order = np.concatenate([a + np.argsort(pix[a:b], kind="stable")
                                for a, b in zip(start[:-1], start[1:])]).astype(np.int64)
        self.cam_of = np.repeat(np.arange(len(self.cameras)), np.diff(start))
        self.spix = (pix[order] - offs[self.cam_of]).astype(np.int32)
        self.svox = vox[order]
        self.szc = zc[order]
        for a in (self.cam_of, self.spix, self.svox, self.szc):
            a.setflags(write=False)
        self.sbg = np.zeros(len(order), dtype=np.float32)
        C = len(self.cameras)
        self._zero = [None] * C       # a missing camera's image, when it is judged at all (min_range 0)
        self._conv = [None] * C       # an image given as another float type, copied to float32
        self._rmask = [None] * C      # a robot mask as a robot depth (offset 0)

    def set_background(self, bg: np.ndarray | None, offs: np.ndarray) -> None:
        """``bg`` (sum H*W,) float32 m the map's flat shell buffer (None: no shell)."""
        if bg is None:
            self.sbg.fill(0.0)
        else:
            self.sbg[...] = bg[offs[self.cam_of] + self.spix.astype(np.int64)]

    def inputs(self, depths, masks, robot_depths) -> list:
        """Per camera ``(depth, mask, robot_depth)`` checked (None where not given; a camera without
        an image has neither): every input is checked before the update changes anything."""
        work = []
        for cam in self.cameras:
            img = depths.get(cam.id)
            d = None if img is None else check_depth_image(cam, img)
            m = masks.get(cam.id) if masks else None
            if m is not None:
                m = np.asarray(m)
                if m.shape != (cam.height, cam.width) or m.dtype != np.bool_:
                    raise ValueError(f"robot mask of camera {cam.id!r}: shape {m.shape} dtype {m.dtype}, expected bool "
                                     f"{(cam.height, cam.width)}")
                m = None if d is None else m
            rd = None if (d is None or not robot_depths) else robot_depths.get(cam.id)
            if rd is not None:
                rd = check_depth_image(cam, rd, "robot depth")
            work.append((d, m, rd))
        return work

    def count(self, work, offset: float, rmin, rmax, half, f, grow, use_bg: bool, bg_tol: float,
              n_free: np.ndarray, n_surf: np.ndarray) -> None:
        """Every camera's views into ``n_free``, ``n_surf`` (N,) uint8 (zeroed first). ``work`` from
        :meth:`inputs`; ``offset`` m the robot pixels' offset; per camera (C,) float64: ``rmin``,
        ``rmax`` m its range, ``half`` m half a voxel's depth extent, ``f`` m ``far + margin``,
        ``grow`` 1/m the margin's growth; ``bg_tol`` m the shell match."""
        n_free.fill(0)
        n_surf.fill(0)
        for ci, (d, m, rd) in enumerate(work):
            a, b = int(self.start[ci]), int(self.start[ci + 1])
            if a == b:
                continue
            off = offset
            if d is None:
                if rmin[ci] > 0.0:
                    continue              # an image of zeros: no pair passes d >= min_range
                flat = self._buffer(self._zero, ci)
            elif d.dtype == np.float32:
                flat = d.reshape(-1)      # the caller's image itself (a view when C-contiguous)
            else:                         # copied as the flat buffer is (negatives 0)
                flat = self._buffer(self._conv, ci)
                np.maximum(d, np.float32(0.0), out=flat.reshape(d.shape), casting="unsafe")
            if rd is not None and not (d.dtype == np.float32 and rd.dtype == np.float32):
                m = robot_pixels(d, rd, offset, np.empty(d.shape, dtype=bool))   # on the caller's arrays
            if m is not None:             # a mask: a robot depth just above 0 at its pixels, offset 0
                rflat = np.multiply(m.reshape(-1), _MASK_DEPTH, out=self._buffer(self._rmask, ci))
                off = 0.0
            else:
                rflat = flat if rd is None else rd.reshape(-1)
            centre_counts(_read_only(flat), _read_only(rflat), off, rd is not None or m is not None, self.spix[a:b], self.svox[a:b],
                          self.szc[a:b], self.sbg[a:b], use_bg, bg_tol, float(rmin[ci]), float(rmax[ci]),
                          float(half[ci]), float(f[ci]), float(grow[ci]), n_free, n_surf)

    def _buffer(self, store: list, ci: int) -> np.ndarray:
        """A (H*W,) float32 buffer of camera ``ci`` kept in ``store`` (made on first use, zeros)."""
        if store[ci] is None:
            c = self.cameras[ci]
            store[ci] = np.zeros(c.width * c.height, dtype=np.float32)
        return store[ci]


def _read_only(a: np.ndarray) -> np.ndarray:
    """A flat read-only view of ``a`` (the image's own data): the kernel sees one array type
    whatever the caller's flags (one compiled signature: a renderer's image is read-only, a
    worker's copy is not)."""
    v = a.reshape(-1)
    v.flags.writeable = False
    return v
