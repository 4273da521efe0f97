"""The channels of one run as a static SVG plot, for the report's per-run pages.

Long runs (an 8 h durability run holds ~29 M samples) are drawn from their minimum and maximum
per pixel column, read from the samples Parquet in batches: the plot shows every excursion of the
signal at a memory cost of one batch. Nothing here writes files; the run pages
(:mod:`pipeline.serve.report.pages`) place the SVG in a page, and ``pneubench plot`` draws its
axes and events the same way (:func:`time_ticks`, :func:`run_events`).
"""
from __future__ import annotations

import html
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from schemas.units import to_display

if TYPE_CHECKING:  # numpy, pyarrow and matplotlib are imported by the functions that draw: kept off
    import numpy as np  # the paths that only publish a report (the no-op rebuild) or name its pages

#: Pixel columns of a plot (one min/max pair per column).
WIDTH = 880
#: Height of one channel's panel [px].
PANEL_H = 110
#: Rows read from Parquet at a time.
BATCH_ROWS = 1_000_000
#: Longest run drawn with its time axis in seconds; past it the axis reads h:mm:ss. [s]
CLOCK_AFTER_S = 3600.0
#: Steps of an h:mm:ss axis. [s]
CLOCK_STEPS = (1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 900, 1800, 3600, 7200, 10800, 21600, 43200, 86400)
#: Most events drawn on one page (a run with more shows the first ones and says so).
MAX_EVENTS = 400
#: What the analyses saw, drawn on the traces: event kind -> (legend text, colour).
EVENT_STYLE = {"onset": ("breakaway onset", "#d62728"), "pass": ("constant-velocity pass", "#2ca02c"),
               "plateau": ("pressure plateau (steady part)", "#ff7f0e"), "step": ("set-point step", "#9467bd")}
COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#17becf", "#7f7f7f")


def downsample_minmax(path: str | Path, columns: list[str], n_rows: int, width: int = WIDTH) -> dict:
    """Minimum and maximum of each column per pixel column, streamed from a Parquet file.

    Parameters
    ----------
    path : path-like
        Samples Parquet file.
    columns : list of str
        Columns to reduce (``t_s`` is always read for the time axis).
    n_rows : int
        Rows of the file (bins are by row index: bin = row * width // n_rows).
    width : int
        Number of bins.

    Returns
    -------
    dict
        ``{"t_s": (t_min, t_max), column: (min array, max array), ...}``; bins without samples are NaN.
    """
    import numpy as np
    import pyarrow.parquet as pq

    pf = pq.ParquetFile(path)
    have = [c for c in columns if c in pf.schema_arrow.names]
    n_rows = max(int(n_rows or pf.metadata.num_rows), 1)
    width = max(1, min(width, n_rows))
    lo = {c: np.full(width, np.inf) for c in have}
    hi = {c: np.full(width, -np.inf) for c in have}
    t_first = t_last = None
    start = 0
    read = have + (["t_s"] if "t_s" in pf.schema_arrow.names else [])
    for batch in pf.iter_batches(batch_size=BATCH_ROWS, columns=read):
        n = batch.num_rows
        if n == 0:
            continue
        idx, ub = bin_starts(start, n, n_rows, width)
        for c in have:
            v = batch.column(c).to_numpy(zero_copy_only=False).astype(float, copy=False)
            if not np.isfinite(v).all():  # +-inf count as no sample, as NaN does
                v = np.where(np.isfinite(v), v, np.nan)
            with np.errstate(invalid="ignore"):
                mn = np.fmin.reduceat(v, idx)
                mx = np.fmax.reduceat(v, idx)
            lo[c][ub] = np.fmin(lo[c][ub], mn)
            hi[c][ub] = np.fmax(hi[c][ub], mx)
        if "t_s" in batch.schema.names:
            t = batch.column("t_s").to_numpy(zero_copy_only=False)
            t_first = float(t[0]) if t_first is None else t_first
            t_last = float(t[-1])
        start += n
    out: dict = {"t_s": (t_first, t_last)}
    for c in have:
        a, b = lo[c], hi[c]
        a[~np.isfinite(a)] = np.nan
        b[~np.isfinite(b)] = np.nan
        out[c] = (a, b)
    return out


