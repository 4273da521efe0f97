"""The channels of one run as a static SVG plot, for the report's per-run pages.

Long runs (an 8 h durability run holds ~29 M samples) are drawn from their minimum and maximum
per pixel column, read from the samples Parquet in batches: the plot shows every excursion of the
signal at a memory cost of one batch. Nothing here writes files or imports the report; the
report (``pipeline/report.py``) places the SVG in a page.
"""
from __future__ import annotations

import hashlib
import html
import re
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # imported by the functions that draw: page_name() needs neither
    import numpy as np

#: Pixel columns of a plot (one min/max pair per column).
WIDTH = 880
#: Height of one channel's panel [px].
PANEL_H = 110
#: Rows read from Parquet at a time.
BATCH_ROWS = 1_000_000
#: Display conversions of SI channels: column suffix -> (factor, unit).
DISPLAY = (("_pa", 1e-5, "bar"), ("_m", 1e3, "mm"), ("_kg_s", None, "l/min ANR"), ("_n", 1.0, "N"),
           ("_v", 1.0, "V"))
COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#17becf", "#7f7f7f")


def page_name(run_id: str) -> str:
    """File name of a run's page: a readable slug of the id plus a hash of it (ids differing only
    in characters the slug drops, or in case, still get different pages)."""
    slug = re.sub(r"[^A-Za-z0-9._-]+", "_", str(run_id)).strip("._")[:80] or "run"
    return f"{slug}-{hashlib.sha256(str(run_id).encode('utf-8')).hexdigest()[:8]}.html"


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
        bins = (np.arange(start, start + n, dtype=np.int64) * width) // n_rows
        bins = np.minimum(bins, width - 1)
        cuts = np.flatnonzero(np.diff(bins)) + 1
        idx = np.concatenate(([0], cuts))
        ub = bins[idx]
        for c in have:
            v = batch.column(c).to_numpy(zero_copy_only=False).astype(float)
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


def _display(column: str, values: np.ndarray) -> tuple[np.ndarray, str, str]:
    """Values in a readable unit: (values, label, unit)."""
    import numpy as np

    for suffix, factor, unit in DISPLAY:
        if column.endswith(suffix):
            name = column[: -len(suffix)]
            if factor is None:
                from schemas.units import kg_s_to_l_min_anr

                return kg_s_to_l_min_anr(values), name, unit
            return values * factor, name, unit
    return values, column, ""


def _tick(v: float) -> str:
    return f"{v:.4g}"


def channels_svg(bands: dict, title: str = "") -> str:
    """One SVG with a panel per channel: the min/max band per pixel column, time axis below.

    ``bands`` is the output of :func:`downsample_minmax`. Returns "" when there is nothing to draw.
    """
    import numpy as np

    chans = [c for c in bands if c != "t_s"]
    if not chans:
        return ""
    t0, t1 = bands["t_s"]
    left, right, top = 70, 10, 8
    w = WIDTH + left + right
    h = top + len(chans) * (PANEL_H + 14) + 24
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" '
             f'role="img" aria-label="{html.escape(title, quote=True)}" style="max-width:100%;height:auto">',
             '<rect width="100%" height="100%" fill="#fff"/>']
    for k, c in enumerate(chans):
        lo, hi = bands[c]
        lo, name, unit = _display(c, lo)
        hi, _, _ = _display(c, hi)
        y0 = top + k * (PANEL_H + 14)
        parts.append(f'<rect x="{left}" y="{y0}" width="{WIDTH}" height="{PANEL_H}" fill="none" stroke="#c5cad3"/>')
        ok = np.isfinite(lo) & np.isfinite(hi)
        label = html.escape(f"{name} [{unit}]" if unit else name)
        parts.append(f'<text x="{left + 6}" y="{y0 + 13}" font-size="12" fill="#1d2330">{label}</text>')
        if not ok.any():
            parts.append(f'<text x="{left + 6}" y="{y0 + 30}" font-size="11" fill="#5b6475">no finite samples</text>')
            continue
        vmin, vmax = float(np.nanmin(lo[ok])), float(np.nanmax(hi[ok]))
        span = vmax - vmin or max(abs(vmax), 1.0) * 1e-3
        n = lo.size
        xs = left + (np.arange(n) + 0.5) * WIDTH / n

        def y(v):
            return y0 + PANEL_H - 4 - (v - vmin) / span * (PANEL_H - 20)

        idx = np.flatnonzero(ok)
        upper = " ".join(f"{xs[i]:.1f},{y(hi[i]):.1f}" for i in idx)
        lower = " ".join(f"{xs[i]:.1f},{y(lo[i]):.1f}" for i in idx[::-1])
        col = COLOURS[k % len(COLOURS)]
        parts.append(f'<polygon points="{upper} {lower}" fill="{col}" fill-opacity="0.35" stroke="{col}" '
                     'stroke-width="1" stroke-linejoin="round"/>')
        parts.append(f'<text x="{left - 4}" y="{y(vmax) + 4:.1f}" font-size="10" text-anchor="end" '
                     f'fill="#5b6475">{_tick(vmax)}</text>')
        parts.append(f'<text x="{left - 4}" y="{y(vmin) + 4:.1f}" font-size="10" text-anchor="end" '
                     f'fill="#5b6475">{_tick(vmin)}</text>')
    yb = h - 8
    if t0 is not None and t1 is not None:
        parts.append(f'<text x="{left}" y="{yb}" font-size="11" fill="#5b6475">t = {_tick(t0)} s</text>')
        parts.append(f'<text x="{left + WIDTH}" y="{yb}" font-size="11" text-anchor="end" fill="#5b6475">'
                     f'{_tick(t1)} s</text>')
    parts.append("</svg>")
    return "".join(parts)
