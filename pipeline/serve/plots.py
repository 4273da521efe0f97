"""One run's channels as a plot (``pneubench plot``): each channel reduced to its minimum and
maximum per pixel column, in the report's display units, with what the analyses saw drawn on
it; and the current figures copied out of their stage folders (``pneubench figures``)."""
from __future__ import annotations

import difflib
import html
import io
import os
import re
import shutil
from pathlib import Path

import numpy as np

from pipeline.serve.door import connect_readonly
from pipeline.serve.formats import is_numeric
from pipeline.serve.query import QueryError
from pipeline.serve.report.channels import EVENT_STYLE, MAX_EVENTS, hms, run_events, time_ticks
from schemas.units import to_display

# matplotlib costs ~0.5 s to import: plot_run imports it, `pneubench figures` only copies files.

#: Channels of a samples view that are not signals.
_NOT_SIGNALS = ("run_id", "kind", "campaign", "t_s")


def run_traces(warehouse: str | Path, run_id: str, channels: list[str] | None = None,
               columns: int = 1000) -> tuple[str, dict[str, tuple[list[float], list[float]]]]:
    """One run's channels, reduced to at most ``2 * columns + 2`` points each.

    A long run is cut into ``columns`` equal time slices (one per pixel column of the plot) and
    each slice keeps its minimum and its maximum, in time order: every spike stays visible; the
    first and last samples are kept too.

    Returns
    -------
    kind : str
    traces : dict
        ``{column: (t [s], values [column's unit])}``.
    """
    con = connect_readonly(Path(warehouse))
    try:
        kind = _run_kind(con, run_id)
        view = f"samples_{kind}"
        wanted = _wanted_channels(con, view, run_id, kind, channels)
        traces = {c: _min_max_trace(con, view, run_id, c, columns) for c in wanted}
    finally:
        con.close()
    return kind, traces


def _run_kind(con, run_id: str) -> str:
    """The run's kind; a :class:`QueryError` naming the closest run ids when there is no such run."""
    row = con.execute("SELECT kind FROM runs WHERE run_id = ?", [run_id]).fetchone()
    if row is None:
        near = difflib.get_close_matches(run_id, [r[0] for r in con.execute("SELECT run_id FROM runs").fetchall()],
                                         n=3)
        raise QueryError(f"no run {run_id!r}" + (f"; did you mean {', '.join(near)}?" if near else ""))
    return row[0]


def _wanted_channels(con, view: str, run_id: str, kind: str, channels: list[str] | None) -> list[str]:
    """``channels`` (every one a numeric channel of ``view``), or by default every numeric channel
    the run has values of; a :class:`QueryError` naming the run's channels for an unknown one."""
    have = [r[0] for r in con.execute(f'DESCRIBE "{view}"').fetchall()
            if r[0] not in _NOT_SIGNALS and is_numeric(r[1])]
    present = {c for c in have if con.execute(
        f'SELECT count("{c}") FROM "{view}" WHERE run_id = ?', [run_id]).fetchone()[0]}
    if channels:
        unknown = [c for c in channels if c not in have]
        if unknown:
            raise QueryError(f"run {run_id!r} ({kind}) has no channel {', '.join(unknown)}; "
                             f"it has {', '.join(c for c in have if c in present)}")
        return list(channels)
    return [c for c in have if c in present]


def _min_max_trace(con, view: str, run_id: str, c: str, columns: int) -> tuple[list[float], list[float]]:
    """``(t [s], values)`` of channel ``c``: min and max per time slice, first and last sample."""
    rows = con.execute(f"""
        WITH s AS (SELECT t_s, "{c}" AS v FROM "{view}" WHERE run_id = $run AND "{c}" IS NOT NULL
                   AND t_s IS NOT NULL),
             r AS (SELECT min(t_s) AS t0, max(t_s) - min(t_s) AS span, count(*) AS n FROM s),
             b AS (SELECT CASE WHEN r.n <= 2 * $cols OR r.span = 0 THEN s.t_s
                               ELSE least(floor((s.t_s - r.t0) / r.span * $cols), $cols - 1) END AS px,
                          s.t_s, s.v FROM s, r)
        SELECT * FROM (
            SELECT px, arg_min(t_s, v) AS t, min(v) AS v FROM b GROUP BY px
            UNION ALL
            SELECT px, arg_max(t_s, v) AS t, max(v) AS v FROM b GROUP BY px
            UNION ALL  -- the first and last samples: the plot spans the whole run
            SELECT -1, min(t_s), arg_min(v, t_s) FROM s
            UNION ALL
            SELECT $cols, max(t_s), arg_max(v, t_s) FROM s)
        ORDER BY t, v""", {"run": run_id, "cols": columns}).fetchall()
    seen, ts, vs = set(), [], []
    for _px, t, v in rows:
        if (t, v) not in seen:
            seen.add((t, v))
            ts.append(t)
            vs.append(v)
    return ts, vs


