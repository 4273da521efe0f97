"""The run pages (``report/runs/<safe id>.html``: a run's channels, metadata, warnings and the
result rows derived from it) and the report's index of runs that links to them.

A page is drawn again only when its inputs changed: its key (samples file, source hash, results,
warnings, parameters, :data:`RUN_PAGE_VERSION`) is in its first line, and a page with the same key
is taken over from the live report (a hard link). A page drawn again takes its channels from the
previous page when their own key is unchanged (:func:`channels_key`: the samples file, the
channels, the events marked on them and the drawing code; :mod:`~pipeline.serve.report.figures`):
a new fit of a run's results changes its page, rarely its channels. ``--full`` draws every page
and figure.

A page shows the rows derived from its run, not the values of a fit pooled over many runs
(:data:`POOLED_COLUMNS`: a spring test's error against its chamber's model, a pressure step's
against its group's): those change on every run of the pool whenever any one of its runs changes
(issue 26: one changed spring test redrew its chamber's 300 pages for a difference in the tenth
digit), so the page names them and where the report shows them, and its key is of what it shows.
"""
from __future__ import annotations

import hashlib
import json
import os
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

from pipeline.serve.report.channels import channels_svg, downsample_minmax, run_events
from pipeline.serve.report.db import ReportDB
from pipeline.serve.report.figures import Figures, code_key, figure_key
from pipeline.serve.report.folders import OWN_PAGE, REPORT_DIR, link_or_copy, page_name, scandir
from pipeline.serve.report.markup import CSS, esc, fmt, one_line_error, run_href
from pipeline.serve.report.tables import coarsest_floor_l_min, html_table
from pipeline.warehouse import sql_str, table_sums

#: Bumped when the run pages' layout changes (cached pages are then drawn again).
RUN_PAGE_VERSION = "5"
#: What a run's channels are drawn with (part of their key): the drawing module, the units it
#: shows them in, and the libraries that read them (its ticks are its own: :func:`~pipeline.serve.report.channels.max_n_ticks`).
CHANNELS_CODE = (("pipeline/serve/report/channels.py", "schemas/units.py"), ("numpy", "pyarrow"))


#: Columns of per-run result tables whose value is computed with a fit pooled over many runs (the
#: model of a chamber or of a group of pressure steps applied to this run): table -> (columns, the
#: report's anchor that shows them). A run page does not show them (see the module's docstring).
POOLED_COLUMNS = {
    "spring_tests": (("nrmse_pct",), "raw-spring_tests"),
    "spring_loop_energy": (("model_loop_energy_j", "structural_energy_j"), "raw-spring_loop_energy"),
    "pressure_steps": (("nrmse_pct",), "raw-pressure_steps"),
}


#: Tables with a ``run_id`` that no run page shows (bookkeeping: after a --full rebuild every run is
#: "changed", every page redrawn; ``durability_strokes``: a stroke table, not results).
_NOT_SHOWN = {"runs", "channels", "rebuild_inputs", "ingest_state", "durability_strokes", "rebuild_changes"}


def _result_tables(db: ReportDB) -> list[str]:
    """The result tables a run page shows rows of: every table with a ``run_id`` column but :data:`_NOT_SHOWN`."""
    return [t for t in sorted(db.tables)
            if t not in _NOT_SHOWN and not t.startswith("samples_") and "run_id" in db.columns(t)]


def _run_results(db: ReportDB, only: list[str] | None = None) -> dict[str, list[tuple[str, list[str], list[tuple]]]]:
    """Per run id: (table, columns, rows) of every result table with a ``run_id`` column, without
    the :data:`POOLED_COLUMNS` (what the run page shows); ``only``: of these runs alone."""
    out: dict[str, list] = {}
    where, params = _of_runs(only)
    for t in _result_tables(db):
        cols = db.columns(t)
        pooled = set(POOLED_COLUMNS.get(t, ((), ""))[0])
        shown = [c for c in cols if c not in pooled]
        cols, rows = db.rows("SELECT " + ", ".join(f'"{c}"' for c in shown) + f' FROM "{t}"{where} ORDER BY run_id',
                             params)
        k = cols.index("run_id")
        for r in rows:
            out.setdefault(r[k], []).append((t, cols, r))
    return out


