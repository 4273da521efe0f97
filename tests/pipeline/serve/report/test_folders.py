"""The report folder's names: a run page's name is safe and distinct per run id."""
import re


def test_page_names_are_safe_and_distinct():
    from pipeline.serve.report.folders import page_name

    ids = ["a/b", "a_b", "A/B", "../../etc/passwd", "x" * 500, "ü/ö", ""]
    names = [page_name(i) for i in ids]
    assert len(set(names)) == len(ids)
    for n in names:
        assert re.fullmatch(r"[A-Za-z0-9._-]+\.html", n) and not n.startswith(".") and len(n) < 100
