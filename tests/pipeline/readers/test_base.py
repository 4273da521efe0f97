"""The helpers every reader shares (pipeline/readers/base.py), on small hand-checked cases."""
import csv

import pytest

from pipeline.readers.base import (INFLATE_CEILING_BYTES, INFLATE_FLOOR_BYTES, MAX_CHANNELS, MAX_PARTS, ReaderError,
                                   SideCsvError, add_comment_line, check_channel_count, check_part_count, decode_text,
                                   exc_text, inflate_cap, mib, parse_key_value, read_time_limit, side_csv_rows,
                                   split_name_unit)


# -- headers -------------------------------------------------------------------------------
@pytest.mark.parametrize("header, expected", [
    ("p_a[bar(a)]", ("p_a", "bar(a)")),        # a unit with parentheses inside brackets
    ("x [mm]", ("x", "mm")),
    ("time(sec)", ("time", "sec")),
    (" p (bar) ", ("p", "bar")),
    ('"t [s]"', ("t", "s")),                   # quotes around the header are not part of it
    ("comment", ("comment", None)),
    ("x[]", ("x", None)),                      # an empty unit is no unit
    ("(s)", ("(s)", None)),                    # a unit without a name is a name
    ("a[b]c", ("a[b]c", None)),                # brackets not at the end: no unit
])
def test_split_name_unit(header, expected):
    assert split_name_unit(header) == expected


# -- text ----------------------------------------------------------------------------------
@pytest.mark.parametrize("data, whole, expected", [
    (b"\xef\xbb\xbfa;b", True, ("a;b", "utf-8-sig")),
    ("t;é\n".encode(), True, ("t;é\n", "utf-8")),
    (b"caf\xe9 ok\n", True, ("caf\xe9 ok\n", "latin-1")),      # not UTF-8: Latin-1
    (b"\xc3(ab", True, ("\xc3(ab", "latin-1")),
    (b"a\xc3", False, ("a", "utf-8")),                 # the first bytes of a file: "é" cut by the read
    (b"a\xe2\x82", False, ("a", "utf-8")),             # "€" cut after two of its three bytes
    (b"a\xc3", True, ("a\xc3", "latin-1")),            # the whole file: nothing was cut, no byte dropped
    (b"caf\xe9\n", True, ("caf\xe9\n", "latin-1")),    # Latin-1 near the end: no byte lost
    (b"caf\xe9\n", False, ("caf\xe9\n", "latin-1")),   # ... whether whole or not (\n is no continuation)
    (b"x;caf\xe9", True, ("x;caf\xe9", "latin-1")),
    (b"ab\xff", False, ("ab\xff", "latin-1")),          # a byte that starts no UTF-8 character
    (b"", True, ("", "utf-8")),
])
def test_decode_text(data, whole, expected):
    assert decode_text(data, whole=whole) == expected


@pytest.mark.parametrize("line, expected", [
    ("key: value", ("key", "value")),
    ("a=b", ("a", "b")),
    ("rig = plpa-1: two", ("rig", "plpa-1: two")),     # the first separator splits
    ("x.y-z: 1 = 2", ("x.y-z", "1 = 2")),
    (" Captured 2020-07-03 03:08:17 by x", None),      # a key has no spaces: a comment
    (":x", None),                                      # no key
    ("k" * 65 + "=1", None),                           # a key of more than 64 characters
    ("no separator", None),
])
def test_parse_key_value(line, expected):
    assert parse_key_value(line) == expected


def test_add_comment_line_keeps_pairs_as_keys_and_other_lines_as_comments_in_order():
    metadata: dict = {}
    for text in [" rig: plpa-1", " free text ", "", " comments: x", " kind=step"]:
        add_comment_line(text, metadata)
    # a `comments` key would replace the comments: it is kept as a comment line itself
    assert metadata == {"rig": "plpa-1", "comments": ["free text", "comments: x"], "kind": "step"}