def _of_runs(only: list[str] | None) -> tuple[str, list | None]:
    """(``WHERE`` clause, parameters) of the rows of the runs ``only`` (all rows when None): a few runs
    as a literal list (the scan's own filter: ~1 ms a table less than a join with a list parameter)."""
    if only is None:
        return "", None
    if len(only) <= 64:
        return " WHERE run_id IN (" + (", ".join(sql_str(r) for r in only) or "NULL") + ")", None
    return " WHERE run_id IN (SELECT unnest($1))", [list(only)]


def _pooled_note(results: list) -> str:
    """The line that names the :data:`POOLED_COLUMNS` of the run's tables and where the report shows them."""
    have = sorted({t for t, _c, _r in results if t in POOLED_COLUMNS})
    if not have:
        return ""
    named = "; ".join(f'<a href="../index.html#{POOLED_COLUMNS[t][1]}">{esc(t)}</a>: '
                      + ", ".join(esc(c) for c in POOLED_COLUMNS[t][0]) for t in have)
    return ('<p class="meta">Not shown here: the values computed with a fit pooled over many runs (they change '
            f"whenever any run of the pool does), in the morning report's tables: {named}.</p>")


def _run_page(run: dict, results: list, svg: str, key: str) -> str:
    """A run's page: channels (``svg``), metadata, warnings and result rows; ``key`` in its first line."""
    warns = run.get("warnings") or []
    warn_html = ("<ul>" + "".join(f"<li>{esc(w)}</li>" for w in warns) + "</ul>") if warns else \
        '<p class="meta">none</p>'
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
        f'<section id="metadata"><h2>Metadata</h2><div class="wrap"><table>{_metadata(run)}</table></div></section>',
        f'<section id="warnings"><h2>Warnings ({len(warns)})</h2>{warn_html}</section>',
        f'<section id="results"><h2>Results derived from this run</h2>{_results(results)}{_pooled_note(results)}'
        "</section>",
        "</body></html>"])


def _metadata(run: dict) -> str:
    """The rows of a run's metadata table: its ``runs`` columns, then each of its parameters."""
    params = run.get("params")
    if isinstance(params, str):
        try:
            params = json.loads(params)
        except ValueError:
            params = {"params": params}
    meta_rows = [(k, run.get(k)) for k in ("kind", "campaign", "rig", "started_at", "source_path", "format",
                                            "n_samples", "sample_rate_hz", "duration_s")]
    meta_rows += [(f"params.{k}", v) for k, v in sorted((params or {}).items())]
    return "".join(f"<tr><th>{esc(k)}</th><td>{fmt(v)}</td></tr>" for k, v in meta_rows)


def _results(results: list) -> str:
    """A run's result rows, a table per result table; a leak under the floor of the run's flow
    sensor (the coarsest its rows' ``sensors`` state) reads "< floor" also in a table without them."""
    by_table: dict[str, tuple[list[str], list[tuple]]] = {}
    for t, cols, r in results:
        by_table.setdefault(t, (cols, []))[1].append(r)
    floor = coarsest_floor_l_min([r[c.index("sensors")] for _t, c, r in results if "sensors" in c])
    return "".join(f"<h3>{esc(t)} ({len(rows)} rows)</h3>" + html_table(cols, rows, 50, links=False,
                                                                        floors=[floor] * len(rows))
                   for t, (cols, rows) in sorted(by_table.items())) or '<p class="meta">no result rows</p>'


