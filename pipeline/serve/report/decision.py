"""The report's first section, "The decision": per hose type the verdict in words, the
information fraction as a bar and the plan to reach a verdict (one table), under each verdict the
verdict under other failure definitions (``decision_sensitivity``, a flip highlighted), then the
running hoses (:mod:`~pipeline.serve.report.running_hoses`) and the looks of each hose type as a
plot of the estimate with its boundaries against the failures.

The words and the reading of the tables are :mod:`pipeline.serve.decision`'s (``pneubench
decision`` prints the same); here they become HTML and a figure. The figure is drawn with
matplotlib's object API (no pyplot: no global state) as a PNG embedded like the stages' figures,
without a date or software stamp (the same tables give the same bytes), under its key
(:func:`looks_key`): a figure whose key the previous report holds is taken from there
(:mod:`~pipeline.serve.report.figures`), and matplotlib is imported only when a look is drawn.
"""
from __future__ import annotations

import base64
import io
import math
import multiprocessing
import os
from collections.abc import Callable

from pipeline.serve.decision import (DECIDED, HoseDecision, information_words, missing_line, plan_words,
                                     read_decisions, verdict_words)
from pipeline.serve.remaining_life import differs, limit_text, ratio_interval, read_sensitivity
from pipeline.serve.report.db import ReportDB
from pipeline.serve.report.figures import Figures, code_key, figure_key
from pipeline.serve.report.markup import esc
from pipeline.serve.report.running_hoses import running_section

#: Hose types whose looks are drawn (one figure each); the others are listed by name.
MAX_LOOK_PLOTS = 20
#: Looks figures to draw from which they are drawn in forked processes, one per core (a plan change redraws
#: all :data:`MAX_LOOK_PLOTS`, ~0.1 CPU-s each: on two cores half the wall); fewer are drawn here.
PARALLEL_FROM = 4
#: Colours of the figure: estimate, repeated interval, efficacy, futility, margin.
COLOURS = {"estimate": "#1f3f8f", "rci": "#9db4e8", "efficacy": "#c62828", "futility": "#2e7d32",
           "margin": "#6b7280", "decides": "#e08a00", "crossed": "#8e24aa"}
#: The figure's margins (fractions of 900 x 400 px): room for the labels, the margin's name on the
#: right and the legend below, fixed so that the figure is drawn once.
MARGINS = {"left": 0.085, "right": 0.9, "top": 0.91, "bottom": 0.25}
#: What a looks figure reads of each look (its key: :func:`looks_key`).
LOOK_FIELDS = ("look", "failures", "life_ratio", "rci_lower", "rci_upper", "efficacy_lower", "efficacy_upper",
               "futility_lower", "futility_upper", "crossed", "decides", "note")
#: What a looks figure is drawn with (part of its key): this module, the decision stage (which
#: crossings the verdict counts) and the libraries that draw.
LOOKS_CODE = (("pipeline/serve/report/decision.py", "pipeline/stages/decision.py"), ("numpy", "matplotlib"))
#: Verdict cell classes (the report's style sheet): decided in colour, the rest grey.
VERDICT_CLASS = {"force longer": "ok", "distance longer": "bad", "no practical difference": "ok"}


def _anchor(k: int) -> str:
    """The figure anchor of the ``k``-th hose type (hose type names are free text from raw/)."""
    return f"decision-looks-{k + 1}"


def decision_section(db: ReportDB, figures: Figures | None = None, pool: Callable | None = None) -> str:
    """The section ``#decision``: one line when the warehouse has no decision, else the table of
    verdicts and the looks of each hose type (the first :data:`MAX_LOOK_PLOTS`), each taken from
    ``figures`` (the previous report) when its key is there, else drawn (in ``pool``'s processes when given:
    :func:`_draw_elsewhere`)."""
    head = '<section id="decision"><h2>The decision</h2>'
    missing = missing_line(db.con)
    if missing:
        return f'{head}<p class="nodata">{esc(missing)}</p></section>'
    decisions = read_decisions(db.con)
    n_decided = sum(1 for d in decisions if d.verdict.get("verdict") in DECIDED)
    intro = (f'<p class="meta">Force-set against distance-set rollers: {len(decisions)} hose '
             f'type{"s" if len(decisions) != 1 else ""}, {n_decided} decided. A verdict is declared at the first look '
             "(each failure) whose repeated confidence interval of the life ratio force / distance excludes 1, or "
             "lies within the plan's margin, and it stays; its error rate holds however often it is read "
             "(docs/decision.md). The interval in words is the fit's profile-likelihood interval.</p>")
    return (head + intro + _verdict_table(decisions, read_sensitivity(db.con)) + running_section(db, figures)
            + _looks_figures(decisions, figures or Figures(), pool) + "</section>")


