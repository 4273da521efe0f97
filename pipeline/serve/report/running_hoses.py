"""The decision section's "Running hoses": per hose type and adjustment a table of the running
hoses, nearest their end first, with the distance now, the remaining kilometres per method
(median and prediction interval at the plan's confidence), the backtest's coverage under each
method's column so that a reader knows how far to trust it, the leak now against the plan's limit,
the notes of what could not be predicted (a leak now under the flow sensor's floor reads
"< floor", :func:`~pipeline.serve.report.tables.floor_text`), and a small plot of the hose's leak
path against the limit (the first :data:`MAX_LEAK_PLOTS` hoses nearest their end; the others are
counted).

The reading and the words are :mod:`pipeline.serve.remaining_life`'s (``pneubench decision``
prints the same); the models behind the numbers: Meeker & Escobar 1998, ch. 12-13; Lu & Meeker
1993 (``docs/decision.md``, "Remaining life: the models"). Each plot is drawn with matplotlib's
object API (no pyplot) at the size it is shown (no scaling: its text as readable as the table's),
embedded as PNG without a date or software stamp (the same tables give the same bytes), under its
key (:func:`leak_key`: the points and rows it draws and the code that draws them): a plot whose key
the previous report holds is taken from there (:class:`~pipeline.serve.report.figures.Figures`), so
a night that changed one hose draws one plot.
"""
from __future__ import annotations

import base64
import io

from pipeline.serve.remaining_life import (METHODS, RunningHose, coverage_text, interval_name, km_text, leak_paths,
                                           num, read_backtest, read_running, rul_missing, rul_text)
from pipeline.serve.report.db import ReportDB
from pipeline.serve.report.figures import Figures, code_key, figure_key
from pipeline.serve.report.markup import esc
from pipeline.serve.report.tables import floor_text, floors_by

#: Running hoses whose leak path is drawn, nearest their end first (a plot each; the rest are counted).
MAX_LEAK_PLOTS = 40
#: Size of one leak-path plot [px], drawn at 100 dpi and shown at this size.
PLOT_PX = (360, 190)
#: Colours of the plot: the leak path, the plan's limit, the distance now, the predicted crossing.
COLOURS = {"path": "#1f3f8f", "limit": "#c62828", "now": "#6b7280", "crossing": "#e08a00"}
#: What a leak-path plot is drawn with (part of its key): this module, the reading of its rows and
#: the libraries that draw.
LEAK_CODE = (("pipeline/serve/report/running_hoses.py", "pipeline/serve/remaining_life.py"), ("numpy", "matplotlib"))
#: What a leak-path plot reads of its hose's rows (besides its points and distance now).
LEAK_FIELDS = (("leak_limit_l_min", None), ("leak_pressure_bar", None), ("rul_median_km", "degradation"),
               ("rul_lower_km", "degradation"), ("rul_upper_km", "degradation"))


def running_section(db: ReportDB, figures: Figures | None = None) -> str:
    """The part ``#running-hoses`` of the decision section: one line when the warehouse has no
    remaining life (built before its stage) or no running hose, else a table per hose type and
    adjustment; each leak-path plot taken from ``figures`` (the previous report) when its key is
    there, else drawn."""
    head = '<h3 id="running-hoses">Running hoses</h3>'
    missing = rul_missing(db.con)
    if missing:
        return f'{head}<p class="nodata">{esc(missing)}</p>'
    hoses = read_running(db.con)
    if not hoses:
        return f'{head}<p class="nodata">no running hose: every hose in the logbooks has failed or was removed</p>'
    drawn = hoses[:MAX_LEAK_PLOTS]
    paths = leak_paths(db.con, drawn)
    figures = figures or Figures()
    plots = {h.hose_id: _plot(h, paths.get(h.hose_id, []), figures) for h in drawn}
    backtest = read_backtest(db.con)
    intro = (f'<p class="meta">{len(hoses)} running hose{"s" if len(hoses) != 1 else ""}, nearest their end first. '
             f"Remaining km: the median and the {esc(interval_name(hoses))} of each method: "
             "<i>weibull</i>, the hose type's life model given that the hose has run this far; <i>degradation</i>, "
             "its own leak path run to the plan's limit, with the logbook's other failures (ruptures) as a competing "
             "risk: the first of the two ends the hose (the one to read where both predict: the weibull intervals "
             "run short on lives that mix a wear-out and a rupture; docs/decision.md). Under each method: how often its intervals held the "
             "true remaining life of the hoses that have since failed, predicted at 50 % and 80 % of their life "
             "(the backtest; docs/decision.md). Leak path: the hose's leak at the plan's pressure against distance "
             "(blue), the limit (red, dashed), the distance now (dotted) and, where the degradation model predicts "
             "one, the crossing of the limit (orange: median and interval).</p>")
    groups: dict[tuple, list[RunningHose]] = {}
    for h in hoses:
        groups.setdefault((h.hose_type, h.adjustment), []).append(h)
    floors = _hose_floors(db, hoses)
    tables = "".join(_group_table(t, a, groups[(t, a)], backtest, plots, floors) for t, a in sorted(groups))
    rest = len(hoses) - len(drawn)
    capped = (f'<p class="meta">Leak paths drawn for the {len(drawn)} hoses nearest their end; {rest} more '
              "listed without one (<code>pneubench query</code> on <code>hose_leak_growth</code> has them all).</p>"
              if rest > 0 else "")
    return head + intro + tables + capped


