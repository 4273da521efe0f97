"""What ingesting one raw file gives: a ``runs`` row, or the one-line reason it is quarantined.

:class:`IngestResult` is what :func:`pipeline.ingest.file.ingest_file` returns and the rebuild
stores; :class:`IngestError` is a file the ingest cannot use; :func:`read_run_record` reads the
runs row back from a samples file's footer.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from pipeline.raw.problems import ConfigError
from pipeline.raw.metadata import MetadataError
from pipeline.readers import ReaderError


class IngestError(Exception):
    """A raw file that cannot be used; the message is the quarantine's one line."""


#: Errors whose message is the quarantine reason as it stands (any other exception is a reader or
#: library tripping over malformed input: ``cannot read file: <type>: <message>``).
QUARANTINE_ERRORS = (IngestError, MetadataError, ReaderError, ConfigError)


@dataclass
class IngestResult:
    """What ingesting one file produced: a runs row, or an error."""

    source_path: str
    campaign: str | None = None
    run: dict | None = None
    channels: list[dict] = field(default_factory=list)
    error: str | None = None
    #: the error may pass (the file could not be opened or read): look at the file again next time
    transient: bool = False
    #: how many bytes ``source_sha256`` was computed over when ingest hashed the file itself [B]
    bytes_hashed: int | None = None
    #: a file of several runs (``sheets = "all"``, ``groups = "all"``): one result per run, each
    #: with ``run`` or ``error`` (then ``run`` and ``error`` of the file's own result are None)
    parts: list["IngestResult"] | None = None
    #: SHA-256 of a file of several runs (the single-run result has it in ``run``) [hex]
    sha256: str | None = None

    def fail(self, exc: Exception, prefix: str = "", unexpected: str = "cannot read file") -> None:
        """Record ``exc`` as the one-line error (``prefix`` before it).

        A :data:`QUARANTINE_ERRORS` error is its message; any other is ``<unexpected>:
        <type>: <message>`` and is transient when it is an OS error (not pyarrow's).
        """
        if isinstance(exc, QUARANTINE_ERRORS):
            self.error = one_line(f"{prefix}{exc}")
            return
        self.error = one_line(f"{prefix}{unexpected}: {type(exc).__name__}: {exc}")
        self.transient = isinstance(exc, OSError) and not isinstance(exc, pa.ArrowException)


def one_line(text: str) -> str:
    """``text`` on one line (runs of white space as one space), at most 500 characters."""
    return " ".join(str(text).split())[:500]


def read_run_record(path: Path) -> dict | None:
    """The runs row and channel list stored in a samples file's footer, or None."""
    try:
        meta = pq.read_metadata(path).metadata or {}
    except (OSError, pa.ArrowException):
        return None
    blob = meta.get(b"pneubench")
    return json.loads(blob) if blob else None
