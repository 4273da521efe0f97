"""The morning report: ``warehouse/report/index.html``, one self-contained static page, and a
small page per run beside it (``report/runs/<safe id>.html``).

Built from the warehouse database alone (read-only), so ``pneubench report`` can rebuild it at
any time. It reads like a results section: a table of contents; findings whose result changed
in the last 24 hours (``findings.changed_at``; an overturned one stays there through further
rebuilds that night); the findings; per paper (:data:`LAYOUT`) each figure with the summary a
reader compares it to and the paper's tables beside the lab's values (:data:`PAPER`: paper value,
measured value with its standard uncertainty, difference), the rows behind them folded with a
CSV download, each figure on a row of its own (drawn near its full size); other figures, when a
figure belongs to no paper; the last rebuild (new, changed, deleted and quarantined inputs with
their reasons); and every run. Column headers carry the unit of the column's suffix, a column of
numbers keeps one format chosen from its range (:func:`column_format`), a leak under its flow
sensor's floor reads "< floor" (:data:`FLOORED_COLUMNS`; the stored value stays), every run id
links to its page (channels drawn by
:mod:`pipeline.serve.run_pages`, metadata, warnings, the results derived from it; a page is redrawn
only when its inputs changed). Figures and downloads are embedded as data: URIs, the style is
inline and there is no script: the files open from disk anywhere. Every piece of text is
escaped (``html.escape``): run metadata, file names and quarantine reasons come from raw/.

The report is never silently stale. The rebuild renders it from the new database before the
swap, so a report that cannot be rendered fails the rebuild (exit 3): the previous warehouse
and its report stay, and they agree. ``pneubench report`` (``write_report``) replaces a page it
cannot render with a short page saying so, with the error, and raises :class:`ReportError`.
The index and its run pages are one folder, published whole with the database (``report`` is a
symlink to it, replaced by one rename: :func:`stage_report`, :func:`publish_report`).
"""
from __future__ import annotations

import base64
import html
import json
import math
import os
import re
from datetime import datetime, timedelta, timezone
from pathlib import Path

from schemas.papers import PLA_CITATION, PLPA_CITATION
from pipeline.serve.door import connect_readonly
from schemas.units import COLUMN_UNITS, display_sensors_text

MAX_ROWS = 30          # rows of a key table shown
FOLD_INPUT_ROWS = 20   # longer lists of changed inputs start folded
MAX_INPUT_ROWS = 300   # rows of the changed-inputs list shown
#: Findings whose result changed this recently are listed first, in the alert box.
CHANGE_WINDOW = timedelta(hours=24)
#: Changes shown in the alert box (``new data`` is only noted in the findings table).
ALERT_CHANGES = ("overturned", "now holds", "no longer checkable")



class ReportError(Exception):
    """The report could not be rendered. ``error``: one line; ``page``: the failure page written
    in place of ``index.html`` (None when even that failed, after removing the stale one)."""

    def __init__(self, error: str, page: Path | None):
        super().__init__(error)
        self.error = error
        self.page = page


def _now() -> datetime:
    """The report's clock (tests replace it)."""
    return datetime.now(timezone.utc)

CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0 auto;max-width:1180px;padding:0 20px 40px;color:#1d2330;line-height:1.4}
h1{font-size:1.6em;margin:20px 0 4px}h2{border-bottom:2px solid #d8dce4;padding-bottom:4px;margin-top:34px}
h3{margin:26px 0 6px}h4{margin:14px 0 4px}.meta{color:#5b6475;font-size:.92em}
table{border-collapse:collapse;margin:8px 0 14px;font-size:.84em}th,td{border:1px solid #d8dce4;padding:3px 7px;text-align:left;vertical-align:top}
th{background:#f1f3f7;font-weight:600}th small{font-weight:400;color:#5b6475;white-space:nowrap}td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
.wrap{overflow-x:auto;max-width:100%}
.ok{background:#e3f5e6;color:#16632a;font-weight:600}.bad{background:#fde4e4;color:#9b1c1c;font-weight:600}
.nodata{background:#eef0f3;color:#5b6475}.alert{border:2px solid #c62828;background:#fff3f3;padding:10px 16px;margin:16px 0}
.cards{display:flex;gap:12px;flex-wrap:wrap}.card{border:1px solid #d8dce4;border-radius:6px;padding:8px 14px;min-width:110px}
.card b{display:block;font-size:1.5em}figure{margin:14px 0}figure img{max-width:100%;border:1px solid #d8dce4}
figcaption{color:#3a4252;font-size:.92em;margin-top:4px}.more{color:#5b6475;font-style:italic}
nav.toc{border:1px solid #d8dce4;background:#f8f9fb;padding:8px 18px;margin:14px 0;columns:2;column-gap:30px;font-size:.92em}
nav.toc ul{margin:2px 0;padding-left:18px}nav.toc>ul{padding-left:0;list-style:none}nav.toc li{break-inside:avoid}
details{margin:6px 0 12px}summary{cursor:pointer;color:#2a4d8f}a{color:#2a4d8f}
td.diff-ok{color:#16632a}td.diff-bad{color:#9b1c1c;font-weight:600}
"""


def esc(value) -> str:
    """Any value as escaped HTML text."""
    return html.escape("" if value is None else str(value), quote=True)


def fmt(value, sig: int = 4) -> str:
    """A cell: numbers to ``sig`` significant digits (no float noise), NULL as an em dash; escaped."""
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        if math.isnan(value):
            return "—"
        return esc(_num(value, sig))
    if isinstance(value, datetime):
        return esc(value.strftime("%Y-%m-%d %H:%M:%S %Z").strip())
    if isinstance(value, (list, tuple)):
        return esc(", ".join(str(v) for v in value))
    return esc(value)


def _num(value: float, sig: int = 4) -> str:
    """A float to ``sig`` significant digits: 19.999999999999982 -> 20, 0.0001541 -> 1.541e-04."""
    if value == 0:
        return "0"
    if 1e-3 <= abs(value) < 1e6:
        digits = max(sig - 1 - math.floor(math.log10(abs(value))), 0)
        text = f"{value:.{digits}f}"
        return text.rstrip("0").rstrip(".") if "." in text else text
    return f"{value:.{sig - 1}e}"


#: Column-name suffixes and the unit they mean (warehouse convention: names end in their unit),
#: longest first: the short forms of the one table, :data:`schemas.units.COLUMN_UNITS`.
UNIT_SUFFIXES = tuple((s, u[1]) for s, u in sorted(COLUMN_UNITS.items(), key=lambda kv: -len(kv[0])))


def split_unit(column: str) -> tuple[str, str]:
    """(name in words, unit) of a warehouse column: ``leak_l_min`` -> (``leak``, ``l/min``)."""
    for suffix, unit in UNIT_SUFFIXES:
        if column.endswith(suffix) and len(column) > len(suffix):
            return column[: -len(suffix)].replace("_", " "), unit
    return column.replace("_", " "), ""


def _th(column: str) -> str:
    name, unit = split_unit(column)
    return f"<th>{esc(name)}" + (f"<br><small>[{esc(unit)}]</small>" if unit else "") + "</th>"


def run_href(run_id: str, prefix: str = "runs/") -> str:
    """Relative link of a run's page (``report/runs/<safe id>.html``)."""
    from pipeline.serve.run_pages import page_name

    return prefix + page_name(run_id)


def _cell(column: str, value, links, number=None) -> str:
    if column == "run_id" and isinstance(value, str) and (links is True or (links and value in links)):
        return f'<td><a href="{esc(run_href(value))}">{esc(value)}</a></td>'
    if column == "sensors" and isinstance(value, str):  # stored in SI; shown in the report's units
        return f"<td>{esc(display_sensors_text(value))}</td>"
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return f'<td class="num">{esc(number(value)) if number is not None else fmt(value)}</td>'
    return f"<td>{fmt(value)}</td>"


#: Leak columns that read "< floor" where their value is under the flow sensor's floor (the stored
#: value stays as it is): a mean leak that small, or negative, is the sensor's own scatter.
FLOORED_COLUMNS = ("leak_l_min", "leak_at_5_bar_l_min", "leak_at_6_bar_l_min")
#: A row's floor of :data:`FLOORED_COLUMNS`: this column when the row has it, else the flow sensor
#: stated in its ``sensors`` text (``leakage_map``).
FLOOR_COLUMN = "leak_floor_l_min"
_FLOW_SENSOR = re.compile(r"q_leak: resolution (\S+), noise (\S+) \([^)]*\) kg/s")


def flow_floor_l_min(sensors) -> float | None:
    """Floor of the leak-flow sensor a ``leakage_map.sensors`` text states, in l/min ANR: the
    larger of its resolution and noise (:meth:`analyses.quality.Sensor.floor`); None without one."""
    from schemas.units import kg_s_to_l_min_anr

    m = _FLOW_SENSOR.search(sensors) if isinstance(sensors, str) else None
    try:
        floor = max(float(m.group(1)), float(m.group(2))) if m else math.nan
    except ValueError:
        return None
    return float(kg_s_to_l_min_anr(floor)) if math.isfinite(floor) and floor > 0 else None


#: A column shows at most this many decimals more than its largest value needs for its digits.
MORE_DECIMALS = 1


def column_format(values, sig: int = 4):
    """One number format for a column (a function float -> text), chosen from its range: fixed
    notation with the decimals its values need for ``sig`` significant digits each (fewer when they
    show the same with fewer; at most :data:`MORE_DECIMALS` past what the largest needs), or
    scientific notation throughout when the largest is under 1e-3 or from 1e6 up. Integers print
    whole; "-0.00" prints "0.00"."""
    finite = [abs(float(v)) for v in values if isinstance(v, float) and math.isfinite(v)]
    hi = max(finite, default=0.0)
    if hi == 0:
        return lambda v: _num(v, sig) if isinstance(v, float) else str(v)
    if not 1e-3 <= hi < 1e6:
        return lambda v: (str(v) if not isinstance(v, float) else "—" if math.isnan(v)
                          else "0" if v == 0 else f"{v:.{sig - 1}e}")
    top = max(sig - 1 - math.floor(math.log10(hi)), 0)
    # as many decimals as the values need to show their own ``sig`` digits (3.5 beside 1300 keeps its
    # .5), at most MORE_DECIMALS past what the largest needs: a value far under the largest is noise there
    need = max((sig - 1 - math.floor(math.log10(v)) for v in finite if v), default=0)
    limit = max(0, min(need, top + MORE_DECIMALS))
    shown = [float(f"{float(_num(v, sig)):.{limit}f}") for v in finite]
    decimals = next(d for d in range(limit + 1) if all(float(f"{v:.{d}f}") == v for v in shown))

    def number(v) -> str:
        if not isinstance(v, float):
            return str(v)
        if not math.isfinite(v):
            return "—" if math.isnan(v) else str(v)
        text = f"{v:.{decimals}f}"
        return text.lstrip("-") if float(text) == 0 else text
    number.decimals = decimals
    return number


def _row_floor(columns: list[str], row: tuple) -> float | None:
    if FLOOR_COLUMN in columns:
        v = row[columns.index(FLOOR_COLUMN)]
        return float(v) if isinstance(v, (int, float)) and math.isfinite(v) and v > 0 else None
    return flow_floor_l_min(row[columns.index("sensors")]) if "sensors" in columns else None


def _under_floor(value, floor) -> bool:
    return floor is not None and isinstance(value, (int, float)) and not isinstance(value, bool) \
        and math.isfinite(value) and abs(value) < floor


def _floor_text(floor: float, number) -> str:
    """``< floor``, the floor rounded up to the column's decimals (at least one significant digit)."""
    decimals = getattr(number, "decimals", None)
    if decimals is None:
        return "< " + _num(floor, 1)
    d = max(decimals, -math.floor(math.log10(floor)))
    return f"< {math.ceil(floor * 10 ** d - 1e-9) / 10 ** d:.{d}f}"


def html_table(columns: list[str], rows: list[tuple], max_rows: int = MAX_ROWS, total: int | None = None,
               links: bool | set = True) -> str:
    """Rows as a table: units from the column names in the headers, run ids linked to run pages
    (``links``: True for every run id, or the set of ids that have a page)."""
    if not rows:
        return '<p class="more">no rows</p>'
    head = "".join(_th(c) for c in columns)
    shown = rows[:max_rows]
    floors = [_row_floor(columns, r) for r in shown] if any(c in FLOORED_COLUMNS for c in columns) else [None] * len(shown)
    numbers = []  # one format per column, from the values it shows as numbers
    for j, c in enumerate(columns):
        values = [r[j] for r, f in zip(shown, floors) if not (c in FLOORED_COLUMNS and _under_floor(r[j], f))]
        numbers.append(column_format(values) if any(isinstance(v, float) for v in values) else None)
    body = []
    for r, floor in zip(shown, floors):
        cells = [f'<td class="num">{esc(_floor_text(floor, n))}</td>' if c in FLOORED_COLUMNS and _under_floor(v, floor)
                 else _cell(c, v, links, n) for c, v, n in zip(columns, r, numbers)]
        body.append("<tr>" + "".join(cells) + "</tr>")
    total = len(rows) if total is None else total
    more = f'<p class="more">{total - max_rows} more rows: query the warehouse</p>' if total > max_rows else ""
    return (f'<div class="wrap"><table><thead><tr>{head}</tr></thead><tbody>{"".join(body)}</tbody>'
            f"</table></div>{more}")


class _DB:
    def __init__(self, con):
        self.con = con
        self.tables = {r[0] for r in con.execute(
            "SELECT table_name FROM duckdb_tables() UNION SELECT view_name FROM duckdb_views() "
            "WHERE NOT internal").fetchall()}

    def has(self, table: str) -> bool:
        return table in self.tables

    def run_ids(self) -> set[str]:
        """Run ids of the warehouse (each has a page)."""
        if not hasattr(self, "_run_ids"):
            self._run_ids = ({r[0] for r in self.con.execute("SELECT run_id FROM runs").fetchall()}
                             if self.has("runs") else set())
        return self._run_ids

    def rows(self, sql: str, params=None) -> tuple[list[str], list[tuple]]:
        cur = self.con.execute(sql, params or [])
        return [d[0] for d in cur.description], cur.fetchall()

    def columns(self, table: str) -> list[str]:
        return [r[0] for r in self.con.execute(f'DESCRIBE "{table}"').fetchall()] if self.has(table) else []

    def count(self, table: str) -> int:
        return self.con.execute(f'SELECT count(*) FROM "{table}"').fetchone()[0] if self.has(table) else 0


def _unit(unit) -> str:
    return "" if unit in (None, "1") else esc(unit)


def _linkify(text, run_ids: set[str]) -> str:
    """Escaped text in which every ``run <id>`` of a known run links to the run's page."""
    import re

    out, last = [], 0
    text = "" if text is None else str(text)
    for m in re.finditer(r"\brun ([^\s,;()]+)", text):
        rid = m.group(1).rstrip(".")
        if rid in run_ids:
            out.append(esc(text[last:m.start(1)]) + f'<a href="{esc(run_href(rid))}">{esc(rid)}</a>')
            last = m.start(1) + len(rid)
    return "".join(out) + esc(text[last:])


def _holds_cell(holds) -> str:
    if holds is None:
        return '<td class="nodata">no data</td>'
    return '<td class="ok">holds</td>' if holds else '<td class="bad">does not hold</td>'


def _when(at) -> str:
    return fmt(at.astimezone(timezone.utc).replace(microsecond=0)) if isinstance(at, datetime) else "—"


def _change_note(change, at) -> str:
    if not change:
        return ""
    return f"<br><b>{esc(change)}</b>" + (f" {_when(at)}" if at is not None else "")


def _p_text(p) -> str:
    """A p-value in one format: four decimals, "< 0.0001" under that (a p of 1e-30 is no more
    meaningful than one of 1e-5)."""
    if not isinstance(p, (int, float)) or isinstance(p, bool) or not math.isfinite(p):
        return "—"
    return "< 0.0001" if p < 5e-5 else f"{p:.4f}"


def _findings_section(db: _DB, now: datetime) -> tuple[str, str]:
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
    if changed:
        items = "".join(f"<li><b>{esc(r[10])}</b>: {esc(r[1])} (measured {fmt(r[2])}{' ' + _unit(r[4]) if _unit(r[4]) else ''}; "
                        f"changed {_when(r[12])})</li>" for r in changed)
        alert = (f'<div class="alert" id="overturned"><h2 style="margin-top:0">New data changed '
                 f'{len(changed)} finding{"s" if len(changed) != 1 else ""} {esc(window)}</h2><ul>{items}</ul></div>')
    else:
        alert = f'<p class="meta" id="changes">No finding changed its result {esc(window)}.</p>'
    body = []
    for (fid, statement, measured, unc, unit, criterion, holds, n, p, detail, change, _prev, at) in rows:
        value = "—" if measured is None else fmt(measured) + (f" ± {fmt(unc, 2)}" if unc is not None else "")
        body.append(f"<tr><td><b>{esc(statement)}</b><br><span class=\"meta\">{esc(fid)}</span></td>"
                    f'<td class="num">{value} {_unit(unit)}</td><td>{esc(criterion)}</td>{_holds_cell(holds)}'
                    f'<td class="num">{fmt(n)}</td><td class="num">{esc(_p_text(p))}</td>'
                    f"<td>{_linkify(detail, db.run_ids())}{_change_note(change, at)}</td></tr>")
    n_hold = sum(1 for r in rows if r[6] is True)
    n_fail = sum(1 for r in rows if r[6] is False)
    n_none = sum(1 for r in rows if r[6] is None)
    section = (f'<section id="findings"><h2>Findings of the two papers on the latest data</h2>'
               f'<p class="meta">{n_hold} hold, {n_fail} do not hold, {n_none} without data.</p>'
               "<table><thead><tr><th>finding</th><th>measured ± std. uncertainty</th><th>holds when</th>"
               "<th>result</th><th>n</th><th>p</th><th>how</th></tr></thead><tbody>"
               + "".join(body) + "</tbody></table></section>")
    return alert, section


def _log_order(db: _DB) -> str:
    """``rebuild_log``'s last rebuild first: by its number, never by wall time (a clock set back)."""
    from pipeline.rebuild.state import log_order

    return log_order(db.columns("rebuild_log"))


def _rebuild_section(db: _DB) -> str:
    out = ['<section id="rebuild"><h2>Last rebuild</h2>']
    if db.has("rebuild_log") and db.count("rebuild_log"):
        cols, rows = db.rows("SELECT generation, finished_at, duration_s, mode, executor, n_files, n_runs, n_new, "
                             "n_changed, n_deleted, n_unchanged, n_quarantined, stages_run, stages_reused "
                             f"FROM rebuild_log ORDER BY {_log_order(db)} LIMIT 1")
        r = dict(zip(cols, rows[0]))
        out.append(f'<p class="meta">generation {esc(r["generation"])}, finished {fmt(r["finished_at"])}, '
                   f'{fmt(r["duration_s"])} s, {esc(r["mode"])} rebuild on the {esc(r["executor"])} executor; '
                   f'stages run: {fmt(r["stages_run"]) or "none"}; reused: {fmt(r["stages_reused"]) or "none"}</p>')
        cards = [("run files", r["n_files"]), ("runs", r["n_runs"]), ("new", r["n_new"]), ("changed", r["n_changed"]),
                 ("deleted", r["n_deleted"]), ("unchanged", r["n_unchanged"]), ("quarantined", r["n_quarantined"])]
        out.append('<div class="cards">' + "".join(f'<div class="card"><b>{fmt(v)}</b>{esc(k)}</div>'
                                                   for k, v in cards) + "</div>")
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
    if db.has("rebuild_inputs"):
        n = db.con.execute("SELECT count(*) FROM rebuild_inputs WHERE status <> 'unchanged'").fetchone()[0]
        per = db.con.execute("SELECT status, count(*) FROM rebuild_inputs WHERE status <> 'unchanged' "
                             "GROUP BY status ORDER BY status").fetchall()
        cols, rows = db.rows("SELECT status, role, source_path, reason, run_id, kind FROM rebuild_inputs "
                             "WHERE status <> 'unchanged' ORDER BY status, source_path")
        counts = ", ".join(f"{c} {esc(st)}" for st, c in per) or "nothing changed"
        # A long list (the first build of a campaign) is folded so the results stay in view.
        opened = " open" if n <= FOLD_INPUT_ROWS else ""
        out.append(f"<details{opened}><summary><b>New, changed and deleted inputs ({n})</b>: {counts}</summary>")
        out.append(html_table(cols, rows, MAX_INPUT_ROWS, n, links=db.run_ids()) if rows
                   else '<p class="meta">nothing changed</p>')
        out.append("</details>")
    out.append("</section>")
    return "".join(out)


# -- raw rows: folded, with the whole table as a CSV download ------------------------------------------
#: Tables up to this many rows come with a CSV download (a data: URI); longer ones say how to query them.
CSV_MAX_ROWS = 20_000


def _csv_uri(columns: list[str], rows: list[tuple]) -> str:
    import csv
    import io

    from pipeline.serve.formats import neutralise_cell

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([neutralise_cell(c) for c in columns])
    for r in rows:  # text a spreadsheet would run as a formula (a run id "=HYPERLINK(...)") made inert
        w.writerow(["" if v is None else (repr(v) if isinstance(v, float) else
                                          neutralise_cell(";".join(map(str, v)) if isinstance(v, (list, tuple)) else v))
                    for v in r])
    return "data:text/csv;charset=utf-8;base64," + base64.b64encode(buf.getvalue().encode("utf-8")).decode("ascii")


def _raw_rows(db: _DB, table: str, what: str = "") -> str:
    """A table's rows behind ``<details>`` (first :data:`MAX_ROWS`), with a CSV of all of them."""
    if not db.has(table):
        return ""
    n = db.count(table)
    if n <= CSV_MAX_ROWS:
        cols, rows = db.rows(f'SELECT * FROM "{table}"')
        dl = (f' · <a download="{esc(table)}.csv" href="{_csv_uri(cols, rows)}">download all {n} rows as CSV</a>'
              if rows else "")
    else:
        cols, rows = db.rows(f'SELECT * FROM "{table}" LIMIT {MAX_ROWS}')
        dl = f' · {n} rows: <code>pneubench query "SELECT * FROM {esc(table)}"</code>'
    return (f'<details class="raw" id="raw-{esc(table)}"><summary><b>{esc(table)}</b> ({n} rows){esc(what)}{dl}'
            f"</summary>{html_table(cols, rows, MAX_ROWS, n)}</details>")


def _img(warehouse: Path, rel: str) -> str:
    path = (warehouse / rel).resolve()
    if warehouse.resolve() not in path.parents or not path.is_file():
        return '<p class="nodata">figure file missing</p>'
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return f'<img alt="{esc(Path(rel).stem)}" src="data:image/png;base64,{data}">'


def _stage_tables() -> dict[str, tuple[list[str], dict]]:
    """Per stage: its TABLES and optional KEY_TABLES (figure name -> table)."""
    try:
        from pipeline import stages
        return {m.NAME: (list(getattr(m, "TABLES", ())), dict(getattr(m, "KEY_TABLES", {}) or {}))
                for m in stages.discover()}
    except Exception:
        return {}


def _key_table(fig: str, stage: str, stage_tables: dict, db: _DB) -> str | None:
    tables, keys = stage_tables.get(stage, ([], {}))
    if fig in keys:
        return keys[fig]
    for t in sorted(tables, key=len, reverse=True):
        if t in fig or fig in t:
            return t
    return next((t for t in tables if db.has(t)), None)


# -- the papers' numbers next to the lab's ------------------------------------------------------------
#: Values printed in the seed papers (docs/physics.md marks them *paper*).
PAPER = {
    "plpa_table2": {"wn_rad_s": 16.7, "zeta": 0.51, "k_lin_m_v_s": 0.82},
    "plpa_fig12": {"mean_0bar_n": 10.0, "mean_ge1bar_n": 5.0, "ratio": 2.0, "rate_slope": 0.0},
    "plpa_fig15": {"overshoot_pct": 1.2, "settling_time_s": 4.0, "steady_state_error_mm": 0.0},
    "pla_table1": {"front": {"n_polytropic": 1.123, "ae_m2": 1.541e-3, "epsilon_m2": 2.143e-5, "delta_n_m": 3.509e3},
                   "rear": {"n_polytropic": 1.063, "ae_m2": 1.795e-3, "epsilon_m2": 2.136e-5, "delta_n_m": 2.963e3}},
    "pla_table2": {"charge": {"wn_rad_s": 52.0, "zeta": 1.00}, "discharge": {"wn_rad_s": 52.0, "zeta": 0.69}},
    "pla_table3": {"nrmse_min_pct": 1.16, "nrmse_max_pct": 2.39, "bound_pct": 2.5},
}


def _mean_se(values) -> tuple[float | None, float | None, int]:
    v = [float(x) for x in values if x is not None and not (isinstance(x, float) and math.isnan(x))]
    if not v:
        return None, None, 0
    m = sum(v) / len(v)
    if len(v) < 2:
        return m, None, 1
    sd = math.sqrt(sum((x - m) ** 2 for x in v) / (len(v) - 1))
    return m, sd / math.sqrt(len(v)), len(v)


NUM_CELL = ' class="num"'


def _cmp_row(label: str, unit: str, paper, measured, unc, how: str = "", judge: bool = True) -> str:
    """One row of a paper-vs-lab table: paper value, measured ± uncertainty, difference."""
    m = "—" if measured is None else fmt(measured) + (f" ± {fmt(unc, 2)}" if unc is not None else "")
    if paper is None or measured is None:
        diff, cls = "—", ""
    else:
        d = measured - paper
        rel = f" ({100 * d / paper:+.1f} %)" if paper else ""
        diff = f"{'+' if d >= 0 else ''}{fmt(d, 3)}{rel}"
        # green: within 2 standard uncertainties or 5 % of the paper; red: further; plain for a paper value of
        # zero (no scale to judge a difference by: the sensor's resolution is on the run pages)
        if not paper or not judge:
            cls = ""
        elif (unc is not None and abs(d) <= 2 * unc) or (paper and abs(d / paper) < 0.05):
            cls = ' class="num diff-ok"'
        else:
            cls = ' class="num diff-bad"'
    return (f"<tr><td>{esc(label)}</td><td>{esc(unit)}</td><td class=\"num\">{'—' if paper is None else fmt(paper)}</td>"
            f'<td class="num">{m}</td><td{cls or NUM_CELL}>{diff}</td><td>{esc(how)}</td></tr>')


def _cmp_table(caption: str, rows: list[str]) -> str:
    return (f'<div class="wrap"><table class="paper"><caption style="text-align:left;font-weight:600;padding:4px 0">'
            f"{esc(caption)}</caption><thead><tr><th>quantity</th><th>unit</th><th>paper</th>"
            "<th>measured ± std. uncertainty</th><th>difference<br><small>measured − paper</small></th>"
            f"<th>from</th></tr></thead><tbody>{''.join(rows)}</tbody></table></div>")


def _q(db: _DB, sql: str, *tables: str) -> list[tuple]:
    if not all(db.has(t) for t in tables):
        return []
    return db.con.execute(sql).fetchall()


def _summary_identification(db: _DB) -> str:
    rows = _q(db, "SELECT wn_rad_s, zeta, k_lin_m_v_s FROM identification", "identification")
    if not rows:
        return ""
    out = []
    for k, (col, label, unit) in enumerate((("wn_rad_s", "natural frequency ωn", "rad/s"),
                                           ("zeta", "damping ratio ζ", ""),
                                           ("k_lin_m_v_s", "gain k_lin", "m/(V s)"))):
        m, se, n = _mean_se([r[k] for r in rows])
        out.append(_cmp_row(label, unit, PAPER["plpa_table2"][col], m, se,
                            f"mean of {n} identification run{'s' if n != 1 else ''} ± s.e."))
    return _cmp_table("PLPA Table 2: identified plant parameters, paper vs lab", out)


def _summary_breakaway(db: _DB) -> str:
    out = []
    r0 = _q(db, "SELECT breakaway_force_n FROM breakaway WHERE backpressure_bar < 0.5", "breakaway")
    r1 = _q(db, "SELECT breakaway_force_n FROM breakaway WHERE backpressure_bar >= 0.5", "breakaway")
    for label, rows, key in (("breakaway force at 0 bar backpressure", r0, "mean_0bar_n"),
                             ("breakaway force at ≥ 1 bar backpressure", r1, "mean_ge1bar_n")):
        m, se, n = _mean_se([r[0] for r in rows])
        if n:
            out.append(_cmp_row(label, "N", PAPER["plpa_fig12"][key], m, se, f"mean of {n} events ± s.e."))
    f = {r[0]: r[1:] for r in _q(db, "SELECT finding, estimate, ci_low, ci_high, confidence, n FROM breakaway_findings "
                                      "WHERE direction = 'all'", "breakaway_findings")}
    for key, label, unit, paper in (("backpressure_ratio", "ratio 0 bar / ≥ 1 bar", "", PAPER["plpa_fig12"]["ratio"]),
                                    ("force_rate_slope", "effect of the force rate (slope)", "N per N/s",
                                     PAPER["plpa_fig12"]["rate_slope"])):
        if key in f and f[key][0] is not None:
            est, lo, hi, conf, n = f[key]
            se = (hi - lo) / (2 * 1.96) if lo is not None and hi is not None else None
            out.append(_cmp_row(label, unit, paper, est, se,
                                f"breakaway_findings, {n} events; {100 * (conf or 0.95):.0f} % CI "
                                f"{fmt(lo, 3)}–{fmt(hi, 3)}" if lo is not None else "breakaway_findings"))
    if not out:
        return ""
    table = _cmp_table("PLPA Fig. 12: breakaway forces, paper vs lab (paper: about twice at 0 bar, no rate effect)", out)
    summary = _q(db, "SELECT backpressure_bar, direction, sum(n) AS n, sum(n * mean_force_n) / sum(n) AS mean_force_n, "
                     "max(std_force_n) AS largest_std_force_n FROM breakaway_summary GROUP BY ALL ORDER BY 1, 2",
                 "breakaway_summary")
    cols = ["backpressure_bar", "direction", "n", "mean_force_n", "largest_std_force_n"]
    return table + ("<h4>Mean breakaway force per backpressure and direction (all rates)</h4>"
                    + html_table(cols, summary, 40) if summary else "")


def _summary_step(db: _DB) -> str:
    rows = _q(db, "SELECT overshoot_pct, settling_time_s, steady_state_error_mm FROM step_response", "step_response")
    if not rows:
        return ""
    out = []
    for k, (col, label, unit) in enumerate((("overshoot_pct", "overshoot", "%"),
                                           ("settling_time_s", "settling time (2 % band)", "s"),
                                           ("steady_state_error_mm", "steady-state error", "mm"))):
        m, se, n = _mean_se([r[k] for r in rows])
        out.append(_cmp_row(label, unit, PAPER["plpa_fig15"][col], m, se, f"mean of {n} steps ± s.e."))
    return _cmp_table("PLPA Fig. 15: closed-loop 20 mm step under PID, paper vs lab "
                      "(paper: about 1.2 % overshoot, about 4 s to the 2 % band, zero steady-state error)", out)


def _summary_leakage(db: _DB) -> str:
    """Seal pressure and leak at 5 and 6 bar per roller setting, from characterisation runs only
    (runs naming a hose are worn-hose checks and are left out)."""
    if not db.has("leakage_map"):
        return ""
    hose = "coalesce(hose_id, '') = ''" if "hose_id" in db.columns("leakage_map") else "true"
    sensors = "sensors" if "sensors" in db.columns("leakage_map") else "NULL::VARCHAR"
    env = db.has("seal_envelope")
    sql = f"""
        WITH m AS (SELECT chamber, adjustment, z_rollers_mm, spring_force_n, run_id, leak_l_min,
                          {sensors} AS sensors, round(pressure_bar) AS nominal_bar FROM leakage_map WHERE {hose}),
        s AS (SELECT chamber, adjustment, z_rollers_mm, spring_force_n,
                     avg(leak_l_min) FILTER (WHERE nominal_bar = 5) AS leak_at_5_bar_l_min,
                     avg(leak_l_min) FILTER (WHERE nominal_bar = 6) AS leak_at_6_bar_l_min,
                     list(DISTINCT sensors) FILTER (WHERE nominal_bar IN (5, 6)) AS leak_floor_l_min,
                     count(DISTINCT run_id) AS n_runs
              FROM m GROUP BY ALL)
        SELECT s.chamber, s.adjustment, coalesce(s.z_rollers_mm, s.spring_force_n) AS setting,
               CASE WHEN s.adjustment = 'distance' THEN 'mm' ELSE 'N' END AS setting_unit,
               {'e.sealed_up_to_bar, e.first_leak_bar,' if env else ''}
               s.leak_at_5_bar_l_min, s.leak_at_6_bar_l_min, s.leak_floor_l_min, s.n_runs
        FROM s {'LEFT JOIN seal_envelope e ON e.chamber = s.chamber AND e.adjustment = s.adjustment AND '
                'e.z_rollers_mm IS NOT DISTINCT FROM s.z_rollers_mm AND '
                'e.spring_force_n IS NOT DISTINCT FROM s.spring_force_n' if env else ''}
        ORDER BY s.chamber, s.adjustment, setting"""
    cols, rows = db.rows(sql)
    if not rows:
        return ""
    # the floor of a mean over runs: the coarsest flow sensor among them (leak cells under it read "< floor")
    j = cols.index(FLOOR_COLUMN)
    rows = [(*r[:j], max((f for t in (r[j] or []) if (f := flow_floor_l_min(t)) is not None), default=None), *r[j + 1:])
            for r in rows]
    return ("<h4>Seal and leak per roller setting (characterisation runs only; worn-hose checks left out)</h4>"
            + html_table(cols, rows, 60))


def _summary_viscous(db: _DB) -> str:
    if not db.has("viscous_fits"):
        return ""
    want = [c for c in ("backpressure_bar", "direction", "coulomb_n", "coulomb_se_n", "viscous_n_s_m",
                        "viscous_se_n_s_m", "nrmse_pct", "n_points", "note") if c in db.columns("viscous_fits")]
    cols, rows = db.rows(f"SELECT {', '.join(want)} FROM viscous_fits ORDER BY backpressure_bar, direction")
    out = "<h4>Coulomb + viscous fit per backpressure and direction</h4>" + html_table(cols, rows, 40)
    if db.has("viscous_transition") and db.count("viscous_transition"):
        vt = [c for c in ("backpressure_bar", "transition_velocity_mm_s", "stribeck_amplitude_n",
                          "stribeck_p_value", "stribeck_dip", "n_points") if c in db.columns("viscous_transition")]
        cols, rows = db.rows(f"SELECT {', '.join(vt)} FROM viscous_transition ORDER BY backpressure_bar")
        out += "<h4>Near zero velocity: tanh transition and Stribeck test</h4>" + html_table(cols, rows, 20)
    return out


def _summary_spring(db: _DB) -> str:
    out = ""
    fits = {r[0]: r[1:] for r in _q(db, "SELECT chamber, n_polytropic, ae_m2, epsilon_m2, delta_n_m, n_tests "
                                        "FROM spring_fits", "spring_fits")}
    se_cols = {c: next((x for x in db.columns("spring_fits") if x.startswith(c.split("_")[0] + "_se")), None)
               for c in ("n_polytropic", "ae_m2", "epsilon_m2", "delta_n_m")}
    rows = []
    labels = {"n_polytropic": ("polytropic index n", ""), "ae_m2": ("effective area Ae", "m²"),
              "epsilon_m2": ("ε (Coulomb-like term)", "m²"), "delta_n_m": ("δ (structural damping)", "N/m")}
    for chamber in ("front", "rear"):
        if chamber not in fits:
            continue
        ses = {}
        for c, sc in se_cols.items():
            if sc:
                ses[c] = db.con.execute(f'SELECT "{sc}" FROM spring_fits WHERE chamber = ?', [chamber]).fetchone()[0]
        for k, c in enumerate(("n_polytropic", "ae_m2", "epsilon_m2", "delta_n_m")):
            label, unit = labels[c]
            rows.append(_cmp_row(f"{chamber}: {label}", unit, PAPER["pla_table1"][chamber][c], fits[chamber][k],
                                 ses.get(c), f"spring_fits, {fits[chamber][4]} tests"
                                 + ("" if ses.get(c) is not None else " (the fit gives no standard error)")))
    if rows:
        out += _cmp_table("PLA Table 1: spring model parameters, paper vs lab", rows)
    nr = _q(db, "SELECT chamber, min(nrmse_pct), max(nrmse_pct), count(nrmse_pct), count(*) FILTER (WHERE nrmse_pct >= 2.5) "
                "FROM spring_tests GROUP BY chamber ORDER BY chamber", "spring_tests")
    if nr:
        p3 = PAPER["pla_table3"]
        rows = []
        for chamber, lo, hi, n, above in nr:
            rows.append(_cmp_row(f"{chamber}: smallest NRMSE", "%", p3["nrmse_min_pct"], lo, None, f"{n} spring tests",
                                 judge=False))
            rows.append(_cmp_row(f"{chamber}: largest NRMSE", "%", p3["nrmse_max_pct"], hi, None,
                                 f"{above} of {n} tests at or above {p3['bound_pct']:g} % (the paper's bound)",
                                 judge=False))
        out += _cmp_table("PLA Table 3: NRMSE of the spring model over the 120 tests, paper range vs lab", rows)
    return out


def _summary_pressure(db: _DB) -> str:
    grouped = db.has("pressure_dynamics") and "level" in db.columns("pressure_dynamics")
    # the paper's PLA chambers, one pooled row per rig (level 'rig'); other rigs' chambers are not the paper's
    if grouped:
        sql = ("SELECT chamber, direction, wn_rad_s, zeta, nrmse_pct, n_steps, rig, campaign FROM pressure_dynamics "
               "WHERE level = 'rig' AND chamber IN ('front', 'rear') ORDER BY chamber, direction, campaign, rig")
    else:
        sql = ("SELECT chamber, direction, wn_rad_s, zeta, nrmse_pct, n_steps, NULL, NULL FROM pressure_dynamics "
               "ORDER BY chamber, direction")
    rows = _q(db, sql, "pressure_dynamics")
    several = len({(r[6], r[7]) for r in rows}) > 1
    out = []
    for chamber, direction, wn, zeta, nrmse, n, rig, campaign in rows:
        p = PAPER["pla_table2"].get(direction)
        if p is None:
            continue
        who = f"{chamber} ({rig}, {campaign})" if several else chamber
        out.append(_cmp_row(f"{who}, {direction}: ωn", "rad/s", p["wn_rad_s"], wn, None,
                            f"{n} steps, NRMSE {fmt(nrmse, 3)} %"))
        out.append(_cmp_row(f"{who}, {direction}: ξ", "", p["zeta"], zeta, None, f"{n} steps"))
    html_out = _cmp_table("PLA Table 2: pressure dynamics (Eq. 11), paper vs lab", out) if out else ""
    if grouped:
        want = ["rig", "part_kind", "part_id", "chamber", "direction", "part_age_h", "part_distance_km", "model",
                "wn_rad_s", "zeta", "tau_s", "wn_change_pct", "zeta_change_pct", "tau_change_pct", "n_steps", "note"]
        cols, prow = db.rows(f"SELECT {', '.join(want)} FROM pressure_dynamics WHERE level = 'part' ORDER BY rig, "
                             "part_kind, part_id, chamber, direction, part_age_h NULLS LAST, "
                             "part_distance_km NULLS LAST")
        if prow:
            html_out += ("<h4>Per part and age: pressure dynamics of each valve / hose under test, and the change "
                         "from its youngest age</h4>" + html_table(cols, prow, 40))
    return html_out


def _summary_service_life(db: _DB) -> str:
    if not db.has("service_life"):
        return ""
    want = [c for c in ("hose_type", "adjustment", "n_hoses", "n_failed", "n_suspended", "weibull_shape",
                        "weibull_scale_km", "b10_km", "b10_lower_km", "b10_upper_km", "confidence", "campaigns", "note")
            if c in db.columns("service_life")]
    cols, rows = db.rows(f"SELECT {', '.join(want)} FROM service_life ORDER BY hose_type, adjustment")
    out = "<h4>Weibull life and B10 per hose type and roller adjustment</h4>" + html_table(cols, rows, 20)
    if db.has("service_life_test") and db.count("service_life_test"):
        cols, rows = db.rows("SELECT * FROM service_life_test")
        out += "<h4>Force- vs distance-set rollers: likelihood-ratio test</h4>" + html_table(cols, rows, 20)
    return out


def _summary_hoses(db: _DB) -> str:
    if not db.has("hose_life"):
        return ""
    want = [c for c in ("hose_id", "adjustment", "z_rollers_mm", "spring_force_n", "status", "failure_mode",
                        "distance_km", "distance_source", "n_runs", "campaigns") if c in db.columns("hose_life")]
    cols, rows = db.rows(f"SELECT {', '.join(want)} FROM hose_life ORDER BY hose_id")
    return "<h4>Hoses</h4>" + html_table(cols, rows, 60)


#: The results section: papers, their topics, the figures of each topic (exact names, or a prefix
#: ending in ``*``), the summary a reader compares them to, and the tables behind it.
LAYOUT = (
    ("plpa", f"PLPA peristaltic actuator ({PLPA_CITATION})", (
        ("leakage", "Leakage maps (Figs. 9–10)", ("leakage_distance", "leakage_force"), _summary_leakage,
         ("leakage_map", "seal_envelope")),
        ("breakaway", "Static breakaway (Fig. 12)", ("breakaway",), _summary_breakaway,
         ("breakaway", "breakaway_summary", "breakaway_findings")),
        ("viscous", "Viscous friction (Figs. 13–14)", ("viscous", "viscous_near_zero"), _summary_viscous,
         ("viscous_points", "viscous_fits", "viscous_transition", "friction_dynamic")),
        ("identification", "Identification (Table 2)", ("identification_*",), _summary_identification,
         ("identification",)),
        ("step", "Closed-loop step (Fig. 15)", ("step_*",), _summary_step, ("step_response",)),
    )),
    ("pla", f"PLA cylinder ({PLA_CITATION})", (
        ("spring", "Spring model (Tables 1 and 3)", ("spring_loops_*", "spring_loop_energy"), _summary_spring,
         ("spring_fits", "spring_tests", "spring_loop_energy")),
        ("pressure", "Pressure dynamics (Table 2)", ("pressure_ageing", "pressure_steps_*"), _summary_pressure,
         ("pressure_dynamics", "pressure_steps")),
    )),
    ("durability", "Durability and hose service life", (
        ("service-life", "Service life: Weibull and B10", ("weibull_probability", "kaplan_meier"),
         _summary_service_life, ("service_life", "service_life_test", "hose_survival")),
        ("hoses", "Hoses and durability runs", ("hose_distance", "leak_growth"), _summary_hoses,
         ("hose_life", "durability_runs", "hose_leak_growth")),
    )),
)


def _matches(name: str, patterns) -> bool:
    return any(name == p or (p.endswith("*") and name.startswith(p[:-1])) for p in patterns)


def _figure(warehouse: Path, name: str, path: str, caption) -> str:
    return (f'<figure id="fig-{esc(name)}">{_img(warehouse, path)}<figcaption><b>{esc(name)}</b>'
            f'{": " + esc(caption) if caption else ""}</figcaption></figure>')


def _results_sections(db: _DB, warehouse: Path) -> tuple[str, list]:
    """(HTML of the papers' sections and the other figures, table-of-contents entries)."""
    figs = db.rows("SELECT stage, name, path, caption FROM figures ORDER BY stage, name")[1] \
        if db.has("figures") else []
    used: set[str] = set()
    html_out, toc = [], []
    for pid, ptitle, topics in LAYOUT:
        parts, sub = [], []
        for tid, ttitle, patterns, summary, tables in topics:
            mine = sorted((f for f in figs if _matches(f[1], patterns)),
                          key=lambda f: (next(k for k, p in enumerate(patterns) if _matches(f[1], [p])), f[1]))
            body = summary(db)
            raws = "".join(_raw_rows(db, t) for t in tables)
            if not mine and not body and not raws:
                continue
            used.update(f[1] for f in mine)
            figs_html = "".join(_figure(warehouse, n, p, c) for _s, n, p, c in mine)  # one per row, full width
            parts.append(f'<section id="{tid}"><h3>{esc(ttitle)}</h3>{body}{figs_html}'
                         f'{"<p class=meta>Rows behind it:</p>" + raws if raws else ""}</section>')
            sub.append((tid, ttitle))
        if parts:
            html_out.append(f'<section id="{pid}"><h2>{esc(ptitle)}</h2>{"".join(parts)}</section>')
            toc.append((pid, ptitle, sub))
    rest = [f for f in figs if f[1] not in used]
    if not rest:  # every figure is shown with its paper above (or there is none): no empty section
        return "".join(html_out), toc
    out = ['<section id="analyses"><h2>Other figures</h2>']
    stage_tables = _stage_tables()
    shown = {t for _p, _t, topics in LAYOUT for tp in topics for t in tp[4]} | {"findings"}
    current = None
    for stage, name, path, caption in rest:
        if stage != current:
            out.append(f"<h3>{esc(stage)}</h3>")
            current = stage
        out.append(_figure(warehouse, name, path, caption))
        key = _key_table(name, stage, stage_tables, db)
        if key and key not in shown:
            shown.add(key)
            out.append(_raw_rows(db, key, f" (key table of {name})"))
    out.append("</section>")
    html_out.append("".join(out))
    toc.append(("analyses", "Other figures", []))
    return "".join(html_out), toc


def _toc(entries: list) -> str:
    items = []
    for anchor, title, sub in entries:
        inner = "".join(f'<li><a href="#{esc(a)}">{esc(t)}</a></li>' for a, t in sub)
        items.append(f'<li><a href="#{esc(anchor)}">{esc(title)}</a>' + (f"<ul>{inner}</ul>" if inner else "") + "</li>")
    return f'<nav class="toc" id="toc"><b>Contents</b><ul>{"".join(items)}</ul></nav>'


# -- per-run pages -------------------------------------------------------------------------------------
#: Bumped when the run pages' layout changes (cached pages are then drawn again).
RUN_PAGE_VERSION = "2"


def _run_results(db: _DB) -> dict[str, list[tuple[str, list[str], list[tuple]]]]:
    """Per run id: (table, columns, rows) of every result table with a ``run_id`` column."""
    out: dict[str, list] = {}
    skip = {"runs", "channels", "rebuild_inputs", "ingest_state", "durability_strokes",
            "rebuild_changes"}  # bookkeeping: after a --full rebuild every run is "changed", every page redrawn
    for t in sorted(db.tables):
        if t in skip or t.startswith("samples_") or "run_id" not in db.columns(t):
            continue
        cols, rows = db.rows(f'SELECT * FROM "{t}" ORDER BY run_id')
        k = cols.index("run_id")
        for r in rows:
            out.setdefault(r[k], []).append((t, cols, r))
    return out


def _run_page(run: dict, results: list, svg: str, key: str) -> str:
    from pipeline.serve.run_pages import page_name  # noqa: F401  (same module the links come from)

    import json as _json

    params = run.get("params")
    if isinstance(params, str):
        try:
            params = _json.loads(params)
        except ValueError:
            params = {"params": params}
    meta_rows = [(k, run.get(k)) for k in ("kind", "campaign", "rig", "started_at", "source_path", "format",
                                            "n_samples", "sample_rate_hz", "duration_s")]
    meta_rows += [(f"params.{k}", v) for k, v in sorted((params or {}).items())]
    meta = "".join(f"<tr><th>{esc(k)}</th><td>{fmt(v)}</td></tr>" for k, v in meta_rows)
    warns = run.get("warnings") or []
    warn_html = ("<ul>" + "".join(f"<li>{esc(w)}</li>" for w in warns) + "</ul>") if warns else \
        '<p class="meta">none</p>'
    by_table: dict[str, tuple[list[str], list[tuple]]] = {}
    for t, cols, r in results:
        by_table.setdefault(t, (cols, []))[1].append(r)
    res_html = "".join(f"<h3>{esc(t)} ({len(rows)} rows)</h3>" + html_table(cols, rows, 50, links=False)
                       for t, (cols, rows) in sorted(by_table.items())) or '<p class="meta">no result rows</p>'
    rid = esc(run["run_id"])
    return "\n".join([
        f"<!DOCTYPE html><!-- key: {key} -->", '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>run {rid}: pneubench</title><style>{CSS}</style></head><body>",
        '<p><a href="../index.html">← morning report</a></p>', f"<h1>Run {rid}</h1>",
        '<section id="channels"><h2>Channels</h2>',
        svg or '<p class="nodata">samples not available</p>',
        '<p class="meta">Each channel drawn from its minimum and maximum per pixel column (every excursion is '
        "visible however long the run); pressures in bar gauge, positions in mm, flows in l/min ANR; shaded and "
        "dashed: what the analyses found (their rows are below).</p></section>",
        f'<section id="metadata"><h2>Metadata</h2><div class="wrap"><table>{meta}</table></div></section>',
        f'<section id="warnings"><h2>Warnings ({len(warns)})</h2>{warn_html}</section>',
        f'<section id="results"><h2>Results derived from this run</h2>{res_html}</section>',
        "</body></html>"])


def write_run_pages(db: _DB, warehouse: Path, folder: Path | None = None, previous: Path | None = None) -> int:
    """Write ``report/runs/<safe id>.html`` for every run; returns how many were drawn anew.

    A page whose inputs (samples file, source hash, results, warnings, layout version) are
    unchanged is kept (its key is in its first line), so a nightly rebuild redraws only the
    runs that changed. Pages of runs no longer in the warehouse are removed. ``previous``: the
    live report's run pages, an unchanged one is linked (or copied) from there into ``folder``.
    """
    import hashlib
    import json as _json

    from pipeline.serve.run_pages import channels_svg, downsample_minmax, page_name, run_events

    if not db.has("runs"):
        return 0
    folder = folder or (Path(warehouse) / "report" / "runs")
    folder.mkdir(parents=True, exist_ok=True)
    results = _run_results(db)
    channels = {}
    if db.has("channels"):
        for rid, col in db.con.execute('SELECT run_id, "column" FROM channels ORDER BY run_id, "column"').fetchall():
            channels.setdefault(rid, []).append(col)
    cols, rows = db.rows("SELECT * FROM runs ORDER BY run_id")
    keep, drawn = set(), 0
    for row in rows:
        run = dict(zip(cols, row))
        rid = run["run_id"]
        name = page_name(rid)
        keep.add(name)
        res = results.get(rid, [])
        key = hashlib.sha256(_json.dumps([RUN_PAGE_VERSION, run.get("samples_path"), run.get("source_sha256"),
                                          [(t, c, r) for t, c, r in res], run.get("warnings"), run.get("params")],
                                         default=str).encode()).hexdigest()[:24]
        page = folder / name
        old = page if previous is None else previous / name
        try:
            with open(old, encoding="utf-8") as fh:
                if f"<!-- key: {key} -->" in fh.readline():
                    if old != page:
                        _link_or_copy(old, page)
                    continue
        except OSError:
            pass
        svg = ""
        samples = (Path(warehouse) / run["samples_path"]) if run.get("samples_path") else None
        if samples is not None and samples.is_file():
            chans = [c for c in channels.get(rid, []) if c not in ("t_s", "run_id")]
            try:
                svg = channels_svg(downsample_minmax(samples, chans, run.get("n_samples") or 0), f"channels of {rid}",
                                   run_events(res))
            except Exception as exc:  # a damaged samples file must not cost the whole report
                svg = f'<p class="nodata">channels could not be drawn: {esc(_one_line_error(exc))}</p>'
        tmp = folder / f".{name}.tmp-{os.getpid()}"
        tmp.write_text(_run_page(run, res, svg, key), encoding="utf-8")
        os.replace(tmp, page)
        drawn += 1
    for old in folder.glob("*.html"):
        if old.name not in keep:
            old.unlink(missing_ok=True)
    return drawn


def _rebuild_line(db: _DB) -> str:
    if not (db.has("rebuild_log") and db.count("rebuild_log")):
        return ""
    r = db.con.execute("SELECT finished_at, n_runs, n_new, n_changed, n_deleted, n_quarantined FROM rebuild_log "
                       f"ORDER BY {_log_order(db)} LIMIT 1").fetchone()
    return (f'Last rebuild {fmt(r[0])}: {fmt(r[1])} runs, {fmt(r[2])} new, {fmt(r[3])} changed, {fmt(r[4])} deleted, '
            f'<a href="#rebuild">{fmt(r[5])} quarantined</a>.')


def _runs_index(db: _DB) -> str:
    """Every run per campaign and kind, each linked to its page."""
    if not db.has("runs") or db.count("runs") == 0:
        return '<section id="runs"><h2>Runs</h2><p class="nodata">no runs</p></section>'
    rows = db.con.execute("SELECT campaign, kind, run_id, len(warnings) FROM runs ORDER BY campaign, kind, run_id").fetchall()
    groups: dict[tuple, list] = {}
    for camp, kind, rid, nw in rows:
        groups.setdefault((camp, kind), []).append((rid, nw))
    out = ['<section id="runs"><h2>Runs</h2><p class="meta">Each run has a page with its channels, metadata, '
           "warnings and the results derived from it.</p>"]
    for (camp, kind), runs in groups.items():
        links = ", ".join(f'<a href="{esc(run_href(r))}">{esc(r)}</a>' + (f" ({n} warning{'s' if n != 1 else ''})"
                                                                          if n else "") for r, n in runs)
        out.append(f"<details><summary><b>{esc(camp)}</b> · {esc(kind)} ({len(runs)} runs)</summary>"
                   f'<p style="font-size:.88em">{links}</p></details>')
    out.append("</section>")
    return "".join(out)


def _run_pages_present(db: _DB, warehouse: Path) -> bool:
    """Whether ``report/runs/`` holds exactly one page per run of the database."""
    from pipeline.serve.run_pages import page_name

    folder = Path(warehouse) / "report" / "runs"
    try:
        have = {n for n in os.listdir(folder) if n.endswith(".html")}
    except OSError:
        return False
    want = {page_name(r) for (r,) in db.con.execute("SELECT run_id FROM runs").fetchall()} if db.has("runs") else set()
    return have == want


def render_report(warehouse: str | Path, now: datetime | None = None, database: str | Path | None = None,
                  run_pages: str = "update", folder: str | Path | None = None) -> str:
    """The report of the warehouse as one HTML string (``now``: the clock for "last 24 hours").

    ``database``: the DuckDB file to read instead of the warehouse's live one (the rebuild
    renders the report from the new database before swapping it in).
    ``folder``: the new report folder (:func:`stage_report`) the run pages and the parts cache
    are written into, each unchanged page taken over from the live report; None writes nothing.
    ``run_pages``: ``"update"`` redraws every run page whose inputs changed (each page's key is
    checked); ``"missing"`` only when a run's page is missing (the no-op rebuild: the runs and
    their results are those of the pages already there).
    """
    warehouse = Path(warehouse)
    now = now or _now()
    live = warehouse / REPORT_DIR
    con = connect_readonly(warehouse, database)
    try:
        db = _DB(con)
        alert, findings = _findings_section(db, now)
        generation = _generation(db)
        cached = _cached_parts(db, warehouse)
        if cached is not None:  # the same inputs as the last report: the same results
            results, toc, runs_index = cached
        else:
            results, toc = _results_sections(db, warehouse)
            runs_index = _runs_index(db)
        if folder is not None:
            (Path(folder) / GENERATION_FILE).write_text(generation or "", encoding="utf-8")
            _cache_parts(db, Path(folder), results, toc, runs_index)
            if run_pages == "missing" and _run_pages_present(db, warehouse):
                _carry_pages(live / "runs", Path(folder) / "runs")
            else:
                write_run_pages(db, warehouse, Path(folder) / "runs", previous=live / "runs")
        entries = ([("overturned", "Findings changed in the last 24 hours", [])] if alert.startswith('<div class="alert"')
                   else []) + [("findings", "Findings of the two papers", [])] + toc + [
            ("rebuild", "Last rebuild: inputs and quarantine", []), ("runs", "Runs", [])]
        parts = [
            "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
            '<meta name="viewport" content="width=device-width, initial-scale=1">',
            "<title>pneubench morning report</title>",
            f"<style>{CSS}</style></head><body>",
            "<h1>pneubench morning report</h1>",
            f'<p class="meta">warehouse {esc(warehouse.resolve())}, generation {esc(generation)}. '
            f"{_rebuild_line(db)}</p>",
            _toc(entries), alert, findings, results, _rebuild_section(db), runs_index,
            "</body></html>",
        ]
        return "\n".join(p for p in parts if p)
    finally:
        con.close()


#: The report's parts that depend on the data only (results sections, runs index), kept beside
#: the page under the inputs key of the rebuild that rendered them.
PARTS_CACHE = ".parts-cache.json"


def _inputs_key(db: _DB) -> str | None:
    """``rebuild_log.inputs_key`` of the last rebuild: every input and all of the code, so equal
    keys mean equal result tables (the rebuild is deterministic)."""
    if not db.has("rebuild_log") or "inputs_key" not in {r[0] for r in db.con.execute("DESCRIBE rebuild_log").fetchall()}:
        return None
    row = db.con.execute(f"SELECT inputs_key FROM rebuild_log ORDER BY {_log_order(db)} LIMIT 1").fetchone()
    return row[0] if row and isinstance(row[0], str) else None


def _cached_parts(db: _DB, warehouse: Path) -> tuple[str, list, str] | None:
    key = _inputs_key(db)
    if key is None:
        return None
    try:
        data = json.loads((Path(warehouse) / "report" / PARTS_CACHE).read_text(encoding="utf-8"))
        if data.get("key") != key:
            return None
        toc = [(a, t, [tuple(x) for x in sub]) for a, t, sub in data["toc"]]
        return str(data["results"]), toc, str(data["runs_index"])
    except (OSError, ValueError, TypeError, KeyError):
        return None  # none yet, or damaged: rendered anew


def _cache_parts(db: _DB, folder: Path, results: str, toc: list, runs_index: str) -> None:
    key = _inputs_key(db)
    if key is None:
        return
    tmp = folder / f".parts-cache.tmp-{os.getpid()}"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp.write_text(json.dumps({"key": key, "results": results, "toc": toc, "runs_index": runs_index}),
                       encoding="utf-8")
        os.replace(tmp, folder / PARTS_CACHE)
    except OSError:
        tmp.unlink(missing_ok=True)  # a cache only: the report itself is unaffected


def _generation(db: _DB) -> str:
    if db.has("rebuild_log") and db.count("rebuild_log"):
        return db.con.execute(f"SELECT generation FROM rebuild_log ORDER BY {_log_order(db)} LIMIT 1").fetchone()[0]
    return ""


def failure_page(warehouse: str | Path, generation: str | None, error: str, now: datetime | None = None) -> str:
    """A minimal self-contained page: the report of ``generation`` failed with ``error``."""
    now = now or _now()
    gen = esc(generation) if generation else "(unknown)"
    return "\n".join([
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        "<title>pneubench morning report: FAILED</title>", f"<style>{CSS}</style></head><body>",
        "<h1>pneubench morning report: FAILED</h1>",
        f'<div class="alert" id="report-failed"><h2 style="margin-top:0">The report for generation {gen} '
        f"could not be written</h2><p><code>{esc(error)}</code></p>"
        f"<p>The warehouse itself is in place and can be queried as usual (<code>pneubench query</code>); "
        f"only this page could not be rendered. This is not yesterday's report: none is shown rather than a "
        f"stale one. Details in <code>logs/rebuild.log</code>; try again with <code>pneubench report</code>.</p>"
        "</div>",
        f'<p class="meta">warehouse {esc(Path(warehouse).resolve())}, generation {gen}, '
        f"failed {esc(f'{now.astimezone(timezone.utc):%Y-%m-%d %H:%M:%S} UTC')}</p>",
        "</body></html>"])


# -- publishing: the report is one folder, swapped in whole --------------------------------------------
#: ``<warehouse>/report`` is a symlink to the live report folder (``.report-<pid>-<hex>/``: the
#: index, ``runs/``, the parts cache and :data:`GENERATION_FILE`). A new report is written into a
#: folder of its own (``.report-tmp-<pid>-<hex>/``), renamed to its final name once complete, and
#: published by renaming a new symlink over ``report`` (rename(2): atomic). A reader following
#: ``report/`` sees the previous index and its pages, or the new ones, never a mix.
REPORT_DIR = "report"
#: The database generation a report folder was rendered from (one line).
GENERATION_FILE = ".generation"
_FOLDER = re.compile(r"\.report-[0-9]+-[0-9a-f]{8}")
_STAGING = re.compile(r"\.report-tmp-[0-9]+-[0-9a-f]{8}")
_LINK_TMP = re.compile(r"\.report\.link-tmp-[0-9]+")
_OWN_FILE = re.compile(r"index\.html|\.generation|\.parts-cache\.json|\.(index\.html|parts-cache)\.tmp-[0-9]+")
_OWN_PAGE = re.compile(r"[A-Za-z0-9._-]{1,80}-[0-9a-f]{8}\.html|\.[A-Za-z0-9._-]{1,80}-[0-9a-f]{8}\.html\.tmp-[0-9]+")


def _link_or_copy(src: Path, dst: Path) -> None:
    """``dst`` as a hard link to ``src`` (a copy where the file system has none)."""
    import shutil

    try:
        os.link(src, dst)
    except FileExistsError:
        raise
    except OSError:
        shutil.copyfile(src, dst)


def _carry_pages(src: Path, dst: Path) -> None:
    """Every run page of ``src`` into ``dst`` (the no-op rebuild: the same pages again)."""
    dst.mkdir(parents=True, exist_ok=True)
    for entry in _scandir(src):  # plain strings: a no-op rebuild of 10,000 runs does this 10,000 times
        if ".tmp-" not in entry.name and _OWN_PAGE.fullmatch(entry.name) and entry.is_file(follow_symlinks=False):
            _link_or_copy(entry.path, os.path.join(dst, entry.name))


def _scandir(folder: Path) -> list:
    try:
        with os.scandir(folder) as it:
            return list(it)
    except OSError:
        return []


def _carry_foreign(live: Path, new: Path) -> None:
    """Files someone else put into the live report folder (or its ``runs/``) go on into the new
    one (hard links): publishing a report never takes a user's file away."""
    for sub, own in (("", _OWN_FILE), ("runs", _OWN_PAGE)):
        for entry in _scandir(live / sub):
            if entry.is_file(follow_symlinks=False) and not own.fullmatch(entry.name) and \
                    not (new / sub / entry.name).exists():
                (new / sub).mkdir(parents=True, exist_ok=True)
                _link_or_copy(Path(entry.path), new / sub / entry.name)


def remove_report_folder(folder: Path, live: Path | None = None) -> None:
    """Delete a report folder the way it was written (index, run pages, cache, temp names). A
    file someone else put there goes only when it was carried into ``live`` (the same inode); a
    folder of theirs is moved into ``live``. Whatever is left keeps the folder."""
    for sub, own in (("runs", _OWN_PAGE), ("", _OWN_FILE)):
        for entry in _scandir(folder / sub):
            if entry.is_file(follow_symlinks=False):
                if own.fullmatch(entry.name) or (live is not None and _same_file(entry.path, live / sub / entry.name)):
                    try:
                        os.unlink(entry.path)
                    except FileNotFoundError:
                        pass
            elif sub == "" and entry.is_dir(follow_symlinks=False) and entry.name != "runs" and live is not None \
                    and not os.path.lexists(live / entry.name):
                try:
                    os.rename(entry.path, live / entry.name)
                except OSError:
                    pass
        try:
            (folder / sub).rmdir()
        except OSError:
            pass  # not empty: it holds something the report did not write


def _same_file(a, b) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _folder_generation(folder: Path) -> str | None:
    try:
        return (folder / GENERATION_FILE).read_text(encoding="utf-8").strip() or None
    except OSError:
        return None


def _live_target(warehouse: Path) -> str | None:
    """Name of the folder ``report`` links to (None: no link, or a folder of the old layout)."""
    try:
        return os.readlink(warehouse / REPORT_DIR)
    except OSError:
        return None


def stage_report(warehouse: str | Path, database: str | Path | None = None, run_pages: str = "update",
                 now: datetime | None = None) -> Path:
    """Render the whole report (index and run pages) into a new folder beside the live one;
    :func:`publish_report` swaps it in. Unchanged run pages are hard links to the live ones.
    A failure removes the folder and raises (the live report is untouched)."""
    return _stage(Path(warehouse), lambda folder: render_report(warehouse, now, database=database,
                                                                 run_pages=run_pages, folder=folder))


def _stage(warehouse: Path, render) -> Path:
    import secrets

    token = f"{os.getpid()}-{secrets.token_hex(4)}"
    tmp = warehouse / f".report-tmp-{token}"
    tmp.mkdir()
    try:
        text = render(tmp)
        (tmp / "index.html").write_text(text, encoding="utf-8")
        _carry_foreign(warehouse / REPORT_DIR, tmp)
        final = warehouse / f".report-{token}"
        os.rename(tmp, final)  # complete: a rebuild killed after this rolls it forward (settle_report)
    except BaseException:
        remove_report_folder(tmp)
        raise
    return final


def publish_report(warehouse: str | Path, staged: Path) -> Path:
    """Point ``report`` at the :func:`stage_report` folder ``staged`` (one rename(2) of a new
    symlink over it) and remove the report folders before it. Returns ``report/index.html``.

    A ``report/`` folder of the old layout (a real folder) is first renamed aside: a crash in
    that moment leaves no ``report`` at all until :func:`settle_report` puts the link in."""
    import secrets

    warehouse = Path(warehouse)
    link = warehouse / REPORT_DIR
    tmp = warehouse / f".report.link-tmp-{os.getpid()}"
    tmp.unlink(missing_ok=True)
    try:
        os.symlink(staged.name, tmp)
    except OSError:  # a file system without symlinks (vfat, exFAT, some SMB shares): two renames
        aside = warehouse / f".report-{os.getpid()}-{secrets.token_hex(4)}"
        if os.path.isdir(link) and not os.path.islink(link):
            os.rename(link, aside)  # killed before the next rename: settle_report renames staged in
        os.rename(staged, link)
        _remove_old_folders(warehouse, None, live=link)
        return link / "index.html"
    if os.path.isdir(link) and not os.path.islink(link):
        os.rename(link, warehouse / f".report-{os.getpid()}-{secrets.token_hex(4)}")
    os.replace(tmp, link)
    _remove_old_folders(warehouse, staged.name)
    return link / "index.html"


def _remove_old_folders(warehouse: Path, keep: str | None, live: Path | None = None) -> None:
    live = live or (warehouse / keep if keep else None)
    for entry in _scandir(warehouse):
        if entry.name != keep and entry.is_dir(follow_symlinks=False) and \
                (_FOLDER.fullmatch(entry.name) or _STAGING.fullmatch(entry.name)):
            remove_report_folder(Path(entry.path), live)
        elif entry.is_symlink() and _LINK_TMP.fullmatch(entry.name):
            Path(entry.path).unlink(missing_ok=True)


def settle_report(warehouse: str | Path) -> None:
    """Bring the report folders in order after a killed rebuild (the caller holds the rebuild
    lock): a complete report of the live database that was not yet published (killed between
    the database swap and the report's) is published; every other report folder but the live
    one, and the temp folders and links, are removed."""
    warehouse = Path(warehouse)
    target = _live_target(warehouse)
    others = [Path(e.path) for e in _scandir(warehouse)
              if e.is_dir(follow_symlinks=False) and _FOLDER.fullmatch(e.name) and e.name != target]
    if others:
        live_gen = None
        try:
            con = connect_readonly(warehouse)
            try:
                live_gen = _generation(_DB(con)) or None
            finally:
                con.close()
        except Exception:
            pass
        current = _folder_generation(warehouse / REPORT_DIR)  # a link, or a folder (no symlinks)
        if live_gen is not None and current != live_gen:
            for folder in others:
                if _folder_generation(folder) == live_gen:
                    publish_report(warehouse, folder)
                    return
    link = warehouse / REPORT_DIR
    _remove_old_folders(warehouse, target, live=link if os.path.isdir(link) else None)


def write_report(warehouse: str | Path, generation: str | None = None, now: datetime | None = None) -> Path:
    """Render the report (index and run pages) into a new folder and publish it in one rename;
    returns ``report/index.html``. The caller holds the warehouse's rebuild lock
    (``pneubench report`` does): a rebuild cannot swap in between.

    Raises
    ------
    FileNotFoundError
        When there is no warehouse (nothing is written).
    ReportError
        When the report could not be rendered or written. The report is then replaced by
        :func:`failure_page` for ``generation`` (read from ``rebuild_log`` when not given), or
        removed if even that cannot be written: never the previous report left in place.
    """
    warehouse = Path(warehouse)
    connect_readonly(warehouse).close()  # FileNotFoundError without a warehouse
    settle_report(warehouse)
    try:
        return publish_report(warehouse, stage_report(warehouse, now=now))
    except Exception as exc:
        original = exc
    cause = _one_line_error(original)
    if generation is None:
        try:
            con = connect_readonly(warehouse)
            try:
                generation = _generation(_DB(con))
            finally:
                con.close()
        except Exception:
            generation = None
    try:
        failed = _stage(warehouse, lambda folder: failure_page(warehouse, generation, cause, now))
        page = publish_report(warehouse, failed)
    except Exception:
        page = None
        try:
            link = warehouse / REPORT_DIR
            (link if os.path.islink(link) else link / "index.html").unlink(missing_ok=True)
        except OSError:
            pass
    raise ReportError(cause, page) from original


def _one_line_error(exc: BaseException) -> str:
    return " ".join(f"{type(exc).__name__}: {exc}".split())
