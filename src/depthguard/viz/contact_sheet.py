"""Contact sheets: the depth images of every camera of a rig on one PNG (matplotlib, Agg)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping

import numpy as np

__all__ = ["contact_sheet", "colorize_depth"]


def colorize_depth(depth: np.ndarray, vmin: float, vmax: float, cmap: str = "turbo") -> np.ndarray:
    """(H, W, 3) float RGB of a depth image (metres) on ``[vmin, vmax]``: near = warm (the top of
    ``cmap``), far = cold; invalid pixels (0 / non-finite) are black."""
    import matplotlib

    d = np.asarray(depth, dtype=np.float64)
    valid = np.isfinite(d) & (d > 0)
    x = np.clip((d - vmin) / max(vmax - vmin, 1e-9), 0.0, 1.0)
    rgb = matplotlib.colormaps[cmap](1.0 - x)[..., :3]  # near = warm, far = cold
    rgb[~valid] = 0.0
    return rgb


def contact_sheet(depths: Mapping[str, np.ndarray], path: str | Path, title: str = "",
                  vmin: float | None = None, vmax: float | None = None, cols: int | None = None,
                  dpi: int = 100) -> Path:
    """Write one PNG showing every depth image (``{camera id: (H, W) metres}``), colour-mapped on a
    common scale (``vmin``/``vmax``: default the 1st/99th percentile of the valid depths),
    black where there is no measurement, with a colour bar in metres. Returns the path."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    if not depths:
        raise ValueError("contact_sheet: no depth images given")
    ids = list(depths)
    valid = np.concatenate([np.asarray(d, np.float64)[np.asarray(d) > 0].ravel() for d in depths.values()])
    valid = valid[np.isfinite(valid)]
    if vmin is None:
        vmin = float(np.percentile(valid, 1)) if valid.size else 0.0
    if vmax is None:
        vmax = float(np.percentile(valid, 99)) if valid.size else 1.0
    if vmax <= vmin:
        vmax = vmin + 1.0
    n = len(ids)
    cols = cols or min(n, 4 if n <= 8 else 6)
    rows = math.ceil(n / cols)
    h, w = np.asarray(depths[ids[0]]).shape
    cell_w = 3.4
    fig, axes = plt.subplots(rows, cols, figsize=(cell_w * cols + 0.8, cell_w * h / w * rows + 0.9),
                             squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, cid in zip(axes.ravel(), ids):
        d = np.asarray(depths[cid])
        ax.imshow(colorize_depth(d, vmin, vmax), interpolation="nearest")
        frac = float((d > 0).mean())
        ax.set_title(f"{cid}  ({frac:.0%} valid)", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    sm = ScalarMappable(norm=Normalize(vmin, vmax), cmap=matplotlib.colormaps["turbo_r"])
    fig.colorbar(sm, ax=axes.ravel().tolist(), fraction=0.02, pad=0.01, label="depth [m]")
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p, dpi=dpi)
    plt.close(fig)
    return p
