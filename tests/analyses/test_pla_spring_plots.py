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
