"""Metadata of a run (pipeline.raw.metadata): precedence rig.toml < file < manifest < part, typing, where `kind` goes."""
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from pipeline.raw.tree import RawTree
from pipeline.raw.metadata import (MetadataError, Part, normalise_keys, parse_started_at, parts_mode,
                                   resolve_metadata, run_metadata)

from tests.conftest import STEP_META
from tests.pipeline.ingest.helpers import BREAKAWAY, T, ingest, quarantine
from tests.pipeline.readers.generators import xlsx_workbook


def test_metadata_precedence_manifest_over_file_over_rig(raw, warehouse):
    raw.write("c/rig.toml", '[metadata]\nrig = "from-rig"\noperator = "rig-op"\nnotes = "rig-notes"\n')
    raw.csv("c/sub/a.csv", {"kind": "step", "started_at": "2026-01-01T00:00:00", "operator": "file-op",
                            "notes": "file-notes"}, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    raw.write("c/manifest.csv", "file,notes,custom_key\nsub/a.csv,manifest-notes,42\n")
    res = ingest(raw, "c/sub/a.csv", warehouse)
    p = res.run["params"]
    assert (p["rig"], p["operator"], p["notes"], p["custom_key"]) == ("from-rig", "file-op", "manifest-notes", "42")
    assert res.run["run_id"] == "c/a"
    assert res.run["started_at"] == "2026-01-01T00:00:00+00:00"


def test_sub_rig_toml_overrides_parent(raw, warehouse):
    raw.write("c/rig.toml", '[metadata]\nrig = "parent"\nkind = "step"\n')
    raw.write("c/sub/rig.toml", '[metadata]\nrig = "child"\n')
    raw.csv("c/sub/a.csv", {"started_at": "2026-01-01"}, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    assert ingest(raw, "c/sub/a.csv", warehouse).run["rig"] == "child"


def test_started_at_with_offset_is_converted_to_utc(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "started_at": "2026-06-01T10:00:00+02:00"}, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    assert ingest(raw, "c/a.csv", warehouse).run["started_at"] == "2026-06-01T08:00:00+00:00"


def test_q_missing_kind(raw, warehouse):
    raw.csv("c/a.csv", {"started_at": "2026-01-01", "rig": "r"}, {"t[s]": T})
    assert "missing metadata `kind`" in quarantine(raw, warehouse)


def test_q_unknown_kind(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "kind": "wobble"}, {"t[s]": T})
    assert "`kind` must be one of" in quarantine(raw, warehouse)


def test_q_bad_number_in_metadata(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "kind": "identification", "kp_v_m": "five"},
            {"t[s]": T, "x[m]": T, "u[V]": T, "u_d[V]": T, "x_ref[m]": T})
    assert "`kp_v_m` must be a number" in quarantine(raw, warehouse)


def test_q_bad_started_at(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "started_at": "last tuesday"}, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    assert "`started_at` is not ISO 8601" in quarantine(raw, warehouse)


def test_tdms_root_group_beats_rig_toml_group(raw, warehouse):
    """Precedence manifest > file > rig.toml also holds for the hints a reader uses."""
    import numpy as np
    from nptdms import ChannelObject, RootObject, TdmsWriter

    path = raw.root / "c" / "two_groups.tdms"
    path.parent.mkdir(parents=True)
    raw.write("c/rig.toml", '[metadata]\ngroup = "wrong"\n')
    root = RootObject({"kind": "step", "started_at": "2026-01-01T00:00:00", "rig": "r", "group": "right"})
    chans = []
    for group, value in (("wrong", 1.0), ("right", 2.0)):
        for name in ("t", "x", "x_ref"):
            data = np.arange(3.0) if name == "t" else np.full(3, value)
            chans.append(ChannelObject(group, name, data, properties={"unit_string": "s" if name == "t" else "m"}))
    with TdmsWriter(str(path)) as w:
        w.write_segment([root] + chans)
    res = ingest(raw, "c/two_groups.tdms", warehouse)
    assert res.error is None, res.error
    assert pq.read_table(warehouse / res.run["samples_path"]).column("x_m").to_pylist() == [2.0, 2.0, 2.0]


@pytest.mark.parametrize("text", ["nan", "inf", "-Infinity"])
def test_q_non_finite_number_in_metadata(raw, warehouse, text):
    raw.csv("c/a.csv", {**BREAKAWAY, "hose_area_m2": text}, {"t[s]": T, "p_a[bar]": T, "p_b[bar]": T, "x[m]": T})
    assert quarantine(raw, warehouse) == f"metadata `hose_area_m2` must be a finite number, got {text!r}"


