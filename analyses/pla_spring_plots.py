"""PLA as a pneumatic spring: the paper's figures (seed 001, Figs. 8-13 and the loop energies).

matplotlib is imported when a figure is drawn, not with the module.
"""
from __future__ import annotations

import numpy as np

from analyses.pla_spring import SpringRun
from analyses.pla_spring_fit import SpringFit, spring_model_force, spring_nrmse

__all__ = ["PAPER_FIGURE_TESTS", "figure_runs", "plot_spring_loops", "plot_loop_energy"]


#: The tests of the paper's Figs. 8-13: (P0 [bar abs], D [mm], f [Hz]).
PAPER_FIGURE_TESTS = ((2, 5, 1), (5, 5, 1), (3, 3, 1), (3, 7, 1), (3, 5, 0.5), (3, 5, 2))


#: Where the panels of :func:`plot_spring_loops` sit (figure fractions, as ``Figure.subplots_adjust``
#: takes them): room for four-digit forces and the axis labels at 12 x 7 in.
LOOPS_MARGINS = {"left": 0.06, "right": 0.99, "bottom": 0.075, "top": 0.905, "wspace": 0.24, "hspace": 0.3}


#: Size of :func:`plot_loop_energy` [in], its legends' font [pt], their distance below the panel
#: (under the tick labels and the axis label) [pt] and the height of a legend row [pt].
ENERGY_SIZE_IN = (11, 5.5)
LEGEND_PT = 7
LEGEND_GAP_PT = 36
LEGEND_ROW_PT = 10


def _closest(runs, p0_bar, d_mm, f_hz):
    def dist(r):
        return (abs(r.p0_abs / 1e5 - p0_bar) / 1.0 + abs(r.amplitude_m * 1e3 - d_mm) / 2.0
                + abs(np.log(r.frequency_hz / f_hz)))
    return min(runs, key=dist) if runs else None


def figure_runs(runs: list, cases=PAPER_FIGURE_TESTS) -> list[str]:
    """The run_ids :func:`plot_spring_loops` shows: the usable run closest to each case.

    Parameters
    ----------
    runs : list of SpringRun or SpringStats
        Runs of one chamber (``p0_abs`` [Pa], ``amplitude_m`` [m], ``frequency_hz`` [Hz]).
    cases : sequence of (P0 [bar abs], D [mm], f [Hz])

    Returns
    -------
    list of str
        Sorted, without repeats: a caller prepares only these runs' samples for the figure.
    """
    usable = [r for r in runs if r.ok]
    return sorted({_closest(usable, *case).run_id for case in cases} if usable else set())


