"""Names and messages made valid one-line UTF-8 wherever a problem is shown or stored."""
import os

from pipeline.raw.problems import Problem, display_name


def test_display_name_escapes_only_bytes_that_are_not_utf8():
    assert display_name("café/ü.csv") == "café/ü.csv"
    assert display_name(os.fsdecode(b"m\xe9sure.csv")) == "m\\xe9sure.csv"
    assert display_name("\ud800x") == "\\ud800x"
    assert display_name("a\nb\x7f") == "a\\x0ab\\x7f"
    for text in (os.fsdecode(b"a\xff\xfe/b\x80"), "\udce9"):
        display_name(text).encode("utf-8")  # valid UTF-8 whatever it gets


def test_a_problem_shows_its_path_and_error_escaped():
    p = Problem(os.fsdecode(b"c1/m\xe9sure.csv"), "bad\nname", 3)
    assert (p.source_path, p.error, p.line, p.stage) == ("c1/m\\xe9sure.csv", "bad\\x0aname", 3, "ingest")
