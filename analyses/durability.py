"""Durability runs: distance travelled, strokes and per-stroke summaries, streamed over chunks.

A durability run is hours of back-and-forth strokes of the PLPA carriage logged at up to 5 kHz
(tens of millions of samples). The carriage position ``x`` [m] comes from an encoder (5 um
counts) plus noise; summing ``|dx|`` sample by sample counts every noise wiggle and every
count the encoder dithers over while the carriage rests, so it overestimates the distance.

Method: reversal detection with a deadband (a zig-zag / turning-point filter)
-------------------------------------------------------------------------------
The motion is split into *strokes*: one-way travels between turning points. While the carriage
moves toward +x we track the running maximum of ``x``; a reversal is confirmed at the first
sample that lies more than ``deadband_m`` below that maximum, and the maximum (its first sample)
becomes the turning point; symmetrically toward -x. Until the first confirmed move (``max - min``
over ``deadband_m``) the direction is unknown and nothing is counted.

* Noise whose peak-to-peak stays under ``deadband_m`` never creates a reversal, however many
  samples it spans (rest at an end stop, encoder dither).
* Real motion is not shrunk: stroke lengths are measured between the *measured extremes*, not
  between filtered positions, so there is no ``2 * deadband`` loss per stroke (as with a
  backlash/play filter). The only bias is the noise excursion at each turning point (a few
  encoder counts), and only reversals smaller than ``deadband_m`` are lost.
* distance = sum of stroke lengths; strokes = number of one-way travels (a back-and-forth
  cycle is two strokes); the last stroke ends at the last extreme reached.

Per stroke: start/end time (turning point samples), length, mean speed (length / duration,
including any dwell at the end it starts from), and the mean pressure difference
``p_a - p_b`` over the stroke [Pa]. Signed by the direction of travel it is a friction
indicator: over a stroke that starts and ends at rest the inertial term ``m * a`` averages to
zero, so ``direction * mean(p_a - p_b) * A`` is the mean force the carriage had to overcome.

The deadband comes from the position sensor
-------------------------------------------
``deadband_m = DEADBAND_N_FLOOR * floor`` (:func:`stroke_deadband`), the floor being the larger
of the encoder's resolution and its noise (stated in run metadata or estimated from the record,
:mod:`analyses.quality`): 20 floors is 20 counts of a quantised encoder (0.1 mm for the bench's
5 um encoder) and about ten times the peak-to-peak of Gaussian noise at rest. Strokes are
detectable only when they are well above it: when the median stroke is shorter than
``1 / DEADBAND_MAX_FRACTION`` deadbands, reversals near the deadband are lost or invented and
:func:`strokes_note` says so (the run's distance and strokes are then not reported).

Streaming
---------
:class:`StrokeCounter` takes the run chunk by chunk (``update``) and carries its state (phase,
running extreme, turning point, cumulative pressure sum, time) across chunks, so the result
does not depend on how the run is chunked. Inside a chunk the work is vectorised: each stroke
costs a few ``numpy`` passes (``maximum.accumulate``, a comparison, ``argmax``) over a window
about the size of the previous stroke, so the cost is O(samples) plus a small constant per
stroke.
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

#: Default reversal deadband [m] of :class:`StrokeCounter`: ``DEADBAND_N_FLOOR`` counts of the
#: bench's 5 um encoder. Analyses use :func:`stroke_deadband` of the run's own sensor.
DEADBAND_M = 1e-4
#: Reversal deadband in position sensor floors. [-]
DEADBAND_N_FLOOR = 20.0
#: Strokes are detectable when the deadband is at most this fraction of the median stroke. [-]
DEADBAND_MAX_FRACTION = 0.25


def stroke_deadband(sensor, x_scale_m: float = 1.0) -> float:
    """Reversal deadband for a position sensor: ``DEADBAND_N_FLOOR`` times its floor.

    Parameters
    ----------
    sensor : analyses.quality.Sensor
        Resolution and noise of ``x``. [m]
    x_scale_m : float
        Magnitude of the positions; an ideal sensor (floor 0) gets 1e-9 of it (float
        round-off is not a reversal). [m]

    Returns
    -------
    float
        Deadband. [m]
    """
    return float(max(DEADBAND_N_FLOOR * sensor.floor(), 1e-9 * abs(x_scale_m), 1e-12))


def strokes_note(summary: "DurabilitySummary", deadband_m: float) -> str | None:
    """Why a run's strokes cannot be told from the position sensor, or None when they can.

    Strokes are detectable when the median stroke is at least ``1 / DEADBAND_MAX_FRACTION``
    deadbands long; a run without strokes has nothing to tell apart (distance 0).
    """
    if summary.strokes == 0 or summary.stroke_table.empty:
        return None
    median = float(np.median(summary.stroke_table["length_m"]))
    if deadband_m > DEADBAND_MAX_FRACTION * median:
        return (f"strokes not detectable: the deadband {deadband_m * 1e3:.3g} mm ({DEADBAND_N_FLOOR:g} x the "
                f"position sensor floor) is over {DEADBAND_MAX_FRACTION:g} of the median stroke "
                f"{median * 1e3:.3g} mm")
    return None

STROKE_COLUMNS = ["stroke", "direction", "t_start_s", "t_end_s", "x_start_m", "x_end_m", "length_m",
                  "mean_speed_m_s", "dp_mean_pa", "dp_friction_pa", "n_samples"]


@dataclass
class DurabilitySummary:
    """What :class:`StrokeCounter` measured on a run.

    Attributes
    ----------
    distance_m : float
        Distance travelled (sum of stroke lengths) [m].
    strokes : int
        Number of one-way strokes (a back-and-forth cycle is two).
    duration_s : float
        Last minus first sample time [s]; NaN without samples.
    n_samples : int
        Samples used (finite ``t`` and ``x``).
    stroke_table : DataFrame
        One row per stroke, columns :data:`STROKE_COLUMNS` (times [s], positions/lengths [m],
        speed [m/s], pressure differences [Pa]).
    """

    distance_m: float
    strokes: int
    duration_s: float
    n_samples: int
    stroke_table: pd.DataFrame = field(repr=False)

    @property
    def distance_km(self) -> float:
        return self.distance_m / 1000.0

    @property
    def duration_h(self) -> float:
        return self.duration_s / 3600.0


class StrokeCounter:
    """Streaming stroke and distance counter with a reversal deadband.

    Parameters
    ----------
    deadband_m : float
        A reversal is confirmed when the position comes back by more than this from the running
        extreme [m]. Must exceed the peak-to-peak noise of ``x`` at rest.

    Examples
    --------
    >>> sc = StrokeCounter(deadband_m=1e-4)
    >>> for t, x, dp in chunks:          # doctest: +SKIP
    ...     sc.update(t, x, dp)
    >>> sc.finish().distance_m           # doctest: +SKIP
    """

    _MIN_WINDOW = 1024
    _MAX_WINDOW = 1 << 22

    def __init__(self, deadband_m: float = DEADBAND_M):
        if not deadband_m > 0:
            raise ValueError("deadband_m must be positive")
        self.db = float(deadband_m)
        self._phase = 0          # 0 unknown, +1 toward +x, -1 toward -x
        self._n = 0              # global samples seen
        self._cdp = 0.0          # sum of finite dp over every sample seen
        self._cnt = 0            # finite dp samples seen
        self._t0 = np.nan
        self._t_last = np.nan
        # records: [value [m], time [s], global index, cumulative dp before the sample,
        # cumulative finite-dp count before the sample]; the last two are filled at the end of
        # the chunk the sample belongs to (one ``reduceat`` pass over the chunk, no cumsum)
        self._lo = self._hi = None      # unknown phase: running min / max
        self._ext = None                # running extreme of the current phase
        self._start = None              # turning point the current stroke started from
        self._strokes: list[tuple] = []  # (start record, end record)
        self._window = 4 * self._MIN_WINDOW

    # -- internals ------------------------------------------------------------------------------
    def _emit(self, end: list) -> None:
        self._strokes.append((self._start, end))
        n = end[2] - self._start[2]
        if n > 0:
            self._window = int(min(self._MAX_WINDOW, max(self._MIN_WINDOW, 1.5 * n)))

    def _resolve(self, pending: list, dp) -> None:
        """Fill the cumulative dp sums / counts of this chunk's records; advance the totals."""
        if dp is None:
            for r in pending:
                r[3], r[4] = np.nan, 0
            return
        n = len(dp)
        idx = np.fromiter((r[2] for r in pending), dtype=np.intp, count=len(pending)) - self._n
        starts = np.unique(np.append(idx, 0))
        part = np.add.reduceat(dp, starts)
        if np.isnan(part).any():  # missing pressure samples: sum the finite ones, count them
            ok = np.isfinite(dp)
            part = np.add.reduceat(np.where(ok, dp, 0.0), starts)
            cnt = np.add.reduceat(ok.astype(np.int64), starts)
        else:
            cnt = np.diff(np.append(starts, n))
        csum = self._cdp + np.concatenate(([0.0], np.cumsum(part)))
        ccnt = self._cnt + np.concatenate(([0], np.cumsum(cnt)))
        k = np.searchsorted(starts, idx)
        for r, c, m in zip(pending, csum[k].tolist(), ccnt[k].tolist()):
            r[3], r[4] = c, m
        self._cdp, self._cnt = float(csum[-1]), int(ccnt[-1])

    def update(self, t, x, dp=None) -> None:
        """Feed the next chunk of the run.

        Parameters
        ----------
        t : array_like
            Sample times [s], increasing.
        x : array_like
            Carriage position [m].
        dp : array_like, optional
            Pressure difference ``p_a - p_b`` [Pa]; NaN per-stroke means without it.
        """
        t = np.asarray(t, dtype=np.float64)
        x = np.asarray(x, dtype=np.float64)
        dp = None if dp is None else np.asarray(dp, dtype=np.float64)
        ok = np.isfinite(t) & np.isfinite(x)
        if not ok.all():
            t, x = t[ok], x[ok]
            dp = None if dp is None else dp[ok]
        n = len(x)
        if n == 0:
            return
        if np.isnan(self._t0):
            self._t0 = float(t[0])
        self._t_last = float(t[-1])
        g0 = self._n
        db = self.db
        pending: list = []

        def rec(i):
            r = [float(x[i]), float(t[i]), g0 + i, None, None]
            pending.append(r)
            return r

        i = 0
        if self._phase == 0:
            if self._lo is None:
                self._lo = self._hi = rec(0)
            while i < n and self._phase == 0:
                j = min(n, i + self._window)
                seg = x[i:j]
                cmax = np.maximum.accumulate(seg)
                np.maximum(cmax, self._hi[0], out=cmax)
                cmin = np.minimum.accumulate(seg)
                np.minimum(cmin, self._lo[0], out=cmin)
                cmax -= cmin
                k = int((cmax > db).argmax())
                if cmax[k] > db:
                    head = seg[:k + 1]
                    if seg[k] > self._hi[0]:           # moved up: starts from the minimum
                        p = int(head.argmin())
                        if seg[p] < self._lo[0]:
                            self._lo = rec(i + p)
                        self._start, self._phase = self._lo, 1
                    else:
                        p = int(head.argmax())
                        if seg[p] > self._hi[0]:
                            self._hi = rec(i + p)
                        self._start, self._phase = self._hi, -1
                    self._ext = rec(i + k)
                    i += k + 1
                else:
                    p, q = int(seg.argmin()), int(seg.argmax())
                    if seg[p] < self._lo[0]:
                        self._lo = rec(i + p)
                    if seg[q] > self._hi[0]:
                        self._hi = rec(i + q)
                    i = j
                    self._window = min(self._MAX_WINDOW, 2 * self._window)
        while i < n:
            j = min(n, i + self._window)
            seg = x[i:j]
            ext = self._ext[0]
            if self._phase > 0:
                m = np.maximum.accumulate(seg)
                np.maximum(m, ext, out=m)
                m -= db
                cond = seg < m
            else:
                m = np.minimum.accumulate(seg)
                np.minimum(m, ext, out=m)
                m += db
                cond = seg > m
            k = int(cond.argmax())
            found = bool(cond[k])
            head = seg[:k + 1] if found else seg
            p = int(head.argmax()) if self._phase > 0 else int(head.argmin())
            if (seg[p] > ext) if self._phase > 0 else (seg[p] < ext):
                self._ext = rec(i + p)
            if found:
                self._emit(self._ext)
                self._start = self._ext
                self._phase = -self._phase
                self._ext = rec(i + k)
                i += k + 1
            else:
                i = j
                self._window = min(self._MAX_WINDOW, 2 * self._window)
        self._resolve(pending, dp)
        self._n += n

    def finish(self) -> DurabilitySummary:
        """Close the last stroke (at the last extreme reached) and summarise the run."""
        if self._phase != 0 and self._ext is not None and self._ext[2] > self._start[2]:
            self._emit(self._ext)
            self._phase = 0
            self._ext = None
        rows = []
        for s, e in self._strokes:
            n, dt = e[2] - s[2], e[1] - s[1]
            length = abs(e[0] - s[0])
            direction = 1 if e[0] > s[0] else -1
            k = e[4] - s[4]
            dp_mean = (e[3] - s[3]) / k if k > 0 else np.nan
            rows.append((direction, s[1], e[1], s[0], e[0], length, length / dt if dt > 0 else np.nan,
                         dp_mean, direction * dp_mean, n))
        table = pd.DataFrame(rows, columns=STROKE_COLUMNS[1:])
        table.insert(0, "stroke", np.arange(len(table), dtype=np.int64))
        table["direction"] = table["direction"].astype(np.int64)
        table["n_samples"] = table["n_samples"].astype(np.int64)
        distance = float(table["length_m"].sum()) if len(table) else 0.0
        duration = self._t_last - self._t0 if self._n else np.nan
        return DurabilitySummary(distance_m=distance, strokes=len(table), duration_s=float(duration),
                                 n_samples=self._n, stroke_table=table)