def test_q_non_finite_number_in_rig_toml_metadata(raw, warehouse):
    raw.write("c/rig.toml", "[metadata]\nhose_area_m2 = nan\n")          # a TOML float, not text
    meta = {k: v for k, v in BREAKAWAY.items() if k != "hose_area_m2"}
    raw.csv("c/a.csv", meta, {"t[s]": T, "p_a[bar]": T, "p_b[bar]": T, "x[m]": T})
    assert quarantine(raw, warehouse) == "metadata `hose_area_m2` must be a finite number, got nan"


def test_parts_keys_are_ignored_by_one_run_formats(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    raw.write("c/rig.toml", '[read]\nsheets = "all"\ngroups = "all"\n')
    res = ingest(raw, "c/a.csv", warehouse)
    assert res.parts is None and res.run["run_id"] == "c/a"


def test_sheet_names_with_control_characters_give_one_line_run_ids(raw, warehouse):
    rows = [["t[s]", "x[mm]", "x_ref[mm]"], [0.0, 1.0, 0.0], [0.1, 2.0, 0.0]]
    xlsx_workbook(raw.root / "c" / "b.xlsx", {"a\tb": rows}, STEP_META)
    raw.write("c/manifest.csv", "file,sheets,run_id\nb.xlsx,all,day3\n")
    (part,) = ingest(raw, "c/b.xlsx", warehouse).parts
    assert part.run["run_id"] == "day3/a\\x09b" and part.run["params"]["sheet"] == "a\tb"


# -- issue 25 item 16: a file without `kind` says where to declare it ---------------------------
def _foreign_lvm_without_kind(raw):
    """The foreign campaign's 1 um encoder run, as LabVIEW wrote it, with no `kind` anywhere:
    not in the LVM's Description, not in its lab's rig.toml, no manifest."""
    from pipeline.simulator.foreign import CAMPAIGN, RIG_TOMLS, plan, simulate
    from pipeline.simulator.writers import ColumnOut, write_lvm

    run = next(r for r in plan() if r.fmt == "lvm")
    sim = simulate(run, 1)
    cols = [ColumnOut(c, c.rsplit("_", 1)[0], u) for c, u in run.units.items()]
    meta = {k: v for k, v in sim.metadata.items() if k not in ("rig", "hose_area_m2", "kind")}  # as write_run
    meta = {"run_id": run.run_id, "started_at": "2026-02-02T09:00:00", "operator": "guest", **meta}
    path = raw.root / run.rel_path
    path.parent.mkdir(parents=True, exist_ok=True)
    write_lvm(path, sim.data, cols, meta, fs_hz=run.sim["fs_hz"])
    raw.write(f"{CAMPAIGN}/{run.folder}/rig.toml", RIG_TOMLS[f"{run.folder}/rig.toml"], dedent=False)
    return run


def test_missing_kind_says_where_to_declare_it_and_each_way_works(raw, warehouse):
    from pipeline.rebuild.flow import rebuild
    from pipeline.simulator.foreign import CAMPAIGN, RIG_TOMLS

    run = _foreign_lvm_without_kind(raw)
    (p,) = rebuild(raw.root, warehouse, jobs=1, report=False).quarantine
    assert p.source_path == run.rel_path and "\n" not in p.error
    assert p.error.startswith("missing metadata `kind` (one of ")
    # the three places, each with its one-line example, the manifest row naming this very file
    assert "`kind=viscous`" not in p.error  # an example, not a guess of this run's kind
    assert "the file's own metadata (LVM: `kind=step` in the header's Description)" in p.error
    assert "a manifest.csv row (`file,kind` then `encoder-1um.lvm,step`)" in p.error
    assert "rig.toml (`[metadata]` then `kind = \"step\"`)" in p.error
    folder = f"{CAMPAIGN}/{run.folder}"
    # as the manifest example says (with this run's kind): the run ingests
    raw.write(f"{folder}/manifest.csv", "file,kind\nencoder-1um.lvm,viscous\n")
    summary = rebuild(raw.root, warehouse, jobs=1, report=False)
    assert summary.quarantine == [] and summary.exit_code == 0
    # as the rig.toml example says: too
    (raw.root / folder / "manifest.csv").unlink()
    raw.write(f"{folder}/rig.toml", RIG_TOMLS[f"{run.folder}/rig.toml"].replace(
        "[metadata]\n", '[metadata]\nkind = "viscous"\n'), dedent=False)
    summary = rebuild(raw.root, warehouse, jobs=1, report=False)
    assert summary.quarantine == [] and summary.exit_code == 0


def test_missing_kind_in_a_csv_names_the_csv_comment_line(raw, warehouse):
    raw.csv("c/run 01.csv", {"started_at": "2026-01-01", "rig": "r"}, {"t[s]": T})
    err = quarantine(raw, warehouse, "c/run 01.csv")
    assert "the file's own metadata (CSV: a `# kind: step` line above the header)" in err
    assert "(`file,kind` then `run 01.csv,step`)" in err
    raw.write("c/a,b.csv", "# rig: r\nt[s]\n0\n")  # a name the CSV row must quote
    assert '(`file,kind` then `"a,b.csv",step`)' in quarantine(raw, warehouse, "c/a,b.csv")


# -- comment lines are not metadata (issue 25 item 4) ------------------------------------------
def test_comment_line_is_kept_under_comments_not_read_as_a_key(raw, warehouse):
    raw.write("c/a.csv", "# Captured 2020-07-03 03:08:17.057076 by unknown user\n# kind: step\n"
                         "# started_at: 2026-01-02T03:04:05\n# rig = plpa-1\nt[s],x[m],x_ref[m]\n0,0,0\n0.1,0,0\n")
    res = ingest(raw, "c/a.csv", warehouse)
    p = res.run["params"]
    assert p["comments"] == ["Captured 2020-07-03 03:08:17.057076 by unknown user"]
    assert not any(k.startswith("Captured") for k in p)
    assert res.run["rig"] == "plpa-1" and res.run["kind"] == "step"



# -- the functions themselves ---------------------------------------------------------------------
def test_resolve_metadata_manifest_over_embedded_over_rig_and_types_the_values():
    meta = resolve_metadata({"Kind": "step", "rig": "r", "operator": "rig-op", "notes": "rig"},
                            {"OPERATOR": "file-op", "notes": "file"}, {"notes": "manifest", "extra": " "},
                            "c", Path("sub/a.csv"))
    assert (meta["kind"], meta["rig"], meta["operator"], meta["notes"]) == ("step", "r", "file-op", "manifest")
    assert meta["run_id"] == "c/a" and "extra" not in meta      # blank values are no value
    assert resolve_metadata({"kind": "step"}, {}, {}, "c", Path("b.xlsx"), part="S1")["run_id"] == "c/b/S1"


def test_parse_started_at_and_normalise_keys():
    assert parse_started_at("2026-01-02 03:04:05") == "2026-01-02T03:04:05+00:00"
    with pytest.raises(MetadataError, match="not ISO 8601"):
        parse_started_at("yesterday")
    assert normalise_keys({" Started_At ": 1, "Custom": 2}) == {"started_at": 1, "Custom": 2}


def test_run_metadata_is_asked_once_and_gives_the_rig_config_and_the_export(raw):
    raw.write("c/rig.toml", '[metadata]\nrig = "r"\n[channels.pos]\nchannel = "x"\nunit = "mm"\n')
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "pos": T, "x_ref[m]": T})
    got = run_metadata(RawTree(raw.root), raw.root / "c" / "a.csv", "c")
    assert got.meta["run_id"] == "c/a" and got.meta["kind"] == "step"
    assert got.rig["channels"] == {"pos": {"channel": "x", "unit": "mm"}}
    assert got.export.format == "csv" and [c.name for c in got.export.columns] == ["t", "pos", "x_ref"]


