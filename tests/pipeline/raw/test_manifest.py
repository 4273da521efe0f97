"""manifest.csv files that cannot be parsed or refused as a whole (each its own quarantine line,
every run under it waits), rows that name no usable file, and rows for one sheet of a file."""
import pytest

from pipeline.raw.tree import RawTree
from pipeline.rebuild.flow import rebuild
from pipeline.rebuild.options import EXIT_QUARANTINED
from tests.conftest import STEP_META, query
from tests.pipeline.raw.conftest import COLS, rebuild_checked


@pytest.mark.parametrize("body,line,error", [
    (b"file,notes\na.csv,fine\nb.csv,x\x00y\n", 3, "NUL byte (a binary or UTF-16 file?); save it as UTF-8 CSV"),
    (b'file,notes\na.csv,fine\nb.csv,"oops\nc.csv,more\n', 3,
     "unclosed quote (the quoted field runs to the end of the file)"),
    (b"file,notes\na.csv," + b"x" * 200_000 + b"\n", 2,
     "a field is longer than 131072 characters (the csv module's limit)"),
])
def test_a_manifest_that_cannot_be_parsed_is_quarantined_with_its_line(tree, warehouse, body, line, error):
    tree.write("c1/manifest.csv", body)
    tree.csv("c1/sub/c.csv", STEP_META, COLS)
    q = rebuild_checked(tree, warehouse, expect_runs=("c2/b",))
    assert q["c1/manifest.csv"] == [(line, error)]
    # the runs under it: their metadata cannot be known, so they wait for the manifest to be fixed
    for run in ("c1/a.csv", "c1/sub/c.csv"):
        assert q[run] == [(None, f"cannot use c1/manifest.csv: line {line}: {error}")]
    assert query(warehouse, "SELECT run_id FROM runs") == [("c2/b",)]


def test_a_manifest_entry_that_cannot_be_a_file_name_is_one_line(tree, warehouse):
    tree.write("c1/manifest.csv", "file,notes\n" + "d/" * 2100 + "x.csv,long\na.csv,fine\n")
    q = rebuild_checked(tree, warehouse)
    assert q == {"c1/manifest.csv": [(2, "entry `" + "d/" * 2100 + "x.csv`: no such file")]}
    assert query(warehouse, "SELECT json_extract_string(params, '$.notes') FROM runs WHERE run_id = 'c1/a'") == [
        ("fine",)]


# Every way a manifest (or rig.toml) is refused as a whole: the refusal is its own quarantine line
# and every run under it waits for it to be fixed, none is published with the remaining sources.
MANIFEST_REFUSALS = [
    ("c1/manifest.csv", "File,notes\na.csv,2\n", None,
     "no `file` column in the header (`File` is not `file`: the column is named in lower case)"),
    ("c1/manifest.csv", "name,notes\na.csv,2\n", None, "no `file` column in the header"),
    ("c1/manifest.csv", "", None, "no header row (an empty manifest: a header naming the `file` column "
                                  "comes first)"),
    ("c1/manifest.csv", "\n \n", None, "no header row (an empty manifest: a header naming the `file` column "
                                        "comes first)"),
    ("c1/manifest.csv", "file,notes,Notes\na.csv,x,y\n", 1,
     "column `Notes` appears twice in the header (columns 2 and 3; names are matched case-insensitively)"),
    ("c1/Manifest.csv", "file,notes\na.csv,x\n", None,
     "named `Manifest.csv`: a manifest must be named `manifest.csv` (lower case); it is not read"),
    ("c1/MANIFEST.CSV", "file,notes\na.csv,x\n", None,
     "named `MANIFEST.CSV`: a manifest must be named `manifest.csv` (lower case); it is not read"),
    ("c1/Rig.toml", "[metadata]\nrig = \"other\"\n", None,
     "named `Rig.toml`: a rig.toml must be named `rig.toml` (lower case); it is not read"),
]


@pytest.mark.parametrize("name,body,line,error", MANIFEST_REFUSALS, ids=[
    "header-File", "no-file-column", "empty", "blank", "duplicate-column", "Manifest.csv", "MANIFEST.CSV",
    "Rig.toml"])
