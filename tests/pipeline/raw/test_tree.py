"""RawTree: paths as stored, what the walk says about one entry, miscased side files, and run
metadata from its rig.toml and manifest files read once."""
import os

import pytest

from pipeline.raw.problems import ConfigError
from pipeline.raw.tree import RawTree, discover_runs


def test_paths_keep_a_links_own_name_and_are_shown_relative_to_raw(raw, tmp_path):
    raw.write("c1/sub/a.csv", "x\n")
    os.symlink(raw.root / "c1", raw.root / "alias")
    tree = RawTree(raw.root)
    assert tree.real(raw.root / "alias" / "sub" / "a.csv") == raw.root.resolve() / "c1" / "sub" / "a.csv"
    assert tree.rel(raw.root / "c1" / "sub" / "a.csv") == "c1/sub/a.csv"
    assert tree.campaign(raw.root / "c1" / "sub" / "a.csv") == "c1"
    assert tree.campaign(raw.root / "top.csv") is None
    assert tree.rel(tmp_path / "elsewhere.csv").endswith("elsewhere.csv")  # not under raw/: still one line
    assert tree.folders(raw.root / "c1" / "sub" / "a.csv") == [
        raw.root.resolve(), raw.root.resolve() / "c1", raw.root.resolve() / "c1" / "sub"]


def test_discover_runs_reuses_the_trees_walk_and_names_the_ignored_files(raw):
    raw.write("c/a.csv", "x\n")
    raw.write("c/photo.png", b"\x89PNG")
    raw.write("c/README.txt", "notes\n")
    tree = RawTree(raw.root)
    ignored = []
    assert discover_runs(tree, ignored) == [raw.root.resolve() / "c" / "a.csv"]
    assert ignored == [raw.root.resolve() / "c" / "photo.png"]
    assert tree.listing() is tree.listing()  # walked once
    assert discover_runs(raw.root) == [raw.root.resolve() / "c" / "a.csv"]


def test_a_miscased_side_file_is_one_problem_and_refuses_the_runs_under_it(raw):
    raw.write("c/a.csv", "x\n")
    raw.write("c/RIG.TOML", "[metadata]\n")
    tree = RawTree(raw.root)
    for _ in range(2):
        with pytest.raises(ConfigError, match="cannot use c/RIG.TOML: named `RIG.TOML`"):
            tree.rig_config(raw.root / "c" / "a.csv")
    assert [(p.source_path, p.error) for p in tree.problems] == [
        ("c/RIG.TOML", "named `RIG.TOML`: a rig.toml must be named `rig.toml` (lower case); it is not read")]


def test_rig_and_manifest_metadata_merge_nearer_over_farther(raw):
    raw.write("rig.toml", '[metadata]\nrig = "A"\nnotes = "far"\n')
    raw.write("c/rig.toml", '[metadata]\nnotes = "near"\n')
    raw.write("c/a.csv", "x\n")
    raw.write("manifest.csv", "file,operator\nc/a.csv,Lee\n")
    tree = RawTree(raw.root)
    path = raw.root / "c" / "a.csv"
    cfg = tree.rig_config(path)
    assert cfg["metadata"] == {"rig": "A", "notes": "near"} and set(cfg) == {
        "read", "channels", "metadata", "sensors", "derived"}
    cfg["metadata"]["rig"] = "changed by a caller"
    assert tree.rig_config(path)["metadata"]["rig"] == "A"  # each caller gets its own copy
    assert tree.rig_json(path).startswith('{"channels": {}, "derived": {}, "metadata": {"notes": "near"')
    assert tree.manifest_metadata(path) == {"operator": "Lee"} and tree.manifest_parts(path) == {}
    tree.scan_rigs()
    tree.scan_manifests()
    assert tree.problems == []
