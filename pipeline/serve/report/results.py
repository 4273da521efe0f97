"""The results: per paper (:data:`LAYOUT`) its topics, each with the summary a reader compares
its figures to, the figures (one per row, embedded as PNG data) and the rows behind them, folded
with a CSV download; then the figures that belong to no paper, each with its stage's key table."""
from __future__ import annotations

import base64
import csv
import hashlib
import io
from pathlib import Path

from pipeline.serve.formats import neutralise_cell
from pipeline.serve.report.db import ReportDB
from pipeline.serve.report.keyed import KeyedParts
from pipeline.serve.report.markup import esc
from pipeline.serve.report.summaries import (summary_breakaway, summary_hoses, summary_identification,
                                             summary_leakage, summary_pressure, summary_service_life,
                                             summary_spring, summary_step, summary_viscous)
from pipeline.serve.report.tables import MAX_ROWS, html_table, leak_floors
from schemas.papers import PLA_CITATION, PLPA_CITATION

# -- raw rows: folded, with the whole table as a CSV download ------------------------------------------
#: Tables up to this many rows come with a CSV download (a data: URI); longer ones say how to query them.
CSV_MAX_ROWS = 20_000


def _csv_uri(columns: list[str], rows: list[tuple]) -> str:
    """All the rows as a CSV file in a data: URI (text a spreadsheet would run is made inert)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([neutralise_cell(c) for c in columns])
    for r in rows:  # text a spreadsheet would run as a formula (a run id "=HYPERLINK(...)") made inert
        w.writerow(["" if v is None else (repr(v) if isinstance(v, float) else
                                          neutralise_cell(";".join(map(str, v)) if isinstance(v, (list, tuple)) else v))
                    for v in r])
    return "data:text/csv;charset=utf-8;base64," + base64.b64encode(buf.getvalue().encode("utf-8")).decode("ascii")


def _raw_rows(db: ReportDB, table: str, what: str = "") -> str:
    """A table's rows behind ``<details>`` (first :data:`MAX_ROWS`), with a CSV of all of them (its
    stored values: a leak under the floor reads "< floor" in the table alone, :func:`leak_floors`)."""
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
            f"</summary>{html_table(cols, rows, MAX_ROWS, n, floors=leak_floors(db, table, cols, rows[:MAX_ROWS]))}"
            "</details>")


def _img(warehouse: Path, rel: str) -> str:
    """The PNG at ``rel`` in the warehouse as an ``<img>`` with its data inline (none outside it)."""
    path = (warehouse / rel).resolve()
    if warehouse.resolve() not in path.parents or not path.is_file():
        return '<p class="nodata">figure file missing</p>'
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return f'<img alt="{esc(Path(rel).stem)}" src="data:image/png;base64,{data}">'


def _stage_tables() -> dict[str, tuple[list[str], dict]]:
    """Per stage: its WRITES and optional KEY_TABLES (figure name -> table)."""
    try:
        from pipeline import stages  # every stage module and its analyses: only when a figure is of no paper
        return {m.NAME: (list(getattr(m, "WRITES", ())), dict(getattr(m, "KEY_TABLES", {}) or {}))
                for m in stages.discover()}
    except Exception:
        return {}


def _key_table(fig: str, stage: str, stage_tables: dict, db: ReportDB) -> str | None:
    """The table a figure of no paper is shown with: its stage's KEY_TABLES entry, else a table
    of the stage named like the figure, else the stage's first table in the database."""
    tables, keys = stage_tables.get(stage, ([], {}))
    if fig in keys:
        return keys[fig]
    for t in sorted(tables, key=len, reverse=True):
        if t in fig or fig in t:
            return t
    return next((t for t in tables if db.has(t)), None)


#: The results section: papers, their topics, the figures of each topic (exact names, or a prefix
#: ending in ``*``), the summary a reader compares them to, and the tables behind it.
LAYOUT = (
    ("plpa", f"PLPA peristaltic actuator ({PLPA_CITATION})", (
        ("leakage", "Leakage maps (Figs. 9–10)", ("leakage_distance", "leakage_force"), summary_leakage,
         ("leakage_map", "seal_envelope")),
        ("breakaway", "Static breakaway (Fig. 12)", ("breakaway",), summary_breakaway,
         ("breakaway", "breakaway_summary", "breakaway_findings")),
        ("viscous", "Viscous friction (Figs. 13–14)", ("viscous", "viscous_near_zero"), summary_viscous,
         ("viscous_points", "viscous_fits", "viscous_transition", "friction_dynamic")),
        ("identification", "Identification (Table 2)", ("identification_*",), summary_identification,
         ("identification",)),
        ("step", "Closed-loop step (Fig. 15)", ("step_*",), summary_step, ("step_response",)),
    )),
    ("pla", f"PLA cylinder ({PLA_CITATION})", (
        ("spring", "Spring model (Tables 1 and 3)", ("spring_loops_*", "spring_loop_energy"), summary_spring,
         ("spring_fits", "spring_tests", "spring_loop_energy")),
        ("pressure", "Pressure dynamics (Table 2)", ("pressure_ageing", "pressure_steps_*"), summary_pressure,
         ("pressure_dynamics", "pressure_steps")),
    )),
    ("durability", "Durability and hose service life", (
        ("service-life", "Service life: Weibull, B-life and reliability", ("weibull_probability", "kaplan_meier"),
         summary_service_life, ("service_life", "service_life_test", "hose_survival")),
        ("hoses", "Hoses and durability runs", ("hose_distance", "leak_growth"), summary_hoses,
         ("hose_life", "durability_runs", "hose_leak_growth")),
    )),
)


