"""The time base of a run: its ``t`` column checked as it streams, or ``t`` from a stated rate.

An export without a time column gets ``t = t0_s + i / sample_rate_hz`` (or ``+ i * dt_s``) from
the run's metadata or a MAT scalar (:func:`resolve_time_base`); a time column is checked batch by
batch (:class:`TimeCheck`: finite, never backwards) and gives the run's rate and span.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.ingest.result import IngestError

#: MAT scalars that state the sample rate [Hz] or interval [s] of a MAT export.
MAT_RATE_KEYS = ("Fs", "fs", "sample_rate_hz")
MAT_DT_KEYS = ("dt",)
#: Relative disagreement between a ``t`` column's rate and a stated rate that is warned about.
RATE_TOLERANCE = 0.01


@dataclass(frozen=True)
class TimeBase:
    """Time of an export without a time column: ``t = t0_s + i / rate_hz`` (or ``+ i * dt_s``)."""

    rate_hz: float | None
    dt_s: float | None
    t0_s: float
    source: str

    @property
    def stated_rate_hz(self) -> float:
        """The stated rate, or ``1 / dt_s``. [Hz]"""
        return self.rate_hz if self.rate_hz is not None else 1.0 / self.dt_s

    def times(self, row0: int, n: int) -> np.ndarray:
        """Times of rows ``row0 .. row0 + n - 1``. [s]"""
        i = np.arange(row0, row0 + n, dtype=np.float64)
        t = i / self.rate_hz if self.rate_hz is not None else i * self.dt_s
        return t + self.t0_s if self.t0_s else t


def _positive(value, what: str) -> float:
    """``value`` as a positive finite float; an IngestError naming ``what`` otherwise."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise IngestError(f"{what} must be a number, got {value!r}") from None
    if isinstance(value, bool) or not math.isfinite(v) or v <= 0:
        raise IngestError(f"{what} must be a positive finite number, got {value!r}")
    return v


def resolve_time_base(meta: dict, export) -> TimeBase | None:
    """The stated time base of a run: metadata ``sample_rate_hz`` or ``dt_s`` (and ``t0_s``),
    else a MAT scalar ``Fs`` / ``fs`` / ``sample_rate_hz`` / ``dt``; None when none is stated."""
    t0 = float(meta.get("t0_s") or 0.0)
    if meta.get("sample_rate_hz") is not None:
        return TimeBase(_positive(meta["sample_rate_hz"], "metadata `sample_rate_hz`"), None, t0, "sample_rate_hz")
    if meta.get("dt_s") is not None:
        return TimeBase(None, _positive(meta["dt_s"], "metadata `dt_s`"), t0, "dt_s")
    if export.format == "mat":
        for k in MAT_RATE_KEYS:
            if k in export.metadata:
                return TimeBase(_positive(export.metadata[k], f"MAT scalar `{k}`"), None, t0, k)
        for k in MAT_DT_KEYS:
            if k in export.metadata:
                return TimeBase(None, _positive(export.metadata[k], f"MAT scalar `{k}`"), t0, k)
    return None


class TimeCheck:
    """Streaming checks of the time channel: present, finite, never backwards; rate and span."""

    def __init__(self):
        self.last = None
        self.first = None
        self.n = 0
        self.repeats = 0
        self.dt_sample: np.ndarray | None = None

    def update(self, t: np.ndarray) -> None:
        """Check the next batch's times [s] (rows numbered from the file's first data row)."""
        if t.size == 0:
            return
        bad = np.flatnonzero(~np.isfinite(t))
        if bad.size:
            raise IngestError(f"time is missing at row {self.n + bad[0] + 1}")
        if self.first is None:
            self.first = float(t[0])
        prev = np.concatenate(([self.last], t)) if self.last is not None else t
        dt = np.diff(prev)
        back = np.flatnonzero(dt < 0)
        if back.size:
            row = self.n + back[0] + (1 if self.last is not None else 2)
            raise IngestError(f"time goes backwards at row {row} ({prev[back[0]]:.6g} s -> {prev[back[0] + 1]:.6g} s)")
        self.repeats += int(np.count_nonzero(dt == 0))
        if self.dt_sample is None and dt.size >= 1:
            self.dt_sample = dt[: 100_000]
        self.last = float(t[-1])
        self.n += t.size

    @property
    def sample_rate_hz(self) -> float | None:
        """1 / the median positive time step of the first 100,000 steps [Hz]; None without one."""
        if self.dt_sample is None:
            return None
        pos = self.dt_sample[self.dt_sample > 0]
        if pos.size == 0:
            return None
        return float(1.0 / np.median(pos))