def plot_spring_loops(runs: list[SpringRun], fit: SpringFit, cases=PAPER_FIGURE_TESTS, title: str = ""):
    """Measured and model force-displacement loops, like Figs. 8-13 of seed 001.

    Parameters
    ----------
    runs : list of SpringRun
        Runs of one chamber.
    fit : SpringFit
    cases : sequence of (P0 [bar abs], D [mm], f [Hz])
        The tests to show; the closest available run is used for each.
    title : str

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 7))
    axes = fig.subplots(2, 3).ravel()
    usable = [r for r in runs if r.ok]
    shown = set()
    for ax, (p0, dmm, fhz) in zip(axes, cases):
        r = _closest(usable, p0, dmm, fhz)
        if r is None or r.run_id in shown:
            ax.set_visible(False)
            continue
        shown.add(r.run_id)
        ax.plot(r.d * 1e3, r.f, color="0.15", lw=1.2, label="experimental")
        if fit.ok:
            ax.plot(r.d * 1e3, spring_model_force(r, fit), color="tab:red", lw=1.0, ls="--", label="model")
            err = f", NRMSE {spring_nrmse(r, fit):.2f} %"
        else:
            err = ""
        ax.set_title(f"P0={r.p0_abs / 1e5:.2f} bar abs, D={r.amplitude_m * 1e3:.0f} mm, "
                     f"f={r.frequency_hz:g} Hz{err}", fontsize=8)
        ax.set_xlabel("displacement [mm]")
        ax.set_ylabel("force [N]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(title or f"PLA {fit.chamber} chamber: force-displacement loops, experiment vs model "
                 f"(n={fit.n_polytropic:.3f}, Ae={fit.ae_m2 * 1e3:.3f}e-3 m2, eps={fit.epsilon_m2 * 1e5:.3f}e-5 m2, "
                 f"delta={fit.delta_n_m / 1e3:.3f}e3 N/m)", fontsize=10)
    # fixed margins, not ``tight_layout()``: its extra draw measured every text of the six panels to
    # find about these numbers, ~40 % of the figure's CPU, on every spring change (issue 26); the test
    # holds every panel's labels inside the figure and off the other panels
    fig.subplots_adjust(**LOOPS_MARGINS)
    return fig


def plot_loop_energy(table, fits: dict | None = None, title: str = ""):
    """Loop energy vs amplitude and vs frequency (the paper's case for structural damping).

    Parameters
    ----------
    table : DataFrame
        Columns ``chamber``, ``amplitude_mm`` [mm], ``frequency_hz`` [Hz] and ``loop_energy_j`` [J]
        (the ones drawn; others are ignored).
    fits : dict of str to SpringFit, optional
        When given, the structural part ``pi delta D^2`` is drawn (of the fits only ``ok`` and
        ``delta_n_m`` are used).
    title : str

    Returns
    -------
    matplotlib.figure.Figure
        Two panels; each legend sits below its panel, where it covers no data.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=ENERGY_SIZE_IN)
    ax1, ax2 = fig.subplots(1, 2)
    colors = {"rear": "tab:blue", "front": "tab:orange"}
    markers = {3.0: "o", 5.0: "s", 7.0: "^"}
    for chamber, grp in table.groupby("chamber"):
        c = colors.get(chamber, None)
        ax1.scatter(grp["amplitude_mm"], grp["loop_energy_j"], s=14, color=c, alpha=0.7, label=f"{chamber}")
        if fits and chamber in fits and fits[chamber].ok:
            dd = np.linspace(0, max(1.0, grp["amplitude_mm"].max()) * 1.05, 50)
            ax1.plot(dd, np.pi * fits[chamber].delta_n_m * (dd * 1e-3) ** 2, color=c, lw=1,
                     label=f"{chamber}: pi delta D^2 (structural part)")
        # vs frequency: mean over P0 per amplitude, one line per (chamber, D)
        for amp, g in grp.groupby(grp["amplitude_mm"].round(1)):
            m = g.groupby("frequency_hz")["loop_energy_j"].mean()
            ax2.plot(m.index, m.values, color=c, marker=markers.get(float(amp), "D"), ms=4, lw=1,
                     label=f"{chamber}, D={amp:g} mm")
    ax1.set_xlabel("displacement amplitude D [mm]")
    ax1.set_ylabel("loop energy per cycle [J]")
    ax1.set_title("vs amplitude (every test); lines: pi delta D^2", fontsize=9)
    ax2.set_xlabel("frequency f [Hz]")
    ax2.set_ylabel("loop energy per cycle [J], mean over P0")
    ax2.set_title("vs frequency (viscous damping would rise with f)", fontsize=9)
    ax2.set_ylim(bottom=0)
    rows = 0
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
        if n := len(ax.get_legend_handles_labels()[0]):
            # below the panel, a fixed distance under its axis labels: off the curves whatever the data
            ax.legend(fontsize=LEGEND_PT, ncols=2, loc="upper center", bbox_to_anchor=(0.5, 0),
                      borderaxespad=LEGEND_GAP_PT / LEGEND_PT)
            rows = max(rows, -(-n // 2))
    # fixed margins, the bottom one from the legends' rows, not constrained layout: its two extra
    # draws measured every text (~40 % of the figure's CPU, on every spring change; issue 26); the
    # test holds the legends inside the figure and off the panels
    height_pt = ENERGY_SIZE_IN[1] * 72
    bottom = (LEGEND_GAP_PT + rows * LEGEND_ROW_PT + 2 * LEGEND_PT) / height_pt
    fig.subplots_adjust(left=0.055, right=0.985, top=0.9, bottom=max(0.12, bottom), wspace=0.14)
    fig.suptitle(title or "PLA spring: energy dissipated per cycle (loop area)")
    return fig
