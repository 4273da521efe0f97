"""The ``pneubench`` command line: thin click wrappers over library functions."""
from __future__ import annotations

import logging
import sys
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


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="pneubench")
def main():
    """pneubench: bench exports in, DuckDB warehouse and durability analytics out."""
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")


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
@click.option("--wait", "wait_s", type=click.FloatRange(min=0), default=0, show_default=True, metavar="SECONDS",
              help="Wait this long for another rebuild of the same warehouse to finish (else exit 4).")
@click.option("--no-report", is_flag=True, help="Do not write the morning report (warehouse/report/index.html).")
@click.option("--keep-superseded", "keep_superseded_h", type=click.FloatRange(min=0), default=None, metavar="HOURS",
              envvar="PNEUBENCH_KEEP_SUPERSEDED_H",
              help="Keep samples and stage files the new warehouse no longer uses this long, for readers of "
                   "an earlier one (default 24; 0: collect at once; or $PNEUBENCH_KEEP_SUPERSEDED_H).")
def rebuild(raw, warehouse, jobs, full, quiet, executor, scheduler, wait_s, no_report, keep_superseded_h):
    """Ingest new or changed raw files, re-run analyses, swap in the new warehouse.

    Exit 0: everything used; 1: warehouse built, some inputs quarantined; 2: usage error;
    3 or more: failed (also when the morning report cannot be rendered), previous warehouse and
    report untouched (4: another rebuild is running).
    """
    from pipeline.rebuild import RebuildError, rebuild as do_rebuild

    if not raw.is_dir():
        raise click.UsageError(f"raw folder {raw} does not exist")
    if scheduler and executor != "dask":
        raise click.UsageError("--scheduler goes with --executor dask")
    try:
        summary = do_rebuild(raw, warehouse, jobs=jobs, full=full, progress=for_stream(sys.stderr, quiet),
                             lock_wait_s=wait_s, executor=executor, scheduler=scheduler, report=not no_report,
                             keep_superseded_h=keep_superseded_h)
    except RebuildError as exc:
        click.echo(f"pneubench rebuild: {exc}", err=True)
        sys.exit(exc.exit_code)
    sys.exit(summary.exit_code)


@main.command()
@click.argument("sql")
@warehouse_option
@click.option("--format", "fmt", type=click.Choice(["table", "csv", "json"]), default="table", show_default=True)
def query(sql, warehouse, fmt):
    """Run read-only SQL on the warehouse, e.g. pneubench query "SELECT * FROM runs"."""
    import duckdb

    from pipeline.query import format_rows, run_query

    try:
        columns, rows = run_query(warehouse, sql)
    except FileNotFoundError as exc:
        raise click.UsageError(str(exc)) from None
    except duckdb.Error as exc:
        click.echo(f"pneubench query: {str(exc).splitlines()[0]}", err=True)
        sys.exit(3)
    click.echo(format_rows(columns, rows, fmt))


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
def report(warehouse):
    """Write the morning report (warehouse/report/index.html) from the warehouse again."""
    from pipeline.report import ReportError, write_report

    try:
        path = write_report(warehouse)
    except FileNotFoundError as exc:
        raise click.UsageError(str(exc)) from None
    except ReportError as exc:
        click.echo(f"pneubench report: failed: {exc.error}" + (f"; {exc.page} says so" if exc.page else ""), err=True)
        sys.exit(3)
    click.echo(str(path))


@main.command()
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--seed", type=int, default=1, show_default=True, help="Same seed, same bytes.")
@click.option("--profile", type=click.Choice(["demo", "full", "mini"]), default="demo", show_default=True,
              help="demo: small files, about a minute with rebuild; full: realistic sizes (GB); mini: for tests.")
@click.option("--runs", type=click.IntRange(min=1), default=None,
              help="Total runs: pads the characterisation matrices with repetitions (1,000+ run campaigns).")
@click.option("--jobs", type=click.IntRange(min=1), default=None, help="Worker processes (default: up to 4).")
@click.option("--quiet", "-q", is_flag=True, help="No progress output.")
def simulate(out_dir, seed, profile, runs, jobs, quiet):
    """Write a synthetic campaign (every kind, every format, hoses.csv, truth.json) into OUT_DIR.

    OUT_DIR holds campaign folders: ingest it with `pneubench rebuild --raw OUT_DIR`.
    """
    from pipeline.simulator.campaign import simulate_campaign

    s = simulate_campaign(out_dir, seed=seed, profile=profile, runs=runs, jobs=jobs,
                          progress=for_stream(sys.stderr, quiet))
    kinds = ", ".join(f"{k} {n}" for k, n in sorted(s.by_kind.items()))
    click.echo(f"simulate: {s.n_runs} runs ({kinds}), {s.n_files} files, {s.bytes / 1e6:.1f} MB in {out_dir}; "
               f"ground truth in {Path(out_dir) / 'truth.json'}")


@main.command()
@raw_option
@warehouse_option
@jobs_option
@click.option("--quiet", "-q", is_flag=True, help="No progress output.")
def demo(raw, warehouse, jobs, quiet):
    """Simulate RAW/demo (seed 1, demo profile) if absent, then rebuild RAW into the warehouse."""
    from pipeline.rebuild import RebuildError, check_folders, rebuild as do_rebuild
    from pipeline.simulator.campaign import simulate_demo

    try:  # before anything is simulated into raw/
        check_folders(raw, warehouse)
    except RebuildError as exc:
        click.echo(f"pneubench demo: {exc}", err=True)
        sys.exit(exc.exit_code)
    progress = for_stream(sys.stderr, quiet)
    made = simulate_demo(raw, jobs=jobs, progress=progress)
    click.echo(f"demo: {'simulated' if made else 'kept the existing'} {raw / 'demo'}", err=True)
    try:
        summary = do_rebuild(raw, warehouse, jobs=jobs, progress=progress)
    except RebuildError as exc:
        click.echo(f"pneubench demo: {exc}", err=True)
        sys.exit(exc.exit_code)
    click.echo(f"demo: {summary.n_runs} runs in {warehouse / 'pneubench.duckdb'}, {len(summary.quarantine)} "
               f"quarantined; try: pneubench query \"SELECT * FROM service_life\"")
    sys.exit(summary.exit_code)
