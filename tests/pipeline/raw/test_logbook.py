"""The hose logbook: reading, quarantining rows that make no sense, merging campaigns."""
import pandas as pd
import pytest

from pipeline.raw.logbook import find_logbooks, merge_logbooks, parse_time, read_logbook, read_logbooks

HEADER = "hose_id,event,at,hose_type,adjustment,z_rollers_mm,spring_force_n,failure_mode,wall_thickness_mm,distance_km,notes\n"


def ts(text):
    return pd.Timestamp(text, tz="UTC")


def test_rows_that_make_no_sense_are_quarantined_with_line_numbers(raw):
    raw.write("c1/hoses.csv", HEADER +
              "H1,installed,2026-01-01T08:00,FLEXIGOM AIR,force,,866,,,,\n"        # line 2
              "H1,exploded,2026-01-02T08:00,,,,,,,,\n"                              # 3 unknown event
              ",failed,2026-01-02T08:00,,,,,rupture,,,\n"                           # 4 no hose_id
              "H1,inspected,yesterday,,,,,,1.9,,\n"                                  # 5 bad time
              "H2,failed,2026-01-01T00:00,,,,,rupture,,3.0,\n"                      # 6 before installation
              "H2,installed,2026-01-05T00:00,FLEXIGOM AIR,distance,4.5,,,,,\n"      # 7
              "H2,removed,2026-01-09T00:00,,,,,,,lots,\n"                            # 8 not a number
              "H3,installed,2026-01-05T00:00,FLEXIGOM AIR,sideways,4.5,,,,,\n"      # 9 bad adjustment
              "\n"
              "H2,removed,2026-01-10T00:00,,,,,,,7.5,stopped\n")                    # 11 fine
    events, problems = read_logbook(raw.root / "c1/hoses.csv", "c1/hoses.csv")
    hoses, merge_problems = merge_logbooks(events)
    problems += merge_problems
    got = sorted((p.line, p.error) for p in problems)
    assert [line for line, _ in got] == [3, 4, 5, 6, 8, 9]
    assert all(p.stage == "logbook" and p.source_path == "c1/hoses.csv" for p in problems)
    assert "unknown event `exploded`" in dict(got)[3]
    assert "no hose_id" in dict(got)[4]
    assert "not ISO 8601" in dict(got)[5]
    assert "before it was installed" in dict(got)[6]
    assert "`lots` is not a number" in dict(got)[8]
    assert "neither distance nor force" in dict(got)[9]
    # the other rows still count
    h = hoses.set_index("hose_id")
    assert list(h.index) == ["H1", "H2"]
    assert h.loc["H1", "status"] == "running" and h.loc["H1", "spring_force_n"] == 866
    assert h.loc["H2", "status"] == "removed" and h.loc["H2", "odometer_km"] == 7.5
    assert h.loc["H2", "z_rollers_mm"] == 4.5


def test_semicolon_logbook_with_decimal_comma_and_offsets(raw):
    raw.write("c/hoses.csv", "hose_id;event;at;adjustment;z_rollers_mm;distance_km\n"
              "H1;installed;2026-01-01T09:00+01:00;Distance;4,5;\n"
              "H1;failed;2026-01-03T08:00:00Z;;;12,25\n")
    events, problems = read_logbook(raw.root / "c/hoses.csv", "c/hoses.csv")
    assert problems == []
    assert list(events["at"]) == [ts("2026-01-01T08:00"), ts("2026-01-03T08:00")]
    hoses, _ = merge_logbooks(events)
    row = hoses.iloc[0]
    assert (row["adjustment"], row["z_rollers_mm"], row["status"], row["odometer_km"]) == ("distance", 4.5, "failed", 12.25)


def test_header_without_required_columns_quarantines_the_file(raw):
    raw.write("c/hoses.csv", "hose,what,when\nH1,installed,2026-01-01\n")
    events, problems = read_logbook(raw.root / "c/hoses.csv", "c/hoses.csv")
    assert events.empty and len(problems) == 1 and problems[0].line == 1
    assert "hose_id" in problems[0].error


