"""The ``pneubench`` command line: thin click wrappers over library functions."""
from __future__ import annotations

import logging
import os
import re
import signal
import sys
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import click

from pipeline.progress import for_stream

RAW_HELP = "Raw tree (default ./raw, or $PNEUBENCH_RAW)."
WH_HELP = "Warehouse folder (default ./warehouse, or $PNEUBENCH_WAREHOUSE)."

# Options several commands share, defined once.
raw_option = click.option("--raw", type=click.Path(file_okay=False, path_type=Path), envvar="PNEUBENCH_RAW",
                          default="raw", show_default=True, help=RAW_HELP)
warehouse_option = click.option("--warehouse", type=click.Path(file_okay=False, path_type=Path),
                                envvar="PNEUBENCH_WAREHOUSE", default="warehouse", show_default=True, help=WH_HELP)
jobs_option = click.option("--jobs", type=click.IntRange(min=1), default=None,
                           help="Worker processes (default: all cores).")


class Interrupted(KeyboardInterrupt):
    """SIGTERM (or SIGINT) received: raised in the main thread, like Ctrl-C's KeyboardInterrupt."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _raise_interrupted(signum, _frame):
    raise Interrupted(signum)


@contextmanager
def _interruptible(command: str):
    """SIGTERM as an interrupt; an interrupt (Ctrl-C, SIGTERM) is one line and exit 128 + signal
    (130, 143), never click's "Aborted!" and exit 1 (= "built, some inputs quarantined"). The
    rebuild has stopped its workers and removed what it wrote before this line is printed."""
    previous = signal.signal(signal.SIGTERM, _raise_interrupted)
    try:
        yield
    except KeyboardInterrupt as exc:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C must not cut the line short
        signum = getattr(exc, "signum", signal.SIGINT)
        live = "the new warehouse was already in place" if getattr(exc, "swapped", False) else \
            "the previous warehouse is kept"
        click.echo(f"pneubench {command}: interrupted ({signal.Signals(signum).name}); nothing half-written is "
                   f"left, {live}", err=True)
        sys.exit(128 + signum)
    finally:
        signal.signal(signal.SIGTERM, previous)


#: Commands whose exit status reports their work (1: inputs quarantined): a closed stdout does not end them at 0.
_EXIT_REPORTS_WORK = {"rebuild", "demo"}


class _Pneubench(click.Group):
    """The ``pneubench`` group; what ends every command the same way:

    * stdout's reader gone (``pneubench query ... | head -1``): not an error, the command ends
      quietly with exit 0 (no traceback, no "Exception ignored"); not for :data:`_EXIT_REPORTS_WORK`.
    * a warehouse database DuckDB cannot open (:class:`pipeline.serve.door.UnreadableDatabase`):
      one line naming the file, exit 3, from every reader of the warehouse.
    """

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except BrokenPipeError:
            if ctx.invoked_subcommand in _EXIT_REPORTS_WORK:
                raise
            _stdout_to_devnull()
            sys.exit(0)
        except RuntimeError as exc:
            door = sys.modules.get("pipeline.serve.door")  # loaded if it raised: `--help` does without it
            if door is None or not isinstance(exc, door.UnreadableDatabase):
                raise
            click.echo(f"pneubench {ctx.invoked_subcommand}: {exc}", err=True)
            sys.exit(3)


def _stdout_to_devnull() -> None:
    """Point stdout's file descriptor at /dev/null: what is still buffered, flushed at exit, goes nowhere."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):  # no file descriptor (click's test runner)
        pass


def _door_ready(command: str, overridden: tuple[str, ...] = ()) -> None:
    """Refuse a bad ``$PNEUBENCH_QUERY_*`` variable before any work: one line naming it, exit 2.

    Every command that reads the warehouse (and ``rebuild``, whose report reads it) calls it first.
    """
    from pipeline.serve.door import DoorSettingError, check_environment

    try:
        check_environment(overridden)
    except DoorSettingError as exc:
        click.echo(f"pneubench {command}: {exc}", err=True)
        sys.exit(2)


