"""A changed cell is said, never silently learned (issue 31 point 4).

A camera with a learned static scene (:mod:`depthguard.learned_scene`) feeds
every frame, with the robot's depth at its capture joints, to its
:class:`SceneChangeWatch` on its worker thread (like the drift watch, R34). On
a fixed subsample of the pixels with a learned surface and no robot in front:

- **new**: measured nearer than the learned surface by more than its band —
  something stands in front of it. It becomes a *change* once it has stayed
  ``new_after_s`` seconds without a break (a person walking through is not one);
- **gone**: measured farther by more than the band — the scene had something
  there that is no longer there (a moved fixture; a bumped camera too, which the
  drift watch flags, R34). A change after ``gone_after_s``.

Changes are counted per **region**: the image is cut into ``regions`` (rows,
columns) tiles, and a tile with at least ``min_share`` of its judged samples (and
:data:`MIN_SAMPLES` of them) changed is reported: camera, kind, tile, its pixel
box, the share and since when. The learned scene is never updated here: a
person standing still for a minute is reported as something new and stays an
obstacle — the known scene is changed only by learning it again, an explicit
command (``depthguard rig learn-scene --replace``).

Cost per frame: one gather and a few comparisons on ~10000 samples.
"""

from __future__ import annotations

import threading

import numpy as np

__all__ = ["SceneChangeWatch", "MIN_SAMPLES"]

#: a tile needs at least this many changed samples to be reported
MIN_SAMPLES = 10


class SceneChangeWatch:
    """The change watch of one camera (module docstring).

    cam : :class:`~depthguard.camera.Camera`; learned : its
    :class:`~depthguard.learned_scene.LearnedScene`; new_after_s, gone_after_s : s;
    regions : (rows, cols); min_share : of a tile's judged samples; stride : 0 = about 10000 samples.
    ``update(depth, robot_depth, stamp)`` per frame; :meth:`changes` the regions changed now.
    """

    def __init__(self, cam, learned, new_after_s: float = 10.0, gone_after_s: float = 1.0,
                 regions: tuple[int, int] = (3, 4), min_share: float = 0.05, stride: int = 0):
        H, W = cam.shape
        if stride <= 0:
            stride = max(1, int(round(np.sqrt(H * W / 10000.0))))
        self.camera_id = cam.id
        self.shape = (H, W)
        grid = np.zeros((H, W), dtype=bool)
        grid[::stride, ::stride] = True
        self.index = np.flatnonzero(grid & (learned.depth > 0))
        z = learned.depth.ravel()[self.index]
        band = learned.band().ravel()[self.index]
        self.near_limit = (z - band).astype(np.float32)
        self.far_limit = (z + band).astype(np.float32)
        rows, cols = (max(1, int(a)) for a in regions)
        self.regions = (rows, cols)
        v, u = np.divmod(self.index, W)
        self.tile = (np.minimum(v * rows // H, rows - 1) * cols + np.minimum(u * cols // W, cols - 1)).astype(np.int64)
        self.new_after_s, self.gone_after_s = float(new_after_s), float(gone_after_s)
        self.min_share = float(min_share)
        n = self.index.size
        self._near_since = np.full(n, np.nan)
        self._far_since = np.full(n, np.nan)
        self._lock = threading.Lock()
        self._changes: list[dict] = []
        self.frames = 0

    def update(self, depth: np.ndarray, robot_depth: np.ndarray | None, stamp: float) -> list[dict]:
        """Judge one frame ((H, W) m depth, (H, W) m robot depth or None, stamp s); returns the
        regions changed now (also kept for :meth:`changes`)."""
        if not self.index.size:
            return []
        m = np.asarray(depth, dtype=np.float32).ravel()[self.index]
        with np.errstate(invalid="ignore"):
            valid = np.isfinite(m) & (m > 0)
            near = valid & (m < self.near_limit)
            far = valid & (m > self.far_limit)
        judged = valid
        if robot_depth is not None:
            rd = np.asarray(robot_depth, dtype=np.float32).ravel()[self.index]
            robot = rd > 0                          # the robot in front: this frame says nothing there
            judged = judged & ~robot
            near &= ~robot
            far &= ~robot
        t = float(stamp)
        # a run is broken only by a judged frame that disagrees; an unjudged one (robot, no return) keeps it
        self._near_since[judged & ~near] = np.nan
        self._far_since[judged & ~far] = np.nan
        self._near_since[near & np.isnan(self._near_since)] = t
        self._far_since[far & np.isnan(self._far_since)] = t
        out = []
        rows, cols = self.regions
        ntile = rows * cols
        H, W = self.shape
        seen = np.bincount(self.tile[judged], minlength=ntile)
        for kind, since, after in (("new", self._near_since, self.new_after_s),
                                   ("gone", self._far_since, self.gone_after_s)):
            changed = judged & (t - since >= after)          # NaN compares False
            cnt = np.bincount(self.tile[changed], minlength=ntile)
            for k in np.flatnonzero(cnt >= MIN_SAMPLES):
                share = cnt[k] / max(seen[k], 1)
                if share < self.min_share:
                    continue
                r, c = divmod(int(k), cols)
                first = float(np.nanmin(since[changed & (self.tile == k)]))
                out.append({"camera": self.camera_id, "kind": kind, "region": f"r{r}c{c}",
                            "box": [c * W // cols, r * H // rows, (c + 1) * W // cols - 1, (r + 1) * H // rows - 1],
                            "share": float(share), "since": first})
        with self._lock:
            self._changes = out
            self.frames += 1
        return out

    def changes(self) -> list[dict]:
        """The regions changed at the last frame (thread-safe copy)."""
        with self._lock:
            return list(self._changes)

    @staticmethod
    def sentence(change: dict) -> str:
        """One line for a log: camera, kind, region and since when."""
        what = ("something new has stayed" if change["kind"] == "new" else "the learned scene is gone")
        u0, v0, u1, v1 = change["box"]
        return (f"camera {change['camera']}: {what} in region {change['region']} (pixels {u0}-{u1} x {v0}-{v1}, "
                f"{100 * change['share']:.0f} % of it) since {change['since']:.2f} s - not learned; relearn with "
                f"depthguard rig learn-scene --replace if the cell changed for good")