def _verdict_table(decisions: list[HoseDecision], sensitivity: dict[str, list[dict]]) -> str:
    """One row per hose type: verdict in words, information bar, plan, note; under it the verdict
    under each failure definition (``decision_sensitivity``) when the warehouse has it."""
    rows = []
    for k, d in enumerate(decisions):
        v = d.verdict
        verdict = v.get("verdict") or "—"
        cls = VERDICT_CLASS.get(verdict, "nodata")
        link = f' <a href="#{_anchor(k)}">looks</a>' if k < MAX_LOOK_PLOTS and _drawable(d) else ""
        note = f'<br><span class="meta">{esc(v.get("note"))}</span>' if v.get("note") else ""
        rows.append(f'<tr><td><b>{esc(d.hose_type)}</b>{link}</td><td class="{cls}">{esc(verdict)}</td>'
                    f"<td>{esc(verdict_words(d))}{note}</td><td>{_bar(v.get('information_fraction'))}<br>"
                    f'<span class="meta">{esc(information_words(d))}</span></td><td>{esc(plan_words(d))}</td></tr>')
        if sensitivity.get(d.hose_type):
            rows.append(_sensitivity_row(sensitivity[d.hose_type]))
    return ('<div class="wrap"><table class="decision"><thead><tr><th>hose type</th><th>verdict</th><th>in words</th>'
            "<th>information</th><th>plan to a verdict</th></tr></thead><tbody>" + "".join(rows)
            + "</tbody></table></div>")


#: Background of a failure definition's row whose verdict differs from the logbook's.
FLIPPED = "#ffe9b3"


def _sensitivity_row(rows: list[dict]) -> str:
    """A row under a hose type's verdict: the verdict under each failure definition, the rows whose
    verdict differs from the logbook's highlighted and marked."""
    body = []
    for r in rows:
        flipped = differs(r, rows)
        verdict = esc(r.get("verdict") or "—") + (" <b>⚠ differs from the logbook</b>" if flipped else "")
        failed = [r.get(k) for k in ("n_failed_force", "n_force", "n_failed_distance", "n_distance")]
        counts = ("—" if None in failed else f"{failed[0]} of {failed[1]} / {failed[2]} of {failed[3]}")
        body.append(f'<tr class="{"flipped" if flipped else "same"}"'
                    + (f' style="background:{FLIPPED}"' if flipped else "")
                    + f"><td>{esc(r.get('definition'))}</td><td>{esc(_limit_cell(r))}</td>"
                    f"<td>{esc(counts)}</td><td>{esc(ratio_interval(r))}</td><td>{verdict}</td>"
                    f'<td class="meta">{esc(r.get("note") or "")}</td></tr>')
    return ('<tr class="sensitivity"><td></td><td colspan="4"><span class="meta">The verdict under other failure '
            "definitions (the decision's rule read once on all of each definition's data now):</span>"
            '<table class="sensitivity"><thead><tr><th>failure</th><th>leak limit</th><th>failed force / distance'
            "</th><th>life ratio force / distance</th><th>verdict</th><th>note</th></tr></thead><tbody>"
            + "".join(body) + "</tbody></table></td></tr>")


def _limit_cell(row: dict) -> str:
    """A failure definition's leak limit: ``2 l/min at 6 bar``, ``as logged`` for the logbook, else a dash."""
    return "as logged" if row.get("definition") == "logbook" else (limit_text(row) or "—")


def _bar(fraction) -> str:
    """The information fraction as a bar (CSS only: the report has no script)."""
    try:
        x = float(fraction)
    except (TypeError, ValueError):
        x = math.nan
    if not math.isfinite(x):
        return '<span class="infobar nodata" title="unknown"><span style="width:0%"></span></span>'
    x = min(max(x, 0.0), 1.0)
    return (f'<span class="infobar" role="img" aria-label="{100 * x:.0f} % of the information" '
            f'title="{100 * x:.0f} %"><span style="width:{100 * x:.1f}%"></span></span>')


