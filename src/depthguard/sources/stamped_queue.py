"""What a live source received and the runtime has not taken yet (R27, R29).

Live sources (``zenoh:KEY`` and ``ros2:`` joint states, ``ros2:`` frames)
receive on their transport's threads and are read by the runner in stamp
order. :class:`StampedQueue` is that hand-over, one per stream:

* a stamp not after the previous accepted one is refused (``"out_of_order"``):
  the monitor's joint history and a camera's frames move forward only (R27);
* at most ``max_pending`` items wait; one more drops the oldest (``"overflow"``):
  a runner that stalled resumes with the newest data, never with a backlog.

Thread-safe: ``offer`` from the receiving threads, ``until`` from the runner;
:meth:`StampedQueue.wait` lets a reader sleep until an item arrives (a camera unit
waiting for the joints of its frame, issue 29) instead of polling.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from typing import Any

__all__ = ["StampedQueue"]


class StampedQueue:
    """Items in strictly increasing stamp order, bounded (module docstring).

    max_pending : int >= 1, the most items waiting to be taken.
    """

    def __init__(self, max_pending: int):
        if int(max_pending) < 1:
            raise ValueError(f"max_pending must be >= 1 (got {max_pending!r})")
        self.max_pending = int(max_pending)
        self._lock = threading.Lock()
        self._arrived = threading.Condition(self._lock)
        self._items: deque[tuple[float, Any]] = deque()
        self._last = -math.inf

    def offer(self, stamp: float, item) -> str | None:
        """Queue ``item`` received with capture ``stamp`` (s). Returns ``None`` when it was
        queued, ``"overflow"`` when it was queued and the oldest waiting item dropped, and
        ``"out_of_order"`` when it was refused (``stamp`` not after the last accepted one)."""
        with self._lock:
            if not stamp > self._last:
                return "out_of_order"
            self._last = stamp
            dropped = len(self._items) >= self.max_pending
            if dropped:
                self._items.popleft()
            self._items.append((stamp, item))
            self._arrived.notify_all()
        return "overflow" if dropped else None

    def wait(self, timeout: float) -> bool:
        """Sleep until an item is waiting (True at once when one is) or ``timeout`` s have passed
        (False); takes nothing."""
        with self._arrived:
            if not self._items:
                self._arrived.wait(max(0.0, float(timeout)))
            return bool(self._items)

    def until(self, t: float) -> list:
        """The items with stamp <= ``t`` (s) not taken yet, oldest first; they are taken."""
        out = []
        with self._lock:
            while self._items and self._items[0][0] <= t:
                out.append(self._items.popleft()[1])
        return out

    def __len__(self) -> int:
        return len(self._items)