def write_run_pages(db: ReportDB, warehouse: Path, folder: Path | None = None, previous: Path | None = None,
                    full: bool = False, ahead: BandsAhead | None = None) -> int:
    """Write ``report/runs/<safe id>.html`` for every run; returns how many were drawn anew.

    A page whose inputs (samples file, source hash, results, warnings, layout version) are
    unchanged is kept (its key is in its first line), so a nightly rebuild redraws only the
    runs that changed; a page drawn again takes its channels from the previous page when their
    key is unchanged. Pages of runs no longer in the warehouse are removed. ``previous``: the
    live report's run pages, an unchanged one is linked (or copied) from there into ``folder``.
    ``full``: every page and its channels drawn anew (``--full``). ``ahead``: channel bands the
    rebuild began to read while it wrote the database (:class:`BandsAhead`).

    Pages staged into a folder of their own (the rebuild's way) are keyed only for the runs whose
    rows may have changed since the live pages were keyed (:func:`_changed_runs`); any other keeps
    its key in :data:`RUN_KEYS` and its page is linked (issue 26: 10,000 pages keyed, and every
    result table read, on every run-file change: ~1 CPU-s at 10,000 runs).
    """
    if not db.has("runs"):
        return 0
    folder = folder or (Path(warehouse) / REPORT_DIR / "runs")
    folder.mkdir(parents=True, exist_ok=True)
    staged = previous is not None and Path(previous) != folder  # pages written into a folder of their own
    # the previous pages' keys without opening them (:data:`RUN_KEYS`); drawn in place, none is trusted
    known = read_run_keys(Path(previous).parent) if staged and not full else {}
    if not staged:
        (folder.parent / RUN_KEYS).unlink(missing_ok=True)  # pages change in place: the index would lie
    sums = table_sums(db.con, ["runs", *(["channels"] if db.has("channels") else []), *_result_tables(db)]) \
        if staged else {}
    changed = _changed_runs(db, Path(warehouse), sums, known.get(_DEPS)) if known else None
    keys, drawn = {}, 0
    here, there = os.fspath(folder), os.fspath(previous) if staged else None  # plain strings: 10,000 pages
    todo = []
    for (rid,) in db.rows("SELECT run_id FROM runs ORDER BY run_id")[1]:
        name = page_name(rid)
        if changed is not None and rid not in changed and name in known and \
                _link_known(os.path.join(there, name), os.path.join(here, name)):
            keys[name] = known[name]  # none of its rows changed since its page was keyed: the same key
        else:
            todo.append(rid)
    some = None if changed is None else todo  # every run's rows read, or only those of the runs to key
    where, params = _of_runs(some)
    results = _run_results(db, some) if todo else {}
    channels = {}
    if db.has("channels") and todo:
        for rid, col in db.con.execute(f'SELECT run_id, "column" FROM channels{where} ORDER BY run_id, "column"',
                                       params or []).fetchall():
            channels.setdefault(rid, []).append(col)
    cols, rows = db.rows(f"SELECT * FROM runs{where} ORDER BY run_id", params) if todo else ([], [])
    for row in rows:
        run = dict(zip(cols, row))
        rid = run["run_id"]
        name = page_name(rid)
        res = results.get(rid, [])
        keys[name] = key = _page_key(run, res)
        if not full and known.get(name) == key and _link_known(os.path.join(there, name), os.path.join(here, name)):
            continue
        page = folder / name
        old = page if previous is None else previous / name
        if not full and name not in known and _take_over(old, page, key):
            continue
        svg = _draw_channels(Path(warehouse), run, channels.get(rid, []), res, (Figures(() if full else (old,)), ahead))
        tmp = folder / f".{name}.tmp-{os.getpid()}"
        tmp.write_text(_run_page(run, res, svg, key), encoding="utf-8")
        os.replace(tmp, page)
        drawn += 1
    for entry in scandir(folder):
        if entry.name.endswith(".html") and entry.name not in keys:
            Path(entry.path).unlink(missing_ok=True)
    if staged:  # the keys, and what they were made from
        _write_run_keys(folder.parent, {**keys, _DEPS: json.dumps({"version": _pages_version(), "tables": sums},
                                                                  sort_keys=True)})
    return drawn


#: The entry of :data:`RUN_KEYS` (not a page name) saying what the pages were keyed from (JSON): the
#: version keying them (:func:`_pages_version`) and each table they read as :func:`~pipeline.warehouse.table_sums` gives it.
_DEPS = "*tables"


def _pages_version() -> str:
    """The version of how a run page is keyed and what it reads: :data:`RUN_PAGE_VERSION` and this module."""
    return f"{RUN_PAGE_VERSION}-{code_key(('pipeline/serve/report/pages.py',))}"


def _run_sums(con, table: str) -> dict:
    """Per run id of ``table``: (its rows, the sum of their hashes)."""
    return {rid: (n, h) for rid, n, h in con.execute(
        f'SELECT run_id, count(*), coalesce(sum(hash(t)), 0)::VARCHAR FROM "{table}" AS t GROUP BY run_id').fetchall()}


