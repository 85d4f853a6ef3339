"""Where the monitor's reactions go (R31): a JSON-lines log, a callback, zenoh topics.

A sink is any callable ``sink(reaction: Reaction) -> None`` with an optional
``close()``. The monitor calls its sinks at the control rate (500 Hz), so it
hands them to a :class:`SinkFanout`: the control thread only enqueues, and one
background thread calls every sink. Schemas: ``docs/MONITOR.md``.
"""

from __future__ import annotations

import json
import re
import threading
import time
from collections import deque
from pathlib import Path
from typing import Callable, Sequence

from depthguard.progress import log
from depthguard.runtime.reaction_json import reaction_json
from depthguard.runtime.result import Reaction

__all__ = ["SinkError", "JsonlLog", "CallbackSink", "ZenohPublisher", "SinkFanout", "reaction_keys", "open_jsonl",
           "run_file"]

_CELL = re.compile(r"^[A-Za-z0-9_\-.]+$")


class SinkError(ValueError):
    """A sink cannot be opened or used as asked."""


class JsonlLog:
    """One line per reaction, ``json.dumps(reaction.to_dict(), allow_nan=False)`` (``docs/MONITOR.md``).

    The file must not exist (a run never overwrites a log). Lines are flushed
    every ``flush_every`` reactions and on :meth:`close`. A NaN or inf that
    reached the record raises ``ValueError`` instead of being written.
    """

    def __init__(self, path: str | Path, flush_every: int = 100):
        self.path = Path(path)
        if int(flush_every) < 1:
            raise SinkError(f"flush_every must be >= 1 (got {flush_every})")
        self.flush_every = int(flush_every)
        try:
            # a 256 KiB buffer: its lines reach the file at the flushes, not every ~5 lines of 1.6 kB
            # (issue 29: 2.5 -> 1.2 us a line); the bytes are the same
            self._fh = open(self.path, "x", encoding="utf-8", buffering=1 << 18)
        except FileExistsError:
            raise SinkError(f"log {self.path} exists already; choose a new file") from None
        self.lines = 0
        from depthguard.runtime.reaction_text import warm_up

        warm_up()                                   # its compiled writer ready before the run's clock

    def __call__(self, reaction: Reaction) -> None:
        if self._fh is None:
            raise SinkError(f"log {self.path} is closed")
        self._fh.write(reaction_json(reaction) + "\n")         # = json.dumps(reaction.to_dict(), allow_nan=False)
        self.lines += 1
        if self.lines % self.flush_every == 0:
            self._fh.flush()

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None


def run_file(argument: str, context: dict, default: str, scheme: str) -> Path:
    """The file of a file sink: ``argument``, else ``default`` in the run's folder ``context["out"]``."""
    if argument:
        return Path(argument)
    if context.get("out") is None:
        raise SinkError(f"--sink {scheme}: needs a file ({scheme}:FILE) when the run has no --out folder")
    return Path(context["out"]) / default


def open_jsonl(argument: str, rig, context: dict) -> JsonlLog:
    """``jsonl:[FILE]`` (:mod:`depthguard.runtime.sink_specs`): default ``OUT/log.jsonl``."""
    return JsonlLog(run_file(argument, context, "log.jsonl", "jsonl"))


class CallbackSink:
    """Calls ``fn(reaction)`` for every reaction (and ``on_close()`` once, if given)."""

    def __init__(self, fn: Callable[[Reaction], None], on_close: Callable[[], None] | None = None):
        if not callable(fn):
            raise SinkError(f"CallbackSink needs a callable (got {type(fn).__name__})")
        self.fn = fn
        self.on_close = on_close

    def __call__(self, reaction: Reaction) -> None:
        self.fn(reaction)

    def close(self) -> None:
        if self.on_close is not None:
            self.on_close()
            self.on_close = None


def reaction_keys(cell: str) -> dict[str, str]:
    """The zenoh keys of ``cell``: ``reaction``, ``distances``, ``health`` -> ``depthguard/<cell>/<name>``."""
    if not isinstance(cell, str) or not _CELL.match(cell):
        raise SinkError(f"cell name {cell!r} cannot name a zenoh key: use letters, digits, '_', '-', '.'")
    return {n: f"depthguard/{cell}/{n}" for n in ("reaction", "distances", "health")}


