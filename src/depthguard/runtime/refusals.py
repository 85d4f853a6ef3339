"""Why a camera is stale: its refused frames, in the stop reason (R27, R28).

A camera whose frames are all refused (depth in the wrong units, a bad image,
stamps outside the joint history) looks to the supervisor like a camera that
sends nothing: ``stale:<camera>`` stops the robot. :func:`explain_stale` adds
to that reason the newest refusal when it came after the frame in use (or
when no frame was ever accepted), so that the user reads the cause on the
status line and in the reaction's ``reasons`` while it happens, not only in
the summary's counters afterwards.
"""

from __future__ import annotations

__all__ = ["explain_stale"]


def explain_stale(reasons: dict[str, str], workers: dict, marks: dict[str, tuple[int, int]]) -> None:
    """Append ``"; its frames are refused: <why>"`` to each ``stale:<camera>`` reason in ``reasons``
    whose camera refused a frame after the one in use.

    workers : camera id -> its worker (``lock``, ``product``, ``refused``, ``last_refusal``).
    marks : camera id -> (version of the frame in use, refusals counted when the monitor first
        saw it); kept by the caller between cycles, updated here.
    """
    for cid, worker in list(workers.items()):
        key = "stale:" + cid
        stale = key in reasons
        # no lock while the frame in use is marked and, when stale, nothing was refused since the mark
        # (attribute reads; a new frame or refusal is read under the lock, at the latest the next cycle):
        # the usual cycle, and every cycle of a camera that is stale for lack of frames (issue 29)
        product = worker.product
        mark = marks.get(cid)
        if mark is not None and mark[0] == (0 if product is None else product.version) and \
                (not stale or worker.refused <= mark[1]):
            continue
        with worker.lock:                    # the counters read once per new frame in use, or when stale
            product = worker.product
            version = 0 if product is None else product.version
            mark = marks.get(cid)
            if mark is None or mark[0] != version:
                mark = marks[cid] = (version, worker.refused if product is not None else 0)
            if not stale:
                continue
            refused, last = worker.refused, worker.last_refusal
        if last and refused > mark[1]:
            why = last.removeprefix(f"camera {cid}: ")
            reasons[key] += f"; its frames are refused ({refused - mark[1]}): {why}"