def _matches(name: str, patterns) -> bool:
    """Whether figure ``name`` is one of ``patterns`` (exact names, or prefixes ending in ``*``)."""
    return any(name == p or (p.endswith("*") and name.startswith(p[:-1])) for p in patterns)


def _figure(warehouse: Path, name: str, path: str, caption) -> str:
    """A figure with its caption, the PNG embedded."""
    return (f'<figure id="fig-{esc(name)}">{_img(warehouse, path)}<figcaption><b>{esc(name)}</b>'
            f'{": " + esc(caption) if caption else ""}</figcaption></figure>')


def results_sections(db: ReportDB, warehouse: Path, keyed: KeyedParts | None = None) -> tuple[str, list]:
    """(HTML of the papers' sections and the other figures, table-of-contents entries). ``keyed``:
    each topic, and the other figures, taken from the live report when the tables it read and its
    figures are unchanged (:class:`~pipeline.serve.report.keyed.KeyedParts`); None renders all."""
    figs = db.rows("SELECT stage, name, path, caption FROM figures ORDER BY stage, name")[1] \
        if db.has("figures") else []
    html_out, toc, used = _paper_sections(db, warehouse, figs, keyed)
    rest = [f for f in figs if f[1] not in used]
    if not rest:  # every figure is shown with its paper above (or there is none): no empty section
        return "".join(html_out), toc
    html_out.append(_part(keyed, "other-figures", lambda d: _other_figures(d, warehouse, rest), rest, db, warehouse))
    toc.append(("analyses", "Other figures", []))
    return "".join(html_out), toc


def _part(keyed: KeyedParts | None, name: str, render, figures: list[tuple], db: ReportDB,
          warehouse: Path | None = None) -> str:
    """``render(db)``, or the live report's part ``name`` of the same tables and ``figures`` (rows
    of ``figures``), each figure by what the part shows of it (:func:`_shown`): its stage, name,
    caption, file name and PNG bytes, not the stage folder it is in (issue 26: a stage that runs
    again puts its figures, mostly the same files linked, into a new folder; a topic whose
    tables and figures' bytes are unchanged is taken, not rendered and its PNGs encoded again)."""
    if keyed is None:
        return render(db)
    return keyed.get(name, render, extra=[_shown(warehouse, f) for f in figures])


def _shown(warehouse: Path | None, figure: tuple) -> list:
    """What a part shows of a row of ``figures`` (stage, name, path, caption): stage, name, caption,
    the file's name (its ``alt``) and the SHA-256 of the PNG :func:`_img` embeds (None where it
    embeds none); without a warehouse, the row as text."""
    row = [str(v) if v is not None else None for v in figure]
    if warehouse is None:
        return row
    stage, name, rel, caption = row
    try:
        path = (warehouse / rel).resolve()
        digest = hashlib.sha256(path.read_bytes()).hexdigest() \
            if warehouse.resolve() in path.parents and path.is_file() else None
    except (OSError, TypeError):
        digest = None
    return [stage, name, caption, Path(rel).stem if rel is not None else None, digest]


def _paper_sections(db: ReportDB, warehouse: Path, figs: list[tuple],
                    keyed: KeyedParts | None = None) -> tuple[list[str], list, set[str]]:
    """(HTML per paper of :data:`LAYOUT`, its table-of-contents entries, the figures shown)."""
    used: set[str] = set()
    html_out, toc = [], []
    for pid, ptitle, topics in LAYOUT:
        parts, sub = [], []
        for tid, ttitle, patterns, summary, tables in topics:
            mine = sorted((f for f in figs if _matches(f[1], patterns)),
                          key=lambda f: (next(k for k, p in enumerate(patterns) if _matches(f[1], [p])), f[1]))
            section = _part(keyed, f"topic-{tid}", lambda d: _topic(d, warehouse, (tid, ttitle, summary, tables), mine),
                            mine, db, warehouse)
            if not section:
                continue
            used.update(f[1] for f in mine)
            parts.append(section)
            sub.append((tid, ttitle))
        if parts:
            html_out.append(f'<section id="{pid}"><h2>{esc(ptitle)}</h2>{"".join(parts)}</section>')
            toc.append((pid, ptitle, sub))
    return html_out, toc, used


def _topic(db: ReportDB, warehouse: Path, topic: tuple, mine: list[tuple]) -> str:
    """One topic's section: its summary, its figures (``mine``, one per row, full width) and the rows
    behind them; "" when it has none of these."""
    tid, ttitle, summary, tables = topic
    body = summary(db)
    raws = "".join(_raw_rows(db, t) for t in tables)
    if not mine and not body and not raws:
        return ""
    figs_html = "".join(_figure(warehouse, n, p, c) for _s, n, p, c in mine)
    return (f'<section id="{tid}"><h3>{esc(ttitle)}</h3>{body}{figs_html}'
            f'{"<p class=meta>Rows behind it:</p>" + raws if raws else ""}</section>')


def _other_figures(db: ReportDB, warehouse: Path, rest: list[tuple]) -> str:
    """The figures of no paper, per stage, each with its stage's key table (once)."""
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
    return "".join(out)
