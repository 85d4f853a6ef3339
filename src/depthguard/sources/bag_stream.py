"""One reading of a ROS 2 bag in bag order, shared by the ``bag:`` sources of a run (R31).

A bag's zstd chunks hold every topic mixed: reading them is most of the cost of a replay
(a 640x480 16UC1 image is ~600 kB to decompress). :class:`BagPass` reads the bag **once**,
in bag order (the recorder's receive order), and routes each message to the consumer that
subscribed to its connection: the frame source's images and CameraInfos, the joint
source's JointStates. Each consumer keeps its items in :class:`StampQueue` s, in stamp
(capture time) order, until they are served.

**Putting stamps in order, with bounded memory.** Messages arrive in receive order, not
in stamp order. The pass keeps ``newest``, the largest stamp accepted so far over all
streams; an item is *final* once its stamp is at or below the watermark
``newest - REORDER_WINDOW_S`` (or the bag has ended): no item read later can be served
before it. An item whose stamp is already at or below the watermark when it is read
arrived too late to be put in order: it is skipped and counted (``late``). So a source
serving the items with stamp <= t first reads the bag until the watermark reaches t, and
holds about ``REORDER_WINDOW_S`` of the bag's images, whatever the bag's length. Which
items are late depends on the bag alone (the order of its messages and their stamps),
never on how fast they are pulled: two replays serve the same items.

**Memory guard.** The items held by the consumers of one pass are counted in bytes. A
consumer that has never pulled (e.g. a frame source opened only for its checks) is
detached once its items pass :data:`IDLE_BUDGET_BYTES` (it starts a pass of its own if it
pulls later); consumers that pull and would hold more than :data:`BUFFER_BUDGET_BYTES`
(the streams' stamps are far apart: not on one clock) stop the pass with a
:class:`~depthguard.sources.bag.BagError` naming the stream that runs ahead.

Thread-safe: the real-time runner pulls frames and joint states from two threads.
"""

from __future__ import annotations

import heapq
import math
import threading
from typing import Callable

__all__ = ["REORDER_WINDOW_S", "IDLE_BUDGET_BYTES", "BUFFER_BUDGET_BYTES", "StampQueue", "BagPass"]

#: an item is final once the newest stamp read is this much later (s); a message stamped this much
#: before the newest stamp already read is too late to be put in order (skipped and counted)
REORDER_WINDOW_S = 0.5
#: bytes a consumer that has never pulled may hold before it is detached from the shared pass
IDLE_BUDGET_BYTES = 64 * 2**20
#: bytes the consumers of one pass may hold at most (the error names the stream that runs ahead)
BUFFER_BUDGET_BYTES = 1024 * 2**20


class StampQueue:
    """The items of one stream (one camera's images, the robot's joint states) not served yet.

    ``offer`` classifies an item as it is read (``None`` = accepted, else the reason it is
    skipped: ``repeated_stamp``, ``late``); ``pop_until(t)`` gives the accepted items with
    stamp <= t in stamp order (ties: arrival order). ``nbytes``: bytes held; ``accepted``:
    items accepted so far; ``reordered``: accepted items stamped before an earlier one.
    """

    def __init__(self, name: str):
        self.name = name
        self._heap: list = []
        self._recent: dict[float, None] = {}      # stamps accepted within the last two windows (repeat check)
        self._prune_at = 64
        self._arrivals = 0
        self.newest = -math.inf
        self.nbytes = 0
        self.accepted = 0
        self.reordered = 0

    def offer(self, stamp: float, item, nbytes: int, watermark: float) -> str | None:
        if stamp in self._recent:
            return "repeated_stamp"
        if stamp <= watermark:
            return "late"
        if stamp < self.newest:
            self.reordered += 1
        self.newest = max(self.newest, stamp)
        self._recent[stamp] = None
        if len(self._recent) > self._prune_at:  # forget stamps older than two windows (they would be late)
            old = watermark - REORDER_WINDOW_S
            self._recent = {s: None for s in self._recent if s > old}
            self._prune_at = max(64, 2 * len(self._recent))
        heapq.heappush(self._heap, (stamp, self._arrivals, nbytes, item))
        self._arrivals += 1
        self.nbytes += nbytes
        self.accepted += 1
        return None

    def head(self) -> float:
        """The smallest stamp held (``inf`` when empty)."""
        return self._heap[0][0] if self._heap else math.inf

    def pop_until(self, t: float) -> list[tuple[float, int, object]]:
        """``[(stamp, arrival, item)]`` with stamp <= ``t``, in order, removed from the queue."""
        out = []
        while self._heap and self._heap[0][0] <= t:
            stamp, arrival, nbytes, item = heapq.heappop(self._heap)
            self.nbytes -= nbytes
            out.append((stamp, arrival, item))
        return out

    def clear(self) -> None:
        self._heap.clear()
        self.nbytes = 0

    def __len__(self) -> int:
        return len(self._heap)