def test_logbooks_merge_across_campaigns_and_skip_dotted_folders(raw):
    raw.write("a/hoses.csv", HEADER + "H1,installed,2026-01-01T00:00,FLEXIGOM AIR,force,,866,,,,\n"
                                      "H2,installed,2026-01-01T00:00,FLEXIGOM AIR,distance,4,,,,,\n")
    # the same installation logged again in campaign b, then the hose fails there
    raw.write("b/sub/hoses.csv", HEADER + "H1,installed,2026-01-01T00:00,,,,,,,,\n"
                                          "H1,inspected,2026-01-20T00:00,,,,,,1.7,,\n"
                                          "H1,failed,2026-02-01T00:00,,,,,leakage,,40,\n")
    raw.write(".trash/hoses.csv", HEADER + "H9,installed,2026-01-01T00:00,,,,,,,,\n")
    assert [p.relative_to(raw.root).as_posix() for p in find_logbooks(raw.root)] == ["a/hoses.csv", "b/sub/hoses.csv"]
    events, problems = read_logbooks(raw.root)
    hoses, merge_problems = merge_logbooks(events)
    assert problems == [] and merge_problems == []
    h = hoses.set_index("hose_id")
    assert list(h.index) == ["H1", "H2"]
    assert h.loc["H1", "status"] == "failed" and h.loc["H1", "failure_mode"] == "leakage"
    assert h.loc["H1", "campaigns"] == ["a", "b"] and h.loc["H1", "n_installations"] == 1
    assert h.loc["H1", "hose_type"] == "FLEXIGOM AIR" and h.loc["H1", "wall_thickness_mm"] == 1.7
    assert h.loc["H2", "status"] == "running"


# -- careless logbooks ------------------------------------------------------------------------------
@pytest.mark.parametrize("at", ["now", "today", "Now", "1/2/2026", "2 Jan 2026", "2026-1-2", "02.01.2026",
                                "2026-01-02T08", "yesterday 08:00", "2026-02-30"])
def test_times_that_are_not_strict_iso_8601_are_quarantined(raw, at):
    raw.write("c/hoses.csv", HEADER + "H1,installed,2026-01-01,T,force,,866,,,,\n"
              f"H1,removed,{at},,,,,,,5,\n")
    events, problems = read_logbook(raw.root / "c/hoses.csv", "c/hoses.csv")
    assert len(events) == 1
    assert [(p.source_path, p.line) for p in problems] == [("c/hoses.csv", 3)]
    assert f"`{at}` is not ISO 8601" in problems[0].error


@pytest.mark.parametrize("at,expected", [
    ("2026-01-02", "2026-01-02T00:00"), ("2026-01-02T08:30", "2026-01-02T08:30"),
    ("2026-01-02 08:30:15.25", "2026-01-02T08:30:15.25"), ("2026-01-02T09:30+01:00", "2026-01-02T08:30"),
    ("2026-01-02T09:30:00+0100", "2026-01-02T08:30"), ("2026-01-02T08:30:00z", "2026-01-02T08:30")])
def test_strict_iso_8601_times_are_read(at, expected):
    assert parse_time(at) == ts(expected)