#: Result tables whose rows name events of a run (see :func:`pipeline.serve.report.channels.run_events`).
EVENT_TABLES = ("breakaway", "viscous_points", "leakage_map", "step_response", "pressure_steps")


def run_result_rows(warehouse: str | Path, run_id: str) -> list[tuple[str, list[str], tuple]]:
    """``(table, columns, row)`` of the rows of :data:`EVENT_TABLES` derived from one run."""
    con = connect_readonly(Path(warehouse))
    try:
        have = {r[0] for r in con.execute("SELECT table_name FROM duckdb_tables() "
                                          "WHERE database_name = current_database()").fetchall()}
        out = []
        for table in EVENT_TABLES:
            if table in have:
                cur = con.execute(f'SELECT * FROM "{table}" WHERE run_id = ?', [run_id])
                cols = [d[0] for d in cur.description]
                out += [(table, cols, r) for r in cur.fetchall()]
    finally:
        con.close()
    return out


def plot_run(warehouse: str | Path, run_id: str, out: str | Path, channels: list[str] | None = None,
             width_px: int = 1200) -> Path:
    """Plot one run's channels against time, one panel per channel, to ``.png``, ``.svg`` or ``.html``.

    ``out`` is written whole through a temporary file beside it (a symlink already there is
    replaced, never what it points at); its folder is created. Raises :class:`QueryError` (one
    line) for an unknown run or channel, another suffix, or an ``out`` that cannot be written.
    """
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".png", ".svg", ".html"):
        raise QueryError(f"{out}: plot to a .png, .svg or .html file")
    kind, traces = run_traces(warehouse, run_id, channels, columns=width_px)
    if not traces:
        raise QueryError(f"run {run_id!r} has no samples to plot")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    dpi = 100
    fig, axes = plt.subplots(len(traces), 1, sharex=True, squeeze=False,
                             figsize=(width_px / dpi, 1.0 + 1.6 * len(traces)), dpi=dpi)
    events = run_events(run_result_rows(warehouse, run_id))[:MAX_EVENTS]  # what the analyses saw
    _draw_panels(axes, traces, events)
    _time_axis(axes[-1, 0], traces)
    if events:
        handles, labels = axes[0, 0].get_legend_handles_labels()
        seen = dict(zip(labels, handles))  # one entry per kind
        axes[0, 0].legend(seen.values(), seen.keys(), fontsize=7, loc="upper right", framealpha=0.8)
    fig.suptitle(f"{run_id} ({kind})", fontsize=10)
    fig.tight_layout()
    _make_folder(out.parent, out)
    try:
        _write_replacing(out, lambda fh: _save(fig, fh, suffix, run_id))
    finally:
        plt.close(fig)
    return out


def _draw_panels(axes, traces: dict[str, tuple[list[float], list[float]]], events: list) -> None:
    """One panel per channel in display units (storage stays SI), the events behind each trace."""
    for ax, (col, (t, v)) in zip(axes[:, 0], traces.items()):
        shown, name, unit = to_display(col, np.asarray(v, dtype=float))  # the report's units; storage stays SI
        for kind_, a, b, _text in events:
            label = EVENT_STYLE[kind_][0] if ax is axes[0, 0] else None
            if b is None:
                ax.axvline(a, color=EVENT_STYLE[kind_][1], lw=1.0, ls="--", label=label)
            else:
                ax.axvspan(a, b, color=EVENT_STYLE[kind_][1], alpha=0.16, lw=0, label=label)
        ax.plot(t, shown, lw=0.7)
        ax.set_ylabel(f"{name}" + (f"\n[{unit}]" if unit else ""), fontsize=8)
        ax.grid(alpha=0.3)