@click.group(cls=_Pneubench, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="pneubench")
def main():
    """pneubench: bench exports in, DuckDB warehouse and durability analytics out."""
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    # distributed sets its own loggers to INFO when imported (a private cluster's start and stop
    # are 33 lines); warnings only, like ours, unless the user configured dask otherwise
    os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "warning")


@main.command()
@raw_option
@warehouse_option
@jobs_option
@click.option("--full", is_flag=True, help="Re-ingest and re-analyse everything.")
@click.option("--quiet", "-q", is_flag=True, help="No progress output (errors still go to stderr).")
@click.option("--executor", type=click.Choice(["local", "dask"]), default="local", show_default=True,
              help="Where per-file ingest and per-run analyses run.")
@click.option("--scheduler", metavar="ADDR", default=None,
              help="Dask scheduler address (tcp://host:8786); without it --executor dask starts a local cluster.")
@click.option("--wait", "lock_wait_s", type=click.FloatRange(min=0), default=0, show_default=True, metavar="SECONDS",
              help="Wait this long for another rebuild of the same warehouse to finish (else exit 4).")
@click.option("--no-report", is_flag=True, help="Do not write the morning report (warehouse/report/index.html).")
@click.option("--keep-superseded", "keep_superseded_h", type=click.FloatRange(min=0), default=None, metavar="HOURS",
              envvar="PNEUBENCH_KEEP_SUPERSEDED_H",
              help="Keep samples and stage files the new warehouse no longer uses this long, for readers of "
                   "an earlier one (default 24; 0: collect at once; or $PNEUBENCH_KEEP_SUPERSEDED_H).")
@click.option("--allow-mass-delete", is_flag=True, envvar="PNEUBENCH_ALLOW_MASS_DELETE",
              help="Go on when every run, or more than half of them (at least 5), would be deleted because "
                   "their raw files are gone; without it such a rebuild exits 2 and keeps the warehouse "
                   "(or $PNEUBENCH_ALLOW_MASS_DELETE=1).")
def rebuild(raw, warehouse, quiet, no_report, **options):
    """Ingest new or changed raw files, re-run analyses, swap in the new warehouse.

    Exit 0: everything used; 1: warehouse built, some inputs quarantined; 2: usage error, or a
    mass delete refused (--allow-mass-delete); 3 or more: failed (also when the morning report cannot be rendered), previous warehouse and
    report untouched (4: another rebuild is running).
    """
    # the rebuild is imported by its commands, not here: `pneubench query` starts without it; Python's
    # cycle collector runs less often from here on, the rebuild's own imports included (issue 26)
    from pipeline.rebuild.executors import fewer_collections

    _door_ready("rebuild")  # the report reads the new warehouse through the door: refuse a bad limit now
    with fewer_collections(keep_frozen=True):   # the process ends after it: nothing to thaw
        from pipeline.rebuild.flow import raw_folder_error, rebuild as do_rebuild
        from pipeline.rebuild.options import RebuildError, RebuildOptions

        if (why := raw_folder_error(raw)) is not None:
            raise click.UsageError(why)
        if options["scheduler"] and options["executor"] != "dask":
            raise click.UsageError("--scheduler goes with --executor dask")
        try:
            with _interruptible("rebuild"):
                summary = do_rebuild(raw, warehouse, RebuildOptions(report=not no_report, **options),
                                     progress=for_stream(sys.stderr, quiet))
        except RebuildError as exc:
            click.echo(f"pneubench rebuild: {exc}", err=True)
            sys.exit(exc.exit_code)
        exit_now(summary.exit_code)