class BagPass:
    """One reading of a bag (module docstring). ``reader``: an opened ``rosbags`` reader (closed
    by the pass unless ``owns_reader`` is False); ``error``: the exception type (a ``ValueError``)
    raised for a bag that cannot be used, called with one sentence that starts with ``name``.

    Consumers call :meth:`subscribe` before the pass starts (``handler(con, raw)`` for every
    message of a connection), then :meth:`advance` with a condition; handlers call
    :meth:`offer`. ``ended``: the bag has been read to its end.
    """

    def __init__(self, reader, name: str, error: type[ValueError], owns_reader: bool = True):
        self.reader = reader
        self._owns_reader = owns_reader
        self.name = name
        self._error = error
        self._routes: dict[int, Callable] = {}
        self._consumers: list = []
        self._iter = None
        self._read = 0
        self.ended = False
        self.failure: Exception | None = None
        self.newest = -math.inf
        self.lock = threading.RLock()

    # ------------------------------------------------------------ setup
    @property
    def started(self) -> bool:
        """Reading has begun (or the pass is over): a new consumer needs a pass of its own."""
        return self._iter is not None or self.ended

    def subscribe(self, consumer, routes: dict[int, Callable]) -> None:
        """Route connections to ``consumer`` (which has ``queues()``, ``pulled`` and ``detach()``)."""
        if self.started:
            raise RuntimeError("a consumer joins a bag pass before it starts")
        self._consumers.append(consumer)
        self._routes.update(routes)

    def unsubscribe(self, consumer) -> bool:
        """Remove ``consumer``; True when no consumer is left (the caller closes the pass)."""
        with self.lock:
            if consumer in self._consumers:
                self._consumers.remove(consumer)
            return not self._consumers

    # ------------------------------------------------------------ reading
    @property
    def watermark(self) -> float:
        """Items stamped at or below this are final (``inf`` once the bag has ended)."""
        return math.inf if self.ended else self.newest - REORDER_WINDOW_S

    def offer(self, queue: StampQueue, stamp: float, item, nbytes: int) -> str | None:
        """Put an item read now into ``queue`` (``None``) or say why it is skipped."""
        reason = queue.offer(stamp, item, nbytes, self.watermark)
        if reason is None and stamp > self.newest:
            self.newest = stamp
        return reason

    def advance(self, until: Callable[[], bool]) -> None:
        """Read messages (routing each) until ``until()`` holds or the bag has ended.

        Call with :attr:`lock` held. A handler's exception (a bag that cannot be used) and a
        damaged chunk stop the pass for every consumer: each later call raises it again."""
        if self.failure is not None:
            raise self.failure
        if self._iter is None:
            conns = [c for c in self.reader.connections if c.id in self._routes]
            self._iter = iter(self.reader.messages(connections=conns)) if conns else iter(())
        routes = self._routes
        try:
            while not self.ended and not until():
                try:
                    con, _log_ns, raw = next(self._iter)
                except StopIteration:
                    self.ended = True
                    break
                routes[con.id](con, raw)
                self._read += 1
                if self._read % 8 == 0:          # the budget is checked every few messages (it sums queues)
                    self._check_budget()
        except Exception as exc:  # noqa: BLE001 - a damaged chunk, or a handler's refusal
            if not isinstance(exc, self._error):
                exc = self._error(f"{self.name} cannot be read to its end: {type(exc).__name__}: {exc} "
                                  "(truncated or damaged?)")
            self.failure = exc
            raise exc from None

    def _check_budget(self) -> None:
        held = [(sum(q.nbytes for q in c.queues()), c) for c in self._consumers]
        if sum(n for n, _c in held) <= IDLE_BUDGET_BYTES:
            return
        for n, c in held:
            if not c.pulled and n > IDLE_BUDGET_BYTES:
                c.detach()                     # opened but never read: it reads on its own if it ever pulls
        total = sum(sum(q.nbytes for q in c.queues()) for c in self._consumers)
        if total > BUFFER_BUDGET_BYTES:
            queues = [q for c in self._consumers for q in c.queues() if len(q)]
            ahead = max(queues, key=lambda q: q.newest)
            behind = min(queues, key=lambda q: q.head())
            raise self._error(
                f"{self.name}: putting the stamps in order would hold more than {BUFFER_BUDGET_BYTES // 2**20} MB: "
                f"{ahead.name} is stamped up to {ahead.newest:.3f} s while {behind.name} still waits at "
                f"{behind.head():.3f} s (are the bag's stamps on one clock?)")

    def close(self) -> None:
        with self.lock:
            self._iter = None
            self.ended = True
            if self.reader is not None and self._owns_reader:
                try:
                    self.reader.close()
                except Exception:  # noqa: BLE001 - closing twice or after a failure
                    pass
                self.reader = None