def test_two_logbooks_that_disagree_on_an_event_are_flagged_with_both_files_and_lines(raw):
    raw.write("a/hoses.csv", HEADER + "H1,installed,2026-01-01T08:00,FLEXIGOM AIR,force,,866,,,,\n"
              "H1,failed,2026-01-09T08:00,,,,,rupture,,40,\n")
    raw.write("b/hoses.csv", HEADER + "H1,installed,2026-01-01T08:00,SILICONE,distance,,866,,,,\n"
              "H1,failed,2026-01-09T08:00,,,,,leakage,,400,\n"
              "H2,installed,2026-01-01T08:00,T,force,,866,,,,same hose twice is fine,\n")
    raw.write("c/hoses.csv", HEADER + "H2,installed,2026-01-01T08:00,T,force,,866,,,,other notes\n")
    events, problems = read_logbooks(raw.root)
    hoses, merge_problems = merge_logbooks(events)
    assert problems == []
    got = sorted((p.source_path, p.line, p.error) for p in merge_problems)
    assert [(s, ln) for s, ln, _ in got] == [("b/hoses.csv", 2), ("b/hoses.csv", 3)]
    assert "disagrees with a/hoses.csv:2" in got[0][2]
    assert "hose_type `SILICONE` vs `FLEXIGOM AIR`" in got[0][2] and "adjustment `distance` vs `force`" in got[0][2]
    assert "disagrees with a/hoses.csv:3" in got[1][2]
    assert "failure_mode `leakage` vs `rupture`" in got[1][2] and "distance_km 400 vs 40" in got[1][2]
    h = hoses.set_index("hose_id")
    assert (h.loc["H1", "hose_type"], h.loc["H1", "failure_mode"], h.loc["H1", "odometer_km"]) == (
        "FLEXIGOM AIR", "rupture", 40.0)  # the first logbook's values, not a silent mix
    warn = " ".join(h.loc["H1", "warnings"])
    assert "logbooks disagree" in warn and "a/hoses.csv:3" in warn and "b/hoses.csv:3" in warn
    assert h.loc["H2", "warnings"] == []  # same values (notes differ): one event, no warning


def test_overlapping_installations_in_two_logbooks_name_the_first(raw):
    raw.write("a/hoses.csv", HEADER + "H1,installed,2026-01-01T08:00,T,force,,866,,,,\n")
    raw.write("b/hoses.csv", HEADER + "H1,installed,2026-01-05T08:00,T,force,,866,,,,\n")
    hoses, problems = merge_logbooks(read_logbooks(raw.root)[0])
    assert [(p.source_path, p.line) for p in problems] == [("b/hoses.csv", 2)]
    assert "still installed since" in problems[0].error and "(a/hoses.csv:2)" in problems[0].error
    assert hoses.iloc[0]["n_installations"] == 1


def test_an_odometer_that_goes_down_is_flagged(raw):
    raw.write("a/hoses.csv", HEADER + "H1,installed,2026-01-01,T,force,,866,,,,\n"
              "H1,removed,2026-01-05,,,,,,,400,\n")
    raw.write("b/hoses.csv", HEADER + "H1,installed,2026-01-06,T,force,,866,,,,\n"
              "H1,failed,2026-01-09,,,,,rupture,,40,\n")
    hoses, problems = merge_logbooks(read_logbooks(raw.root)[0])
    assert [(p.source_path, p.line) for p in problems] == [("b/hoses.csv", 3)]
    assert "distance_km 40 at 2026-01-09" in problems[0].error and "lower than 400" in problems[0].error
    assert "(a/hoses.csv:3)" in problems[0].error
    row = hoses.iloc[0]
    assert row["status"] == "failed" and row["odometer_km"] == 400.0  # the event counts, the reading does not
    assert any("b/hoses.csv:3" in w and "does not go back" in w for w in row["warnings"])


