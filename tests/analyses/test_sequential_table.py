"""The even designs as arrays: adopted, they give every design bit for bit without a recursion; a table of
another form is refused whole."""
import numpy as np
import pytest

from analyses import sequential, sequential_boundaries
from analyses.sequential_table import FIRST_MAXIMUM, adopt_table, holds_table, table_names


@pytest.fixture
def table(designs_table):
    """The even designs of alpha 0.05 and O'Brien-Fleming (tests/conftest.py, computed once)."""
    return designs_table


CASES = [(1.5, 0.8, shape, hoses) for shape in (1.6, 2.3, 3.1) for hoses in (None, 6, 15)] + [(2.0, 0.9, 2.0, None)]


def _designs():
    return [sequential.design_for(m, 0.05, p, "obrien-fleming", s, h) for m, p, s, h in CASES]


def test_adopted_designs_are_the_computed_ones_bit_for_bit_and_run_no_recursion(table, monkeypatch):
    sequential.clear_caches()
    computed = _designs()
    boundaries = [sequential_boundaries.efficacy_boundaries(np.arange(1, m + 1) / m) for m in (4, 37, 100)]
    sequential.clear_caches()
    assert set(table) == set(table_names()) and table["c_4"].shape == (4,) and table["flat_100"].shape[0] == 5
    assert adopt_table(table, 0.05, "obrien-fleming") and holds_table(0.05, "obrien-fleming")
    assert not holds_table(0.05, "pocock")

    def no_recursion(*_a, **_k):
        raise AssertionError("a recursion ran")
    monkeypatch.setattr(sequential_boundaries._Recursion, "advance", no_recursion)
    monkeypatch.setattr(sequential_boundaries._Recursion, "null_boundary", no_recursion)
    assert _designs() == computed      # every field, exactly
    for m, ref in zip((4, 37, 100), boundaries):
        assert np.array_equal(sequential_boundaries.efficacy_boundaries(np.arange(1, m + 1) / m), ref)
    sequential.clear_caches()


def _changed(table, name, value):
    out = dict(table)
    out[name] = value
    return out


@pytest.mark.parametrize("bad", [
    "missing", "extra", "float32", "nan", "above 40", "zero", "short", "flat rows", "negative mass", "not a mapping"])
def test_a_table_of_another_form_is_refused_whole(table, bad):
    c10, flat = table["c_10"], table["flat_20"]
    bad_flat = flat.copy()
    bad_flat[1, 0] = -1.0
    tables = {"missing": {k: v for k, v in table.items() if k != "c_50"},
              "extra": _changed(table, "c_101", np.ones(101)),
              "float32": _changed(table, "c_10", c10.astype(np.float32)),
              "nan": _changed(table, "c_10", np.where(np.arange(10) == 3, np.nan, c10)),
              "above 40": _changed(table, "c_10", c10 + 40.0),
              "zero": _changed(table, "c_10", 0.0 * c10),
              "short": _changed(table, "c_10", c10[:9]),
              "flat rows": _changed(table, "flat_20", flat[:4]),
              "negative mass": _changed(table, "flat_20", bad_flat),
              "not a mapping": [table[k] for k in table_names()]}
    sequential.clear_caches()
    assert not adopt_table(tables[bad], 0.05, "obrien-fleming")
    assert not sequential_boundaries._DESIGNS          # nothing kept, not even the valid part
    assert not adopt_table(table, 0.05, "neither")     # an unknown spending function
    assert adopt_table(table, 0.05, "obrien-fleming") and len(sequential_boundaries._DESIGNS) == 101 - FIRST_MAXIMUM
    sequential.clear_caches()
