"""SHA-256 of a raw file: the ``source_sha256`` of its runs and part of its samples file's key.

A new file is hashed in a thread while it is parsed (:class:`BackgroundHash`: hashlib releases
the GIL), so its bytes are read for the hash and for the data at the same time.
"""
from __future__ import annotations

import hashlib
import threading
from pathlib import Path


def sha256_file(path: Path, chunk: int = 1 << 22, stop=None, counted: list | None = None) -> str | None:
    """SHA-256 of a file, read in chunks. [hex] (None when the ``stop`` event was set.)
    ``counted``: a list the number of bytes hashed is appended to [B]."""
    h = hashlib.sha256()
    n = 0
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            if stop is not None and stop.is_set():
                return None
            h.update(block)
            n += len(block)
    if counted is not None:
        counted.append(n)
    return h.hexdigest()


def hash_whole(path: Path) -> tuple[str, int | None]:
    """SHA-256 of a file [hex] and how many bytes it was computed over [B]."""
    counted: list[int] = []
    sha = sha256_file(path, counted=counted)
    return sha, counted[0] if counted else None


class BackgroundHash:
    """SHA-256 of a file computed in a thread while the file is parsed (hashlib releases the
    GIL): a new file is read for its hash and for its data at the same time."""

    def __init__(self, path: Path):
        self._stop = threading.Event()
        self._out: dict = {}
        self.n_bytes: int | None = None  # bytes hashed, once done
        self._thread = threading.Thread(target=self._run, args=(path,), name="ingest-sha256", daemon=True)
        self._thread.start()

    def _run(self, path):
        """The thread: hash ``path``, keep the hash (or the error) and the bytes hashed."""
        counted: list[int] = []
        try:
            self._out["sha"] = sha256_file(path, stop=self._stop, counted=counted)
            self.n_bytes = counted[0] if counted else None
        except BaseException as exc:  # noqa: BLE001 - re-raised by result()
            self._out["error"] = exc

    def result(self) -> str:
        """The file's SHA-256 [hex], once the thread is done; its error re-raised."""
        self._thread.join()
        if "error" in self._out:
            raise self._out["error"]
        return self._out["sha"]

    def cancel(self) -> None:
        """Stop hashing (the file's data failed, or it is written)."""
        self._stop.set()