def durability_summary(t, x, p_a=None, p_b=None, deadband_m: float = DEADBAND_M,
                       chunk: int | None = None) -> DurabilitySummary:
    """Distance, strokes, duration and per-stroke summary of a whole run in memory.

    Parameters
    ----------
    t : array_like
        Time [s].
    x : array_like
        Carriage position [m].
    p_a, p_b : array_like, optional
        Chamber pressures [Pa] (gauge or absolute, only the difference is used).
    deadband_m : float
        Reversal deadband [m], see :class:`StrokeCounter`.
    chunk : int, optional
        Feed the counter this many samples at a time (the result is the same).

    Returns
    -------
    DurabilitySummary
    """
    t = np.asarray(t, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    dp = None if p_a is None or p_b is None else np.asarray(p_a, float) - np.asarray(p_b, float)
    sc = StrokeCounter(deadband_m)
    step = chunk or max(len(x), 1)
    for a in range(0, len(x), step):
        sc.update(t[a:a + step], x[a:a + step], None if dp is None else dp[a:a + step])
    return sc.finish()


def durability_from_chunks(chunks: Iterable[tuple], deadband_m: float = DEADBAND_M) -> DurabilitySummary:
    """:func:`durability_summary` over an iterable of ``(t, x, dp)`` chunks (bounded memory).

    Parameters
    ----------
    chunks : iterable of (array, array, array or None)
        Time [s], position [m], pressure difference ``p_a - p_b`` [Pa].
    deadband_m : float
        Reversal deadband [m].
    """
    sc = StrokeCounter(deadband_m)
    for t, x, dp in chunks:
        sc.update(t, x, dp)
    return sc.finish()


def naive_distance(x) -> float:
    """Sum of ``|dx|`` over every sample [m]: counts noise; a reference, not an estimator."""
    x = np.asarray(x, dtype=np.float64)
    return float(np.abs(np.diff(x)).sum()) if len(x) > 1 else 0.0


__all__ = ["StrokeCounter", "DurabilitySummary", "durability_summary", "durability_from_chunks",
           "naive_distance", "DEADBAND_M", "STROKE_COLUMNS", "DEADBAND_N_FLOOR", "DEADBAND_MAX_FRACTION",
           "stroke_deadband", "strokes_note"]
