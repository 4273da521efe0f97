"""Figures of hose service life: suspensions marked, B10 and its bounds drawn, legends that hide
no data, and large campaigns drawn in part with a title that says so."""
import numpy as np
import pandas as pd
import pytest
from matplotlib.figure import Figure

from analyses.service_life import b10
from analyses.service_life_plots import (MAX_GROUPS_DRAWN, MAX_HOSES_DRAWN, plot_hose_distances, plot_kaplan_meier,
                                         plot_leak_growth, plot_weibull_probability)
from tests.analyses.test_service_life import fans


def test_figures_mark_suspensions():
    life, failed = fans()
    fig = plot_weibull_probability({"fans": (life, failed)}, unit="1000 h")
    assert isinstance(fig, Figure)
    ax = fig.axes[0]
    labels = [ln.get_label() for ln in ax.get_lines()]
    assert "fans: suspensions (58)" in labels
    sus = next(ln for ln in ax.get_lines() if ln.get_label() == "fans: suspensions (58)")
    assert len(sus.get_xdata()) == 58
    fig = plot_kaplan_meier({"force": (life, failed), "distance": (life / 2, failed)})
    assert len(fig.axes[0].get_lines()) == 4            # a step curve and censoring marks per group
    import pandas as pd
    fig = plot_hose_distances(pd.DataFrame({"hose_id": ["a", "b"], "distance_km": [1.0, 2.0],
                                            "status": ["failed", "running"], "adjustment": ["force", "distance"]}))
    assert [p.get_height() for p in fig.axes[0].patches] == [2.0, 1.0]
    fig = plot_leak_growth(pd.DataFrame({"hose_id": ["a", "a"], "distance_km": [0.0, 5.0], "leak_l_min": [0.1, 0.9],
                                         "adjustment": ["distance"] * 2, "pressure_bar": [6.0, 6.0]}))
    assert fig.axes[0].get_lines()[0].get_ydata().tolist() == [0.1, 0.9]


def _drawn(fig):
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    fig.canvas.draw()
    return fig.canvas.get_renderer()


def test_weibull_legend_leaves_the_suspensions_and_failures_visible():
    life, failed = fans()
    fig = plot_weibull_probability({"force": (life, failed), "distance": (life * 2, failed)}, unit="1000 h")
    ax = fig.axes[0]
    renderer = _drawn(fig)
    legends = fig.legends + ([ax.get_legend()] if ax.get_legend() else [])
    assert len(legends) == 1
    box = legends[0].get_window_extent(renderer)
    sus = [ln for ln in ax.get_lines() if ln.get_label().endswith("suspensions (58)")]
    assert len(sus) == 2
    for ln in sus:
        assert not box.overlaps(ln.get_window_extent(renderer))
    # every point drawn (failures and suspension ticks) lies inside the axes and outside the legend
    axes_box = ax.get_window_extent(renderer)
    for ln in ax.get_lines():
        if ln.get_marker() in ("o", "|"):
            for x, y in ax.transData.transform(np.column_stack([ln.get_xdata(), ln.get_ydata()])):
                assert axes_box.contains(x, y) and not box.contains(x, y)
    # one row per group: equal lives of two groups do not hide each other
    assert len({float(ln.get_ydata()[0]) for ln in sus}) == 2
    assert all(len(set(map(float, ln.get_ydata()))) == 1 for ln in sus)


def test_leak_growth_keeps_a_series_lying_on_another_visible():
    import pandas as pd

    same = {"distance_km": [0.0, 14.0], "leak_l_min": [1.4, 1.55], "adjustment": ["force"] * 2,
            "pressure_bar": [6.0, 6.0]}
    df = pd.concat([pd.DataFrame({"hose_id": h, **same}) for h in ("H102", "H106")], ignore_index=True)
    fig = plot_leak_growth(df)
    ax = fig.axes[0]
    first, second = ax.get_lines()
    assert first.get_marker() != second.get_marker()            # own marker shape per hose
    assert first.get_markerfacecolor() == "none" == second.get_markerfacecolor()   # hollow: see through
    assert first.get_linewidth() > second.get_linewidth()       # the earlier line shows as an edge
    assert second.get_alpha() < 1
    renderer = _drawn(fig)
    legend = (fig.legends + [ax.get_legend()])[0]
    assert [t.get_text() for t in legend.get_texts()] == ["H102 (force)", "H106 (force)"]
    assert not legend.get_window_extent(renderer).overlaps(ax.get_window_extent(renderer))


def test_weibull_plot_marks_b10_and_its_bounds():

    rng = np.random.default_rng(5)
    life = 40 * rng.weibull(1.8, 12)
    failed = np.ones(12, bool)
    failed[:2] = False
    fig = plot_weibull_probability({"g": (life, failed)}, confidence=0.9)
    ax = fig.axes[0]
    r = b10(life, failed, 0.9)
    (marker,) = [ln for ln in ax.get_lines() if ln.get_marker() == "D"]
    assert marker.get_xdata()[0] == pytest.approx(r["b10"])
    assert "B10" in marker.get_label() and f"{r['b10_lower']:.3g}" in marker.get_label()
    segs = [s for c in ax.collections for s in c.get_segments() if len(s) == 2 and s[0][1] == s[1][1]]
    assert any(s[0][0] == pytest.approx(r["b10_lower"]) and s[1][0] == pytest.approx(r["b10_upper"]) for s in segs)


def test_life_figures_draw_the_first_groups_and_say_how_many_of_how_many():
    """Past MAX_GROUPS_DRAWN groups (MAX_HOSES_DRAWN hoses) a figure draws the first ones by name
    and its title says so; with fewer it is drawn whole and the title is unchanged."""
    rng = np.random.default_rng(3)
    groups = {f"T{j:03d} force": (rng.weibull(2.0, 6) * 100, np.array([1, 1, 1, 0, 1, 0], bool))
              for j in range(MAX_GROUPS_DRAWN + 5)}
    fig = plot_kaplan_meier(groups)
    ax = fig.axes[0]
    assert len([ln for ln in ax.get_lines() if ln.get_label().startswith("T")]) == MAX_GROUPS_DRAWN
    assert f"first {MAX_GROUPS_DRAWN} of {MAX_GROUPS_DRAWN + 5} groups" in ax.get_title()
    fig = plot_weibull_probability(groups)
    labels = fig.axes[0].get_legend_handles_labels()[1]
    assert {lb.split(":")[0] for lb in labels} == set(sorted(groups)[:MAX_GROUPS_DRAWN])
    assert f"of {MAX_GROUPS_DRAWN + 5} groups" in fig.axes[0].get_title()
    hoses = pd.DataFrame({"hose_id": [f"H{i:04d}" for i in range(MAX_HOSES_DRAWN + 20)],
                          "distance_km": np.arange(MAX_HOSES_DRAWN + 20, dtype=float),
                          "status": "running", "adjustment": "force"})
    fig = plot_hose_distances(hoses)
    assert len(fig.axes[0].patches) == MAX_HOSES_DRAWN
    assert f"first {MAX_HOSES_DRAWN} of {MAX_HOSES_DRAWN + 20} hoses" in fig.axes[0].get_title()
    few = plot_kaplan_meier(dict(list(groups.items())[:2]))
    assert few.axes[0].get_title() == "Kaplan-Meier survival (+ = suspension)"
