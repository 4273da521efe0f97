"""pipeline/stages/warehouse_paths.py: one rule for paths under the warehouse, in the memo's keys and the spring fit's digest."""
import os

from pipeline.stages.warehouse_paths import under_warehouse, warehouse_prefix


def test_a_path_under_the_warehouse_is_written_relative_to_it_and_others_are_not(tmp_path):
    wh = tmp_path / "wh"
    prefix = warehouse_prefix(wh)
    assert prefix == str(wh) + os.sep == warehouse_prefix(str(wh) + os.sep)   # one trailing separator
    assert under_warehouse(str(wh / "samples" / "a.parquet"), prefix) == os.path.join("samples", "a.parquet")
    assert under_warehouse(str(tmp_path / "wh2" / "a.parquet"), prefix) is None  # a sibling's name is not under it
    assert under_warehouse(str(wh), prefix) is None                              # the warehouse itself is not
    assert under_warehouse(str(wh / "a"), None) is None


def test_the_memo_and_the_spring_fit_key_a_moved_warehouse_alike(tmp_path):
    """The memo's key and the models stage's digest of a chamber's runs both follow the rule: a moved
    warehouse keeps them, a samples file elsewhere is named absolutely."""
    from pipeline.rebuild.memo import item_key
    from pipeline.stages.models import _fit_item, fit_spring_item

    def runs(wh):
        return (("spring", "c/r1", str(wh / "samples" / "r1.parquet"), {"p0_bar_abs": 2.0}),
                ("spring", "c/r2", "/elsewhere/r2.parquet", {}))

    a, b = tmp_path / "a", tmp_path / "b"
    assert _fit_item("front", runs(a), a).memo_key == _fit_item("front", runs(b), b).memo_key
    assert item_key(fit_spring_item, ("front", runs(a)), a) == item_key(fit_spring_item, ("front", runs(b)), b)
    assert _fit_item("front", runs(a), b).memo_key != _fit_item("front", runs(a), a).memo_key
