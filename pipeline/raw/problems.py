"""How raw/ says that something cannot be used: the :class:`Problem` row (a future quarantine
line), the :class:`ConfigError` of a rig.toml or manifest, and names made valid one-line UTF-8
(:func:`display_name`) wherever they are shown or stored."""
from __future__ import annotations

import re
from dataclasses import dataclass

_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def display_name(text) -> str:
    """A file name or path as valid UTF-8 text on one line: bytes that are not UTF-8 (carried
    by Python as lone surrogates, PEP 383) become ``\\xNN`` (``b"m\\xe9sure"`` ->
    ``"m\\xe9sure"``), and so do control characters (a newline in a name: ``\\x0a``)."""
    text = str(text)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        try:
            text = text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
        except UnicodeEncodeError:  # a surrogate that is not an escaped byte
            text = text.encode("utf-8", "backslashreplace").decode("utf-8")
    if _CONTROL.search(text):
        text = _CONTROL.sub(lambda m: f"\\x{ord(m.group()):02x}", text)
    return text


@dataclass
class Problem:
    """An input (or a line of one) that cannot be used: a future quarantine row.

    ``source_path`` and ``error`` are made valid UTF-8 (:func:`display_name`): they land in
    DuckDB, Parquet, JSON and the report.
    """

    source_path: str
    error: str
    line: int | None = None
    stage: str = "ingest"

    def __post_init__(self):
        self.source_path = display_name(self.source_path)
        self.error = display_name(self.error)


class ConfigError(Exception):
    """A rig.toml or manifest that applies to a run cannot be used."""


def os_reason(exc: OSError) -> str:
    """Why an OS call failed, as shown in a quarantine line (``Permission denied``)."""
    return exc.strerror or type(exc).__name__
