"""Figures of hose service life: the Weibull probability plot, Kaplan-Meier, leak growth and the hoses' distances.

Each function takes the tables or the (life, failed) groups that :mod:`analyses.service_life`
fits and returns a matplotlib ``Figure`` (matplotlib is imported when a figure is drawn, not with
the module). A figure past :data:`MAX_GROUPS_DRAWN` groups or :data:`MAX_HOSES_DRAWN` hoses draws
the first ones by name and says so in its title; the tables hold them all.
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from analyses.service_life import _as_arrays, b10, kaplan_meier, weibull_fit, weibull_plotting_positions

def _figure(size=(7.0, 4.5)):
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    return fig, fig.add_subplot()


#: Groups (hose type x adjustment) drawn in one life figure, and hoses in one per-hose figure:
#: past these a figure is unreadable (and its legend and layout cost grows with the square of the
#: series: a 100-hose-type campaign spent 518 s drawing them). The first ones by name are drawn,
#: the title says how many of how many; the tables hold them all.
MAX_GROUPS_DRAWN = 12
MAX_HOSES_DRAWN = 80


def _drawn(names: list, limit: int, what: str) -> tuple[list, str]:
    """The first ``limit`` of ``names`` and a title suffix saying so ("" when all are drawn)."""
    if len(names) <= limit:
        return list(names), ""
    return list(names[:limit]), f"\n(first {limit} of {len(names)} {what} by name; all in the tables)"


def plot_weibull_probability(groups: dict, unit: str = "km", confidence: float = 0.90):
    """Weibull probability plot: failures at their plotting positions, suspensions as ticks.

    Suspensions are drawn as ``|`` ticks in a strip below the lowest plotted failure, one row per
    group (so that equal lives of two groups do not hide each other); fitted lines stop at the
    strip. The legend is placed below the axes, where it covers no data.

    Parameters
    ----------
    groups : dict of str to (life, failed)
        One series (and its fitted line, when it has one) per group; the first
        :data:`MAX_GROUPS_DRAWN` by name are drawn.
    unit : str
        Unit of the lives, for the axis label.
    confidence : float
        Two-sided confidence of the B10 bounds drawn on each fitted line (as :func:`b10`).

    Returns
    -------
    matplotlib.figure.Figure
        B10 (10 % failed) of each fitted group is marked with a diamond on its line, its
        bounds as a horizontal bar at 10 %.
    """
    shown, more = _drawn(sorted(groups), MAX_GROUPS_DRAWN, "groups")
    groups = {name: groups[name] for name in shown}
    fig, ax = _figure(size=(7.0, 5.8))
    ticks = [0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.3, 0.5, 0.632, 0.8, 0.9, 0.95, 0.99]
    lin = lambda F: np.log(-np.log1p(-np.asarray(F, float)))  # noqa: E731
    all_x = []
    lowest = lin(ticks[0])
    names = [name for name in sorted(groups) if len(_as_arrays(*groups[name])[0])]
    for name in names:
        pp = weibull_plotting_positions(*_as_arrays(*groups[name]))
        if len(pp):
            lowest = min(lowest, float(lin(pp["F"].min())))
    strip_top = lowest - 0.3          # separator between the probability scale and the strip
    with_sus = [name for name in names if (~_as_arrays(*groups[name])[1]).any()]
    row = {name: strip_top - 0.4 * (j + 1) for j, name in enumerate(with_sus)}
    strip_bottom = strip_top - 0.4 * (len(with_sus) + 1) if with_sus else strip_top
    for i, name in enumerate(sorted(groups)):
        life, failed = _as_arrays(*groups[name])
        if len(life) == 0:
            continue
        all_x.append(life)
        color = f"C{i}"
        pp = weibull_plotting_positions(life, failed)
        fit = weibull_fit(life, failed)
        label = f"{name}: {int(failed.sum())} failed / {len(life)}"
        if fit.ok:
            label += f", shape {fit.shape:.2f}, scale {fit.scale:.3g} {unit}"
        ax.plot(pp["life"], lin(pp["F"]), "o", color=color, label=label)
        sus = life[~failed]
        if len(sus):
            ax.plot(sus, np.full(len(sus), row[name]), marker="|", ls="none", ms=16, mew=2.5, color=color,
                    label=f"{name}: suspensions ({len(sus)})", gid="suspensions")
        if fit.ok:
            xs = np.geomspace(max(life.min() / 3, 1e-9), life.max() * 3, 100)
            ys = fit.shape * np.log(xs / fit.scale)
            ax.plot(xs, np.where(ys >= strip_top, ys, np.nan), "-", color=color, lw=1)
            r = b10(life, failed, confidence)
            if r["b10"] is not None and np.isfinite(r["b10"]):
                lo, hi = r["b10_lower"], r["b10_upper"]
                ok = lo is not None and hi is not None and np.isfinite(lo) and np.isfinite(hi)
                text = (f"{name}: B10 {r['b10']:.3g} {unit}"
                        + (f" [{lo:.3g}–{hi:.3g}] ({100 * confidence:g} %)" if ok else " (no bounds)"))
                y10 = float(lin(0.10)) + 0.06 * (i - (len(names) - 1) / 2)
                all_x.append(np.array([lo, hi] if ok else [r["b10"]], float))
                if ok:  # the bounds: a bar at 10 % with end ticks (collections, not data lines)
                    ax.hlines(y10, lo, hi, color=color, lw=2.0, zorder=4)
                    ax.vlines([lo, hi], y10 - 0.12, y10 + 0.12, color=color, lw=2.0, zorder=4)
                ax.plot([r["b10"]], [y10], "D", color=color, mec="black", ms=7, zorder=5, label=text)
    if all_x:
        x = np.concatenate(all_x)
        ax.set_xlim(x.min() / 2, x.max() * 2)
    ax.set_xscale("log")
    ax.axhline(float(lin(0.10)), color="0.5", lw=0.7, ls=":")
    ax.set_yticks(lin(ticks), [f"{100 * t:g}" for t in ticks])
    ax.set_ylim(min(strip_bottom, strip_top - 0.2), lin(ticks[-1]) + 0.2)
    if with_sus:
        ax.axhline(strip_top, color="grey", lw=0.8)
        ax.axhspan(strip_bottom, strip_top, color="0.93", zorder=0)
        ax.text(0.005, strip_top - 0.05, "suspensions", transform=ax.get_yaxis_transform(), ha="left", va="top",
                fontsize="x-small", color="0.35")
    ax.set_xlabel(f"life [{unit}]")
    ax.set_ylabel("fraction failed [%] (Weibull scale)")
    ax.set_title("Weibull probability plot (| = suspension)" + more)
    ax.grid(True, which="both", alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", fontsize="small", ncols=1)
    return fig


def plot_kaplan_meier(groups: dict, unit: str = "km"):
    """Kaplan-Meier survival curves per group (the first :data:`MAX_GROUPS_DRAWN` by name),
    suspensions marked with ``+``.

    Returns
    -------
    matplotlib.figure.Figure
    """
    shown, more = _drawn(sorted(groups), MAX_GROUPS_DRAWN, "groups")
    fig, ax = _figure()
    for i, name in enumerate(shown):
        life, failed = _as_arrays(*groups[name])
        km = kaplan_meier(life, failed)
        if km.empty:
            continue
        xs = np.concatenate([[0.0], km["life"].to_numpy()])
        ys = np.concatenate([[1.0], km["survival"].to_numpy()])
        ax.step(xs, ys, where="post", color=f"C{i}", label=f"{name} ({int(failed.sum())}/{len(life)} failed)")
        cens = km[km["n_censored"] > 0]
        ax.plot(cens["life"], cens["survival"], "+", color=f"C{i}", ms=9)
    ax.set_ylim(0, 1.05)
    ax.set_xlim(left=0)
    ax.set_xlabel(f"distance [{unit}]")
    ax.set_ylabel("fraction surviving")
    ax.set_title("Kaplan-Meier survival (+ = suspension)" + more)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small")
    return fig


def plot_leak_growth(df: pd.DataFrame):
    """Leak versus hose distance, one line per hose (and chamber / pressure).

    Each hose has its own colour and (hollow) marker shape; lines are dashed for distance-set
    rollers, slightly transparent and thinner for each further hose, so that a series lying on
    another stays visible. The legend is outside the axes.

    Parameters
    ----------
    df : DataFrame
        ``hose_id``, ``distance_km``, ``leak_l_min`` and optionally ``adjustment``,
        ``pressure_bar``: points to draw (e.g. one pressure level per hose); the hoses drawn are
        the first :data:`MAX_GROUPS_DRAWN` by id.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, ax = _figure(size=(8.0, 4.5))
    styles = {"force": "-", "distance": "--"}
    markers = ["o", "s", "^", "D", "v", "P", "X", "<", ">", "*"]
    shown, more = _drawn(sorted(df["hose_id"].unique()), MAX_GROUPS_DRAWN, "hoses")
    for i, (hose, g) in enumerate(df[df["hose_id"].isin(shown)].groupby("hose_id", sort=True)):
        g = g.sort_values("distance_km")
        adj = g["adjustment"].iloc[0] if "adjustment" in g else None
        # hollow markers of a shape per hose, translucent lines getting thinner hose by hose: a
        # series lying on an earlier one still shows as a coloured edge and its own markers
        ax.plot(g["distance_km"], g["leak_l_min"], marker=markers[i % len(markers)], ms=9 - 0.4 * min(i, 5),
                mfc="none", mew=1.6, ls=styles.get(adj, "-"), lw=max(0.9, 2.6 - 0.3 * i), alpha=0.75,
                color=f"C{i % 10}",
                label=f"{hose}" + (f" ({adj})" if isinstance(adj, str) else ""))
    ax.set_xlabel("hose distance at the leakage run [km]")
    ax.set_ylabel("leak [l/min ANR]")
    title = "Leakage growth per hose"
    if "pressure_bar" in df and len(df):
        title += f" at {df['pressure_bar'].max():.1f} bar"
    ax.set_title(title + " (dashed: distance-set rollers)" + more)
    ax.grid(True, alpha=0.3)
    if len(df):
        fig.legend(*ax.get_legend_handles_labels(), loc="outside right upper", fontsize="small")
    return fig