def exit_now(code: int) -> None:
    """End a ``pneubench`` process with exit ``code`` without Python's teardown (every module's
    objects freed one by one: pandas, pyarrow, duckdb, the rebuild's frames; ~0.15 CPU-s, about
    5 % of a one-file change's rebuild at 1,000 runs, issue 26), else ``sys.exit(code)``.

    What a normal exit does that matters is done first: the output is flushed, logging shut down
    and the ``atexit`` handlers run (the door's private folder removed, multiprocessing's
    finalizers). Only in a process that runs ``pneubench`` itself (its main module the console
    script, or ``python -c`` as the benchmarks start it), with the interpreter's own standard streams
    (not click's test runner) and no other thread alive; otherwise it is ``sys.exit``.

    Parameters
    ----------
    code : int
        The exit status [-].
    """
    import threading

    main_file = getattr(sys.modules.get("__main__"), "__file__", None)
    ours = main_file is None or Path(main_file).name == "pneubench"
    if not (ours and sys.stdout is sys.__stdout__ and sys.stderr is sys.__stderr__
            and threading.active_count() == 1):
        sys.exit(code)
    import atexit

    try:
        logging.shutdown()
        atexit._run_exitfuncs()
        sys.stdout.flush()
        sys.stderr.flush()
    except BaseException:  # a handler failed: exit the usual way, which reports it
        sys.exit(code)
    os._exit(code)


# The door's commands (query, tables, describe, plot, decision, figures) import pipeline.serve where they
# run: it imports duckdb (and plot matplotlib), which `pneubench --help`, `schedule` and `simulate` do without.


def _query_error(exc, command: str = "query") -> None:
    """Print a refused or failed query and exit: 2 refused/usage, 3 failed; the line names ``command``."""
    import duckdb

    from pipeline.serve.query import QueryError, QueryLimitError

    if isinstance(exc, QueryLimitError):  # a limit of the door: one line naming it
        click.echo(f"pneubench {command}: {exc}", err=True)
        sys.exit(3)
    if isinstance(exc, QueryError):
        click.echo(f"pneubench {command}: {exc}", err=True)
        sys.exit(2)
    if isinstance(exc, duckdb.PermissionException):  # a way out of the door: one line
        click.echo(f"pneubench {command}: {str(exc).splitlines()[0]} (only the warehouse's tables and samples)",
                   err=True)
        sys.exit(3)
    click.echo(f"pneubench {command}: {str(exc).rstrip()}", err=True)  # DuckDB's whole message (hints)
    sys.exit(3)


@main.command()
@click.argument("sql", required=False)
@click.option("-f", "--file", "sql_file", type=click.File("r", encoding="utf-8"), metavar="FILE",
              help="Read the SQL from FILE (- : stdin).")
@warehouse_option
@click.option("--format", "fmt", type=click.Choice(["auto", "table", "line", "csv", "json", "markdown"]),
              default="auto", show_default=True,
              help="csv/json/markdown stream every row; table shows the first --max-rows; line shows them one "
                   "record per block (name | value); auto: table, or line when the table would wrap a column "
                   "narrower than its header or 10 characters.")
@click.option("--max-rows", type=click.IntRange(min=0), default=100, show_default=True,
              help="Rows the table and line formats show (0: all); they say how many more there are.")
@click.option("--max-width", type=click.IntRange(min=0), default=None,
              help="Widest a table column gets before its cells wrap (default: fit the terminal; 0: never wrap).")
@click.option("--csv-safe", is_flag=True,
              help="CSV to open in a spreadsheet: a text cell starting with = + - @ tab or CR gets a leading ' "
                   "(without it, the data is exact).")
@click.option("--timeout", "timeout_s", type=click.FloatRange(min=0), default=None, metavar="SECONDS",
              help="Stop the statement after this long (default 600, or $PNEUBENCH_QUERY_TIMEOUT; 0: never).")
@click.option("--memory-limit", default=None, metavar="SIZE",
              help="DuckDB's memory (default 2GB, or $PNEUBENCH_QUERY_MEMORY_LIMIT); beyond it DuckDB spills to "
                   "disk or the statement fails.")
