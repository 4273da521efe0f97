"""The report's flow: render the index from the database (and the run pages into a new report
folder), stage that folder beside the live one, publish it; ``pneubench report``
(:func:`write_report`) puts a failure page in place of a report it cannot render.

The order of the index: contents, the decision (:mod:`~pipeline.serve.report.decision`), the
alert box of changed findings, the findings, the results per paper
(:mod:`~pipeline.serve.report.results`), the last rebuild, the runs.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from pipeline.serve.report.cache import REPORT_CODE, cache_parts, cached_parts, live_keyed
from pipeline.serve.report.db import ReportDB
from pipeline.serve.report.decision import decision_section
from pipeline.serve.report.figures import Figures, code_key
from pipeline.serve.report.keyed import KeyedParts
from pipeline.serve.report.folders import GENERATION_FILE, REPORT_DIR
from pipeline.serve.report.markup import CSS, esc, one_line_error
from pipeline.serve.report.pages import BandsAhead, carry_pages, run_pages_present, runs_index, write_run_pages
from pipeline.serve.report.publish import live_generation, publish_report, settle_report, stage_folder
from pipeline.serve.report.results import results_sections
from pipeline.serve.report.sections import findings_section, rebuild_line, rebuild_section, toc
from pipeline.serve.door import connect_readonly


#: Libraries whose versions key the parts kept by their tables' keys (they read and draw them).
KEYED_LIBRARIES = ("numpy", "pandas", "pyarrow", "duckdb", "matplotlib")
#: The run pages as one kept part: what they read (runs, channels, every result table with a
#: ``run_id``) unchanged, the live report's pages are this report's (each page's own key matches).
RUN_PAGES = "run-pages"


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


@dataclass(frozen=True)
class FromRebuild:
    """What the rebuild gives the report it renders from its new database, before its swap.

    Attributes
    ----------
    code : str or None
        The version of the code rendering it, as the rebuild hashed it (the parts cache's key,
        :func:`~pipeline.serve.report.cache.parts_key`); None: the report hashes its code itself.
    ahead : BandsAhead or None
        Channel bands the rebuild began to read for the run pages
        (:class:`~pipeline.serve.report.pages.BandsAhead`).
    keys_checked : bool
        Every ``table_keys`` row of the database matches its table (the rebuild that just wrote it
        checked them); else each key's row count and hash sum are checked on its table here
        (:func:`~pipeline.serve.report.keyed.table_keys`).
    """

    code: str | None = None
    ahead: BandsAhead | None = None
    keys_checked: bool = False


def render_report(warehouse: str | Path, now: datetime | None = None, database: str | Path | None = None,
                  run_pages: str = "update", folder: str | Path | None = None,
                  rebuild: FromRebuild | None = None) -> str:
    """The report of the warehouse as one HTML string (``now``: the clock for "last 24 hours").

    ``database``: the DuckDB file to read instead of the warehouse's live one (the rebuild
    renders the report from the new database before swapping it in).
    ``folder``: the new report folder (:func:`stage_report`) the run pages and the parts cache
    are written into, each unchanged page taken over from the live report; None writes nothing.
    ``run_pages``: ``"update"`` redraws every run page whose inputs changed (each page's key is
    checked); ``"missing"`` only when a run's page is missing (the no-op rebuild: the runs and
    their results are those of the pages already there); ``"all"`` draws every page and figure
    (``--full``). Otherwise a figure whose key is in the live report is taken from there
    (:mod:`~pipeline.serve.report.figures`).
    ``rebuild``: what the rebuild rendering it gives (:class:`FromRebuild`: its hash of the code, the
    channel bands read ahead, whether ``table_keys`` is checked); None: none of it.
    """
    given = rebuild or FromRebuild()
    code, ahead, keys_checked = given.code, given.ahead, given.keys_checked
    warehouse = Path(warehouse)
    now = now or _now()
    con = connect_readonly(warehouse, database)
    try:
        db = ReportDB(con)
        alert, findings = findings_section(db, now)
        generation = db.generation()
        cached = None if run_pages == "all" else cached_parts(db, warehouse, code)
        if cached is not None:  # the same inputs and code as the last report: the same results
            parts, keyed = cached, live_keyed(warehouse)
        else:  # each part the live report's when the tables it reads are unchanged (issue 26)
            keyed = KeyedParts(db, f"{code or code_key(REPORT_CODE)}-{code_key((), KEYED_LIBRARIES)}",
                               {} if run_pages == "all" else live_keyed(warehouse), checked=keys_checked)
            results, entries = results_sections(db, warehouse, keyed)
            live = () if run_pages == "all" else (warehouse / REPORT_DIR / "index.html",)
            parts = (results, entries, keyed.get("runs-index", runs_index),
                     keyed.get("decision", lambda d: decision_section(d, Figures(live))))
        if folder is not None:
            _fill_folder(db, warehouse, Path(folder), generation, run_pages, (parts, code, keyed), ahead)
        return _index(db, warehouse, generation, (alert, findings), parts)
    finally:
        con.close()


def _fill_folder(db: ReportDB, warehouse: Path, folder: Path, generation: str, run_pages: str,
                 parts_code: tuple, ahead: BandsAhead | None = None) -> None:
    """The new report ``folder``'s generation, parts cache (``parts_code``: the parts, the code's
    version and the :class:`KeyedParts`, or the live report's kept parts when the parts were taken
    whole) and run pages (see :func:`render_report`)."""
    parts, code, keyed = parts_code
    live = warehouse / REPORT_DIR
    (folder / GENERATION_FILE).write_text(generation or "", encoding="utf-8")
    if run_pages == "missing" and run_pages_present(db, warehouse):
        carry_pages(live / "runs", folder / "runs")
    elif isinstance(keyed, KeyedParts) and run_pages == "update" and keyed.taken_from_live(RUN_PAGES) and \
            run_pages_present(db, warehouse):  # the tables every run page reads unchanged: the live pages
        carry_pages(live / "runs", folder / "runs")
    elif isinstance(keyed, KeyedParts):
        keyed.render(RUN_PAGES, lambda d: write_run_pages(d, warehouse, folder / "runs", previous=live / "runs",
                                                          full=run_pages == "all", ahead=ahead))
    else:
        write_run_pages(db, warehouse, folder / "runs", previous=live / "runs", full=run_pages == "all", ahead=ahead)
    cache_parts(db, folder, *parts, code=code, keyed=keyed.kept if isinstance(keyed, KeyedParts) else keyed)


def _index(db: ReportDB, warehouse: Path, generation: str, findings: tuple[str, str], parts: tuple) -> str:
    """The index page: ``findings`` (alert, section) and the data-only ``parts`` (results,
    their contents entries, runs index, the decision) with the header, contents and last rebuild."""
    alert, findings_html = findings
    results, entries, runs, decision = parts
    contents = [("decision", "The decision", [])] + (
        [("overturned", "Findings changed in the last 24 hours", [])] if alert.startswith('<div class="alert"')
        else []) + [("findings", "Findings of the two papers", [])] + entries + [
        ("rebuild", "Last rebuild: inputs and quarantine", []), ("runs", "Runs", [])]
    page = [
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        "<title>pneubench morning report</title>",
        f"<style>{CSS}</style></head><body>",
        "<h1>pneubench morning report</h1>",
        f'<p class="meta">warehouse {esc(warehouse.resolve())}, generation {esc(generation)}. '
        f"{rebuild_line(db)}</p>",
        toc(contents), decision, alert, findings_html, results, rebuild_section(db), runs,
        "</body></html>",
    ]
    return "\n".join(p for p in page if p)


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


def stage_report(warehouse: str | Path, database: str | Path | None = None, run_pages: str = "update",
                 now: datetime | None = None, rebuild: FromRebuild | None = None) -> Path:
    """Render the whole report (index and run pages) into a new folder beside the live one;
    :func:`~pipeline.serve.report.publish.publish_report` swaps it in. Unchanged run pages are
    hard links to the live ones. A failure removes the folder and raises (the live report is
    untouched). ``rebuild`` as for :func:`render_report`."""
    return stage_folder(Path(warehouse), lambda folder: render_report(warehouse, now, database=database,
                                                                      run_pages=run_pages, folder=folder,
                                                                      rebuild=rebuild))


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
    cause = one_line_error(original)
    if generation is None:
        generation = live_generation(warehouse)
    page = _publish_failure(warehouse, generation, cause, now)
    raise ReportError(cause, page) from original


def _publish_failure(warehouse: Path, generation: str | None, cause: str, now: datetime | None) -> Path | None:
    """Publish :func:`failure_page` in place of the report; None (and no stale index left) when
    even that fails."""
    try:
        failed = stage_folder(warehouse, lambda folder: failure_page(warehouse, generation, cause, now))
        return publish_report(warehouse, failed)
    except Exception:
        try:
            link = warehouse / REPORT_DIR
            (link if os.path.islink(link) else link / "index.html").unlink(missing_ok=True)
        except OSError:
            pass
        return None
