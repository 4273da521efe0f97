"""Report parts kept by the content keys of the tables they read."""
import duckdb

from pipeline.serve.report.db import ReportDB
from pipeline.serve.report.keyed import ABSENT, CATALOGUE, KeyedParts, TrackedDB


def _db(a_rows=(1, 2), b_rows=(5,)):
    """A database as a rebuild writes it: tables ``a`` and ``b``, a view over ``a`` and the keys."""
    con = duckdb.connect(":memory:")
    con.execute("CREATE TABLE a (x INTEGER)")
    con.execute("CREATE TABLE b (y INTEGER)")
    con.execute("CREATE VIEW va AS SELECT x * 2 AS x2 FROM a")
    for t, rows in (("a", a_rows), ("b", b_rows)):
        for r in rows:
            con.execute(f"INSERT INTO {t} VALUES (?)", [r])
    sums = dict((t, f"{c}-{h}") for t, c, h in con.execute(
        "SELECT 'a', count(*), coalesce(sum(hash(t)), 0)::VARCHAR FROM a AS t UNION ALL "
        "SELECT 'b', count(*), coalesce(sum(hash(t)), 0)::VARCHAR FROM b AS t").fetchall())
    con.execute("CREATE TABLE table_keys (table_name VARCHAR, content_key VARCHAR)")
    for t in ("a", "b"):  # the frame key's half: the rows themselves here
        con.execute("INSERT INTO table_keys VALUES (?, ?)", [t, f"{sorted(a_rows if t == 'a' else b_rows)}:{sums[t]}"])
    return con


def test_a_tracked_database_records_the_tables_a_part_reads_a_view_standing_for_its_tables():
    db = ReportDB(_db())
    t = TrackedDB(db, {"va": "CREATE VIEW va AS SELECT x * 2 AS x2 FROM a"})
    assert t.rows("SELECT sum(x2) FROM va")[1] == [(6,)]
    assert t.has("nothing_here") is False
    assert t.read == {"va", "a", "nothing_here"} and not t.everything
    t.columns("b")
    t.con.execute("SELECT table_name FROM duckdb_tables()")
    assert CATALOGUE in t.read and "b" not in t.read  # a table's columns are the catalogue's
    t.con.sql  # anything else of the connection: nothing to keep by
    assert t.everything


def test_a_part_is_taken_while_what_it_read_is_unchanged_and_rendered_when_it_changed():
    calls = []

    def part(db):
        calls.append(1)
        return f"a={db.rows('SELECT sum(x) FROM a')[1][0][0]} c={db.has('c')}"

    first = KeyedParts(ReportDB(_db()), "code")
    assert first.get("p", part) == "a=3 c=False"
    assert first.kept["p"]["deps"] == {"a": first.keys["a"], "c": ABSENT}
    again = KeyedParts(ReportDB(_db(b_rows=(6, 7))), "code", first.kept)  # only b changed: taken
    assert again.get("p", part) == "a=3 c=False" and len(calls) == 1 and again.taken == 1
    assert KeyedParts(ReportDB(_db()), "other code", first.kept).get("p", part) and len(calls) == 2
    assert KeyedParts(ReportDB(_db(a_rows=(1, 5))), "code", first.kept).get("p", part) == "a=6 c=False"
    assert KeyedParts(ReportDB(_db()), "code", first.kept).get("p", part, extra=["a figure"]) and len(calls) == 4
    con = _db()
    con.execute("CREATE TABLE c (z INTEGER)")  # a table it asked for and did not find: now there
    assert KeyedParts(ReportDB(con), "code", first.kept).get("p", part) == "a=3 c=True"


def test_rows_edited_without_their_key_are_never_taken():
    con = _db()
    first = KeyedParts(ReportDB(con), "code")
    first.get("p", lambda db: str(db.rows("SELECT sum(x) FROM a")[1][0][0]))
    con.execute("UPDATE a SET x = 10 WHERE x = 2")  # not by the rebuild: table_keys not updated
    later = KeyedParts(ReportDB(con), "code", first.kept)
    assert "a" not in later.keys
    assert later.get("p", lambda db: str(db.rows("SELECT sum(x) FROM a")[1][0][0])) == "11"
    assert "p" not in later.kept  # read a table without a key: not kept


def test_without_table_keys_nothing_is_kept():
    con = _db()
    con.execute("DROP TABLE table_keys")
    parts = KeyedParts(ReportDB(con), "code")
    assert parts.get("p", lambda db: str(db.count("a"))) == "2" and parts.kept == {}