@click.option("--temp-limit", default=None, metavar="SIZE",
              help="DuckDB's spill files in all (default 10GB, or $PNEUBENCH_QUERY_TEMP_LIMIT).")
def query(sql, sql_file, warehouse, **options):
    """Run one read-only SQL statement on the warehouse.

    \b
    pneubench query "SELECT * FROM runs"
    pneubench query -f q.sql --format csv > out.csv
    echo "FROM service_life" | pneubench query -
    """
    import duckdb

    from pipeline.serve.query import QueryError, QueryLimitError, read_sql

    opts = QueryOptions(**options)
    _door_ready("query", tuple(env for env, given in (("PNEUBENCH_QUERY_MEMORY_LIMIT", opts.memory_limit),
                                                      ("PNEUBENCH_QUERY_TEMP_LIMIT", opts.temp_limit),
                                                      ("PNEUBENCH_QUERY_TIMEOUT", opts.timeout_s)) if given is not None))
    if sql is not None and sql_file is not None:
        raise click.UsageError("give the SQL as an argument or with -f, not both")
    if opts.csv_safe and opts.fmt != "csv":
        raise click.UsageError("--csv-safe goes with --format csv")
    if sql == "-":
        sql, sql_file = None, sys.stdin
    try:
        _write_query(warehouse, read_sql(sql, sql_file), opts)
    except FileNotFoundError as exc:
        raise click.UsageError(str(exc)) from None
    except (QueryError, QueryLimitError, duckdb.Error) as exc:
        _query_error(exc)


@dataclass(frozen=True)
class QueryOptions:
    """The options of ``pneubench query`` after the SQL and the warehouse: how the result is
    written (``fmt``, ``max_rows``, ``max_width``, ``csv_safe``) and the limits of its statement
    (``timeout_s`` [s], ``memory_limit``, ``temp_limit``: DuckDB sizes such as ``2GB``)."""

    fmt: str
    max_rows: int
    max_width: int | None
    csv_safe: bool
    timeout_s: float | None
    memory_limit: str | None
    temp_limit: str | None


def _write_query(warehouse: Path, sql: str, opts: QueryOptions) -> None:
    """Run ``sql`` through the door and stream its result to stdout in ``opts.fmt``."""
    from pipeline.serve.formats import terminal_width, write_result
    from pipeline.serve.query import open_query

    with open_query(warehouse, sql, arrow=opts.fmt == "csv", timeout_s=opts.timeout_s, memory_limit=opts.memory_limit,
                    temp_limit=opts.temp_limit) as result:  # pyarrow only to stream CSV
        out = sys.stdout
        width = terminal_width() if opts.fmt in ("auto", "table", "line") and opts.max_width is None else None
        write_result(result, out, opts.fmt, max_rows=opts.max_rows, width=width, max_width=opts.max_width,
                     csv_safe=opts.csv_safe)
        out.flush()


@main.command()
@warehouse_option
def tables(warehouse):
    """List the warehouse's tables and views: science first, internal (rebuild) ones last."""
    _door_ready("tables")
    from pipeline.serve.catalogue import list_tables
    from pipeline.serve.formats import terminal_width
    from pipeline.warehouse import INTERNAL_PREFIX

    try:
        found = list_tables(warehouse)
    except FileNotFoundError as exc:
        raise click.UsageError(str(exc)) from None

    width = max((len(t["name"]) for t in found), default=4)
    room = terminal_width() - width - 16
    for t in found:
        n = t["rows"]
        rows = f"{n:>9} {'row ' if n == 1 else 'rows'}" if n is not None else f"{'view':>14}"
        text = (t["comment"] or "").removeprefix(INTERNAL_PREFIX).strip()
        text = ("[internal] " if t["internal"] else "") + text
        if len(text) > room > 10:
            text = text[: room - 1] + "…"
        click.echo(f"{t['name']:<{width}}  {rows}  {text}".rstrip())


