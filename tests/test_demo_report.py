"""The closed loop's figures (issue 33 item 14): every title and axis label inside its figure (a
long scenario title was cut at the edge) and the camera snapshots on one colour scale with its bar in metres."""

from __future__ import annotations

import types

import numpy as np


def _figures(tmp_path, monkeypatch, description):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from depthguard.evaluation.closed_loop.report import write_report

    kept = []
    monkeypatch.setattr(plt, "close", lambda fig=None: kept.append(fig))
    n = 50
    t = np.linspace(0, 1, n)
    res = types.SimpleNamespace(t=t, ee=np.zeros((n, 3)), D=np.full((n, 3), 0.3), gt_cp=np.full((n, 3), 0.35),
                                gt_robot_dyn=np.full(n, 0.4), control_point_names=("ee", "elbow", "wrist"),
                                rep=np.zeros((n, 3)), scale=np.ones(n), override=np.ones(n))
    hexagon = types.SimpleNamespace(corners=np.array([[0, 0, 0], [0, 0.1, 0], [0, 0.1, 0.1]]),
                                    center=np.zeros(3))
    near = np.full((48, 64), 1.5, np.float32)
    near[:10] = 0.0                                   # no return
    far = np.full((48, 64), 3.5, np.float32)
    paths = write_report(tmp_path, res, {"scenario": "elbow", "description": description}, hexagon, 0.4,
                         snapshots=[(0.5, "cam0", near), (0.5, "cam1", far)])
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    for fig in kept:
        FigureCanvasAgg(fig).draw()
    return paths, list(kept)            # left open: closing them would drop their Agg canvas


def test_every_text_lies_inside_its_figure_and_snapshots_share_a_scale(tmp_path, monkeypatch):
    description = ("a ball sits on the elbow's path and the arm reconfigures through redundancy while the "
                   "end effector keeps the hexagon, with both Kinects and the product's defaults")
    paths, figs = _figures(tmp_path, monkeypatch, description)
    assert len(paths) == 5 and len(figs) == 4
    for fig in figs:
        box = fig.bbox
        renderer = fig.canvas.get_renderer()          # the Agg canvas drawn above
        texts = [t for ax in fig.axes for t in (ax.title, ax.xaxis.label, ax.yaxis.label)]
        assert any(t.get_text() for t in texts)
        for text in texts:
            if not text.get_visible() or not text.get_text():
                continue
            e = text.get_window_extent(renderer)
            assert e.x0 >= box.x0 - 1 and e.x1 <= box.x1 + 1 and e.y0 >= box.y0 - 1 and e.y1 <= box.y1 + 1, \
                (text.get_text()[:60], e, box)
    snaps = figs[-1]
    images = [a.get_images()[0] for a in snaps.axes if a.get_images()]
    assert len(images) == 2 and len({im.get_clim() for im in images}) == 1
    assert images[0].get_clim() == (1.5, 3.5)
    bars = [a for a in snaps.axes if "depth [m]" in a.get_ylabel()]
    assert len(bars) == 1