def plot_hose_distances(hoses: pd.DataFrame):
    """Distance per hose as bars coloured by status (failed / removed / running).

    Parameters
    ----------
    hoses : DataFrame
        ``hose_id``, ``distance_km``, ``status`` and optionally ``adjustment``; the first
        :data:`MAX_HOSES_DRAWN` by id are drawn.

    Returns
    -------
    matplotlib.figure.Figure
    """
    colors = {"failed": "tab:red", "removed": "tab:orange", "running": "tab:green"}
    shown, more = _drawn(sorted(hoses["hose_id"].astype(str)), MAX_HOSES_DRAWN, "hoses")
    h = hoses[hoses["hose_id"].astype(str).isin(shown)]
    h = h.sort_values(["adjustment", "distance_km"] if "adjustment" in h else ["distance_km"])
    fig, ax = _figure((max(6.0, 0.3 * len(h) + 2), 4.5))
    pos = np.arange(len(h))
    ax.bar(pos, h["distance_km"].fillna(0.0), color=[colors.get(s, "grey") for s in h["status"]])
    labels = [f"{hid}" + (f" ({adj[0]})" if isinstance(adj, str) and adj else "")
              for hid, adj in zip(h["hose_id"], h["adjustment"] if "adjustment" in h else [None] * len(h))]
    ax.set_xticks(pos, labels, rotation=90, fontsize="x-small")
    from matplotlib.patches import Patch

    ax.legend(handles=[Patch(color=c, label=s) for s, c in colors.items()], fontsize="small")
    ax.set_ylabel("distance [km]")
    ax.set_title("Distance per hose (f = force-set, d = distance-set rollers)" + more)
    ax.grid(True, axis="y", alpha=0.3)
    return fig


__all__ = ["MAX_GROUPS_DRAWN", "MAX_HOSES_DRAWN", "plot_weibull_probability", "plot_kaplan_meier", "plot_leak_growth",
           "plot_hose_distances"]
