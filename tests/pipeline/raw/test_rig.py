"""rig.toml files that cannot be used: each is its own quarantine line and the runs under it wait."""
import os

from pipeline.raw.rig import MAX_RIG_BYTES, bad_tables, deep_merge
from tests.pipeline.raw.conftest import rebuild_checked


def test_a_rig_toml_nested_too_deeply_is_quarantined(tree, warehouse):
    tree.write("c1/rig.toml", "[metadata]\nx = " + "[" * 1000 + "]" * 1000 + "\n")
    q = rebuild_checked(tree, warehouse, expect_runs=("c2/b",))
    msg = "invalid TOML: too deeply nested (arrays or inline tables inside each other)"
    assert q == {"c1/rig.toml": [(None, msg)], "c1/a.csv": [(None, f"cannot use c1/rig.toml: {msg}")]}


def test_a_rig_toml_over_the_size_cap_is_not_parsed(tree, warehouse):
    tree.write("c1/rig.toml", "[metadata]\nnotes = \"" + "x" * MAX_RIG_BYTES + "\"\n")
    q = rebuild_checked(tree, warehouse, expect_runs=("c2/b",))
    size = (tree.root / "c1" / "rig.toml").stat().st_size
    msg = f"{size} bytes, larger than the {MAX_RIG_BYTES} bytes a rig.toml may have"
    assert q == {"c1/rig.toml": [(None, msg)], "c1/a.csv": [(None, f"cannot use c1/rig.toml: {msg}")]}


def test_a_rig_toml_linked_from_outside_raw_is_not_read(tree, warehouse, tmp_path):
    (tmp_path / "shared-rig.toml").write_text('[metadata]\nrig = "other"\n')
    os.symlink(tmp_path / "shared-rig.toml", tree.root / "c1" / "rig.toml")
    q = rebuild_checked(tree, warehouse, expect_runs=("c2/b",))
    msg = f"symlink to a file outside raw/: {tmp_path / 'shared-rig.toml'}"
    assert q == {"c1/rig.toml": [(None, msg)], "c1/a.csv": [(None, f"cannot use c1/rig.toml: {msg}")]}


def test_deep_merge_puts_the_nearer_table_on_top_key_by_key():
    far = {"metadata": {"rig": "A", "notes": "far"}, "channels": {"x": {"unit": "mm"}}}
    near = {"metadata": {"notes": "near"}, "channels": {"x": {"scale": 2}}}
    assert deep_merge(far, near) == {"metadata": {"rig": "A", "notes": "near"},
                                     "channels": {"x": {"unit": "mm", "scale": 2}}}
    assert far["metadata"]["notes"] == "far"  # the inputs are left as they were


def test_bad_tables_names_unknown_and_malformed_tables():
    assert bad_tables({"metadata": {}, "read": {}}) is None
    assert bad_tables({"metadta": {}, "channels": 3}) == (
        "unknown or malformed table(s) channels, metadta "
        "(expected [read], [channels], [metadata], [sensors], [derived])")
