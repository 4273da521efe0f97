"""The spring figures: measured and model loops (the paper's Figs. 8-13) and the loop energies."""
import pandas as pd
from matplotlib.figure import Figure

from analyses.pla_spring_fit import fit_spring_chamber
from analyses.pla_spring_plots import plot_loop_energy, plot_spring_loops
from tests.analyses.test_pla_spring import _prepared


def test_figures():
    runs, _ = _prepared("front", [(2.0, 5.0, 1.0), (5.0, 5.0, 1.0), (3.0, 3.0, 1.0), (3.0, 7.0, 1.0)])
    fit = fit_spring_chamber(runs)
    fig = plot_spring_loops(runs, fit)
    assert isinstance(fig, Figure)
    assert sum(ax.get_visible() for ax in fig.axes) == 4
    table = pd.DataFrame({"chamber": "front", "p0_bar_abs": [r.p0_abs / 1e5 for r in runs],
                          "amplitude_mm": [r.amplitude_m * 1e3 for r in runs],
                          "frequency_hz": [r.frequency_hz for r in runs],
                          "loop_energy_j": [r.loop_energy_j for r in runs]})
    fig = plot_loop_energy(table, {"front": fit})
    assert isinstance(fig, Figure)
    # each legend sits off its panel, so it hides no curve (the D = 7 mm lines at 2.5-4 Hz were)
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig).draw()
    renderer = fig.canvas.get_renderer()
    for ax in fig.axes:
        legend = ax.get_legend()
        assert legend is not None and legend.get_texts()
        box = legend.get_window_extent(renderer)
        assert not box.overlaps(ax.get_window_extent(renderer))
        assert all(not box.overlaps(other.get_window_extent(renderer)) for other in fig.axes)


def _boxes(fig):
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig).draw()
    return fig.canvas.get_renderer(), fig.bbox


def test_loops_fixed_margins_keep_every_label_inside_the_figure_and_off_the_other_panels():
    # six panels laid out by fixed margins (no tight_layout draw): four-digit forces, the titles and
    # the axis labels of each panel stay inside the figure and clear of the neighbouring panels
    runs, _ = _prepared("front", [(2.0, 5.0, 1.0), (5.0, 5.0, 1.0), (3.0, 3.0, 1.0), (3.0, 7.0, 1.0),
                                  (3.0, 5.0, 0.5), (3.0, 5.0, 2.0)])
    for r in runs:
        r.f = r.f * 10.0 + 1000.0   # forces of four digits and more: the widest tick labels
    fig = plot_spring_loops(runs, fit_spring_chamber(runs))
    assert fig.get_layout_engine() is None
    renderer, page = _boxes(fig)
    shown = [ax for ax in fig.axes if ax.get_visible()]
    assert len(shown) == 6
    tight = [ax.get_tightbbox(renderer) for ax in shown]
    for i, box in enumerate(tight):
        assert page.x0 <= box.x0 and box.x1 <= page.x1 and page.y0 <= box.y0 and box.y1 <= page.y1
        assert not any(box.overlaps(other.get_window_extent(renderer)) for j, other in enumerate(shown) if j != i)
    title = fig._suptitle.get_window_extent(renderer)
    assert title.y1 <= page.y1 and all(title.y0 >= box.y1 for box in tight)


def test_loop_energy_legends_stay_inside_the_figure_however_many_rows():
    # the bottom margin grows with the legends' rows (fixed margins, no constrained layout): 2 to 4 rows
    runs, _ = _prepared("front", [(2.0, 5.0, 1.0), (5.0, 3.0, 1.0)])
    fit = fit_spring_chamber(runs)
    for amplitudes in ([3.0], [3.0, 5.0, 7.0], [2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]):
        rows = [{"chamber": c, "p0_bar_abs": 3.0, "amplitude_mm": a, "frequency_hz": f, "loop_energy_j": 0.01 * a * a}
                for c in ("front", "rear") for a in amplitudes for f in (0.5, 1.0, 2.0)]
        fig = plot_loop_energy(pd.DataFrame(rows), {"front": fit, "rear": fit})
        assert fig.get_layout_engine() is None
        renderer, page = _boxes(fig)
        for ax in fig.axes:
            box = ax.get_legend().get_window_extent(renderer)
            assert page.y0 <= box.y0 and page.x0 <= box.x0 and box.x1 <= page.x1
            for other in fig.axes:   # nor the panels, nor their tick labels and axis labels
                assert not box.overlaps(other.get_window_extent(renderer))
                assert not box.overlaps(other.xaxis.get_tightbbox(renderer))