def _time_axis(ax, traces: dict[str, tuple[list[float], list[float]]]) -> None:
    """The bottom panel's time axis: seconds, or h:mm:ss past an hour (``run_pages.time_ticks``)."""
    from matplotlib.ticker import FixedLocator, FuncFormatter

    ts = [x for t, _v in traces.values() for x in t if x is not None]
    t0, t1 = (min(ts), max(ts)) if ts else (0.0, 0.0)
    ticks, _labels, tunit = time_ticks(t0, t1)
    if tunit == "h:mm:ss":  # past an hour: h:mm:ss on whole minutes or hours, not 1.125e+04
        ax.xaxis.set_major_locator(FixedLocator(ticks))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _pos: hms(x)))
    ax.set_xlabel(f"t [{tunit}]")


def _save(fig, fh, suffix: str, run_id: str) -> None:
    """Write the figure to the binary file ``fh``: PNG or SVG without a date or software stamp,
    HTML as a page around the SVG."""
    if suffix == ".html":
        buf = io.StringIO()
        fig.savefig(buf, format="svg", metadata={"Date": None})
        fh.write(f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{html.escape(run_id)}'
                 f"</title></head><body>\n{buf.getvalue()}\n</body></html>\n".encode("utf-8"))
    else:
        fig.savefig(fh, format=suffix[1:], metadata={"Software": None} if suffix == ".png" else {"Date": None})


def _make_folder(folder: Path, out: Path) -> None:
    """Create ``folder`` (and its parents) for ``out``, or refuse in one line (:class:`QueryError`)
    naming ``out`` and what is in the way: a file where a folder should be, or the system's reason."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        blocking = next((p for p in (folder, *folder.parents) if os.path.lexists(p)), None)
        if blocking is not None and os.path.islink(blocking) and not os.path.exists(blocking):
            why = f"{blocking} is a symlink loop or a symlink to nothing"
        elif blocking is not None and not blocking.is_dir():
            why = f"{blocking} is not a folder"
        else:
            why = f"cannot create {folder} ({exc.strerror or exc})"
        raise QueryError(f"cannot write {out}: {why}") from None


def _write_replacing(target: Path, write) -> None:
    """Write ``target`` whole: ``write(fh)`` fills a temporary file beside it (opened without
    following a symlink), which is then renamed onto ``target`` (``os.replace``), as the report and
    the stage folders are written. A symlink already at ``target`` is replaced, never what it
    points at; an interrupted write leaves no half file. An error of the file system is one line
    (:class:`QueryError`) naming ``target``; the temporary file is removed."""
    tmp = target.with_name(f".{target.name}.tmp-{os.getpid()}")
    try:
        try:
            tmp.unlink(missing_ok=True)
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o666)
            with os.fdopen(fd, "wb") as fh:
                write(fh)
            os.replace(tmp, target)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
    except OSError as exc:
        raise QueryError(f"cannot write {target}: {exc.strerror or exc}") from None


def copy_figures(warehouse: str | Path, dest: str | Path) -> list[tuple[Path, str]]:
    """Copy the current figures (table ``figures``) out of their content-hashed stage folders.

    Files are named ``<stage>-<name><ext>`` in ``dest`` and written whole through a temporary file
    (a symlink already at a name is replaced, never what it points at). Returns ``(file, caption)``
    per figure. Raises :class:`QueryError` (one line) for a figure outside the warehouse and for
    a ``dest`` that cannot be written (a file in the way).
    """
    warehouse = Path(warehouse).resolve()
    dest = Path(dest)
    con = connect_readonly(warehouse)
    try:
        has = con.execute("SELECT count(*) FROM duckdb_tables() WHERE table_name = 'figures' "
                          "AND database_name = current_database()").fetchone()[0]
        rows = con.execute("SELECT stage, name, path, caption FROM figures ORDER BY stage, name").fetchall() \
            if has else []
    finally:
        con.close()
    _make_folder(dest, dest)
    out = []
    for stage, name, rel, caption in rows:
        src = (warehouse / rel).resolve()
        if not src.is_relative_to(warehouse) or not src.is_file():
            raise QueryError(f"figure {stage}/{name}: {rel} is not a file of the warehouse")
        target = dest / (re.sub(r"[^A-Za-z0-9._-]+", "_", f"{stage}-{name}") + src.suffix)
        with open(src, "rb") as fh_src:
            _write_replacing(target, lambda fh: shutil.copyfileobj(fh_src, fh))
        out.append((target, caption or ""))
    return out
