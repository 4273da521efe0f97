"""The report's sections that are not results: the findings (and the alert box of those whose
result changed in the last 24 hours), the last rebuild with its inputs and quarantine, and the
table of contents."""
from __future__ import annotations

import math
import re
from datetime import datetime, timedelta, timezone

from pipeline.serve.report.db import ReportDB
from pipeline.serve.report.markup import esc, fmt, run_href
from pipeline.serve.report.tables import html_table

#: Longer lists of changed inputs start folded.
FOLD_INPUT_ROWS = 20
#: Rows of the changed-inputs list (and of the quarantine) shown.
MAX_INPUT_ROWS = 300
#: Findings whose result changed this recently are listed first, in the alert box.
CHANGE_WINDOW = timedelta(hours=24)
#: Changes shown in the alert box (``new data`` is only noted in the findings table).
ALERT_CHANGES = ("overturned", "now holds", "no longer checkable")


def _unit(unit) -> str:
    """A finding's unit as text (none for a plain number)."""
    return "" if unit in (None, "1") else esc(unit)


def _linkify(text, run_ids: set[str]) -> str:
    """Escaped text in which every ``run <id>`` of a known run links to the run's page."""
    out, last = [], 0
    text = "" if text is None else str(text)
    for m in re.finditer(r"\brun ([^\s,;()]+)", text):
        rid = m.group(1).rstrip(".")
        if rid in run_ids:
            out.append(esc(text[last:m.start(1)]) + f'<a href="{esc(run_href(rid))}">{esc(rid)}</a>')
            last = m.start(1) + len(rid)
    return "".join(out) + esc(text[last:])


def _holds_cell(holds) -> str:
    """A finding's result cell: holds, does not hold, no data."""
    if holds is None:
        return '<td class="nodata">no data</td>'
    return '<td class="ok">holds</td>' if holds else '<td class="bad">does not hold</td>'


def _when(at) -> str:
    """A moment in UTC to the second (a dash when there is none)."""
    return fmt(at.astimezone(timezone.utc).replace(microsecond=0)) if isinstance(at, datetime) else "—"


def _change_note(change, at) -> str:
    """A finding's last change and when it was (none without one)."""
    if not change:
        return ""
    return f"<br><b>{esc(change)}</b>" + (f" {_when(at)}" if at is not None else "")


def _p_text(p) -> str:
    """A p-value in one format: four decimals, "< 0.0001" under that (a p of 1e-30 is no more
    meaningful than one of 1e-5)."""
    if not isinstance(p, (int, float)) or isinstance(p, bool) or not math.isfinite(p):
        return "—"
    return "< 0.0001" if p < 5e-5 else f"{p:.4f}"


def findings_section(db: ReportDB, now: datetime) -> tuple[str, str]:
    """(first section: findings whose result changed in the last 24 hours, findings section)."""
    since = now - CHANGE_WINDOW
    window = (f"in the last {CHANGE_WINDOW.total_seconds() / 3600:g} hours "
              f"(since {since.astimezone(timezone.utc):%Y-%m-%d %H:%M} UTC)")
    if not db.has("findings") or db.count("findings") == 0:
        return "", '<section id="findings"><h2>Findings</h2><p class="nodata">no findings table: no data yet</p></section>'
    changed_at = "changed_at" if "changed_at" in db.columns("findings") else "NULL::TIMESTAMPTZ"
    cols, rows = db.rows("SELECT finding_id, statement, measured, uncertainty, unit, criterion, holds, n, p_value, "
                         f"detail, change, previous_holds, {changed_at} FROM findings ORDER BY ord, finding_id")
    changed = [r for r in rows if r[10] in ALERT_CHANGES and r[12] is not None and r[12] >= since]
    return _alert(changed, window), _findings_table(rows, db.run_ids())


def _alert(changed: list[tuple], window: str) -> str:
    """The alert box of the findings whose result changed in the ``window`` (or a line: none did)."""
    if not changed:
        return f'<p class="meta" id="changes">No finding changed its result {esc(window)}.</p>'
    items = "".join(f"<li><b>{esc(r[10])}</b>: {esc(r[1])} (measured {fmt(r[2])}{' ' + _unit(r[4]) if _unit(r[4]) else ''}; "
                    f"changed {_when(r[12])})</li>" for r in changed)
    return (f'<div class="alert" id="overturned"><h2 style="margin-top:0">New data changed '
            f'{len(changed)} finding{"s" if len(changed) != 1 else ""} {esc(window)}</h2><ul>{items}</ul></div>')


def _findings_table(rows: list[tuple], run_ids: set[str]) -> str:
    """The findings section: one row per finding, its result and how it was reached."""
    body = []
    for (fid, statement, measured, unc, unit, criterion, holds, n, p, detail, change, _prev, at) in rows:
        value = "—" if measured is None else fmt(measured) + (f" ± {fmt(unc, 2)}" if unc is not None else "")
        body.append(f"<tr><td><b>{esc(statement)}</b><br><span class=\"meta\">{esc(fid)}</span></td>"
                    f'<td class="num">{value} {_unit(unit)}</td><td>{esc(criterion)}</td>{_holds_cell(holds)}'
                    f'<td class="num">{fmt(n)}</td><td class="num">{esc(_p_text(p))}</td>'
                    f"<td>{_linkify(detail, run_ids)}{_change_note(change, at)}</td></tr>")
    n_hold = sum(1 for r in rows if r[6] is True)
    n_fail = sum(1 for r in rows if r[6] is False)
    n_none = sum(1 for r in rows if r[6] is None)
    return (f'<section id="findings"><h2>Findings of the two papers on the latest data</h2>'
            f'<p class="meta">{n_hold} hold, {n_fail} do not hold, {n_none} without data.</p>'
            "<table><thead><tr><th>finding</th><th>measured ± std. uncertainty</th><th>holds when</th>"
            "<th>result</th><th>n</th><th>p</th><th>how</th></tr></thead><tbody>"
            + "".join(body) + "</tbody></table></section>")


