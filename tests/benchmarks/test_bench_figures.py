"""bench_figures: a recipe drawn and saved in a process of a tree, timed; two PNGs compared by pixel."""
import pickle

import pandas as pd

from analyses.service_life_plots import plot_leak_growth
from benchmarks.bench_figures import _child_time, pixel_diff
from pipeline.stages import FigureRecipe


def _recipe(tmp_path, leak):
    df = pd.DataFrame({"hose_id": ["a", "a"], "distance_km": [0.0, 5.0], "leak_l_min": [0.1, leak],
                       "adjustment": ["force"] * 2, "pressure_bar": [6.0, 6.0]})
    path = tmp_path / f"durability.leak_growth.{leak}.pkl"
    path.write_bytes(pickle.dumps(FigureRecipe(plot_leak_growth, (df,))))
    return path


def test_a_recipe_drawn_and_saved_with_its_cpu_and_pngs_compared(tmp_path):
    one, two, other = tmp_path / "1.png", tmp_path / "2.png", tmp_path / "3.png"
    got = _child_time(_recipe(tmp_path, 0.9), one)
    assert set(got) == {"import", "draw", "save"} and all(v >= 0 for v in got.values())
    assert one.read_bytes().startswith(b"\x89PNG")
    _child_time(_recipe(tmp_path, 0.9), two)
    assert pixel_diff(one, two) == "same bytes"
    _child_time(_recipe(tmp_path, 1.9), other)
    said = pixel_diff(one, other)
    assert said.startswith("max diff ") and "px differ" in said and not said.startswith("max diff 0/")
