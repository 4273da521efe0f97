"""The parts cache: the data-only parts are taken again only under the same inputs key."""
import json

import duckdb

from pipeline.serve.report.cache import PARTS_CACHE, cache_parts, cached_parts
from pipeline.serve.report.db import ReportDB


def _db(key: str) -> ReportDB:
    """A database whose last rebuild (by number) had inputs key ``key``."""
    con = duckdb.connect()
    con.execute("CREATE TABLE rebuild_log (seq INTEGER, generation VARCHAR, inputs_key VARCHAR)")
    con.execute("INSERT INTO rebuild_log VALUES (2, 'g2', ?), (1, 'g1', 'older')", [key])
    return ReportDB(con)


def test_parts_are_taken_again_only_under_the_same_inputs_key(tmp_path):
    folder = tmp_path / ".report-1-abcdef01"
    toc = [("plpa", "PLPA", [("leakage", "Leakage")])]
    cache_parts(_db("k1"), folder, "<section>results</section>", toc, "<section>runs</section>", "<section>d</section>")
    assert (folder / PARTS_CACHE).is_file() and not [p for p in folder.iterdir() if ".tmp-" in p.name]
    (tmp_path / "report").symlink_to(folder.name)  # the live report
    assert cached_parts(_db("k1"), tmp_path) == ("<section>results</section>", toc, "<section>runs</section>",
                                                 "<section>d</section>")
    assert cached_parts(_db("older"), tmp_path) is None  # another rebuild's inputs: rendered anew
    # a cache written before the decision was kept: rendered anew, not shown without it
    data = json.loads((folder / PARTS_CACHE).read_text(encoding="utf-8"))
    del data["decision"]
    (folder / PARTS_CACHE).write_text(json.dumps(data), encoding="utf-8")
    assert cached_parts(_db("k1"), tmp_path) is None
    (folder / PARTS_CACHE).write_text("{damaged", encoding="utf-8")
    assert cached_parts(_db("k1"), tmp_path) is None


def test_without_an_inputs_key_nothing_is_cached(tmp_path):
    con = duckdb.connect()
    con.execute("CREATE TABLE rebuild_log (seq INTEGER, generation VARCHAR)")  # a log from before the key
    db = ReportDB(con)
    cache_parts(db, tmp_path / "folder", "results", [], "runs", "decision")
    assert not (tmp_path / "folder").exists()
    assert cached_parts(db, tmp_path) is None


def test_parts_cached_by_other_code_are_rendered_anew(tmp_path, monkeypatch):
    from pipeline.serve.report import figures

    (tmp_path / "pipeline").mkdir()
    section = tmp_path / "pipeline" / "sections.py"
    section.write_text("def runs_index(db):\n    return 'old'\n")
    monkeypatch.setattr(figures, "ROOT", tmp_path)
    figures.code_key.cache_clear()
    folder = tmp_path / ".report-1-abcdef01"
    cache_parts(_db("k1"), folder, "results", [], "runs", "decision")
    (tmp_path / "report").symlink_to(folder.name)
    assert cached_parts(_db("k1"), tmp_path) == ("results", [], "runs", "decision")
    section.write_text("def runs_index(db):\n    return 'new'\n")
    figures.code_key.cache_clear()
    assert cached_parts(_db("k1"), tmp_path) is None
    figures.code_key.cache_clear()


def test_pneubench_report_after_a_code_change_does_not_serve_stale_sections(raw, warehouse, tmp_path):
    """The report rendered by changed code (a section function that says something else now) from
    the same database shows what the new code renders, not the parts the old code cached."""
    import shutil
    import subprocess
    import sys

    from pipeline.rebuild.flow import rebuild
    from pipeline.serve.report.figures import ROOT
    from tests.conftest import STEP_META

    raw.csv("c/s0.csv", {**STEP_META, "run_id": "s0"}, {"t[s]": [0, 0.1, 0.2], "x[mm]": [0, 1, 1],
                                                      "x_ref[mm]": [1, 1, 1]})
    rebuild(raw.root, warehouse, jobs=1)
    assert (warehouse / "report" / PARTS_CACHE).is_file()
    code = tmp_path / "updated"
    for d in ("pipeline", "analyses", "schemas"):
        shutil.copytree(ROOT / d, code / d, ignore=shutil.ignore_patterns("__pycache__"))
    pages = code / "pipeline" / "serve" / "report" / "pages.py"
    text = pages.read_text(encoding="utf-8")
    assert "Each run has a page with its channels" in text
    pages.write_text(text.replace("Each run has a page with its channels", "Each run has a new page with its channels"),
                     encoding="utf-8")
    done = subprocess.run([sys.executable, "-c", "import sys; from pipeline.serve.report.render import write_report; "
                           "write_report(sys.argv[1])", str(warehouse)], cwd=code, capture_output=True, text=True,
                          env={**__import__("os").environ, "PYTHONPATH": str(code)}, timeout=300)
    assert done.returncode == 0, done.stderr
    index = (warehouse / "report" / "index.html").read_text(encoding="utf-8")
    assert "Each run has a new page with its channels" in index


def test_the_code_version_the_rebuild_gives_keys_the_parts_and_the_code_is_not_hashed_again(raw, warehouse,
                                                                                              tmp_path, monkeypatch):
    """The rebuild passes its one hash of the project's code (``project_code_version``) to the
    report: the parts cache is keyed by it, taken only under it, and the report hashes no code."""
    import pytest

    from pipeline.rebuild.flow import rebuild
    from pipeline.serve.report import cache
    from pipeline.versions import project_code_version
    from tests.conftest import STEP_META

    monkeypatch.setattr(cache, "code_key", lambda *a, **k: pytest.fail("the report hashed the code again"))
    folder = tmp_path / ".report-1-abcdef01"
    cache_parts(_db("k1"), folder, "results", [], "runs", "decision", code="v1")
    (tmp_path / "report").symlink_to(folder.name)
    assert cached_parts(_db("k1"), tmp_path, "v1") == ("results", [], "runs", "decision")
    assert cached_parts(_db("k1"), tmp_path, "v2") is None  # other code: rendered anew
    raw.csv("c/s0.csv", {**STEP_META, "run_id": "s0"}, {"t[s]": [0, 0.1, 0.2], "x[mm]": [0, 1, 1],
                                                      "x_ref[mm]": [1, 1, 1]})
    rebuild(raw.root, warehouse, jobs=1)
    key = json.loads((warehouse / "report" / PARTS_CACHE).read_text(encoding="utf-8"))["key"]
    assert key.endswith("-" + project_code_version())