def _changed_runs(db: ReportDB, warehouse: Path, sums: dict[str, str], deps: str | None) -> set | None:
    """Run ids whose rows in the tables a page reads (``sums``, :func:`~pipeline.warehouse.table_sums` of each) may differ
    from those the live pages were keyed from (``deps``: their :data:`_DEPS` entry); None when that
    cannot be told: no entry (a report from before it), another version or other tables, or a changed
    table the live database (of ``warehouse``) does not hold as it was when the pages were keyed.

    A table whose sums are those the pages were keyed from has the same rows; of a changed table, the
    runs whose rows (their count and sum of hashes) differ from the live database's. A page's key is
    made of its run's rows alone (:func:`_page_key` of its ``runs`` row and :func:`_run_results`): any
    other run's page has the key :data:`RUN_KEYS` gives it."""
    try:
        old = json.loads(deps) if deps else None
    except ValueError:
        return None
    if not isinstance(old, dict) or old.get("version") != _pages_version() or \
            not isinstance(old.get("tables"), dict) or set(old["tables"]) != set(sums):
        return None
    moved = sorted(t for t in sums if old["tables"][t] != sums[t])
    if not moved:
        return set()
    from pipeline.serve.door import connect_readonly

    try:
        live = connect_readonly(warehouse)
    except Exception:
        return None
    try:
        if table_sums(live, moved) != {t: old["tables"][t] for t in moved}:
            return None  # the live database is not the one the pages were keyed from
        out: set = set()
        for t in moved:
            now, then = _run_sums(db.con, t), _run_sums(live, t)
            out |= {rid for rid in now.keys() | then.keys() if now.get(rid) != then.get(rid)}
        return out
    except Exception:  # a table of another shape: every page keyed
        return None
    finally:
        live.close()


#: The run pages' keys in one file at the top of the report folder (``{page name: key}``, JSON),
#: written after the pages: the next rebuild takes an unchanged page over by its key here instead of
#: opening it for its first line (issue 26: 10,000 pages opened on every run-file change, ~0.3
#: CPU-s). Used only for pages staged into a new folder (the rebuild's way); a page it does not name
#: (a report from before it) is read for its key line as before, one it names with another key is drawn.
RUN_KEYS = ".run-keys.json"