def test_a_refused_manifest_quarantines_every_run_under_it(tree, warehouse, name, body, line, error):
    tree.write(name, body)
    tree.csv("c1/sub/c.csv", STEP_META, COLS)
    q = rebuild_checked(tree, warehouse, expect_runs=("c2/b",))
    assert q.pop(name) == [(line, error)]
    reason = f"cannot use {name}: line {line}: {error}" if line else f"cannot use {name}: {error}"
    assert q == {"c1/a.csv": [(None, reason)], "c1/sub/c.csv": [(None, reason)]}
    assert query(warehouse, "SELECT run_id FROM runs") == [("c2/b",)]


def test_a_wrong_case_header_does_not_publish_its_runs_with_fallback_metadata(raw, warehouse):
    """Issue 21 item 14: `File` instead of `file` published the run with the rig.toml's
    backpressure 0 instead of the manifest's 2; it waits now, and is published with 2 once the
    header is fixed."""
    raw.write("c/rig.toml", "[metadata]\nbackpressure_bar = 0\n")
    raw.csv("c/a.csv", STEP_META, COLS)
    raw.write("c/manifest.csv", "File,backpressure_bar\na.csv,2\n")
    summary = rebuild(raw.root, warehouse, jobs=1)
    assert summary.exit_code == EXIT_QUARANTINED
    assert query(warehouse, "SELECT count(*) FROM runs") == [(0,)]
    raw.write("c/manifest.csv", "file,backpressure_bar\na.csv,2\n")
    assert rebuild(raw.root, warehouse, jobs=1).exit_code == 0
    assert query(warehouse, "SELECT json_extract(params, '$.backpressure_bar')::DOUBLE FROM runs") == [(2.0,)]


def test_a_manifest_row_with_cells_beyond_the_header_quarantines_its_run_only(tree, warehouse):
    """A row with more cells than the header (an unquoted `,` in a note) has its values shifted:
    the run it names waits; the manifest's other rows apply."""
    tree.csv("c1/c.csv", STEP_META, COLS)
    tree.csv("c1/d.csv", STEP_META, COLS)
    tree.write("c1/manifest.csv", "file,operator,notes,\na.csv,Smith, J.,ok,\nc.csv,Lee,fine,\n"
                                  "d.csv,Lee,fine,,\n")
    q = rebuild_checked(tree, warehouse, expect_runs=("c1/c", "c1/d", "c2/b"))
    msg = "row has a value in column 4 (`ok`), which the header does not name (an unquoted delimiter in a value?)"
    assert q == {"c1/manifest.csv": [(2, msg)], "c1/a.csv": [(None, f"cannot use c1/manifest.csv: line 2: {msg}")]}
    assert query(warehouse, "SELECT run_id, json_extract_string(params, '$.operator') FROM runs ORDER BY 1") == [
        ("c1/c", "Lee"), ("c1/d", "Lee"), ("c2/b", None)]


def test_manifest_rows_for_one_sheet_are_kept_apart_from_the_file_row(raw):
    raw.write("c/b.xlsx", b"x")
    raw.write("c/odd#name.csv", b"x")          # a real file with `#` in its name is that file
    raw.write("manifest.csv", "file,kind\nc/b.xlsx#S1,step\nc/b.xlsx#S2,leakage\n")
    raw.write("c/manifest.csv", "file,kind,rig\nb.xlsx,spring,r1\nb.xlsx#S1,identification,\n"
                                "odd#name.csv,step,\n../c/b.xlsx#S3,step,\n")
    tree = RawTree(raw.root)
    assert tree.manifest_metadata(raw.root / "c/b.xlsx") == {"kind": "spring", "rig": "r1"}
    # nearer manifests override farther ones, part by part
    assert tree.manifest_parts(raw.root / "c/b.xlsx") == {
        "S1": {"kind": "identification"}, "S2": {"kind": "leakage"}, "S3": {"kind": "step"}}
    assert tree.manifest_metadata(raw.root / "c/odd#name.csv") == {"kind": "step"}
    assert tree.manifest_parts(raw.root / "c/odd#name.csv") == {}
    assert tree.problems == []
