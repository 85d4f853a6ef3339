"""Progress for long work: a rich bar on a terminal, plain log lines otherwise."""

from __future__ import annotations

import sys
import time
from contextlib import contextmanager
from typing import Iterable, Iterator, TypeVar

T = TypeVar("T")

__all__ = ["track", "log", "is_terminal"]


def is_terminal() -> bool:
    return sys.stderr.isatty()


def log(msg: str) -> None:
    """One plain line on stderr, with a time stamp."""
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def track(items: Iterable[T], description: str, total: int | None = None,
          quiet: bool = False) -> Iterator[T]:
    """Iterate ``items`` showing progress: a rich bar on a terminal, else a log line per 10 %."""
    if total is None:
        try:
            total = len(items)  # type: ignore[arg-type]
        except TypeError:
            total = None
    if quiet:
        yield from items
        return
    if is_terminal():
        from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                                   TimeElapsedColumn, TimeRemainingColumn)

        cols = [TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                TimeElapsedColumn(), TimeRemainingColumn()]
        with Progress(*cols, transient=False) as prog:
            task = prog.add_task(description, total=total)
            for it in items:
                yield it
                prog.advance(task)
        return
    t0 = time.perf_counter()
    step = max(1, (total or 10) // 10)
    log(f"{description}: start" + (f" ({total} steps)" if total else ""))
    n = 0
    for it in items:
        yield it
        n += 1
        if n % step == 0 and (total is None or n < total):
            log(f"{description}: {n}/{total if total else '?'} ({time.perf_counter() - t0:.1f} s)")
    log(f"{description}: done, {n} steps in {time.perf_counter() - t0:.1f} s")


@contextmanager
def stage(description: str, quiet: bool = False):
    """Log the start and the duration of one piece of work."""
    t0 = time.perf_counter()
    if not quiet:
        log(f"{description} ...")
    yield
    if not quiet:
        log(f"{description}: {time.perf_counter() - t0:.1f} s")
