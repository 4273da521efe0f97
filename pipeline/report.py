"""The morning report: ``warehouse/report/index.html``, one self-contained static page.

Built from the warehouse database alone (read-only), so ``pneubench report`` can rebuild it at
any time. Order: findings whose result changed in the last 24 hours (``findings.changed_at``;
an overturned one stays there through further rebuilds that night), the findings, the last rebuild
(new, changed, deleted and quarantined inputs with their reasons), hose life and service life,
then every analysis figure with its key table. Figures are embedded as base64 PNG, the style
is inline and there is no script: the file opens from disk anywhere. Every piece of text is
escaped (``html.escape``): run metadata, file names and quarantine reasons come from raw/.

The report is never silently stale. The rebuild renders it from the new database before the
swap, so a report that cannot be rendered fails the rebuild (exit 3): the previous warehouse
and its report stay, and they agree. ``pneubench report`` (``write_report``) replaces a page it
cannot render with a short page saying so, with the error, and raises :class:`ReportError`.
"""
from __future__ import annotations

import base64
import html
import math
import os
from datetime import datetime, timedelta, timezone
from pathlib import Path

from pipeline.warehouse import DB_NAME, connect_readonly

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
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0 auto;max-width:1200px;padding:0 20px 40px;color:#1d2330}
h1{font-size:1.6em;margin:20px 0 4px}h2{border-bottom:2px solid #d8dce4;padding-bottom:4px;margin-top:34px}
h3{margin:22px 0 6px}.meta{color:#5b6475;font-size:.92em}
table{border-collapse:collapse;margin:8px 0 14px;font-size:.88em}th,td{border:1px solid #d8dce4;padding:3px 8px;text-align:left;vertical-align:top}
th{background:#f1f3f7}td.num{text-align:right;font-variant-numeric:tabular-nums}
.ok{background:#e3f5e6;color:#16632a;font-weight:600}.bad{background:#fde4e4;color:#9b1c1c;font-weight:600}
.nodata{background:#eef0f3;color:#5b6475}.alert{border:2px solid #c62828;background:#fff3f3;padding:10px 16px;margin:16px 0}
.cards{display:flex;gap:12px;flex-wrap:wrap}.card{border:1px solid #d8dce4;border-radius:6px;padding:8px 14px;min-width:110px}
.card b{display:block;font-size:1.5em}figure{margin:14px 0}figure img{max-width:100%;border:1px solid #d8dce4}
figcaption{color:#3a4252;font-size:.92em;margin-top:4px}.more{color:#5b6475;font-style:italic}
"""


def esc(value) -> str:
    """Any value as escaped HTML text."""
    return html.escape("" if value is None else str(value), quote=True)


def fmt(value) -> str:
    """A cell: numbers with 4 significant digits, NULL as an em dash; escaped."""
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        if math.isnan(value):
            return "—"
        return esc(f"{value:.4g}")
    if isinstance(value, datetime):
        return esc(value.strftime("%Y-%m-%d %H:%M:%S %Z").strip())
    if isinstance(value, (list, tuple)):
        return esc(", ".join(str(v) for v in value))
    return esc(value)


def html_table(columns: list[str], rows: list[tuple], max_rows: int = MAX_ROWS, total: int | None = None) -> str:
    if not rows:
        return '<p class="more">no rows</p>'
    head = "".join(f"<th>{esc(c)}</th>" for c in columns)
    body = []
    for r in rows[:max_rows]:
        cells = "".join(f'<td class="num">{fmt(v)}</td>' if isinstance(v, (int, float)) and not isinstance(v, bool)
                        else f"<td>{fmt(v)}</td>" for v in r)
        body.append(f"<tr>{cells}</tr>")
    total = len(rows) if total is None else total
    more = f'<p class="more">{total - max_rows} more rows: query the warehouse</p>' if total > max_rows else ""
    return (f'<div style="overflow-x:auto"><table><thead><tr>{head}</tr></thead><tbody>{"".join(body)}</tbody>'
            f"</table></div>{more}")


class _DB:
    def __init__(self, con):
        self.con = con
        self.tables = {r[0] for r in con.execute(
            "SELECT table_name FROM duckdb_tables() UNION SELECT view_name FROM duckdb_views() "
            "WHERE NOT internal").fetchall()}

    def has(self, table: str) -> bool:
        return table in self.tables

    def rows(self, sql: str, params=None) -> tuple[list[str], list[tuple]]:
        cur = self.con.execute(sql, params or [])
        return [d[0] for d in cur.description], cur.fetchall()

    def columns(self, table: str) -> list[str]:
        return [r[0] for r in self.con.execute(f'DESCRIBE "{table}"').fetchall()] if self.has(table) else []

    def count(self, table: str) -> int:
        return self.con.execute(f'SELECT count(*) FROM "{table}"').fetchone()[0] if self.has(table) else 0


def _unit(unit) -> str:
    return "" if unit in (None, "1") else esc(unit)


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
        value = "—" if measured is None else fmt(measured) + (f" ± {fmt(unc)}" if unc is not None else "")
        body.append(f"<tr><td><b>{esc(statement)}</b><br><span class=\"meta\">{esc(fid)}</span></td>"
                    f'<td class="num">{value} {_unit(unit)}</td><td>{esc(criterion)}</td>{_holds_cell(holds)}'
                    f'<td class="num">{fmt(n)}</td><td class="num">{fmt(p)}</td>'
                    f"<td>{esc(detail)}{_change_note(change, at)}</td></tr>")
    n_hold = sum(1 for r in rows if r[6] is True)
    n_fail = sum(1 for r in rows if r[6] is False)
    n_none = sum(1 for r in rows if r[6] is None)
    section = (f'<section id="findings"><h2>Findings of the two papers on the latest data</h2>'
               f'<p class="meta">{n_hold} hold, {n_fail} do not hold, {n_none} without data.</p>'
               "<table><thead><tr><th>finding</th><th>measured ± std. uncertainty</th><th>holds when</th>"
               "<th>result</th><th>n</th><th>p</th><th>how</th></tr></thead><tbody>"
               + "".join(body) + "</tbody></table></section>")
    return alert, section


def _rebuild_section(db: _DB) -> str:
    out = ['<section id="rebuild"><h2>Last rebuild</h2>']
    if db.has("rebuild_log") and db.count("rebuild_log"):
        cols, rows = db.rows("SELECT generation, finished_at, duration_s, mode, executor, n_files, n_runs, n_new, "
                             "n_changed, n_deleted, n_unchanged, n_quarantined, stages_run, stages_reused "
                             "FROM rebuild_log ORDER BY finished_at DESC LIMIT 1")
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
        out.append(html_table(cols, rows, MAX_INPUT_ROWS, n) if rows else '<p class="meta">nothing changed</p>')
        out.append("</details>")
    out.append("</section>")
    return "".join(out)


def _table_block(db: _DB, table: str, title: str | None = None) -> str:
    if not db.has(table):
        return ""
    n = db.count(table)
    cols, rows = db.rows(f'SELECT * FROM "{table}" LIMIT {MAX_ROWS}')
    return f"<h3>{esc(title or table)} <span class=\"meta\">({n} rows)</span></h3>" + html_table(cols, rows, MAX_ROWS, n)


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


def _figures_section(db: _DB, warehouse: Path) -> str:
    out = ['<section id="analyses"><h2>Analyses</h2>']
    if not db.has("figures") or db.count("figures") == 0:
        out.append('<p class="nodata">no figures</p>')
    else:
        stage_tables = _stage_tables()
        cols, rows = db.rows("SELECT stage, name, path, caption FROM figures ORDER BY stage, name")
        shown: set[str] = {"hose_life", "service_life", "findings"}
        current = None
        for stage, name, path, caption in rows:
            if stage != current:
                out.append(f"<h3>{esc(stage)}</h3>")
                current = stage
            out.append(f'<figure>{_img(warehouse, path)}<figcaption><b>{esc(name)}</b>'
                       f'{": " + esc(caption) if caption else ""}</figcaption></figure>')
            key = _key_table(name, stage, stage_tables, db)
            if key and key not in shown:
                shown.add(key)
                out.append(_table_block(db, key, f"{key} (key table of {name})"))
    out.append("</section>")
    return "".join(out)


def render_report(warehouse: str | Path, now: datetime | None = None, database: str | Path | None = None) -> str:
    """The report of the warehouse as one HTML string (``now``: the clock for "last 24 hours").

    ``database``: the DuckDB file to read instead of the warehouse's live one (the rebuild
    renders the report from the new database before swapping it in).
    """
    warehouse = Path(warehouse)
    now = now or _now()
    con = connect_readonly(warehouse, database)
    try:
        db = _DB(con)
        alert, findings = _findings_section(db, now)
        generation = _generation(db)
        hoses = ('<section id="hoses"><h2>Hose life and service life</h2>'
                 + (_table_block(db, "service_life", "Service life per hose type and adjustment") or "")
                 + (_table_block(db, "hose_life", "Hose life") or "")
                 + ("" if db.has("service_life") or db.has("hose_life") else '<p class="nodata">no data</p>')
                 + "</section>")
        parts = [
            "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
            '<meta name="viewport" content="width=device-width, initial-scale=1">',
            "<title>pneubench morning report</title>",
            f"<style>{CSS}</style></head><body>",
            "<h1>pneubench morning report</h1>",
            f'<p class="meta">warehouse {esc(warehouse.resolve())}, generation {esc(generation)}</p>',
            alert, findings, _rebuild_section(db), hoses, _figures_section(db, warehouse),
            "</body></html>",
        ]
        return "\n".join(p for p in parts if p)
    finally:
        con.close()


def _generation(db: _DB) -> str:
    if db.has("rebuild_log") and db.count("rebuild_log"):
        return db.con.execute("SELECT generation FROM rebuild_log ORDER BY finished_at DESC LIMIT 1").fetchone()[0]
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


def stage_page(warehouse: str | Path, text: str) -> Path:
    """Write ``text`` beside ``report/index.html`` under a temporary name; :func:`publish_page`
    renames it into place. The rebuild stages the page before its database swap and publishes
    it right after, so a full disk fails the rebuild instead of leaving no report."""
    folder = Path(warehouse) / "report"
    folder.mkdir(parents=True, exist_ok=True)
    tmp = folder / f".index.html.tmp-{os.getpid()}"
    try:
        tmp.write_text(text, encoding="utf-8")
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return tmp


def publish_page(staged: Path) -> Path:
    """Rename a :func:`stage_page` file to ``index.html`` (atomic). Returns the page's path."""
    final = staged.parent / "index.html"
    os.replace(staged, final)
    return final


def _write_atomic(folder: Path, text: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    final = folder / "index.html"
    tmp = folder / f".index.html.tmp-{os.getpid()}"
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, final)
    finally:
        tmp.unlink(missing_ok=True)
    return final


def write_report(warehouse: str | Path, generation: str | None = None, now: datetime | None = None) -> Path:
    """Write ``report/index.html`` (temp file, then an atomic rename). Returns its path.

    Raises
    ------
    FileNotFoundError
        When there is no warehouse (nothing is written).
    ReportError
        When the report could not be rendered or written. ``index.html`` is then replaced by
        :func:`failure_page` for ``generation`` (read from ``rebuild_log`` when not given), or
        removed if even that cannot be written: never the previous report left in place.
    """
    warehouse = Path(warehouse)
    folder = warehouse / "report"
    try:
        return _write_atomic(folder, render_report(warehouse, now))
    except Exception as exc:
        if isinstance(exc, FileNotFoundError) and not (warehouse / DB_NAME).is_file():
            raise  # no warehouse at all: nothing to report on
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
        page = _write_atomic(folder, failure_page(warehouse, generation, cause, now))
    except Exception:
        page = None
        try:
            (folder / "index.html").unlink(missing_ok=True)
        except OSError:
            pass
    raise ReportError(cause, page) from original


def _one_line_error(exc: BaseException) -> str:
    return " ".join(f"{type(exc).__name__}: {exc}".split())
