"""The ``pneubench`` command line: thin click wrappers over library functions."""
from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

import click

from pipeline.progress import for_stream

RAW_HELP = "Raw tree (default ./raw, or $PNEUBENCH_RAW)."
WH_HELP = "Warehouse folder (default ./warehouse, or $PNEUBENCH_WAREHOUSE)."


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="pneubench")
def main():
    """pneubench: bench exports in, DuckDB warehouse and durability analytics out."""
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")


@main.command()
@click.option("--raw", type=click.Path(file_okay=False, path_type=Path), envvar="PNEUBENCH_RAW",
              default="raw", show_default=True, help=RAW_HELP)
@click.option("--warehouse", type=click.Path(file_okay=False, path_type=Path), envvar="PNEUBENCH_WAREHOUSE",
              default="warehouse", show_default=True, help=WH_HELP)
@click.option("--jobs", type=click.IntRange(min=1), default=None, help="Worker processes (default: all cores).")
@click.option("--full", is_flag=True, help="Re-ingest and re-analyse everything.")
@click.option("--quiet", "-q", is_flag=True, help="No progress output (errors still go to stderr).")
def rebuild(raw, warehouse, jobs, full, quiet):
    """Ingest new or changed raw files, re-run analyses, swap in the new warehouse.

    Exit 0: everything used; 1: warehouse built, some inputs quarantined; 2: usage error;
    3 or more: failed, previous warehouse untouched.
    """
    from pipeline.rebuild import RebuildError, rebuild as do_rebuild

    if not raw.is_dir():
        raise click.UsageError(f"raw folder {raw} does not exist")
    try:
        summary = do_rebuild(raw, warehouse, jobs=jobs, full=full, progress=for_stream(sys.stderr, quiet))
    except RebuildError as exc:
        click.echo(f"pneubench rebuild: {exc}", err=True)
        sys.exit(exc.exit_code)
    sys.exit(summary.exit_code)


@main.command()
@click.argument("sql")
@click.option("--warehouse", type=click.Path(file_okay=False, path_type=Path), envvar="PNEUBENCH_WAREHOUSE",
              default="warehouse", show_default=True, help=WH_HELP)
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
