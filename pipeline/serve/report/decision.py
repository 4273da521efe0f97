"""The report's first section, "The decision": per hose type the verdict in words, the
information fraction as a bar and the plan to reach a verdict (one table), under each verdict the
verdict under other failure definitions (``decision_sensitivity``, a flip highlighted), then the
running hoses (:mod:`~pipeline.serve.report.running_hoses`) and the looks of each hose type as a
plot of the estimate with its boundaries against the failures.

The words and the reading of the tables are :mod:`pipeline.serve.decision`'s (``pneubench
decision`` prints the same); here they become HTML and a figure. The figure is SVG text
(:mod:`~pipeline.serve.report.looks_svg`: about a millisecond a figure, no matplotlib), without a date
(the same tables give the same bytes), under its key (:func:`looks_key`): a figure whose key the
previous report holds is taken from there (:mod:`~pipeline.serve.report.figures`).
"""
from __future__ import annotations

import math

from pipeline.serve.decision import (DECIDED, HoseDecision, information_words, missing_line, plan_words,
                                     read_decisions, verdict_words)
from pipeline.serve.remaining_life import differs, limit_text, ratio_interval, read_sensitivity
from pipeline.serve.report.db import ReportDB
from pipeline.serve.report.figures import Figures, code_key, figure_key
from pipeline.serve.report.looks_svg import Looks, looks_svg
from pipeline.serve.report.markup import esc
from pipeline.serve.report.running_hoses import running_section

#: Hose types whose looks are drawn (one figure each); the others are listed by name.
MAX_LOOK_PLOTS = 20
#: What a looks figure reads of each look (its key: :func:`looks_key`).
LOOK_FIELDS = ("look", "failures", "life_ratio", "rci_lower", "rci_upper", "efficacy_lower", "efficacy_upper",
               "futility_lower", "futility_upper", "crossed", "decides", "note")
#: What a looks figure is drawn with (part of its key): this module, the one that draws it and the decision
#: stage (which crossings the verdict counts); no library draws it.
LOOKS_CODE = (("pipeline/serve/report/decision.py", "pipeline/serve/report/looks_svg.py", "pipeline/stages/decision.py"),
              ())
#: Verdict cell classes (the report's style sheet): decided in colour, the rest grey.
VERDICT_CLASS = {"force longer": "ok", "distance longer": "bad", "no practical difference": "ok"}


def _anchor(k: int) -> str:
    """The figure anchor of the ``k``-th hose type (hose type names are free text from raw/)."""
    return f"decision-looks-{k + 1}"


def decision_section(db: ReportDB, figures: Figures | None = None) -> str:
    """The section ``#decision``: one line when the warehouse has no decision, else the table of
    verdicts and the looks of each hose type (the first :data:`MAX_LOOK_PLOTS`), each taken from
    ``figures`` (the previous report) when its key is there, else drawn."""
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
            + _looks_figures(decisions, figures or Figures()) + "</section>")


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


def _looks_figures(decisions: list[HoseDecision], figures: Figures) -> str:
    """The looks of each hose type as a figure (the first :data:`MAX_LOOK_PLOTS` with looks), from
    ``figures`` when its key is there."""
    out = []
    for k, d in enumerate(decisions[:MAX_LOOK_PLOTS]):
        if not _drawable(d):
            continue
        img = figures.figure(looks_key(d), lambda d=d: looks_svg(looks_of(d)))
        out.append(f'<figure id="{_anchor(k)}">{img}'
                   f"<figcaption><b>{esc(d.hose_type)}</b>: the estimate of the life ratio force / distance at each "
                   "look (failure) with its repeated confidence interval, the efficacy boundaries (crossing one "
                   "declares a longer life) and the futility boundaries (inside both: no practical difference), "
                   "against the failures, up to the planned maximum; the margins dotted. Ringed: the looks whose "
                   "crossing the verdict counts (the profile likelihood confirmed it); an estimate beyond a boundary "
                   "without a ring did not cross (the likelihood did not confirm it) or came after the verdict. The "
                   "early looks' boundaries run off the axis. Point at a look for its figures.</figcaption></figure>")
    rest = [d.hose_type for d in decisions[MAX_LOOK_PLOTS:] if _drawable(d)]
    if rest:
        out.append(f'<p class="meta">Looks not drawn for {len(rest)} more hose types ({esc(", ".join(rest))}): '
                   "<code>pneubench decision --hose-type T</code> lists them.</p>")
    return "".join(out)


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
    """A key of the looks figure of ``d``: a hash of what :func:`looks_of` reads and of the code and libraries
    that draw it (:data:`LOOKS_CODE`; equal keys, equal bytes) [32 hex digits]."""
    looks = [[lk.get(c) for c in LOOK_FIELDS] for lk in d.looks]
    verdict = [d.verdict.get(c) for c in ("verdict", "margin", "max_failures")]
    return figure_key(code_key(*LOOKS_CODE), d.hose_type, verdict, looks)


def looks_of(d: HoseDecision) -> Looks:
    """What the looks figure of ``d`` shows (:class:`~pipeline.serve.report.looks_svg.Looks`): each look's
    failures, estimate, repeated interval and boundaries (NULL as a gap), the crossings the verdict counts,
    the deciding look, the margin and the planned maximum."""
    v = d.verdict
    top = v.get("max_failures")
    return Looks(hose_type=str(d.hose_type), verdict=v.get("verdict"),
                 failures=[float(lk.get("failures") or lk.get("look") or 0) for lk in d.looks],
                 **{c: _series(d.looks, c) for c in ("rci_lower", "rci_upper", "efficacy_lower", "efficacy_upper",
                                                      "futility_lower", "futility_upper")},
                 ratio=_series(d.looks, "life_ratio"), counted=counted_crossings(d),
                 deciding=next((i for i, lk in enumerate(d.looks) if lk.get("decides")), None),
                 margin=v.get("margin"), max_failures=float(top) if isinstance(top, (int, float)) else None,
                 looks=[lk.get("look") for lk in d.looks])