def _looks_figures(decisions: list[HoseDecision], figures: Figures, pool: Callable | None = None) -> str:
    """The looks of each hose type as a figure (the first :data:`MAX_LOOK_PLOTS` with looks), from
    ``figures`` when its key is there."""
    out = []
    shown = [(k, d, looks_key(d)) for k, d in enumerate(decisions[:MAX_LOOK_PLOTS]) if _drawable(d)]
    drawn = _draw_elsewhere([(d, key) for _k, d, key in shown if key not in figures.held], pool)
    for k, d, key in shown:
        img = figures.figure(key, lambda d=d, key=key: drawn[key] if key in drawn else _looks_img(d))
        out.append(f'<figure id="{_anchor(k)}">{img}'
                   f"<figcaption><b>{esc(d.hose_type)}</b>: the estimate of the life ratio force / distance at each "
                   "look (failure) with its repeated confidence interval, the efficacy boundaries (crossing one "
                   "declares a longer life) and the futility boundaries (inside both: no practical difference), "
                   "against the failures, up to the planned maximum; the margins dotted. Ringed: the looks whose "
                   "crossing the verdict counts (the profile likelihood confirmed it); an estimate beyond a boundary "
                   "without a ring did not cross (the likelihood did not confirm it) or came after the verdict. The "
                   "early looks' boundaries run off the axis.</figcaption></figure>")
    rest = [d.hose_type for d in decisions[MAX_LOOK_PLOTS:] if _drawable(d)]
    if rest:
        out.append(f'<p class="meta">Looks not drawn for {len(rest)} more hose types ({esc(", ".join(rest))}): '
                   "<code>pneubench decision --hose-type T</code> lists them.</p>")
    return "".join(out)


def _draw_elsewhere(todo: list[tuple[HoseDecision, str]], pool: Callable | None = None) -> dict[str, str]:
    """The figures of ``todo`` ((decision, key) pairs) drawn in ``pool(workers)``'s processes, one per core
    (:func:`_looks_img` there: the same bytes as here), by key; empty (each then drawn here) without a
    ``pool``, with fewer than :data:`PARALLEL_FROM`, one core, no ``fork``, or when the processes fail. The
    rebuild gives its own kind (:func:`pipeline.rebuild.executors.forked_pool`: processes forked from this one
    that exit within 0.2 s of its death, so a killed rebuild's lock, which they share while they draw, is not
    held on); the report does not import the rebuild (the house's map: ``serve`` is below ``rebuild``)."""
    workers = min(len(todo), os.cpu_count() or 1)
    if pool is None or len(todo) < PARALLEL_FROM or workers < 2 or "fork" not in multiprocessing.get_all_start_methods():
        return {}
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: F401  loaded once, before the fork
    from matplotlib.figure import Figure  # noqa: F401

    try:
        with pool(workers) as processes:
            imgs = list(processes.map(_looks_img, [d for d, _key in todo]))
    except Exception:   # a process that could not start or died: drawn here instead
        return {}
    return {key: img for (_d, key), img in zip(todo, imgs)}


def _looks_img(d: HoseDecision) -> str:
    """The looks figure of ``d`` as an ``<img>`` with its PNG embedded ("" when there is none)."""
    png = looks_png(d)
    if png is None:
        return ""
    data = base64.b64encode(png).decode("ascii")
    return f'<img alt="looks of {esc(d.hose_type)}" src="data:image/png;base64,{data}">'


def _series(looks: list[dict], column: str) -> list[float]:
    """A column of the looks as floats, NULL as NaN (a gap in the line)."""
    out = []
    for lk in looks:
        try:
            x = float(lk.get(column))
        except (TypeError, ValueError):
            x = math.nan
        out.append(x if math.isfinite(x) and x > 0 else math.nan)
    return out


def _drawable(d: HoseDecision) -> bool:
    """Whether a look of ``d`` has an estimate (there is something to draw)."""
    return any(math.isfinite(r) for r in _series(d.looks, "life_ratio"))


def counted_crossings(d: HoseDecision) -> list[int]:
    """Indices of the looks of ``d`` whose crossing the verdict counts: ``crossed`` up to the verdict (checked by
    the profile likelihood), not a crossing after it (the Wald one, unchecked: its note says so)."""
    from pipeline.stages.decision import AFTER_VERDICT   # here: the stage imports scipy, the no-op must not

    return [i for i, lk in enumerate(d.looks) if lk.get("crossed") and AFTER_VERDICT not in (lk.get("note") or "")]