def read_run_keys(report: Path) -> dict[str, str]:
    """:data:`RUN_KEYS` of a report folder (empty when missing or unreadable)."""
    try:
        data = json.loads((Path(report) / RUN_KEYS).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    if not isinstance(data, dict):
        return {}
    return {k: v for k, v in data.items() if isinstance(k, str) and isinstance(v, str)}


def _write_run_keys(report: Path, keys: dict[str, str]) -> None:
    """Write :data:`RUN_KEYS` (temp name, then renamed: never half a file)."""
    tmp = report / f"{RUN_KEYS}.tmp-{os.getpid()}"
    tmp.write_text(json.dumps(keys, sort_keys=True, separators=(",", ":")), encoding="utf-8")
    os.replace(tmp, report / RUN_KEYS)


def _link_known(old: str, page: str) -> bool:
    """The previous page ``old``, whose key :data:`RUN_KEYS` gives as the page's, as ``page`` (linked
    or copied there); False when it is not there any more."""
    try:
        link_or_copy(old, page)
    except OSError:
        return False
    return True


def _page_key(run: dict, results: list) -> str:
    """The key of a run's page: everything it shows (a page with this key need not be drawn again)."""
    return hashlib.sha256(json.dumps([RUN_PAGE_VERSION, run.get("samples_path"), run.get("source_sha256"),
                                      [(t, c, r) for t, c, r in results], run.get("warnings"), run.get("params")],
                                     default=str).encode()).hexdigest()[:24]


def _take_over(old: Path, page: Path, key: str) -> bool:
    """Whether the page ``old`` has ``key`` (then it is ``page``, linked or copied there when elsewhere)."""
    try:
        with open(old, encoding="utf-8") as fh:
            if f"<!-- key: {key} -->" in fh.readline():
                if old != page:
                    link_or_copy(old, page)
                return True
    except OSError:
        pass
    return False


def _draw_channels(warehouse: Path, run: dict, columns: list[str], results: list, taken: tuple) -> str:
    """The run's channels as SVG with the events of its ``results`` ("" without a samples file),
    taken from the previous page when their key is there. ``taken``: (:class:`Figures` of the
    previous page, :class:`BandsAhead` or None: the bands when they were read ahead)."""
    figures, ahead = taken
    samples = (warehouse / run["samples_path"]) if run.get("samples_path") else None
    if samples is None or not samples.is_file():
        return ""
    chans = [c for c in columns if c not in ("t_s", "run_id")]
    n_rows, title, events = run.get("n_samples") or 0, f"channels of {run['run_id']}", run_events(results)
    read = ahead.take(run["samples_path"], chans, n_rows) if ahead is not None else None
    try:
        return figures.figure(channels_key(run["samples_path"], chans, n_rows, title, events),
                              lambda: channels_svg(read.result() if read is not None else
                                                   downsample_minmax(samples, chans, n_rows), title, events))
    except Exception as exc:  # a damaged samples file must not cost the whole report
        return f'<p class="nodata">channels could not be drawn: {esc(one_line_error(exc))}</p>'


#: Runs whose channel bands :class:`BandsAhead` reads at most (a few tens of kB each).
AHEAD_RUNS = 8


class BandsAhead:
    """The channel bands (:func:`downsample_minmax`) of the first run pages a rebuild's report will
    draw, read in a thread while the rebuild assembles and writes its database (issue 26: a new
    100 MB export's bands are ~0.2 CPU-s of reading and reducing its samples file, otherwise
    serial after the database write).

    Used as a context manager around the database write and the report; :meth:`read` starts the
    thread. Nothing is written: a band read ahead and not taken is dropped; a failure is raised
    where the report takes it (:meth:`take`), as the report's own read would have raised it.

    Parameters
    ----------
    warehouse : path-like
        The warehouse folder (samples paths are relative to it).
    """

    def __init__(self, warehouse: str | Path):
        self.warehouse = Path(warehouse)
        self._pool: ThreadPoolExecutor | None = None
        self._reads: dict[tuple, Future] = {}

    def read(self, runs: list[tuple[str, list[str], int]]) -> None:
        """Start reading the bands of ``runs`` (the first :data:`AHEAD_RUNS`): (samples path relative
        to the warehouse, columns as the run page draws them, rows as ``runs.n_samples`` says)."""
        runs = runs[:AHEAD_RUNS]
        if not runs:
            return
        self._pool = self._pool or ThreadPoolExecutor(1, thread_name_prefix="report-bands")
        for path, columns, n_rows in runs:
            key = (path, tuple(columns), n_rows)
            if key not in self._reads:
                self._reads[key] = self._pool.submit(downsample_minmax, self.warehouse / path, list(columns), n_rows)

    def take(self, path: str, columns: list[str], n_rows: int) -> Future | None:
        """The read of these bands when it was started ahead (then the caller's), else None."""
        return self._reads.pop((path, tuple(columns), n_rows), None)

    def __enter__(self) -> BandsAhead:
        return self

    def __exit__(self, *exc) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
        self._reads.clear()


def channels_key(samples_path: str, columns: list[str], n_rows: int, title: str, events: list) -> str:
    """The key of a run's channels SVG: its samples file (named by its content key), the channels
    drawn, the rows binned, the title, the events marked and :data:`CHANNELS_CODE`."""
    return figure_key(code_key(*CHANNELS_CODE), samples_path, columns, n_rows, title, events)


def carry_pages(src: Path, dst: Path) -> None:
    """Every run page of ``src`` into ``dst`` (the no-op rebuild: the same pages again)."""
    dst.mkdir(parents=True, exist_ok=True)
    for entry in scandir(src):  # plain strings: a no-op rebuild of 10,000 runs does this 10,000 times
        if ".tmp-" not in entry.name and OWN_PAGE.fullmatch(entry.name) and entry.is_file(follow_symlinks=False):
            link_or_copy(entry.path, os.path.join(dst, entry.name))
    keys = Path(src).parent / RUN_KEYS  # the same pages: their keys with them
    if keys.is_file() and not (Path(dst).parent / RUN_KEYS).exists():
        link_or_copy(keys, Path(dst).parent / RUN_KEYS)


def run_pages_present(db: ReportDB, warehouse: Path) -> bool:
    """Whether ``report/runs/`` holds exactly one page per run of the database."""
    folder = Path(warehouse) / REPORT_DIR / "runs"
    try:
        have = {n for n in os.listdir(folder) if n.endswith(".html")}
    except OSError:
        return False
    want = {page_name(r) for (r,) in db.con.execute("SELECT run_id FROM runs").fetchall()} if db.has("runs") else set()
    return have == want


def runs_index(db: ReportDB) -> str:
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