class ZenohPublisher:
    """Publishes reactions on ``depthguard/<cell>/{reaction,distances,health}`` (UTF-8 JSON).

    ``reaction``: the whole ``to_dict()`` record; ``distances``: ``{"t", "points"}``;
    ``health``: ``{"t", "override", "reasons", "cameras", "joints_age_s"}``.
    All three go out together, at most ``rate_hz`` times per second of ``clock``
    (wall time), except that a reaction whose override or set of reason keys
    differs from the last published one is always published. ``published`` /
    ``skipped`` count reactions. The session is a loopback zenoh peer unless
    ``session`` is given (then it is not closed here).
    """

    def __init__(self, cell: str, session=None, listen: str = "tcp/127.0.0.1:0", rate_hz: float = 50.0,
                 connect: Sequence[str] = (), clock: Callable[[], float] = time.monotonic):
        if not rate_hz > 0:
            raise SinkError(f"rate_hz must be > 0 (got {rate_hz})")
        self.keys = reaction_keys(cell)
        self.period = 1.0 / float(rate_hz)
        self._clock = clock
        self._own = session is None
        if session is None:
            import zenoh

            from depthguard.transport.settings import zenoh_config
            session = zenoh.open(zenoh_config([listen], list(connect)))
        self.session = session
        self._pubs = {n: session.declare_publisher(k) for n, k in self.keys.items()}
        self._last_time = -float("inf")
        self._last_state: tuple | None = None
        self.published = 0
        self.skipped = 0

    def __call__(self, reaction: Reaction) -> None:
        if self._pubs is None:
            raise SinkError("ZenohPublisher is closed")
        now = self._clock()
        state = (float(reaction.override), frozenset(reaction.reasons))
        if state == self._last_state and now - self._last_time < self.period:
            self.skipped += 1
            return
        rec = reaction.to_dict()
        health = {k: rec[k] for k in ("t", "override", "reasons", "cameras", "joints_age_s")}
        for name, body in (("reaction", rec), ("distances", {"t": rec["t"], "points": rec["points"]}),
                           ("health", health)):
            self._pubs[name].put(json.dumps(body, allow_nan=False).encode("utf-8"))
        self._last_time, self._last_state = now, state
        self.published += 1

    def close(self) -> None:
        if self._pubs is None:
            return
        for p in self._pubs.values():
            try:
                p.undeclare()
            except Exception:  # noqa: BLE001 - closing anyway
                pass
        self._pubs = None
        if self._own:
            self.session.close()


def _name(sink) -> str:
    return getattr(sink, "name", None) or type(sink).__name__


