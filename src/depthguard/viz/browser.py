"""A headless Chromium for the live view: screenshots, and a browser connected during a bench (R29).

Nothing is fetched from the internet: the page is the view's own server on
this machine (viser ships its web client). The flags are those measured to
render WebGL without a GPU (SwiftShader); without a virtual-time budget the
screenshot is taken before the page has drawn and comes out blank.

- :func:`find_browser` — ``$DEPTHGUARD_BROWSER``, else ``chromium`` /
  ``chromium-browser`` / ``google-chrome`` on the ``PATH``; None when none.
- :class:`HeadlessBrowser` — a running Chromium on one URL (a context manager).
- :func:`wait_for_client` — until the view's server has a connected browser.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

__all__ = ["find_browser", "HeadlessBrowser", "wait_for_client", "BROWSER_FLAGS"]

#: measured here: WebGL in software (SwiftShader), no GPU, no network of Chromium's own
BROWSER_FLAGS = ("--headless=new", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--no-first-run", "--disable-default-apps", "--mute-audio", "--hide-scrollbars")


def find_browser() -> str | None:
    """The Chromium to use, or None (``$DEPTHGUARD_BROWSER`` first)."""
    env = os.environ.get("DEPTHGUARD_BROWSER")
    if env:
        return env if Path(env).exists() else shutil.which(env)
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    return None


class HeadlessBrowser:
    """Headless Chromium showing ``url`` in a ``size`` (width, height) px window.

    With ``screenshot`` (a PNG path) it draws for ``budget_ms`` of virtual time, writes the
    screenshot and exits (:meth:`wait`); without, it stays connected until :meth:`close`.
    ``nice`` > 0 runs it at that lower priority (a bench: the browser stands for one on
    another machine and must not take the control thread's core).
    ``FileNotFoundError`` when there is no browser.
    """

    def __init__(self, url: str, *, size: tuple[int, int] = (1280, 800), screenshot: str | Path | None = None,
                 budget_ms: int = 10000, browser: str | None = None, nice: int = 0):
        exe = browser or find_browser()
        if exe is None:
            raise FileNotFoundError("no Chromium found (install the Debian package `chromium`, or set "
                                    "DEPTHGUARD_BROWSER to a Chromium or Chrome executable)")
        self._tmp = tempfile.mkdtemp(prefix="depthguard-browser-")
        args = [exe, *BROWSER_FLAGS, f"--user-data-dir={self._tmp}", f"--window-size={int(size[0])},{int(size[1])}"]
        self.screenshot = None if screenshot is None else Path(screenshot)
        if self.screenshot is not None:
            args += [f"--virtual-time-budget={int(budget_ms)}", f"--screenshot={self.screenshot.resolve()}"]
        else:
            args += ["--remote-debugging-port=0"]            # keeps a headless browser open on its page
        if int(nice) > 0 and shutil.which("nice"):
            args = ["nice", "-n", str(int(nice))] + args
        self.proc = subprocess.Popen(args + [url], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                     stdin=subprocess.DEVNULL, start_new_session=True)

    def wait(self, timeout: float = 60.0) -> int:
        """Wait for the browser to exit (a screenshot run); its exit status. ``TimeoutError`` after
        ``timeout`` s (the browser is then closed)."""
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.close()
            raise TimeoutError(f"the headless browser did not finish within {timeout:g} s") from None

    def close(self) -> None:
        """End the browser (its own process group: the renderer and GPU processes too)."""
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, 15)
            except ProcessLookupError:
                pass
            try:
                self.proc.wait(5.0)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, 9)
                self.proc.wait(5.0)
        shutil.rmtree(self._tmp, ignore_errors=True)

    def __enter__(self) -> "HeadlessBrowser":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def wait_for_client(server, timeout: float = 30.0):
    """The first browser connected to the viser ``server``; ``TimeoutError`` after ``timeout`` s."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        clients = server.get_clients()
        if clients:
            return next(iter(clients.values()))
        time.sleep(0.05)
    raise TimeoutError(f"no browser connected to the view within {timeout:g} s")