def rebuild_section(db: ReportDB) -> str:
    """The last rebuild: its generation and counts, the quarantined inputs, the files not read and
    the new, changed and deleted inputs."""
    out = ['<section id="rebuild"><h2>Last rebuild</h2>']
    if db.has("rebuild_log") and db.count("rebuild_log"):
        out += _rebuild_counts(db)
    out += _quarantine(db)
    if db.has("rebuild_inputs"):
        out += _changed_inputs(db)
    out.append("</section>")
    return "".join(out)


def _rebuild_counts(db: ReportDB) -> list[str]:
    """The last rebuild's line and its cards (files, runs, new, changed, ...)."""
    cols, rows = db.rows("SELECT generation, finished_at, duration_s, mode, executor, n_files, n_runs, n_new, "
                         "n_changed, n_deleted, n_unchanged, n_quarantined, stages_run, stages_reused "
                         f"FROM rebuild_log ORDER BY {db.log_order()} LIMIT 1")
    r = dict(zip(cols, rows[0]))
    line = (f'<p class="meta">generation {esc(r["generation"])}, finished {fmt(r["finished_at"])}, '
            f'{fmt(r["duration_s"])} s, {esc(r["mode"])} rebuild on the {esc(r["executor"])} executor; '
            f'stages run: {fmt(r["stages_run"]) or "none"}; reused: {fmt(r["stages_reused"]) or "none"}</p>')
    cards = [("run files", r["n_files"]), ("runs", r["n_runs"]), ("new", r["n_new"]), ("changed", r["n_changed"]),
             ("deleted", r["n_deleted"]), ("unchanged", r["n_unchanged"]), ("quarantined", r["n_quarantined"])]
    return [line, '<div class="cards">' + "".join(f'<div class="card"><b>{fmt(v)}</b>{esc(k)}</div>'
                                                  for k, v in cards) + "</div>"]


def _quarantine(db: ReportDB) -> list[str]:
    """The quarantined inputs with their reasons, then the files not read (if any)."""
    out = []
    n_q = db.count("quarantine")
    out.append(f"<h3>Quarantined inputs ({n_q})</h3>")
    if n_q:
        cols, rows = db.rows("SELECT source_path, line, stage, error FROM quarantine ORDER BY source_path, line")
        out.append(html_table(cols, rows, MAX_INPUT_ROWS, n_q))
    else:
        out.append('<p class="meta">none: every input was used</p>')
    n_s = db.count("skipped_files") if db.has("skipped_files") else 0
    if n_s:  # not errors, but a run saved in an unsupported format is missing from every analysis
        cols, rows = db.rows("SELECT source_path, reason FROM skipped_files ORDER BY source_path")
        out.append(f"<h3>Files not read ({n_s})</h3>")
        out.append(html_table(cols, rows, MAX_INPUT_ROWS, n_s))
    return out


def _changed_inputs(db: ReportDB) -> list[str]:
    """The new, changed and deleted inputs of the last rebuild (``rebuild_inputs``), folded when long."""
    n = db.con.execute("SELECT count(*) FROM rebuild_inputs WHERE status <> 'unchanged'").fetchone()[0]
    per = db.con.execute("SELECT status, count(*) FROM rebuild_inputs WHERE status <> 'unchanged' "
                         "GROUP BY status ORDER BY status").fetchall()
    cols, rows = db.rows("SELECT status, role, source_path, reason, run_id, kind FROM rebuild_inputs "
                         "WHERE status <> 'unchanged' ORDER BY status, source_path")
    counts = ", ".join(f"{c} {esc(st)}" for st, c in per) or "nothing changed"
    # A long list (the first build of a campaign) is folded so the results stay in view.
    opened = " open" if n <= FOLD_INPUT_ROWS else ""
    return [f"<details{opened}><summary><b>New, changed and deleted inputs ({n})</b>: {counts}</summary>",
            html_table(cols, rows, MAX_INPUT_ROWS, n, links=db.run_ids()) if rows
            else '<p class="meta">nothing changed</p>',
            "</details>"]


def rebuild_line(db: ReportDB) -> str:
    """The header's line on the last rebuild: when, runs, new, changed, deleted, quarantined."""
    if not (db.has("rebuild_log") and db.count("rebuild_log")):
        return ""
    r = db.con.execute("SELECT finished_at, n_runs, n_new, n_changed, n_deleted, n_quarantined FROM rebuild_log "
                       f"ORDER BY {db.log_order()} LIMIT 1").fetchone()
    return (f'Last rebuild {fmt(r[0])}: {fmt(r[1])} runs, {fmt(r[2])} new, {fmt(r[3])} changed, {fmt(r[4])} deleted, '
            f'<a href="#rebuild">{fmt(r[5])} quarantined</a>.')


def toc(entries: list) -> str:
    """The table of contents: ``(anchor, title, [(anchor, title), ...])`` per entry."""
    items = []
    for anchor, title, sub in entries:
        inner = "".join(f'<li><a href="#{esc(a)}">{esc(t)}</a></li>' for a, t in sub)
        items.append(f'<li><a href="#{esc(anchor)}">{esc(title)}</a>' + (f"<ul>{inner}</ul>" if inner else "") + "</li>")
    return f'<nav class="toc" id="toc"><b>Contents</b><ul>{"".join(items)}</ul></nav>'