def _hose_floors(db: ReportDB, hoses: list[RunningHose]) -> dict[str, float]:
    """Per running hose, the floor of the coarsest flow sensor of its leakage runs
    (:func:`~pipeline.serve.report.tables.floors_by` ``hose_id``) [l/min ANR]; a hose without one is left out."""
    return floors_by(db, "hose_id", [h.hose_id for h in hoses])


def _group_table(hose_type: str, adjustment: str, hoses: list[RunningHose], backtest: dict, plots: dict,
                 floors: dict | None = None) -> str:
    """One hose type and adjustment: a row per running hose, the backtest under each method's name;
    ``floors``: per hose, its flow sensor's floor [l/min ANR] (:func:`_hose_floors`)."""
    heads = "".join(f'<th>{m}<br><small>remaining km</small><br><span class="meta" style="font-weight:400">'
                    f"{esc(coverage_text(backtest.get((hose_type, adjustment, m))))}</span></th>" for m in METHODS)
    rows = []
    for h in hoses:
        cells = "".join(f'<td class="num">{esc(rul_text(h.rows.get(m)))}</td>' for m in METHODS)
        rows.append(f"<tr><td>{esc(h.hose_id)}</td><td class=\"num\">{esc(km_text(h.distance_km))}</td>{cells}"
                    f"<td>{_leak_cell(h, (floors or {}).get(str(h.hose_id)))}</td><td>{_plot_cell(h, plots)}</td>"
                    f'<td class="meta">{esc(h.notes())}</td></tr>')
    return (f"<h4>{esc(hose_type)}, {esc(adjustment or 'unknown')}-set: {len(hoses)} running</h4>"
            '<div class="wrap"><table class="running"><thead><tr><th>hose</th><th>now<br><small>km</small></th>'
            f"{heads}<th>leak now / limit</th><th>leak path</th><th>note</th></tr></thead><tbody>"
            + "".join(rows) + "</tbody></table></div>")


def _leak_cell(h: RunningHose, floor: float | None = None) -> str:
    """``0.41 / 2 l/min`` over ``at 6 bar, 9 points`` (HTML), the leak now ``< floor`` under the flow
    sensor's ``floor`` [l/min ANR]; ``no limit in plan.toml`` without one."""
    r = h.row("leak_limit_l_min")
    if not r:
        return "no limit in plan.toml"
    now = num(h.row("leak_now_l_min").get("leak_now_l_min"))
    p = num(r.get("leak_pressure_bar"))
    n = h.row("n_leak_points").get("n_leak_points")
    under = ", ".join(([f"at {p:.3g} bar"] if p is not None else [])
                      + ([f"{int(n)} point{'s' if n != 1 else ''}"] if n is not None else []))
    shown = "—" if now is None else esc(floor_text(now, floor) or f"{now:.3g}")
    return (f'<span style="white-space:nowrap">{shown} / '
            f'{num(r["leak_limit_l_min"]):.3g} l/min</span>'
            + (f'<br><span class="meta">{under}</span>' if under else ""))


def _plot_cell(h: RunningHose, plots: dict) -> str:
    """The hose's leak-path plot (:func:`_plot`), or why there is none."""
    return plots.get(h.hose_id, '<span class="meta">not drawn (see below)</span>')