# -- side CSV files ------------------------------------------------------------------------
def test_side_csv_rows_give_first_and_last_line_of_each_row():
    assert list(side_csv_rows(b"a,b\n1,2\n")) == [(1, 1, ["a", "b"]), (2, 2, ["1", "2"])]
    # a quoted field over two lines: the row spans lines 2 to 3
    assert list(side_csv_rows(b'a;b\n"x\ny";2\n')) == [(1, 1, ["a", "b"]), (2, 3, ["x\ny", "2"])]


def test_side_csv_delimiter_is_the_one_the_first_non_blank_line_uses_most():
    # "a\tb;c": one tab, one ";" -> the first of , ; tab with the most wins on a tie (";")
    assert list(side_csv_rows(b"\n\na\tb;c\n1\t2;3\n")) == [
        (1, 1, []), (2, 2, []), (3, 3, ["a\tb", "c"]), (4, 4, ["1\t2", "3"])]
    assert list(side_csv_rows(b"a\tb\n1\t2\n")) == [(1, 1, ["a", "b"]), (2, 2, ["1", "2"])]


@pytest.mark.parametrize("data, message, line", [
    (b"a,b\n1,\x002\n", "NUL byte (a binary or UTF-16 file?); save it as UTF-8 CSV", 2),
    (b'a,b\n"1,2\n3,4\n', "unclosed quote (the quoted field runs to the end of the file)", 2),
])
def test_side_csv_errors_name_the_line(data, message, line):
    with pytest.raises(SideCsvError) as err:
        list(side_csv_rows(data))
    assert err.value.args == (message, line)


def test_side_csv_field_over_the_csv_limit_is_an_error():
    limit = csv.field_size_limit()
    data = b"a,b\n1," + b"x" * (limit + 1) + b"\n"
    with pytest.raises(SideCsvError) as err:
        list(side_csv_rows(data))
    assert err.value.args == (f"a field is longer than {limit} characters (the csv module's limit)", 2)


# -- resource limits -----------------------------------------------------------------------
def test_inflate_cap_is_the_ratio_between_the_floor_and_the_ceiling():
    assert INFLATE_FLOOR_BYTES == 64 << 20 and INFLATE_CEILING_BYTES == 4 << 30
    assert inflate_cap(0) == 64 << 20                      # the floor
    assert inflate_cap(-5) == 64 << 20
    assert inflate_cap(671_088) == 64 << 20                # 100 x 671,088 B = 67,108,800 B: under the floor
    assert inflate_cap(671_089) == 67_108_900              # 100 x the size: just over the floor
    assert inflate_cap(1 << 20) == 100 << 20
    assert inflate_cap(1 << 30) == 4 << 30                 # the ceiling (not 100 GiB)


def test_read_time_limit():
    assert read_time_limit(0) == 300.0
    assert read_time_limit(-1) == 300.0
    assert read_time_limit(1_000_000) == 302.0             # + 1 MB at 0.5 MB/s


def test_channel_and_part_counts_are_refused_past_their_limits():
    check_channel_count(MAX_CHANNELS)
    with pytest.raises(ReaderError, match=rf"^{MAX_CHANNELS + 1} columns: more than the limit of {MAX_CHANNELS} "
                                          r"channels per file$"):
        check_channel_count(MAX_CHANNELS + 1)
    check_part_count(MAX_PARTS, "sheets")
    with pytest.raises(ReaderError, match=rf"^{MAX_PARTS + 1} sheets: more than the limit of {MAX_PARTS} runs "
                                          r"per file$"):
        check_part_count(MAX_PARTS + 1, "sheets")


def test_mib_and_exc_text_for_messages():
    assert mib(3 << 19) == "1.5 MiB"
    assert exc_text(KeyError(3)) == "KeyError: 3"
    assert exc_text(ValueError("")) == "ValueError"
    assert exc_text(ValueError("two\n   lines"), limit=7) == "ValueError: two lin"


def test_a_latin1_side_file_whose_only_accent_is_on_its_last_line_keeps_it():
    # a manifest saved by Excel in Latin-1 on a Windows PC: the last note must not lose its end
    data = "file,notes\na.csv,ok\nb.csv,café\n".encode("latin-1")
    assert [cells for _first, _last, cells in side_csv_rows(data)] == [["file", "notes"], ["a.csv", "ok"],
                                                                       ["b.csv", "café"]]