class SinkFanout:
    """Calls every sink from one background thread fed by a bounded queue.

    ``fanout(reaction)`` never blocks: when ``maxsize`` reactions are waiting,
    the oldest is dropped and ``dropped`` counts it (the log then has a gap at
    that time; report ``dropped``). With ``block=True`` (a replay as fast as
    possible, where a complete log matters more than the caller's pace) it
    waits for room instead. A sink that raises is disabled: its message
    goes to ``errors`` (``"<sink>: <message>"``) and to the log, the other sinks
    go on. :meth:`close` delivers what is queued, then closes every sink.

    The thread wakes every ``period_s`` (default 20 ms: ten 500 Hz reactions) and delivers what
    is queued, one reaction at a time, rather than once per reaction (issue 29: a wake-up per
    control cycle took the GIL from the camera workers and the simulator 500 times a second); it
    wakes at once for a reaction whose override is lower than the one queued before it or whose
    reasons name other keys (a slowing or a stop reaches the sinks without the wait), and when
    half the queue is full.
    """

    def __init__(self, sinks: Sequence[Callable[[Reaction], None]], maxsize: int = 1024, block: bool = False,
                 period_s: float = 0.02):
        if int(maxsize) < 1:
            raise SinkError(f"maxsize must be >= 1 (got {maxsize})")
        if not period_s > 0:
            raise SinkError(f"period_s must be > 0 (got {period_s})")
        self.sinks = list(sinks)
        self.maxsize = int(maxsize)
        self.block = bool(block)          # wait for room instead of dropping (replays as fast as possible)
        self.period_s = float(period_s)
        self.dropped = 0
        self.delivered = 0
        self.wakes = 0                    # times the thread woke to deliver (issue 29)
        self.errors: list[str] = []
        self._enabled = [True] * len(self.sinks)
        self._queue: deque[Reaction] = deque()
        self._cond = threading.Condition(threading.Lock())
        self._closing = False
        self._urgent = False
        self._last: tuple = (float("inf"), ())  # the newest queued reaction's override and reason keys
        self._thread = threading.Thread(target=self._run, name="depthguard-sinks", daemon=True)
        self._thread.start()

    @property
    def disabled(self) -> list[str]:
        """Names of the sinks disabled after an exception."""
        return [_name(s) for s, on in zip(self.sinks, self._enabled) if not on]

    def __call__(self, reaction: Reaction) -> None:
        override, keys = reaction.override, tuple(reaction.reasons)
        last_override, last_keys = self._last
        self._last = (override, keys)
        with self._cond:
            if self._closing:
                raise SinkError("SinkFanout is closed")
            q = self._queue
            while self.block and len(q) >= self.maxsize and self._thread.is_alive():
                self._urgent = True
                self._cond.notify()
                self._cond.wait(0.1)
            if len(q) >= self.maxsize:
                q.popleft()
                self.dropped += 1
            q.append(reaction)
            if override < last_override or keys != last_keys or 2 * len(q) >= self.maxsize:
                self._urgent = True
                self._cond.notify()

    def _run(self) -> None:
        cond, q = self._cond, self._queue
        while True:
            with cond:
                if not (self._closing or self._urgent or 2 * len(q) >= self.maxsize):
                    cond.wait(self.period_s)
                self._urgent = False
                if self._closing and not q:
                    return                          # closing and drained
                self.wakes += 1
            while True:
                with cond:
                    if not q:
                        break
                    reaction = q.popleft()
                    if self.block:
                        cond.notify_all()           # room for a blocked producer
                for i, sink in enumerate(self.sinks):
                    if self._enabled[i]:
                        try:
                            sink(reaction)
                        except Exception as exc:  # noqa: BLE001 - a sink must never stop the others
                            self._fail(i, exc)
                self.delivered += 1

    def write_map(self, snapshot) -> None:
        """R37: hand a free-space map to every enabled sink that takes one (``write_map``: the
        ``mcap:`` and ``ros2:`` sinks), on the caller's thread (the map's, at ``free_space_hz``),
        not through the reaction queue; nothing after :meth:`close`. A sink that raises is
        disabled like for a reaction."""
        if self._closing:
            return
        for i, sink in enumerate(self.sinks):
            write = getattr(sink, "write_map", None)
            if write is not None and self._enabled[i]:
                try:
                    write(snapshot)
                except Exception as exc:  # noqa: BLE001 - a sink must never stop the map's thread
                    self._fail(i, exc, " (map)")

    def _fail(self, i: int, exc: Exception, when: str = "") -> None:
        self._enabled[i] = False
        msg = f"{_name(self.sinks[i])}: {type(exc).__name__}: {exc}"
        self.errors.append(msg)
        log(f"sink disabled{when}: {msg}")

    def close(self, timeout: float | None = 10.0) -> None:
        """Deliver what is queued (waiting at most ``timeout`` s, the rest counts as ``dropped``),
        then close every sink."""
        with self._cond:
            if self._closing:
                return
            self._closing = True
            self._cond.notify()
        self._thread.join(timeout)
        if self._thread.is_alive():                 # a slow sink: give up on the rest of the queue
            with self._cond:
                left = len(self._queue)
                self._queue.clear()
                self.dropped += left
            log(f"sinks: {left} reactions dropped, not delivered within {timeout} s at close")
            self._thread.join(timeout)
        for i, sink in enumerate(self.sinks):
            close = getattr(sink, "close", None)
            if close is not None:
                try:
                    close()
                except Exception as exc:  # noqa: BLE001 - close the others anyway
                    self._fail(i, exc, " at close")
