"""prefetch: batches made in a background thread, in order, errors and early exits handed back."""
import threading
import time

import pytest

from pipeline.ingest.prefetch import prefetch


def test_batches_come_in_order_and_ahead_of_the_consumer():
    made = []

    def batches():
        for i in range(20):
            made.append(i)
            yield i

    it = prefetch(batches(), depth=2)
    assert next(it) == 0
    deadline = time.monotonic() + 5
    while len(made) < 3 and time.monotonic() < deadline:  # made while the consumer holds batch 0
        time.sleep(0.005)
    assert len(made) >= 3 and len(made) <= 4  # at most ``depth`` ahead (plus the one being put)
    assert [0, *it] == list(range(20))


def test_an_error_of_the_producer_reaches_the_consumer_after_the_batches_before_it():
    def batches():
        yield 1
        yield 2
        raise ValueError("corrupt row group 3")

    got = []
    with pytest.raises(ValueError, match="corrupt row group 3"):
        for b in prefetch(batches()):
            got.append(b)
    assert got == [1, 2]


def test_leaving_early_stops_the_thread_and_closes_the_source():
    closed = threading.Event()

    def batches():
        try:
            for i in range(10_000):
                yield i
        finally:
            closed.set()

    before = threading.active_count()
    for b in prefetch(batches()):
        if b == 3:
            break
    assert closed.wait(5)
    assert threading.active_count() == before  # the thread is joined, not left running
