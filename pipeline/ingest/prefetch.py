"""Batches produced in a background thread while the caller works on the previous one."""
from __future__ import annotations

import queue
import threading


def prefetch(batches, depth: int = 2):
    """Iterate ``batches`` in a background thread, ``depth`` batches ahead (bounded memory).

    Producing the next batch (pyarrow's CSV reader, npTDMS reads, Parquet decoding: all release
    the GIL) overlaps with the caller's work on the current one: converting and writing it in the
    ingest, counting strokes in the durability stage. Exceptions reach the caller unchanged;
    closing the generator early stops the thread (and closes ``batches``).

    Parameters
    ----------
    batches : iterable
        Record batches (or anything) produced by a generator or reader.
    depth : int
        How many items are made ahead of the caller.

    Yields
    ------
    object
        The items of ``batches``, in order.
    """
    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    done = object()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def work():
        try:
            for batch in batches:
                if not put(batch):
                    return
            put(done)
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer
            put(exc)
        finally:
            close = getattr(batches, "close", None)
            if close is not None and stop.is_set():
                close()

    thread = threading.Thread(target=work, name="prefetch", daemon=True)
    thread.start()
    try:
        while True:
            item = q.get()
            if item is done:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        thread.join()
