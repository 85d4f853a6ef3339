"""The live sources' hand-over queue (depthguard.sources.stamped_queue): order, bound, take."""

import threading
import time

import pytest

from depthguard.sources.stamped_queue import StampedQueue


def test_refuses_what_is_not_newer_and_hands_over_in_stamp_order():
    q = StampedQueue(10)
    assert q.offer(1.0, "a") is None
    assert q.offer(1.0, "again") == "out_of_order"          # equal stamp: not after the last
    assert q.offer(0.5, "older") == "out_of_order"
    assert q.offer(2.0, "b") is None
    assert q.offer(3.0, "c") is None
    assert q.until(0.9) == []
    assert q.until(2.0) == ["a", "b"]                      # taken: not given again
    assert q.until(2.0) == []
    assert q.offer(2.5, "late") == "out_of_order"          # older than the last accepted, though untaken
    assert q.until(10.0) == ["c"]


def test_a_full_queue_drops_the_oldest_and_says_so():
    q = StampedQueue(3)
    assert [q.offer(float(i), i) for i in range(3)] == [None, None, None]
    assert q.offer(3.0, 3) == "overflow"
    assert q.offer(4.0, 4) == "overflow"
    assert len(q) == 3
    assert q.until(100.0) == [2, 3, 4]                     # the newest kept, in order


def test_bad_bound_is_refused():
    with pytest.raises(ValueError, match="max_pending"):
        StampedQueue(0)


def test_concurrent_offers_keep_the_order_and_lose_nothing_within_the_bound():
    q = StampedQueue(100000)
    lock = threading.Lock()
    counter = iter(range(1, 20001))
    taken, refused = [], []

    def producer():
        while True:
            with lock:                                     # stamps drawn in order, offered racing
                try:
                    s = next(counter)
                except StopIteration:
                    return
            if q.offer(float(s), s) is not None:
                refused.append(s)

    threads = [threading.Thread(target=producer) for _ in range(4)]
    for th in threads:
        th.start()
    while any(th.is_alive() for th in threads):
        taken += q.until(1e9)
    for th in threads:
        th.join()
    taken += q.until(1e9)
    assert taken == sorted(taken)                          # never out of order
    assert len(taken) + len(refused) == 20000              # each accepted or refused, none lost


def test_stamped_queue_wait_wakes_on_an_offer_and_takes_nothing():
    sq = StampedQueue(4)
    t0 = time.perf_counter()
    assert sq.wait(0.05) is False and time.perf_counter() - t0 >= 0.04     # nothing came: the timeout
    th = threading.Timer(0.1, lambda: sq.offer(1.0, "a"))
    th.start()
    assert sq.wait(30.0) is True                                           # woken by the offer
    th.join()
    assert sq.wait(30.0) is True and len(sq) == 1                           # waiting already: at once
    assert sq.until(2.0) == ["a"]
