"""``depthguard view``: a monitor's output folder in the browser, or a screenshot of a live one (R29, R31).

- ``depthguard view DIR``: the ``log.jsonl`` and ``summary.json`` that
  ``depthguard monitor --out DIR`` wrote, with a time slider
  (:mod:`depthguard.viz.playback`). Recordings (bags) are not read here yet.
- ``depthguard view --screenshot PNG``: the monitor running live on a
  built-in cell's simulator, with its view, photographed by a headless
  Chromium after ``--seconds`` (the docs' ``docs/img/view.png``).
- ``depthguard view DIR --screenshot PNG``: the folder's view at its first record, photographed.

A live view of a running monitor: ``depthguard monitor --view``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

import typer

from depthguard.cli.app import app


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        w = h = 0
    if not (200 <= w <= 4096 and 200 <= h <= 4096):
        raise ValueError(f"--size: expected WIDTHxHEIGHT in pixels, each 200..4096 (got {text!r})")
    return w, h


def _check_png(path: Path) -> None:
    if path.suffix.lower() != ".png":
        raise ValueError(f"--screenshot {path}: the file must end in .png")
    if path.exists():
        raise ValueError(f"--screenshot {path}: exists already (a screenshot never overwrites a file)")
    if not path.parent.is_dir():
        raise ValueError(f"--screenshot {path}: the folder {path.parent} does not exist")


def _photograph(view, path: Path, size, budget_ms: int) -> None:
    from depthguard.progress import log
    from depthguard.viz.browser import HeadlessBrowser

    log(f"view: headless Chromium photographs {view.url} ...")
    with HeadlessBrowser(view.url, size=size, screenshot=path, budget_ms=budget_ms) as browser:
        status = browser.wait(120.0)
    if status != 0 or not path.is_file():
        raise ValueError(f"--screenshot {path}: Chromium exited with status {status} and wrote no image")


@app.command("view")
def view(
    folder: Optional[Path] = typer.Argument(None, help="Output folder of `depthguard monitor --out` (log.jsonl + summary.json)."),
    rig: Optional[Path] = typer.Option(None, "--rig", help="Rig file of the folder's cell (default: the built-in cell named in its summary)."),
    cell: str = typer.Option("flacco-cell", "--cell", help="Built-in cell of a live screenshot (no folder)."),
    source: Optional[str] = typer.Option(None, "--source", help="sim: source of a live screenshot (default sim:CELL)."),
    host: str = typer.Option("127.0.0.1", "--host", help="Address the view's web server listens on (anyone who reaches it can change rho)."),
    port: int = typer.Option(8080, "--port", min=0, max=65535, help="Port of the view (a busy one: the next free)."),
    screenshot: Optional[Path] = typer.Option(None, "--screenshot", help="Write a PNG of the view taken by a headless Chromium, then exit."),
    seconds: float = typer.Option(4.0, "--seconds", help="Live screenshot: seconds the monitor runs before the photograph."),
    size: str = typer.Option("1280x800", "--size", help="Screenshot size WIDTHxHEIGHT (px)."),
    speed: float = typer.Option(1.0, "--speed", help="Playback speed (1 = real time)."),
) -> None:
    """Look at what the monitor saw: a run's output folder with a time slider, in the browser.

    Without a folder, ``--screenshot PNG`` runs the monitor on a built-in cell's
    simulator with its live view and photographs it (for a live view of your own
    monitor: ``depthguard monitor --view``).
    """
    from depthguard.progress import log

    wh = _size(size)
    if screenshot is not None:
        _check_png(screenshot)
    if not seconds > 0:
        raise ValueError(f"--seconds must be > 0 (got {seconds})")
    if not speed > 0:
        raise ValueError(f"--speed must be > 0 (got {speed})")
    if folder is None:
        if screenshot is None:
            raise ValueError("give a monitor's output folder (depthguard view DIR), or --screenshot PNG for a "
                             "photograph of a live monitor; a live view: depthguard monitor --view")
        from depthguard.viz.live_demo import live_monitor

        def during(the_view, _mon):
            time.sleep(seconds)
            _photograph(the_view, screenshot, wh, 8000)

        _, summary = live_monitor(during, cell, source=source, host=host, port=port)
        typer.echo(f"view: wrote {screenshot} ({summary['cycles']} control cycles, step p99 "
                   f"{summary['step_ms']['p99']} ms, {summary['view_updates']} view updates)")
        return
    from depthguard.viz.live import LiveView
    from depthguard.viz.playback import Playback, load_run, rig_of_run

    recording = load_run(folder)
    the_rig = rig_of_run(recording, rig)
    with LiveView(the_rig, host=host, port=port, title=f"depthguard - {folder.name}") as the_view:
        cfg = recording.summary.get("config") or {}
        if isinstance(cfg.get("rho"), (int, float)):
            the_view.rho = float(cfg["rho"])
            the_view.gui_rho.value = round(the_view.rho, 2)
        the_view.gui_rho.disabled = True                  # a record's distances were computed with its rho
        playback = Playback(the_view, recording, speed=speed)
        try:
            if screenshot is not None:
                time.sleep(2 * the_view.period)
                _photograph(the_view, screenshot, wh, 8000)
                typer.echo(f"view: wrote {screenshot}")
                return
            log(f"view: {recording.lines} records of {folder} ({len(recording.times)} kept, "
                f"t {recording.times[0]:.2f}..{recording.times[-1]:.2f} s) at {the_view.url} - Ctrl-C stops")
            try:
                while True:
                    time.sleep(0.5)
            except KeyboardInterrupt:
                pass
        finally:
            playback.close()