def test_careless_logbooks_in_a_rebuild_are_quarantine_lines_and_hose_warnings(raw, tmp_path):
    from pipeline.rebuild.flow import rebuild
    from pipeline.rebuild.options import EXIT_QUARANTINED
    from tests.conftest import STEP_META, query

    raw.csv("a/run.csv", STEP_META, {"t[s]": [0.0, 0.1], "x[m]": [0.0, 0.1], "x_ref[m]": [0.1, 0.1]})
    raw.write("a/hoses.csv", HEADER + "H1,installed,2026-01-01,T,force,,866,,,,\nH1,removed,now,,,,,,,5,\n"
              "H2,installed,2026-01-01,T,force,,866,,,,\nH2,failed,2026-01-09,,,,,rupture,,40,\n")
    raw.write("b/hoses.csv", HEADER + "H2,failed,2026-01-09,,,,,rupture,,400,\n")
    wh = tmp_path / "wh"
    before = {p: p.read_bytes() for p in raw.root.rglob("*") if p.is_file()}
    assert rebuild(raw.root, wh, jobs=1).exit_code == EXIT_QUARANTINED
    assert {p: p.read_bytes() for p in raw.root.rglob("*") if p.is_file()} == before
    rows = query(wh, "SELECT source_path, line, error FROM quarantine ORDER BY 1, 2")
    assert [(s, ln) for s, ln, _ in rows] == [("a/hoses.csv", 3), ("b/hoses.csv", 2)]
    assert "`now` is not ISO 8601" in rows[0][2] and "disagrees with a/hoses.csv:5" in rows[1][2]
    life = dict(query(wh, "SELECT hose_id, warnings FROM hose_life ORDER BY 1"))
    assert life["H1"] == [] and any("b/hoses.csv:2" in w for w in life["H2"])
    assert query(wh, "SELECT run_id FROM runs") == [("a/run",)]


@pytest.mark.parametrize("body,line,error", [
    (HEADER.encode() + b"H1,installed,2026-01-01,T,force,,866,,,,\nH1,failed,2026-01-09,,,,,rup\x00ture,,,\n", 3,
     "NUL byte (a binary or UTF-16 file?)"),
    (HEADER.encode() + b'H1,installed,2026-01-01,"T,force,,866,,,,\nH1,failed,2026-01-09,,,,,rupture,,,\n', 2,
     "unclosed quote (the quoted field runs to the end of the file)"),
    (HEADER.encode() + b"H1,installed,2026-01-01,T,force,,866,,,," + b"x" * 200_000 + b"\n", 2,
     "a field is longer than 131072 characters"),
])
def test_a_logbook_that_is_not_csv_text_is_quarantined_whole_with_its_line(raw, body, line, error):
    raw.write("c/hoses.csv", body)
    events, problems = read_logbook(raw.root / "c/hoses.csv", "c/hoses.csv")
    assert events.empty  # no silently swallowed or mangled events
    assert [(p.source_path, p.line) for p in problems] == [("c/hoses.csv", line)]
    assert problems[0].error.startswith(error) and problems[0].error.endswith("no row of it is read")


def test_within_the_rebuilds_walk_logbooks_are_found_without_walking_and_read_once(raw, monkeypatch):
    """``walked``: the logbooks of the walk the rebuild made (raw/ not walked again) and one read of
    them for every stage that asks, each caller getting its own copy of what was read."""
    from pipeline.raw import logbook
    from pipeline.raw.walk import walk_raw

    raw.write("c1/hoses.csv", HEADER + "H1,installed,2026-01-01T08:00,FLEXIGOM AIR,force,,866,,,,\n"
              "H1,exploded,2026-01-02T08:00,,,,,,,,\n")
    raw.write("c2/hoses.csv", HEADER + "H2,installed,2026-01-05T00:00,FLEXIGOM AIR,distance,4.5,,,,,\n")
    alone_events, alone_problems = read_logbooks(raw.root)
    side = walk_raw(raw.root).side
    reads = []
    real = logbook.read_logbook
    monkeypatch.setattr(logbook, "read_logbook", lambda p, *a, **k: reads.append(p) or real(p, *a, **k))
    monkeypatch.setattr(logbook, "walk_raw", lambda *a, **k: pytest.fail("raw/ walked again"))
    with logbook.walked(raw.root, side):
        assert find_logbooks(raw.root) == [p for p in side if p.name == "hoses.csv"]
        first, first_problems = read_logbooks(raw.root)
        first.loc[0, "hose_id"] = "changed by a stage"
        second, second_problems = read_logbooks(raw.root)
    assert len(reads) == 2  # each logbook once for both stages
    pd.testing.assert_frame_equal(second, alone_events)
    assert second_problems == alone_problems and second_problems is not first_problems
    monkeypatch.setattr(logbook, "walk_raw", walk_raw)
    assert len(find_logbooks(raw.root)) == 2  # outside it: walked as before