def bin_starts(start: int, n: int, n_rows: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Where the pixel columns begin in a batch of rows ``start`` .. ``start + n - 1``.

    Row ``r`` falls in column ``min(r * width // n_rows, width - 1)``. Returns (offsets in the batch
    where a column begins, the first one 0; those columns), as :func:`numpy.ufunc.reduceat` takes
    them. Column ``k`` begins at row ``ceil(k * n_rows / width)``: computed for the ``width`` columns,
    not for every row of the batch (~10 ms per million rows).
    """
    import numpy as np

    first = min(start * width // n_rows, width - 1)
    last = min((start + n - 1) * width // n_rows, width - 1)
    cols = np.arange(first + 1, last + 1, dtype=np.int64)
    rows = -((-cols * n_rows) // width) - start  # ceil(k * n_rows / width), relative to the batch
    return np.concatenate(([0], rows)), np.concatenate(([first], cols))


def _tick(v: float) -> str:
    """A value as tick text (6 significant digits)."""
    return f"{v:.6g}"


def hms(t: float, decimals: int = 0) -> str:
    """Seconds as ``h:mm:ss`` (``11250`` -> ``3:07:30``), negative with a sign."""
    sign = "-" if t < 0 else ""
    t = round(abs(float(t)), decimals)
    h, rest = divmod(t, 3600.0)
    m, sec = divmod(rest, 60.0)
    width = 2 + (decimals + 1 if decimals else 0)
    return f"{sign}{int(h)}:{int(m):02d}:{sec:0{width}.{decimals}f}"


def number_labels(ticks) -> list[str]:
    """Tick values in one format, as few decimals as they need (``0, 0.5, 1`` -> ``0.0, 0.5, 1.0``)."""
    ticks = [float(v) for v in ticks]
    if not ticks:
        return []
    big = max(abs(v) for v in ticks)
    step = min((abs(b - a) for a, b in zip(ticks, ticks[1:]) if b != a), default=big or 1.0)
    if big >= 1e6 or step < 1e-4:
        return [f"{v:.3g}" for v in ticks]
    d = next((d for d in range(7) if all(abs(round(v, d) - v) <= step * 1e-6 for v in ticks)), 6)
    labels = [f"{v:.{d}f}" for v in ticks]
    return [t.lstrip("-") if float(t) == 0 else t for t in labels]


#: The tick steps (multiples of a power of ten) :func:`value_ticks` chooses from.
TICK_STEPS = (1, 2, 2.5, 5, 10)


def value_ticks(vmin: float, vmax: float, n: int = 4) -> list[float]:
    """Round tick values inside [vmin, vmax]: those of matplotlib's ``MaxNLocator(nbins=n,
    steps=TICK_STEPS).tick_values`` (with ``axes.autolimit_mode`` "data", the default), computed
    here (:func:`max_n_ticks`) so that a run page drawn without a stage figure imports no
    matplotlib (~0.5 CPU-s of a one-file change, issue 26; tested equal to matplotlib's)."""
    if not vmax > vmin:
        return [vmin]
    tol = (vmax - vmin) * 1e-9
    ticks = max_n_ticks(vmin, vmax, n, TICK_STEPS)
    return [float(v) for v in ticks if vmin - tol <= v <= vmax + tol]


def max_n_ticks(vmin: float, vmax: float, nbins: int, steps=TICK_STEPS):
    """matplotlib's ``MaxNLocator(nbins, steps=steps).tick_values(vmin, vmax)`` (3.x, ``integer``,
    ``symmetric`` and ``prune`` off, ``min_n_ticks`` 2, autolimit mode "data"): the same
    operations on the same numpy types, so the same floats. ``steps`` ascending in [1, 10]."""
    import numpy as np

    vmin, vmax = _nonsingular(vmin, vmax, expander=1e-13, tiny=1e-14)
    st = np.asarray(steps)
    if st[0] != 1:
        st = np.concatenate([[1], st])
    if st[-1] != 10:
        st = np.concatenate([st, [10]])
    extended = np.concatenate([0.1 * st[:-1], st, [10 * st[1]]])
    dv = abs(vmax - vmin)  # scale_range
    meanv = (vmax + vmin) / 2
    offset = 0 if abs(meanv) / dv < 100 else math.copysign(10 ** (math.log10(abs(meanv)) // 1), meanv)
    scale = 10 ** (math.log10(dv / nbins) // 1)
    _vmin, _vmax = vmin - offset, vmax - offset
    steps_ = extended * scale
    raw_step = (_vmax - _vmin) / nbins
    large = steps_ >= raw_step
    istep = np.nonzero(large)[0][0] if any(large) else len(steps_) - 1
    ticks = None
    for step in steps_[:istep + 1][::-1]:
        best_vmin = (_vmin // step) * step
        low = _edge(step, offset, _vmin - best_vmin, True)
        high = _edge(step, offset, _vmax - best_vmin, False)
        ticks = np.arange(low, high + 1) * step + best_vmin
        if ((ticks <= _vmax) & (ticks >= _vmin)).sum() >= 2:
            break
    return ticks + offset


def _edge(step, offset, x, lower: bool):
    """matplotlib's ``_Edge_integer(step, offset).le(x)`` (``lower``) or ``.ge(x)``."""
    import numpy as np

    offset = abs(offset)
    if offset > 0:
        tol = min(0.4999, max(1e-10, 10 ** (np.log10(offset / step) - 12)))
    else:
        tol = 1e-10
    d, m = divmod(x, step)
    if lower:
        return d + 1 if abs(m / step - 1) < tol else d
    return d if abs(m / step - 0) < tol else d + 1


def _nonsingular(vmin: float, vmax: float, expander: float, tiny: float) -> tuple[float, float]:
    """matplotlib's ``transforms._nonsingular`` (increasing): the endpoints widened when the range
    is too small to divide."""
    import numpy as np

    if not np.isfinite(vmin) or not np.isfinite(vmax):
        return -expander, expander
    if vmax < vmin:
        vmin, vmax = vmax, vmin
    vmin, vmax = float(vmin), float(vmax)
    maxabs = max(abs(vmin), abs(vmax))
    if maxabs < (1e6 / tiny) * np.finfo(float).tiny:
        return -expander, expander
    if vmax - vmin <= maxabs * tiny:
        if vmax == 0 and vmin == 0:
            return -expander, expander
        return vmin - expander * abs(vmin), vmax + expander * abs(vmax)
    return vmin, vmax


def time_ticks(t0: float, t1: float, n: int = 8) -> tuple[list[float], list[str], str]:
    """Ticks of a time axis: (positions [s], labels, unit). In seconds up to
    :data:`CLOCK_AFTER_S`, past it in ``h:mm:ss`` on whole seconds, minutes or hours."""
    if not t1 > t0:
        return [t0], number_labels([t0]), "s"
    if max(abs(t0), abs(t1)) <= CLOCK_AFTER_S:
        ticks = value_ticks(t0, t1, n)
        return ticks, number_labels(ticks), "s"
    step = next((s for s in CLOCK_STEPS if (t1 - t0) / s <= n), None)
    if step is None:
        step = 86400 * math.ceil((t1 - t0) / n / 86400)
    ticks = [k * step for k in range(math.ceil(t0 / step), math.floor(t1 / step) + 1)]
    if len(ticks) < 2:
        return [t0, t1], [hms(t0, 1), hms(t1, 1)], "h:mm:ss"
    return [float(v) for v in ticks], [hms(v) for v in ticks], "h:mm:ss"


def run_events(results) -> list[tuple[str, float, float | None, str]]:
    """The events the analyses found in a run, from its result rows.

    ``results``: ``(table, columns, row)`` per result row (what the run page shows). Returns
    ``(kind, t_start [s], t_end [s] or None for an instant, text)`` in time order, kinds of
    :data:`EVENT_STYLE`: breakaway onsets (``breakaway.onset_t_s``), constant-velocity passes
    (``viscous_points``), the steady part of pressure plateaus (``leakage_map``), set-point steps
    (``step_response`` / ``pressure_steps.t_step_s``).
    """
    def num(v):
        try:
            v = float(v)
        except (TypeError, ValueError):
            return None
        return v if math.isfinite(v) else None

    out = []
    for table, cols, row in results:
        r = dict(zip(cols, row))
        if table == "breakaway" and num(r.get("onset_t_s")) is not None:
            out.append(("onset", num(r["onset_t_s"]), None, f"breakaway onset {r.get('direction') or ''}".rstrip()))
        elif table in ("viscous_points", "leakage_map"):
            a, b = num(r.get("t_start_s")), num(r.get("t_end_s"))
            if a is not None and b is not None:
                kind = "pass" if table == "viscous_points" else "plateau"
                idx = r.get("pass_index") if kind == "pass" else r.get("plateau")
                text = f"{EVENT_STYLE[kind][0]} {'' if idx is None else idx}".rstrip()
                out.append((kind, min(a, b), max(a, b), text))
        elif table in ("step_response", "pressure_steps") and num(r.get("t_step_s")) is not None:
            where = r.get("chamber") or ""
            out.append(("step", num(r["t_step_s"]), None, f"set-point step {where}".rstrip()))
    return sorted(out, key=lambda e: (e[1], e[0]))


#: Margins of the plot left of the panels (value ticks) and right of them. [px]
LEFT, RIGHT = 70, 10


@dataclass(frozen=True)
class _Frame:
    """Where a plot's panels are: time span ``t0``..``t1`` [s] across :data:`WIDTH` px from
    :data:`LEFT`, the first panel's top at ``top`` [px]."""

    t0: float
    t1: float
    top: int

    def x(self, t: float) -> float:
        """Pixel column of time ``t`` [s]."""
        return LEFT + (t - self.t0) / (self.t1 - self.t0) * WIDTH

    def panel_top(self, k: int) -> int:
        """Top of the ``k``-th channel's panel [px]."""
        return self.top + k * (PANEL_H + 14)


def channels_svg(bands: dict, title: str = "", events=None) -> str:
    """One SVG with a panel per channel: the min/max band per pixel column, time axis below.

    ``bands`` is the output of :func:`downsample_minmax`; values are shown in the report's units
    (:func:`schemas.units.to_display`) on round ticks, time in s or h:mm:ss past an hour.
    ``events``: :func:`run_events`, drawn on every panel (spans and lines) with a legend.
    Returns "" when there is nothing to draw.
    """
    chans = [c for c in bands if c != "t_s"]
    if not chans:
        return ""
    t0, t1 = bands["t_s"]
    have_t = t0 is not None and t1 is not None and t1 > t0
    events = [e for e in (events or []) if have_t and e[1] <= t1 and (e[2] if e[2] is not None else e[1]) >= t0]
    dropped = max(len(events) - MAX_EVENTS, 0)
    events = events[:MAX_EVENTS]
    kinds = [k for k in EVENT_STYLE if any(e[0] == k for e in events)]
    frame = _Frame(t0, t1, 8 + (20 if kinds else 0))
    w = WIDTH + LEFT + RIGHT
    h = frame.top + len(chans) * (PANEL_H + 14) + 34
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" '
             f'role="img" aria-label="{html.escape(title, quote=True)}" style="max-width:100%;height:auto" '
             'font-family="sans-serif">',
             '<rect width="100%" height="100%" fill="#fff"/>']
    if kinds:  # legend: what the analysis saw
        parts += _legend(kinds, events, dropped)
    tticks, tlabels, tunit = time_ticks(t0, t1) if have_t else ([], [], "s")
    for k, c in enumerate(chans):
        parts += _panel(frame, k, c, bands[c], tticks, events)
    parts += _time_axis(frame, len(chans), h, (tticks, tlabels, tunit) if have_t else None)
    parts.append("</svg>")
    return "".join(parts)


def _legend(kinds: list[str], events: list, dropped: int) -> list[str]:
    """The legend above the panels: each kind of event drawn, with how many (and how many not)."""
    parts = []
    x = LEFT
    for k in kinds:
        text, col = EVENT_STYLE[k]
        n_k = sum(e[0] == k for e in events)
        label = html.escape(f"{text} ({n_k})")
        if any(e[0] == k and e[2] is not None for e in events):
            parts.append(f'<rect x="{x}" y="6" width="14" height="10" fill="{col}" fill-opacity="0.25" '
                         f'stroke="{col}"/>')
        else:
            parts.append(f'<line x1="{x + 7}" y1="5" x2="{x + 7}" y2="17" stroke="{col}" stroke-width="2" '
                         'stroke-dasharray="4 2"/>')
        parts.append(f'<text x="{x + 18}" y="15" font-size="11" fill="#1d2330">{label}</text>')
        x += 30 + 6.5 * len(label)
    if dropped:
        parts.append(f'<text x="{x}" y="15" font-size="11" fill="#5b6475">'
                     f'(first {MAX_EVENTS} drawn, {dropped} more in the tables)</text>')
    return parts


def _panel(frame: _Frame, k: int, column: str, band: tuple, tticks: list[float], events: list) -> list[str]:
    """The ``k``-th channel's panel: frame, time grid, events, then its min/max band on round ticks."""
    lo, hi = band
    lo, name, unit = to_display(column, lo)
    hi, _, _ = to_display(column, hi)
    y0 = frame.panel_top(k)
    parts = [f'<rect x="{LEFT}" y="{y0}" width="{WIDTH}" height="{PANEL_H}" fill="none" stroke="#c5cad3"/>']
    for t in tticks:  # time grid
        parts.append(f'<line x1="{frame.x(t):.1f}" y1="{y0}" x2="{frame.x(t):.1f}" y2="{y0 + PANEL_H}" stroke="#eceef2"/>')
    parts += _event_marks(frame, y0, events)
    return parts + _band(y0, COLOURS[k % len(COLOURS)], (lo, hi), name, unit)


def _event_marks(frame: _Frame, y0: int, events: list) -> list[str]:
    """The events on one panel: a shaded span each, or a dashed line for an instant."""
    parts = []
    for kind, a, b, text in events:
        col = EVENT_STYLE[kind][1]
        tip = f"<title>{html.escape(text)}: " + (f"{_tick(a)} to {_tick(b)} s" if b is not None else
                                                 f"{_tick(a)} s") + "</title>"
        if b is not None:
            xa, xb = frame.x(max(a, frame.t0)), frame.x(min(b, frame.t1))
            parts.append(f'<rect x="{xa:.1f}" y="{y0}" width="{max(xb - xa, 1.0):.1f}" height="{PANEL_H}" '
                         f'fill="{col}" fill-opacity="0.16">{tip}</rect>')
        else:
            parts.append(f'<line x1="{frame.x(a):.1f}" y1="{y0}" x2="{frame.x(a):.1f}" y2="{y0 + PANEL_H}" '
                         f'stroke="{col}" stroke-width="1.5" stroke-dasharray="4 2">{tip}</line>')
    return parts


def _band(y0: int, col: str, band: tuple, name: str, unit: str) -> list[str]:
    """A channel's min/max band (display units) in its panel at ``y0``, with value ticks and label."""
    import numpy as np

    lo, hi = band
    ok = np.isfinite(lo) & np.isfinite(hi)
    label = html.escape(f"{name} [{unit}]" if unit else name)
    if not ok.any():
        return [f'<text x="{LEFT + 6}" y="{y0 + 13}" font-size="12" fill="#1d2330">{label}</text>',
                f'<text x="{LEFT + 6}" y="{y0 + 30}" font-size="11" fill="#5b6475">no finite samples</text>']
    vmin, vmax = float(np.nanmin(lo[ok])), float(np.nanmax(hi[ok]))
    span = vmax - vmin or max(abs(vmax), 1.0) * 1e-3
    n = lo.size
    xs = LEFT + (np.arange(n) + 0.5) * WIDTH / n

    def y(v):
        return y0 + PANEL_H - 4 - (v - vmin) / span * (PANEL_H - 20)

    parts = []
    yticks = value_ticks(vmin, vmax) if vmax > vmin else [vmin]
    for v, text in zip(yticks, number_labels(yticks)):
        parts.append(f'<line x1="{LEFT - 3}" y1="{y(v):.1f}" x2="{LEFT + WIDTH}" y2="{y(v):.1f}" '
                     'stroke="#eceef2"/>')
        parts.append(f'<text x="{LEFT - 5}" y="{y(v) + 3.5:.1f}" font-size="10" text-anchor="end" '
                     f'fill="#5b6475">{text}</text>')
    idx = np.flatnonzero(ok)
    upper = " ".join(f"{xs[i]:.1f},{y(hi[i]):.1f}" for i in idx)
    lower = " ".join(f"{xs[i]:.1f},{y(lo[i]):.1f}" for i in idx[::-1])
    extremes = html.escape(f"{name}: {_tick(vmin)} to {_tick(vmax)}" + (f" {unit}" if unit else ""))
    parts.append(f'<polygon points="{upper} {lower}" fill="{col}" fill-opacity="0.35" stroke="{col}" '
                 f'stroke-width="1" stroke-linejoin="round"><title>{extremes}</title></polygon>')
    parts.append(f'<text x="{LEFT + 6}" y="{y0 + 13}" font-size="12" fill="#1d2330" stroke="#fff" '
                 f'stroke-width="3" paint-order="stroke">{label}</text>')
    return parts


def _time_axis(frame: _Frame, n_panels: int, h: int, ticks: tuple | None) -> list[str]:
    """The time axis under the panels (``ticks``: :func:`time_ticks`), or the one instant there is."""
    tticks, tlabels, tunit = ticks if ticks is not None else ([], [], "s")
    yb = frame.panel_top(n_panels) - 14
    parts = []
    for t, text in zip(tticks, tlabels):
        parts.append(f'<line x1="{frame.x(t):.1f}" y1="{yb}" x2="{frame.x(t):.1f}" y2="{yb + 4}" stroke="#5b6475"/>')
        parts.append(f'<text x="{frame.x(t):.1f}" y="{yb + 15}" font-size="10" text-anchor="middle" fill="#5b6475">'
                     f'{text}</text>')
    if ticks is not None:
        parts.append(f'<text x="{LEFT + WIDTH}" y="{h - 4}" font-size="11" text-anchor="end" fill="#5b6475">'
                     f't [{tunit}]</text>')
    elif frame.t0 is not None:
        parts.append(f'<text x="{LEFT}" y="{h - 4}" font-size="11" fill="#5b6475">t = {_tick(frame.t0)} s</text>')
    return parts
