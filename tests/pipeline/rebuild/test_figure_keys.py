"""A figure's key: the content of its arguments hashed canonically (equal data, equal key, however
built), its plot function's code, the libraries; a previous folder's figures found by key."""
import json
import math

import numpy as np
import pandas as pd
import pytest

from pipeline.rebuild import figure_keys as fk
from pipeline.stages import FigureRecipe


def _frame():
    return pd.DataFrame({"run_id": ["a", "b", None], "x_mm": [1.0, np.nan, -0.0], "n": pd.array([1, None, 3], "Int64"),
                         "at": pd.to_datetime(["2026-01-01", "2026-01-02", None], utc=True)})


def test_equal_data_built_differently_have_one_hash(tmp_path):
    df = _frame()
    df.to_parquet(tmp_path / "f.parquet")
    back = pd.read_parquet(tmp_path / "f.parquet")  # read back: other objects, other blocks, the same data
    assert fk.content_hash(back) == fk.content_hash(df)
    strings = ["".join(["ru", "n"]) for _ in range(3)]  # equal strings, distinct objects
    assert fk.content_hash({"k": strings}) == fk.content_hash({"k": ["run"] * 3})
    assert fk.content_hash(np.arange(4.0)) == fk.content_hash(np.arange(4.0)[::-1][::-1].copy())


@pytest.mark.parametrize("change", [
    lambda df: df.assign(x_mm=[1.0, np.nan, 0.0]),            # -0.0 -> 0.0: a different value
    lambda df: df.assign(x_mm=[1.0, 2.0, -0.0]),             # NaN -> a number
    lambda df: df.assign(run_id=["a", "b", "None"]),         # None -> the text "None"
    lambda df: df[["x_mm", "run_id", "n", "at"]],            # columns reordered
    lambda df: df.astype({"x_mm": "float32"}),               # another dtype
    lambda df: df.set_axis([1, 2, 3]),                       # another index
    lambda df: df.rename(columns={"n": "m"}),                # another name
    lambda df: df.iloc[:2],                                   # a row less
])
def test_any_change_of_content_changes_the_hash(change):
    assert fk.content_hash(change(_frame())) != fk.content_hash(_frame())


def test_containers_keep_their_types_and_order():
    h = fk.content_hash
    assert h([1, 2]) != h((1, 2)) != h([2, 1])
    assert h({"a": 1, "b": 2}) != h({"b": 2, "a": 1})  # a plot may draw them in that order
    assert h({1, 2, 3}) == h({3, 2, 1})
    assert h(1) != h(1.0) != h("1") != h(True)
    assert h(np.float64(1.5)) != h(1.5)
    assert h(math.nan) == h(float("nan"))


def _plot(df, title=""):
    """A plot function of a module (never called here)."""


def test_a_figure_key_names_function_arguments_and_libraries():
    key = fk.figure_key(FigureRecipe(_plot, (_frame(),), {"title": "t"}))
    assert len(key) == 64
    assert fk.figure_key(FigureRecipe(_plot, (_frame(),), {"title": "t"})) == key
    assert fk.figure_key(FigureRecipe(_plot, (_frame(),), {"title": "u"})) != key
    assert fk.figure_key(FigureRecipe(_plot, (_frame().iloc[:2],), {"title": "t"})) != key
    assert fk.figure_key(FigureRecipe(lambda df: None, (_frame(),))) is None  # no module-level name: no key
    assert "matplotlib" in fk.plotting_environment()


def test_arguments_that_cannot_be_hashed_give_no_key():
    import threading

    assert fk.figure_key(FigureRecipe(_plot, (threading.Lock(),))) is None


def test_the_previous_folder_gives_its_keyed_figures(tmp_path):
    (tmp_path / "figures").mkdir()
    (tmp_path / "figures" / "a.png").write_bytes(b"png")
    (tmp_path / "output.json").write_text(json.dumps({"figures": {
        "a": {"file": "a.png", "caption": "", "key": "k1"},
        "b": {"file": "b.png", "caption": "", "key": "k2"},     # file gone: not offered
        "c": {"file": "a.png", "caption": ""},                  # no key (written before keys)
        "d": {"file": "../x.png", "caption": "", "key": "k3"}}}))  # not a file of the folder
    assert fk.reusable_figures(tmp_path) == {"k1": tmp_path / "figures" / "a.png"}
    assert fk.reusable_figures(None) == {} and fk.reusable_figures(tmp_path / "none") == {}
    (tmp_path / "output.json").write_text("{damaged")
    assert fk.reusable_figures(tmp_path) == {}


def test_the_plotting_environment_is_the_same_whether_matplotlib_is_imported_or_not():
    """Keys name the installed version when the library is not imported (no 0.5 s import for a key,
    issue 26): the same text as the imported module's ``__version__``, so stored keys still match."""
    import subprocess
    import sys

    from tests.conftest import PROJECT_ROOT

    code = ("import sys\nfrom pipeline.rebuild import figure_keys as fk\ncold = fk.plotting_environment()\n"
            "assert 'matplotlib' not in sys.modules\nimport matplotlib, numpy, pandas\nfk.plotting_environment.cache_clear()\n"
            "print(cold == fk.plotting_environment(), cold)")
    out = subprocess.run([sys.executable, "-c", code], cwd=PROJECT_ROOT, capture_output=True, text=True, check=True)
    same, env = out.stdout.strip().split(" ", 1)
    assert same == "True" and "matplotlib 3." in env and " -" not in env