def test_a_part_takes_the_files_row_then_its_own_and_drops_the_parts_keys(raw):
    rows = [["t[s]", "x[mm]", "x_ref[mm]"], [0.0, 1.0, 0.0], [0.1, 2.0, 0.0]]
    xlsx_workbook(raw.root / "c" / "b.xlsx", {"S1": rows, "S2": rows}, STEP_META)
    raw.write("c/manifest.csv", "file,sheets,run_id,operator\nb.xlsx,all,day3,ann\nb.xlsx#S2,,,bob\n")
    tree, path = RawTree(raw.root), raw.root / "c" / "b.xlsx"
    assert parts_mode(tree, path) == ("sheets", "sheet")
    one, two = (run_metadata(tree, path, "c", part=Part("sheets", "sheet", n)).meta for n in ("S1", "S2"))
    assert (one["run_id"], one["operator"], one["sheet"]) == ("day3/S1", "ann", "S1") and "sheets" not in one
    assert (two["run_id"], two["operator"], two["sheet"]) == ("day3/S2", "bob", "S2")


def test_parts_key_other_than_all_is_refused(raw):
    raw.write("c/rig.toml", '[read]\nsheets = "first"\n')
    with pytest.raises(MetadataError, match='the only value is "all" \\(one run per sheet\\)'):
        parts_mode(RawTree(raw.root), raw.root / "c" / "b.xlsx")
