"""Accuracy of a voxel reconstruction against ground truth (Hamersma 2011 tables 1-2, R24).

Per voxel, with the simulation (truth) and the reconstruction:

====  ==========  ==============  =======================
case  truth       reconstruction  verdict
====  ==========  ==============  =======================
1     free        free            correct free
2     free        occupied        free seen as object
3     occupied    occupied        correct object
4     occupied    free            object seen as free
====  ==========  ==============  =======================

``free accuracy = n1 / (n1 + n2)``, ``object accuracy = n3 / (n3 + n4)``.
Case 2 stops the machine needlessly; case 4 can let it collide.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

__all__ = ["Confusion", "confusion", "cases", "plot_case_slices", "CASE_COLOURS"]

CASE_COLOURS = {0: (0.85, 0.85, 0.85), 1: (1.0, 1.0, 1.0), 2: (0.2, 0.4, 1.0),
                3: (0.1, 0.7, 0.2), 4: (0.9, 0.1, 0.1)}   # fig. 9: white, blue, green, red


@dataclass(frozen=True)
class Confusion:
    correct_free: int
    free_as_object: int
    correct_object: int
    object_as_free: int

    @property
    def n_free(self) -> int:
        return self.correct_free + self.free_as_object

    @property
    def n_object(self) -> int:
        return self.correct_object + self.object_as_free

    @property
    def free_accuracy(self) -> float:
        """Share of truly free voxels reconstructed free (nan when there are none)."""
        return self.correct_free / self.n_free if self.n_free else float("nan")

    @property
    def object_accuracy(self) -> float:
        """Share of truly occupied voxels reconstructed occupied (nan when there are none)."""
        return self.correct_object / self.n_object if self.n_object else float("nan")

    def as_dict(self) -> dict:
        d = asdict(self)
        d.update(free_accuracy=self.free_accuracy, object_accuracy=self.object_accuracy)
        return d

    def __add__(self, other: "Confusion") -> "Confusion":
        return Confusion(self.correct_free + other.correct_free, self.free_as_object + other.free_as_object,
                         self.correct_object + other.correct_object, self.object_as_free + other.object_as_free)


def _check(reconstructed, truth, mask):
    r = np.asarray(reconstructed, dtype=bool)
    t = np.asarray(truth, dtype=bool)
    if r.shape != t.shape:
        raise ValueError(f"reconstruction {r.shape} and truth {t.shape} differ in shape")
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        if m.shape != r.shape:
            raise ValueError(f"mask {m.shape} differs in shape from the grid {r.shape}")
    else:
        m = np.ones(r.shape, dtype=bool)
    return r, t, m


def confusion(reconstructed_occupied, true_occupied, mask=None) -> Confusion:
    """R24: the four cases counted over the voxels (optionally only where ``mask``).

    Both grids (nx, ny, nz) bool, True = occupied.
    """
    r, t, m = _check(reconstructed_occupied, true_occupied, mask)
    return Confusion(int(np.count_nonzero(~t & ~r & m)), int(np.count_nonzero(~t & r & m)),
                     int(np.count_nonzero(t & r & m)), int(np.count_nonzero(t & ~r & m)))


def cases(reconstructed_occupied, true_occupied, mask=None) -> np.ndarray:
    """(nx, ny, nz) int8: case 1..4 per voxel (0 outside ``mask``)."""
    r, t, m = _check(reconstructed_occupied, true_occupied, mask)
    out = np.where(t, np.where(r, 3, 4), np.where(r, 2, 1)).astype(np.int8)
    out[~m] = 0
    return out


def plot_case_slices(case_grid: np.ndarray, lo, voxel_size: float, path, title: str = "",
                     z_levels=None, x_levels=None) -> Path:
    """A picture like the paper's fig. 9: horizontal slices (and optionally vertical ones)
    of the case grid, coloured white / blue / green / red for cases 1 / 2 / 3 / 4."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    g = np.asarray(case_grid)
    nx, ny, nz = g.shape
    lo = np.asarray(lo, float)
    cmap = ListedColormap([CASE_COLOURS[k] for k in range(5)])
    z_levels = list(z_levels) if z_levels is not None else [int(nz * f) for f in (0.15, 0.4, 0.65)]
    x_levels = list(x_levels) if x_levels is not None else [nx // 2]
    n = len(z_levels) + len(x_levels)
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 4.4), squeeze=False)
    ext_xy = [lo[0], lo[0] + nx * voxel_size, lo[1], lo[1] + ny * voxel_size]
    ext_yz = [lo[1], lo[1] + ny * voxel_size, lo[2], lo[2] + nz * voxel_size]
    for ax, k in zip(axes[0], z_levels):
        ax.imshow(g[:, :, k].T, origin="lower", extent=ext_xy, cmap=cmap, vmin=0, vmax=4,
                  interpolation="nearest")
        ax.set_title(f"z = {lo[2] + (k + 0.5) * voxel_size:.2f} m")
        ax.set_xlabel("x [m]"); ax.set_ylabel("y [m]")
    for ax, i in zip(axes[0][len(z_levels):], x_levels):
        ax.imshow(g[i, :, :].T, origin="lower", extent=ext_yz, cmap=cmap, vmin=0, vmax=4,
                  interpolation="nearest")
        ax.set_title(f"x = {lo[0] + (i + 0.5) * voxel_size:.2f} m")
        ax.set_xlabel("y [m]"); ax.set_ylabel("z [m]")
    fig.legend(handles=[Patch(facecolor=CASE_COLOURS[k], edgecolor="k", label=lab) for k, lab in
                        ((1, "1 correct free"), (2, "2 free seen as object"), (3, "3 correct object"),
                         (4, "4 object seen as free"))], loc="lower center", ncol=4)
    fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.07, 1, 0.95))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
