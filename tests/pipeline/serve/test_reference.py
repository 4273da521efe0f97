"""The users' copy of the contracts in docs/: complete, in step with the DDL and the warehouse."""
from __future__ import annotations

import re
import subprocess
from pathlib import Path

from pipeline.serve import reference
from pipeline.serve.door import connect_readonly

ROOT = Path(__file__).resolve().parents[3]


def _sections(text: str) -> dict[str, str]:
    """``### `name` `` sections of docs/warehouse.md: {name: section text}."""
    parts = re.split(r"^### `([^`]+)`.*$", text, flags=re.MULTILINE)
    return {parts[i]: parts[i + 1] for i in range(1, len(parts), 2)}


def test_the_table_reference_is_in_step_with_the_ddl():
    assert reference.main(["--check"]) == 0, "run `python -m pipeline.serve.reference` and commit docs/warehouse.md"


def test_every_table_and_column_of_a_built_warehouse_is_documented(demo):
    sections = _sections(reference.DOC.read_text(encoding="utf-8"))
    con = connect_readonly(demo["warehouse"])
    try:
        rows = con.execute("SELECT table_name, column_name FROM duckdb_columns() "
                           "WHERE database_name = current_database()").fetchall()
    finally:
        con.close()
    assert len({t for t, _ in rows}) > 20
    missing = []
    for table, column in rows:
        key = "samples_<kind>" if table.startswith("samples_") and table != "samples_files" else table
        section = sections.get(key)
        if section is None:
            missing.append(table)
        elif key != "samples_<kind>" and f"| `{column}` |" not in section:
            missing.append(f"{table}.{column}")
    assert not missing, f"not in docs/warehouse.md: {sorted(set(missing))}"


def _documented(section: str) -> dict[str, tuple[str, str]]:
    """``{column: (unit, meaning)}`` of one section's Markdown table (the samples one has no unit)."""
    out = {}
    for line in section.splitlines():
        m = re.match(r"^\| `([^`]+)` \|(.*)\|$", line)
        if m:
            cells = [c.strip() for c in re.split(r"(?<!\\)\|", m.group(2))]
            out[m.group(1)] = (cells[1], cells[2]) if len(cells) == 3 else ("", cells[0])
    return out


def test_every_meaning_and_unit_the_page_gives_is_the_databases_comment_and_describes(demo):
    from pipeline.serve.catalogue import describe_table

    sections = _sections(reference.DOC.read_text(encoding="utf-8"))
    con = connect_readonly(demo["warehouse"])
    try:
        comments = {(t, c): x for t, c, x in con.execute(
            "SELECT table_name, column_name, comment FROM duckdb_columns() "
            "WHERE database_name = current_database()").fetchall()}
    finally:
        con.close()
    tables = sorted({t for t, _ in comments})
    wrong, checked = [], 0
    for table in tables:
        key = "samples_<kind>" if table.startswith("samples_") and table != "samples_files" else table
        documented = _documented(sections.get(key, ""))
        _grain, described = describe_table(demo["warehouse"], table)
        for col in described:
            unit, meaning = documented.get(col["column"], (None, None))
            if not meaning:
                continue
            checked += 1
            got = reference._cell(comments[(table, col["column"])])
            if got != meaning or reference._cell(col["comment"]) != meaning:
                wrong.append(f"{table}.{col['column']}: page {meaning!r}, database {got!r}")
            if key != "samples_<kind>" and (col["unit"] or "") != unit:
                wrong.append(f"{table}.{col['column']}: page unit {unit!r}, describe {col['unit']!r}")
    assert checked > 500 and not wrong, "\n".join(wrong)
    # the reviewers' cases: a view's columns, a pooled table's, runs' own, units not in the name
    for table, column in (("breakaway_summary", "mean_force_n"), ("runs", "rig"), ("runs", "source_sha256"),
                          ("hose_runs", "hose_id"), ("latest_results", "rig"), ("runs_per_hose", "n_runs")):
        assert comments[(table, column)], f"{table}.{column} has no comment"
    _grain, cols = describe_table(demo["warehouse"], "hose_runs")
    assert {c["column"]: c["unit"] for c in cols}["hose_km_before"] == "km"


def test_column_meanings_are_one_rule_for_the_page_and_the_comments():
    from pipeline.warehouse import ddl_comments

    described = ddl_comments()
    got = reference.column_meanings("viscous_transition", ["transition_ci_low_mm_s", "n_runs", "no_such"], described)
    assert got == {"transition_ci_low_mm_s": "lower confidence bound of `transition_velocity_mm_s`",
                   "n_runs": reference.COMMON_COLUMNS["n_runs"]}
    assert reference.table_comment("no_such_table", described) is None
    assert reference.samples_meanings()["campaign"] == reference.COMMON_COLUMNS["campaign"]


def test_a_table_missing_from_the_page_is_caught(tmp_path, monkeypatch):
    page = tmp_path / "warehouse.md"
    text = reference.DOC.read_text(encoding="utf-8")
    page.write_text(text.replace("### `hose_life`", "### `hose_lives`"), encoding="utf-8")
    monkeypatch.setattr(reference, "DOC", page)
    assert reference.main(["--check"]) == 1
    assert reference.main([]) == 0 and reference.main(["--check"]) == 0
    assert "### `hose_life`" in page.read_text(encoding="utf-8")


def test_replace_block_appends_then_replaces():
    once = reference.replace_block("# Title\n", "B\n" + reference.BEGIN + "x" + reference.END)
    assert once.startswith("# Title\n\nB\n")
    block = reference.BEGIN + "\nnew\n" + reference.END
    assert reference.replace_block("head\n" + reference.BEGIN + "\nold\n" + reference.END + "\ntail\n", block) \
        == "head\n" + block + "\ntail\n"


def test_column_meaning_prefers_the_ddl_then_the_glossary_then_the_name():
    assert reference.column_meaning("run_id", {"run_id": "from the DDL"}) == "from the DDL"
    assert reference.column_meaning("run_id", {}) == reference.COMMON_COLUMNS["run_id"]
    assert reference.column_meaning("coulomb_se_n", {}) == "standard error of `coulomb_n`"
    assert reference.column_meaning("b10_lower_km", {}) == "lower bound of `b10_km`"
    assert reference.column_meaning("transition_ci_low_mm_s", {}) == "lower confidence bound of `transition_mm_s`"
    assert reference.column_meaning("second", {}) is None  # "se" inside a word is not a standard error


def test_the_project_stands_alone_no_link_leaves_the_repository():
    tracked = subprocess.run(["git", "ls-files", "*.md", "*.py", "*.sql"], cwd=ROOT, capture_output=True,
                             text=True, check=True).stdout.split()
    assert tracked
    leaving = [p for p in tracked if "shared/spec" in (ROOT / p).read_text(encoding="utf-8", errors="replace")
               and p != "tests/pipeline/serve/test_reference.py"]
    assert not leaving, f"links to files a clone does not have: {leaving}"
    for doc in ("bench-exports.md", "warehouse.md", "physics.md"):
        assert (ROOT / "docs" / doc).stat().st_size > 2000