def looks_key(d: HoseDecision) -> str:
    """A key of the looks figure of ``d``: a hash of what :func:`looks_png` reads and of the code and libraries
    that draw it (:data:`LOOKS_CODE`; equal keys, equal bytes) [32 hex digits]."""
    looks = [[lk.get(c) for c in LOOK_FIELDS] for lk in d.looks]
    verdict = [d.verdict.get(c) for c in ("verdict", "margin", "max_failures")]
    return figure_key(code_key(*LOOKS_CODE), d.hose_type, verdict, looks)


def looks_png(d: HoseDecision) -> bytes | None:
    """The looks of one hose type as PNG bytes: the estimate (log axis) with its repeated interval,
    efficacy and futility boundaries and the margins against the failures; None without a look
    that has an estimate."""
    if not _drawable(d):
        return None
    ratio = _series(d.looks, "life_ratio")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 4), dpi=100)
    FigureCanvasAgg(fig)
    fig.subplots_adjust(**MARGINS)       # fixed: tight_layout would draw the figure twice
    ax = fig.add_subplot(1, 1, 1)
    _draw_looks(ax, d, ratio)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()


def _draw_looks(ax, d: HoseDecision, ratio: list[float]) -> None:
    """The looks on ``ax``: estimate, repeated interval, boundaries, margins, the deciding look."""
    x = [float(lk.get("failures") or lk.get("look") or 0) for lk in d.looks]
    ax.fill_between(x, _series(d.looks, "rci_lower"), _series(d.looks, "rci_upper"), step="mid",
                    color=COLOURS["rci"], alpha=0.45, lw=0, label="repeated confidence interval")
    for side in ("lower", "upper"):
        ax.step(x, _series(d.looks, f"efficacy_{side}"), where="mid", color=COLOURS["efficacy"], lw=1.3,
                ls="--", label="efficacy boundary" if side == "upper" else None)
        ax.step(x, _series(d.looks, f"futility_{side}"), where="mid", color=COLOURS["futility"], lw=1.3,
                ls="-.", label="futility boundary" if side == "upper" else None)
    ax.plot(x, ratio, "o-", color=COLOURS["estimate"], ms=3.5, lw=1.4, label="estimate force / distance")
    counted = counted_crossings(d)
    if counted:
        ax.plot([x[i] for i in counted], [ratio[i] for i in counted], "o", mfc="none", mec=COLOURS["crossed"], ms=9,
                mew=1.6, label="crossed (confirmed)")
    v = d.verdict
    ax.axhline(1.0, color="black", lw=0.7)
    margin = v.get("margin")
    if isinstance(margin, (int, float)) and math.isfinite(margin) and margin > 1:
        for m in (margin, 1 / margin):
            ax.axhline(m, color=COLOURS["margin"], lw=0.8, ls=":")
        ax.text(1.0, margin, f" margin {margin:g}", transform=ax.get_yaxis_transform(), va="center", ha="left",
                fontsize=7, color=COLOURS["margin"], clip_on=False)
    deciding = next((i for i, lk in enumerate(d.looks) if lk.get("decides")), None)
    if deciding is not None:
        ax.axvline(x[deciding], color=COLOURS["decides"], lw=1.2)
        ax.plot([x[deciding]], [ratio[deciding]], "*", color=COLOURS["decides"], ms=13,
                label=f"decided: {v.get('verdict')}")
    ax.set_yscale("log")
    ax.set_ylim(*_ratio_window(ratio, margin))
    _ratio_ticks(ax)
    top = v.get("max_failures")
    ax.set_xlim(0, max([*x, float(top) if isinstance(top, (int, float)) else 0.0]) * 1.02 + 0.5)
    ax.set_xlabel("failures (both adjustments)")
    ax.set_ylabel("life ratio force / distance")
    ax.set_title(f"{d.hose_type}: {v.get('verdict') or 'no verdict'}", fontsize=10, y=1.0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=5, frameon=False)


def _ratio_window(ratio: list[float], margin) -> tuple[float, float]:
    """The y range: the estimates and the margins with room around them (a factor of 2.5 each
    way); the early looks' boundaries, which can be a hundredfold, run off it."""
    known = [r for r in ratio if math.isfinite(r)]
    if isinstance(margin, (int, float)) and math.isfinite(margin) and margin > 1:
        known += [margin, 1 / margin]
    return min(known + [1.0]) / 2.5, max(known + [1.0]) * 2.5


def _ratio_ticks(ax) -> None:
    """Plain ratios (0.5, 1, 2) on the log axis, not powers of ten."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    ax.yaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    ax.yaxis.set_major_formatter(FuncFormatter(lambda y, _pos: f"{y:g}"))
    ax.yaxis.set_minor_formatter(NullFormatter())