@main.command()
@click.argument("table")
@warehouse_option
@click.option("--max-width", type=click.IntRange(min=0), default=None,
              help="Widest a column gets before its cells wrap (default: fit the terminal; 0: never wrap).")
def describe(table, warehouse, max_width):
    """Columns of TABLE with their types, units and meaning."""
    _door_ready("describe")
    from pipeline.serve.catalogue import describe_table
    from pipeline.serve.formats import format_table, terminal_width
    from pipeline.serve.query import QueryError

    try:
        comment, cols = describe_table(warehouse, table)
    except FileNotFoundError as exc:
        raise click.UsageError(str(exc)) from None
    except QueryError as exc:
        _query_error(exc, "describe")
    if comment:
        click.echo(f"{table}: {comment}\n")
    rows = [(c["column"], c["type"], c["unit"] or "", c["comment"] or "") for c in cols]
    click.echo(format_table(["column", "type", "unit", "meaning"], ["VARCHAR"] * 4, rows,
                            width=terminal_width() if max_width is None else None, max_width=max_width))


@main.command()
@click.argument("run_id")
@warehouse_option
@click.option("--channels", "-c", multiple=True, metavar="COLUMN",
              help="Channel column(s) to plot, e.g. -c x_m -c p_a_pa (default: every channel of the run).")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Output .png, .svg or .html (default: plot-<run>.png).")
def plot(run_id, warehouse, channels, output):
    """Plot one run's channels against time (long runs: min/max per pixel column)."""
    _door_ready("plot")
    from pipeline.serve.plots import plot_run
    from pipeline.serve.query import QueryError

    output = output or Path("plot-" + re.sub(r"[^A-Za-z0-9._-]+", "_", run_id).strip("._") + ".png")
    try:
        click.echo(plot_run(warehouse, run_id, output, [c for part in channels for c in part.split(",") if c]))
    except FileNotFoundError as exc:
        raise click.UsageError(str(exc)) from None
    except QueryError as exc:
        _query_error(exc, "plot")


@main.command()
@warehouse_option
@click.option("--hose-type", "hose_type", default=None, metavar="T",
              help="Only hose type T, with every look and all its running hoses (default: every hose type, "
                   "without the looks, the 20 running hoses nearest their end).")
def decision(warehouse, hose_type):
    """The decision per hose type: force- vs distance-set rollers, the verdict in words, the
    information fraction, the plan to a verdict, the verdict under other failure definitions (and
    the looks of one --hose-type); then the running hoses nearest their end first, with the
    remaining km per method and its backtest.

    Exit 0; 2 for a hose type the warehouse has no decision for (the line names the known ones).
    """
    _door_ready("decision")
    from pipeline.serve.decision import decision_text
    from pipeline.serve.formats import terminal_width
    from pipeline.serve.query import QueryError

    try:
        click.echo(decision_text(warehouse, hose_type, width=terminal_width()))
    except FileNotFoundError as exc:
        raise click.UsageError(str(exc)) from None
    except QueryError as exc:
        _query_error(exc, "decision")


