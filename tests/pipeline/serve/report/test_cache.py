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