def _plot(h: RunningHose, points: list[tuple[float, float]], figures: Figures) -> str:
    """The hose's leak-path plot as an ``<img>`` under its key (:func:`leak_key`), from ``figures``
    or drawn; without points, why there is none."""
    if not points:
        why = ("no leak pressure in plan.toml" if num(h.row("leak_pressure_bar").get("leak_pressure_bar")) is None
               else "no leak point at the plan's pressure")
        return f'<span class="meta">{why}</span>'
    return figures.figure(leak_key(h, points), lambda: _img(h, leak_png(points, h)))


def _img(h: RunningHose, png: bytes) -> str:
    """The plot's PNG as an ``<img>`` shown at the size it was drawn."""
    data = base64.b64encode(png).decode("ascii")
    return (f'<img class="leakpath" alt="leak path of {esc(h.hose_id)}" width="{PLOT_PX[0]}" height="{PLOT_PX[1]}" '
            f'src="data:image/png;base64,{data}">')


def leak_key(h: RunningHose, points: list[tuple[float, float]]) -> str:
    """A key of the leak-path plot of ``h``: a hash of what :func:`leak_png` and :func:`_img` read (the
    points, the distance now, :data:`LEAK_FIELDS`, the hose's name) and of the code and libraries that
    draw it (:data:`LEAK_CODE`; equal keys, equal bytes) [32 hex digits]."""
    rows = [num((h.rows.get(method) or {}).get(field) if method else h.row(field).get(field))
            for field, method in LEAK_FIELDS]
    return figure_key(code_key(*LEAK_CODE), h.hose_id, num(h.distance_km), [[num(x), num(y)] for x, y in points], rows)


def leak_png(points: list[tuple[float, float]], hose: RunningHose) -> bytes | None:
    """One hose's leak path as PNG bytes (:data:`PLOT_PX`): its points against distance, the plan's
    limit as a line, the distance now, and the degradation model's predicted crossing (median and
    interval on the limit) when it has one; None without points."""
    if not points:
        return None
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(PLOT_PX[0] / 100, PLOT_PX[1] / 100), dpi=100)
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.16, right=0.97, top=0.95, bottom=0.22)
    ax = fig.add_subplot(1, 1, 1)
    _draw_path(ax, points, hose)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()


def _draw_path(ax, points: list[tuple[float, float]], hose: RunningHose) -> None:
    """The leak path on ``ax`` (see :func:`leak_png`)."""
    x, y = [p[0] for p in points], [p[1] for p in points]
    ax.plot(x, y, "o-", color=COLOURS["path"], ms=3, lw=1.1)
    limit = num(hose.row("leak_limit_l_min").get("leak_limit_l_min"))
    now = hose.distance_km
    right = max(x + ([now] if now is not None else []))
    deg = hose.rows.get("degradation") or {}
    med, lo, hi = (num(deg.get(k)) for k in ("rul_median_km", "rul_lower_km", "rul_upper_km"))
    if limit is not None:
        ax.axhline(limit, color=COLOURS["limit"], lw=1.4, ls="--")
        ax.text(0.01, limit, f" limit {limit:.3g} l/min", transform=ax.get_yaxis_transform(), va="bottom",
                ha="left", fontsize=7, color=COLOURS["limit"])
        if now is not None and med is not None:
            span = [now + v for v in (lo, hi) if v is not None]
            if span:
                ax.plot([min(span), max(span)], [limit, limit], color=COLOURS["crossing"], lw=4, alpha=0.6,
                        solid_capstyle="butt")
            ax.plot([now + med], [limit], "D", color=COLOURS["crossing"], ms=5)
            right = max([right, now + med, *span])
    if now is not None:
        ax.axvline(now, color=COLOURS["now"], lw=0.8, ls=":")
    top = max(y + ([limit] if limit is not None else []))
    ax.set_ylim(min(0.0, min(y)), top * 1.22 if top > 0 else 1.0)
    ax.set_xlim(0, right * 1.04 if right > 0 else 1.0)
    p = num(hose.row("leak_pressure_bar").get("leak_pressure_bar"))
    ax.set_xlabel("distance [km]", fontsize=7.5, labelpad=1)
    ax.set_ylabel(f"leak at {p:g} bar [l/min]" if p is not None else "leak [l/min]", fontsize=7.5)
    ax.tick_params(labelsize=7, length=2, pad=1)
    ax.grid(alpha=0.3)
