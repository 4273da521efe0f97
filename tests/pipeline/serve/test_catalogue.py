"""pipeline/serve/catalogue.py: ``pneubench tables`` and ``describe``: the science first, internal
tables marked, every column with its type, unit and meaning."""
from __future__ import annotations

import duckdb
from click.testing import CliRunner

from pipeline.cli import main
from pipeline.warehouse import DB_NAME


def test_tables_lists_science_first_and_marks_internal_ones(built):
    res = CliRunner().invoke(main, ["tables", "--warehouse", str(built)])
    assert res.exit_code == 0
    lines = res.stdout.splitlines()
    names = [x.split()[0] for x in lines]
    internal = [n for n, x in zip(names, lines) if "[internal]" in x]
    assert set(internal) == {"rebuild_log", "rebuild_inputs", "rebuild_changes", "ingest_state", "stage_cache", "samples_files",
                             "figures", "table_keys"}
    assert names.index("runs") < min(names.index(n) for n in internal)
    assert names.index("service_life") < names.index("samples_step") < min(names.index(n) for n in internal)
    runs_line = lines[names.index("runs")]
    assert "2 rows" in runs_line and "One row per ingested run" in runs_line


def test_describe_gives_types_units_and_meaning(built):
    res = CliRunner().invoke(main, ["describe", "leakage_map", "--warehouse", str(built), "--max-width", "0"])
    assert res.exit_code == 0
    line = next(x for x in res.stdout.splitlines() if x.startswith("leak_l_min"))
    assert "DOUBLE" in line and "l/min (ANR)" in line and "plateau mean, l/min ANR" in line
    res = CliRunner().invoke(main, ["describe", "samples_step", "--warehouse", str(built), "--max-width", "0"])
    line = next(x for x in res.stdout.splitlines() if x.startswith("x_m "))
    assert " m " in line and "Carriage position." in line
    res = CliRunner().invoke(main, ["describe", "runz", "--warehouse", str(built)])
    assert res.exit_code == 2 and "did you mean runs" in res.stderr


def test_descriptions_are_in_the_database_for_any_client(built):
    con = duckdb.connect(str(built / DB_NAME), read_only=True)
    try:
        got = con.execute("SELECT comment FROM duckdb_columns() WHERE table_name = 'runs' "
                          "AND column_name = 'campaign'").fetchone()
        assert got == ("first folder under raw/",)
        got = con.execute("SELECT comment FROM duckdb_tables() WHERE table_name = 'rebuild_log'").fetchone()[0]
        assert got.startswith("(internal")
    finally:
        con.close()


def test_a_column_whose_name_does_not_end_in_its_unit_has_its_unit_from_the_named_table(built):
    from pipeline.serve.catalogue import describe_table, unit_of

    assert unit_of("km_per_day") == "km/day" and unit_of("hose_km_before") == "km"
    assert unit_of("distance_km") == "km" and unit_of("hose_id") is None
    units = {c["column"]: c["unit"] for c in describe_table(built, "test_plan")[1]}
    assert units["km_per_day"] == "km/day"
    comments = {c["column"]: c["comment"] for c in describe_table(built, "breakaway_summary")[1]}
    assert all(comments.values()), comments  # the glossary's meanings reach the database, not only the page
