"""``depthguard view``: a monitor's output folder or a recording in the browser, or a screenshot of a live one (R29, R31).

- ``depthguard view DIR [--bag BAG]``: the ``log.jsonl`` and ``summary.json`` that
  ``depthguard monitor --out DIR`` wrote, with a time slider, play switch and
  speed; each camera's points from the bag the run read (named in the summary,
  or ``--bag``) — :mod:`depthguard.viz.replay`.
- ``depthguard view BAG [--out DIR]``: the monitor replays the bag as fast as
  possible first (``depthguard monitor --source bag:BAG --fast --out DIR``; a
  temporary folder without ``--out``), then the view shows that run with the
  bag's depth (why: :mod:`depthguard.viz.replay`).
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
from depthguard.cli.common import in_range


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
    target: Optional[Path] = typer.Argument(None, help="Output folder of `depthguard monitor --out` (log.jsonl + summary.json), or a ROS 2 bag (rosbag2 folder or .mcap file)."),
    bag: Optional[Path] = typer.Option(None, "--bag", help="The bag the folder's run read, for the cameras' points (default: the bag named in its summary.json, when it is here)."),
    rig: Optional[Path] = typer.Option(None, "--rig", help="Rig file of the cell (default: the built-in cell named in the folder's summary; for a bag: --cell)."),
    cell: Optional[str] = typer.Option(None, "--cell", help="Built-in cell of a bag, or of a live screenshot (default flacco-cell)."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="A bag: keep the monitor's replay in this new folder (default: a temporary one, removed at the end)."),
    source: Optional[str] = typer.Option(None, "--source", help="sim: source of a live screenshot (default sim:CELL)."),
    host: str = typer.Option("127.0.0.1", "--host", help="Address the view's web server listens on (anyone who reaches it can change rho)."),
    port: int = typer.Option(8080, "--port", callback=in_range(0, 65535), help="Port of the view, 0 to 65535 (a busy one: the next free)."),
    screenshot: Optional[Path] = typer.Option(None, "--screenshot", help="Write a PNG of the view taken by a headless Chromium, then exit."),
    at: Optional[float] = typer.Option(None, "--at", help="A folder or bag's screenshot: the time shown (s, the log's clock t; default its first record)."),
    seconds: float = typer.Option(4.0, "--seconds", help="Live screenshot: seconds the monitor runs before the photograph."),
    size: str = typer.Option("1280x800", "--size", help="Screenshot size WIDTHxHEIGHT (px)."),
    speed: float = typer.Option(1.0, "--speed", help="Playback speed (1 = real time; also in the panel)."),
) -> None:
    """Look at what the monitor saw: a run's output folder or a recording, with a time slider, in the browser.

    A bag alone is replayed by the monitor first (as fast as possible), so that the
    view shows its decisions and reasons, not only the depth. Without a folder,
    ``--screenshot PNG`` runs the monitor on a built-in cell's simulator with its
    live view and photographs it (for a live view of your own monitor:
    ``depthguard monitor --view``).
    """
    wh = _size(size)
    if screenshot is not None:
        _check_png(screenshot)
    if not seconds > 0:
        raise ValueError(f"--seconds must be > 0 (got {seconds})")
    if not speed > 0:
        raise ValueError(f"--speed must be > 0 (got {speed})")
    if target is None:
        if screenshot is None:
            raise ValueError("give a monitor's output folder or a bag (depthguard view DIR|BAG), or --screenshot PNG "
                             "for a photograph of a live monitor; a live view: depthguard monitor --view")
        for name, value in (("--bag", bag), ("--out", out), ("--at", at)):
            if value is not None:
                raise ValueError(f"{name} goes with a folder or a bag (depthguard view DIR|BAG), not with a live "
                                 f"screenshot")
        from depthguard.viz.live_demo import live_monitor

        def during(the_view, _mon):
            time.sleep(seconds)
            _photograph(the_view, screenshot, wh, 8000)

        _, summary = live_monitor(during, cell or "flacco-cell", source=source, host=host, port=port)
        typer.echo(f"view: wrote {screenshot} ({summary['cycles']} control cycles, step p99 "
                   f"{summary['step_ms']['p99']} ms, {summary['view_updates']} view updates)")
        return
    from depthguard.viz.replay import is_bag, open_run

    if not target.exists():
        raise FileNotFoundError(f"{target}: no such folder or bag (give the --out folder of `depthguard monitor`, "
                                f"or a ROS 2 bag)")
    cleanup = []
    if is_bag(target) and not (target / "log.jsonl").is_file():
        if bag is not None:
            raise ValueError(f"--bag {bag}: {target} is a bag already (--bag goes with a monitor's output folder)")
        folder, cleanup = _replay_bag(target, rig, cell, out)
        try:
            source_in = open_run(folder, bag=target, rig_path=rig)
        except BaseException:
            for fn in cleanup:
                fn()
            raise
    else:
        if target.is_dir() and not (target / "log.jsonl").is_file():
            raise FileNotFoundError(f"{target}: no log.jsonl - neither the output folder of `depthguard monitor` "
                                    f"nor a ROS 2 bag (no metadata.yaml)")
        for name, value in (("--out", out), ("--cell", cell)):
            if value is not None:
                raise ValueError(f"{name} goes with a bag; {target} is a monitor's output folder")
        source_in = open_run(target, bag=bag, rig_path=rig)
    source_in.cleanup += cleanup
    try:
        _show(source_in, target, host, port, screenshot, wh, at, speed)
    finally:
        source_in.close()


def _replay_bag(bag: Path, rig: Optional[Path], cell: Optional[str], out: Optional[Path]):
    """Run ``depthguard monitor --source bag:BAG --fast --quiet --out DIR`` (the command itself, with
    its checks and defaults; a temporary DIR without ``--out``); returns ``(DIR, [cleanup])``."""
    import shutil
    import tempfile

    from typer.main import get_command

    from depthguard.progress import log

    cleanup = []
    if out is None:
        tmp = Path(tempfile.mkdtemp(prefix="depthguard-view-"))
        cleanup.append(lambda: shutil.rmtree(tmp, ignore_errors=True))
        out = tmp / "run"
    log(f"view: the monitor replays {bag} as fast as possible into {out} ...")
    try:
        args = ["monitor", "--source", f"bag:{bag}", "--fast", "--quiet", "--out", str(out)]
        args += ["--rig", str(rig)] if rig is not None else ["--cell", cell] if cell is not None else []
        get_command(app).main(args=args, prog_name="depthguard", standalone_mode=False)   # the command itself
    except BaseException:
        for fn in cleanup:
            fn()
        raise
    return out, cleanup


def _show(source_in, target: Path, host: str, port: int, screenshot, wh, at, speed: float) -> None:
    from depthguard.progress import log
    from depthguard.viz.live import LiveView
    from depthguard.viz.replay import Replay

    recording = source_in.recording
    with LiveView(source_in.rig, host=host, port=port, title=f"depthguard - {target.name}") as the_view:
        cfg = recording.summary.get("config") or {}
        if isinstance(cfg.get("rho"), (int, float)):
            the_view.rho = float(cfg["rho"])
            the_view.gui_rho.value = round(the_view.rho, 2)
        the_view.gui_rho.disabled = True                  # a record's distances were computed with its rho
        playback = Replay(the_view, source_in, speed=speed)
        try:
            if at is not None:
                if not recording.times[0] <= at <= recording.times[-1]:
                    raise ValueError(f"--at {at}: the run's records span t = {recording.times[0]:.3f} .. "
                                     f"{recording.times[-1]:.3f} s")
                playback.seek(at)
            if screenshot is not None:
                time.sleep(3 * the_view.period)
                _photograph(the_view, screenshot, wh, 8000)
                typer.echo(f"view: wrote {screenshot}")
                return
            log(f"view: {recording.lines} records of {recording.folder} ({len(recording.times)} kept, "
                f"t {recording.times[0]:.2f}..{recording.times[-1]:.2f} s"
                f"{', depth from ' + str(source_in.depth.path) if source_in.depth is not None else ', no depth'}) "
                f"at {the_view.url} - Ctrl-C stops")
            try:
                while True:
                    time.sleep(0.5)
            except KeyboardInterrupt:
                pass
        finally:
            playback.close()