@main.command()
@warehouse_option
@click.option("-o", "--output", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Folder to copy the figures into.")
def figures(warehouse, output):
    """Copy the current figures out of their stage folders into OUTPUT (<stage>-<name>.png)."""
    _door_ready("figures")
    from pipeline.serve.plots import copy_figures
    from pipeline.serve.query import QueryError

    try:
        copied = copy_figures(warehouse, output)
    except FileNotFoundError as exc:
        raise click.UsageError(str(exc)) from None
    except QueryError as exc:
        _query_error(exc, "figures")
    for path, caption in copied:
        click.echo(f"{path}  {caption}".rstrip())
    if not copied:
        click.echo("no figures in the warehouse", err=True)


@main.command()
@raw_option
@warehouse_option
@click.option("--at", "at", default="02:30", show_default=True, metavar="HH:MM", help="Time of the nightly run.")
@click.option("--workdir", type=click.Path(file_okay=False, path_type=Path), default=".", show_default=True,
              help="Working directory of the job.")
@click.option("--log", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Log file (default <warehouse>/logs/rebuild.log).")
@click.option("--user", default=None, help="User the systemd service runs as.")
@click.option("--wait", "wait_s", type=click.IntRange(min=0), default=900, show_default=True, metavar="SECONDS",
              help="How long a run waits for the previous one to finish.")
@click.option("--format", "fmt", type=click.Choice(["all", "cron", "service", "timer"]), default="all",
              show_default=True, help="What to print.")
def schedule(raw, warehouse, at, workdir, log, user, wait_s, fmt):
    """Print a crontab line and a systemd service + timer for the nightly rebuild."""
    from pipeline.schedule import Schedule, render

    try:
        s = Schedule(raw=raw, warehouse=warehouse, workdir=workdir, at=at, log=log, user=user, wait_s=wait_s)
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None
    click.echo(render(s, fmt))


@main.command()
@warehouse_option
@click.option("--wait", "wait_s", type=click.FloatRange(min=0), default=0, show_default=True, metavar="SECONDS",
              help="Wait this long for a rebuild of the same warehouse to finish (else exit 4).")
def report(warehouse, wait_s):
    """Write the morning report (warehouse/report/index.html) from the warehouse again.

    Holds the rebuild lock while it renders (a rebuild cannot swap its database in between);
    exit 4 when a rebuild is running: it writes the report itself when it finishes.
    """
    _door_ready("report")
    from pipeline.rebuild.options import RebuildError
    from pipeline.rebuild.publish import warehouse_lock
    from pipeline.serve.report.render import ReportError, write_report
    from pipeline.warehouse import DB_NAME

    if not (Path(warehouse) / DB_NAME).is_file():
        raise click.UsageError(f"no warehouse at {Path(warehouse) / DB_NAME} (run `pneubench rebuild` first)")
    try:
        with warehouse_lock(Path(warehouse), wait_s):
            path = write_report(warehouse)
    except RebuildError as exc:
        click.echo(f"pneubench report: {exc}", err=True)
        sys.exit(exc.exit_code)
    except FileNotFoundError as exc:
        raise click.UsageError(str(exc)) from None
    except ReportError as exc:
        click.echo(f"pneubench report: failed: {exc.error}" + (f"; {exc.page} says so" if exc.page else ""), err=True)
        sys.exit(3)
    click.echo(str(path))


@main.command()
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--seed", type=click.IntRange(min=0), default=1, show_default=True, help="Same seed, same bytes.")
@click.option("--profile", type=click.Choice(["demo", "full", "mini", "foreign", "decision", "rul"]), default="demo",
              show_default=True,
              help="demo: small files, about a minute with rebuild; full: realistic sizes (GB); mini: for tests; "
                   "foreign: other labs' rigs and exports (campaign foreign-2026); decision: 300 hose types "
                   "known by their odometer, with a plan.toml and their true life ratios (calibrating the verdict); "
                   "rul: 500 hoses with leak checks after short runs and every hose's true failure distance "
                   "(calibrating the remaining life).")
@click.option("--runs", type=click.IntRange(min=1), default=None,
              help="Total runs: pads the characterisation matrices with repetitions (1,000+ run campaigns).")
@click.option("--jobs", type=click.IntRange(min=1), default=None, help="Worker processes (default: up to 4).")
@click.option("--quiet", "-q", is_flag=True, help="No progress output.")
def simulate(out_dir, seed, profile, runs, jobs, quiet):
    """Write a synthetic campaign (every kind, every format, hoses.csv, truth.json) into OUT_DIR.

    OUT_DIR holds campaign folders: ingest it with `pneubench rebuild --raw OUT_DIR`. It is
    created; one that exists must be empty (hidden files aside): anything else in it is refused
    (exit 2), never overwritten.
    """
    from pipeline.simulator.campaign import DemoError, refuse_occupied, simulate_campaign

    try:  # before anything is written: the simulator replaces files of the same names
        refuse_occupied(out_dir, "simulate writes only into a new or empty folder (give another one)")
        out_dir.mkdir(parents=True, exist_ok=True)
    except DemoError as exc:
        raise click.UsageError(str(exc)) from None
    except OSError as exc:  # a file where a folder should be, no permission
        raise click.UsageError(f"cannot create {out_dir} ({exc.strerror or exc})") from None
    s = simulate_campaign(out_dir, seed=seed, profile=profile, runs=runs, jobs=jobs,
                          progress=for_stream(sys.stderr, quiet))
    kinds = ", ".join(f"{k} {n}" for k, n in sorted(s.by_kind.items()))
    runs_text = f"{s.n_runs} runs ({kinds})" if s.n_runs else "no runs (hose logbooks only)"
    click.echo(f"simulate: {runs_text}, {s.n_files} files, {s.bytes / 1e6:.1f} MB in {out_dir}; "
               f"ground truth in {Path(out_dir) / 'truth.json'}")


#: The demo's closing hint: does imposing the roller force make a hose live longer? (fits 80 columns)
DEMO_HINT_SQL = "SELECT hose_type, adjustment, n_hoses, n_failed, weibull_shape, b10_km FROM service_life"


@main.command()
@raw_option
@warehouse_option
@jobs_option
@click.option("--quiet", "-q", is_flag=True, help="No progress output.")
@click.pass_context
def demo(ctx, raw, warehouse, jobs, quiet):
    """Simulate the demo campaigns into RAW (seed 1, demo profile) unless they are there, then
    rebuild RAW into the warehouse.

    RAW gets plpa-2025/, pla-2016/, durability-2025/, durability-2026/ and truth.json; a RAW
    that holds anything else is refused (its runs would be pooled with the demo's).
    """
    import shlex

    from pipeline.rebuild.flow import check_folders, rebuild as do_rebuild
    from pipeline.rebuild.options import RebuildError
    from pipeline.simulator.campaign import DemoError, simulate_demo

    _door_ready("demo")  # its rebuild writes the report through the door
    try:  # before anything is simulated into raw/
        check_folders(raw, warehouse)
    except RebuildError as exc:
        click.echo(f"pneubench demo: {exc}", err=True)
        sys.exit(exc.exit_code)
    progress = for_stream(sys.stderr, quiet)
    try:
        made = simulate_demo(raw, jobs=jobs, progress=progress)
    except DemoError as exc:
        raise click.UsageError(str(exc)) from None
    click.echo(f"demo: {'simulated' if made else 'kept the existing'} campaigns in {raw} "
               f"(ground truth in {raw / 'truth.json'})", err=True)
    try:
        with _interruptible("demo"):
            summary = do_rebuild(raw, warehouse, jobs=jobs, progress=progress)
    except RebuildError as exc:
        click.echo(f"pneubench demo: {exc}", err=True)
        sys.exit(exc.exit_code)
    # the hint must work as printed: the same pneubench (e.g. .venv/bin/pneubench), the same warehouse
    prog = sys.argv[0] if Path(sys.argv[0]).name == "pneubench" else "pneubench"
    where = ""
    if ctx.get_parameter_source("warehouse") == click.core.ParameterSource.COMMANDLINE:
        where = f" --warehouse {shlex.quote(str(warehouse))}"
    report = f"; report: {summary.report}" if getattr(summary, "report", None) else ""
    click.echo(f"demo: {summary.n_runs} runs in {warehouse / 'pneubench.duckdb'}, {len(summary.quarantine)} "
               f"quarantined{report}\ntry: {shlex.quote(prog)} query \"{DEMO_HINT_SQL}\"{where}")
    sys.exit(summary.exit_code)
