"""Leakage between the chambers of the PLPA (seed 000, section 3.1, Figs. 9 and 10).

A leakage run pressurises one chamber in steps (0 to 6 bar, 1 bar apart) with the carriage
blocked and the other chamber open, and logs the supply pressure and the leakage flow. This
module finds the steady part of each pressure step (a *plateau*), averages pressure and leak
over it, and summarises a roller setting by its *seal envelope*: the highest tested pressure up
to which the leak stays below a threshold.

Characterisation runs and hose checks (:func:`characterisation_rows`)
--------------------------------------------------------------------
A leakage run that names a ``hose_id`` is a *check on that hose* (e.g. a durability hose after
some kilometres of wear); a run naming no hose is a *characterisation run* of the roller
setting. A worn hose leaks far more than the setting does, so the per-setting results (the
curves of Figs. 9/10 and the seal envelope) use the characterisation runs of a setting only.
A setting that has no characterisation run at all falls back to its hose checks, and says so
(``runs_used = 'hose_checks'``, a dashed curve marked "hose checks"), so no tested setting
silently disappears. Hose checks stay in the plateau table with their ``hose_id`` for the
leak-growth analysis of the durability stage.

Plateau detection (:func:`find_pressure_plateaus`)
-------------------------------------------------
1. The pressure noise ``sigma`` is estimated from the first differences (robust MAD), so the
   detector needs no sensor setting.
2. The run is cut into blocks of ``block_s`` seconds; a block is *flat* when the straight line
   fitted to its pressure changes by less than ``flat_tol_bar`` over the block and its residual
   scatter is close to the noise (no step inside the block).
3. Consecutive flat blocks whose means agree within ``level_tol_bar`` form a plateau; a plateau
   shorter than ``min_duration_s`` is dropped.
4. Transients are excluded: the first ``settle_s`` seconds of a plateau are dropped (the leak
   flow lags the pressure), then leading blocks whose leak differs from the plateau's settled
   (second half) leak by more than the noise allows are dropped too.
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from analyses.quality import Sensor
from schemas.units import kg_s_to_l_min_anr

#: Default leak threshold of the seal envelope. [l/min ANR]
LEAK_THRESHOLD_L_MIN = 0.05
#: Maximum roller spring force of the rig (seed 000). [N]
SPRING_FORCE_MAX_N = 1300.0
#: Columns that identify a roller setting in a leakage map.
SETTING_COLUMNS = ("chamber", "adjustment", "z_rollers_mm", "spring_force_n")
#: ``runs_used`` values: what the rows of a setting's curve / envelope come from.
RUNS_CHARACTERISATION, RUNS_HOSE_CHECKS, RUNS_MIXED = "characterisation", "hose_checks", "mixed"

_BAR = 1e5


def _noise_sigma(y: np.ndarray) -> float:
    """Robust white-noise sigma from first differences (MAD / 0.6745 / sqrt 2)."""
    d = np.diff(y)
    if d.size < 2:
        return 0.0
    mad = np.median(np.abs(d - np.median(d)))
    return float(mad / 0.6745 / np.sqrt(2.0))


def find_pressure_plateaus(t_s, p_pa, q=None, *, block_s: float = 0.1, flat_tol_bar: float = 0.02,
                           level_tol_bar: float = 0.05, min_duration_s: float = 0.5,
                           settle_s: float = 0.2, sensor_p: Sensor | None = None,
                           sensor_q: Sensor | None = None) -> list[tuple[int, int]]:
    """Steady parts of a stepped pressure record.

    Parameters
    ----------
    t_s : array_like
        Time [s], increasing.
    p_pa : array_like
        Pressure of the pressurised chamber [Pa] (gauge).
    q : array_like, optional
        Leakage flow (any unit); when given, leading blocks of a plateau where the flow has not
        settled are dropped as well.
    block_s : float
        Block length of the flatness test [s].
    flat_tol_bar : float
        Largest pressure change across a flat block (line fit) [bar].
    level_tol_bar : float
        Largest difference between the means of neighbouring blocks of one plateau [bar].
    min_duration_s : float
        Shortest plateau kept, after trimming [s].
    settle_s : float
        Time dropped at the start of every plateau (valve and flow transients) [s].
    sensor_p, sensor_q : analyses.quality.Sensor, optional
        Pressure [Pa] and flow [unit of ``q``] sensors (stated by the rig): their noise replaces
        the estimate from the record, and the pressure's resolution widens the flatness test.

    Returns
    -------
    list of (start, stop)
        Sample index ranges ``[start, stop)`` of the plateaus, in time order.
    """
    t = np.asarray(t_s, dtype=float)
    p = np.asarray(p_pa, dtype=float) / _BAR
    n = t.size
    if n < 4:
        return []
    dt = float(np.median(np.diff(t)))
    if not np.isfinite(dt) or dt <= 0:
        return []
    k = max(4, int(round(block_s / dt)))
    nb = n // k
    if nb < 1:
        return []
    sigma = _noise_sigma(p) if sensor_p is None else float(sensor_p.noise) / _BAR
    res_p = 0.0 if sensor_p is None else float(sensor_p.resolution) / _BAR
    # block statistics: mean, slope change across the block, residual scatter
    tb = t[: nb * k].reshape(nb, k)
    pb = p[: nb * k].reshape(nb, k)
    tc = tb - tb.mean(axis=1, keepdims=True)
    pm = pb.mean(axis=1)
    slope = (tc * (pb - pm[:, None])).sum(axis=1) / np.maximum((tc**2).sum(axis=1), 1e-300)
    change = np.abs(slope) * (tb[:, -1] - tb[:, 0])
    resid = pb - pm[:, None] - slope[:, None] * tc
    scatter = resid.std(axis=1)
    # a block with a step inside has a large residual scatter even after the line fit
    flat = ((change <= flat_tol_bar + 4 * sigma / np.sqrt(k) + res_p)
            & (scatter <= 2.0 * sigma + 0.25 * flat_tol_bar + 0.5 * res_p))
    groups: list[list[int]] = []
    for b in range(nb):
        if not flat[b]:
            continue
        if groups and groups[-1][-1] == b - 1 and abs(pm[b] - pm[groups[-1][-1]]) <= level_tol_bar:
            groups[-1].append(b)
        else:
            groups.append([b])
    qa = None if q is None else np.asarray(q, dtype=float)
    q_sigma = 0.0 if qa is None else (_noise_sigma(qa) if sensor_q is None else float(sensor_q.floor()))
    out = []
    for g in groups:
        start, stop = g[0] * k, (g[-1] + 1) * k
        start = int(np.searchsorted(t, t[start] + settle_s))
        if qa is not None and stop - start > 2 * k:
            start = _trim_unsettled(qa, start, stop, k, q_sigma)
        if stop - start < 2 or t[stop - 1] - t[start] < min_duration_s:
            continue
        out.append((start, stop))
    return out


def _trim_unsettled(q: np.ndarray, start: int, stop: int, k: int, sigma: float) -> int:
    """Drop leading blocks whose flow is off the settled (second-half) flow of the plateau."""
    mid = (start + stop) // 2
    settled = q[mid:stop]
    ref = float(np.median(settled))
    spread = max(sigma, float(np.std(settled)))
    tol = 4.0 * spread / np.sqrt(k) + 0.01 * abs(ref)
    i = start
    while i + k <= mid:
        if abs(float(np.mean(q[i:i + k])) - ref) <= tol:
            break
        i += k
    return i


def leakage_plateaus(t_s, p_pa, q_leak_kg_s, sensor_p: Sensor | None = None, sensor_q: Sensor | None = None,
                     **kwargs) -> pd.DataFrame:
    """One row per pressure plateau of a leakage run: mean pressure and mean leak.

    Parameters
    ----------
    t_s : array_like
        Time [s].
    p_pa : array_like
        Pressure of the pressurised chamber, gauge [Pa].
    q_leak_kg_s : array_like
        Leakage mass flow [kg/s].
    sensor_p, sensor_q : analyses.quality.Sensor, optional
        Pressure [Pa] and flow [kg/s] sensors; see :func:`find_pressure_plateaus`.
    **kwargs
        Passed to :func:`find_pressure_plateaus`.

    Returns
    -------
    DataFrame
        ``plateau`` (0, 1, ...), ``t_start_s``, ``t_end_s``, ``n_samples``, ``pressure_bar``
        (mean, gauge), ``leak_l_min`` (mean, l/min ANR), ``leak_std_l_min`` (sample scatter),
        ``leak_se_l_min`` (standard error of the mean, from block means; at least the flow
        sensor's resolution over ``sqrt(12 n)``).
    """
    t = np.asarray(t_s, dtype=float)
    p = np.asarray(p_pa, dtype=float)
    q = np.asarray(q_leak_kg_s, dtype=float)
    ok = np.isfinite(t) & np.isfinite(p) & np.isfinite(q)
    t, p, q = t[ok], p[ok], q[ok]
    rows = []
    sensor_q_l_min = 0.0 if sensor_q is None else float(kg_s_to_l_min_anr(sensor_q.resolution))
    for i, (a, b) in enumerate(find_pressure_plateaus(t, p, q, sensor_p=sensor_p, sensor_q=sensor_q, **kwargs)):
        ql = kg_s_to_l_min_anr(q[a:b])
        rows.append({"plateau": i, "t_start_s": float(t[a]), "t_end_s": float(t[b - 1]), "n_samples": b - a,
                     "pressure_bar": float(np.mean(p[a:b]) / _BAR), "leak_l_min": float(np.mean(ql)),
                     "leak_std_l_min": float(np.std(ql)), "leak_se_l_min": _mean_se(ql, sensor_q_l_min)})
    return pd.DataFrame(rows, columns=["plateau", "t_start_s", "t_end_s", "n_samples", "pressure_bar",
                                       "leak_l_min", "leak_std_l_min", "leak_se_l_min"])


def _mean_se(y: np.ndarray, floor: float = 0.0) -> float:
    """Standard error of the mean of a (possibly correlated) plateau: the scatter of the means of
    (at most) 10 consecutive blocks, and never finer than the sensor's resolution floor."""
    y = np.asarray(y, dtype=float)
    nb = min(10, y.size // 2)
    if nb >= 2:
        means = np.array([b.mean() for b in np.array_split(y, nb)])
        se = float(np.std(means, ddof=1) / np.sqrt(nb))
    else:
        se = float(np.std(y) / np.sqrt(max(y.size, 1)))
    return max(se, floor / np.sqrt(12.0 * max(y.size, 1)))


def leakage_power_law(p_bar, c_l_min_bar15: float, p_seal_bar: float):
    """Leak model of physics.md: no leak below the seal pressure, ``c (p - p_seal)^1.5`` above.

    Parameters
    ----------
    p_bar : array_like
        Gauge pressure [bar].
    c_l_min_bar15 : float
        Leak coefficient [l/min / bar^1.5].
    p_seal_bar : float
        Seal pressure [bar].

    Returns
    -------
    ndarray
        Leak [l/min ANR].
    """
    return c_l_min_bar15 * np.clip(np.asarray(p_bar, dtype=float) - p_seal_bar, 0.0, None) ** 1.5


def is_hose_check(leakage_map: pd.DataFrame) -> pd.Series:
    """True for rows of runs that name a hose (``hose_id`` not NULL and not empty): hose checks.

    Parameters
    ----------
    leakage_map : DataFrame
        Rows of the ``leakage_map`` table; without a ``hose_id`` column no row is a hose check.

    Returns
    -------
    Series of bool
    """
    if "hose_id" not in leakage_map.columns:
        return pd.Series(False, index=leakage_map.index)
    h = leakage_map["hose_id"]
    return h.notna() & (h.astype(str) != "")


def characterisation_rows(leakage_map: pd.DataFrame, by=SETTING_COLUMNS) -> pd.DataFrame:
    """The rows that characterise each setting: its characterisation runs, else its hose checks.

    Rule (module docstring): per setting (``by``), the rows of runs naming no hose are used and
    the setting's hose checks are left out; a setting with no characterisation run at all keeps
    its hose-check rows (all of them, averaged later like repeat runs) and is marked as such.

    Parameters
    ----------
    leakage_map : DataFrame
        Rows of the ``leakage_map`` table.
    by : sequence of str
        Columns identifying a setting.

    Returns
    -------
    DataFrame
        The selected rows (original index) with a column ``runs_used``: ``'characterisation'`` or
        ``'hose_checks'`` (the fallback).
    """
    by = [c for c in by if c in leakage_map.columns]
    check = is_hose_check(leakage_map)
    if leakage_map.empty:
        return leakage_map.assign(runs_used=pd.Series(dtype=object))
    if by:
        has_char = (~check).groupby([leakage_map[c] for c in by], dropna=False).transform("any")
    else:
        has_char = pd.Series(bool((~check).any()), index=leakage_map.index)
    keep = ~check | ~has_char.astype(bool)
    out = leakage_map[keep]
    return out.assign(runs_used=np.where(check[keep], RUNS_HOSE_CHECKS, RUNS_CHARACTERISATION))


def seal_envelope(leakage_map: pd.DataFrame, threshold_l_min: float = LEAK_THRESHOLD_L_MIN,
                  by=SETTING_COLUMNS, pressure_step_bar: float = 0.1,
                  spring_force_max_n: float = SPRING_FORCE_MAX_N,
                  characterisation_only: bool = True) -> pd.DataFrame:
    """The highest tested pressure up to which a setting stays sealed.

    Only characterisation runs count (:func:`characterisation_rows`): hose checks of a setting
    are left out, unless the setting has nothing else (``runs_used = 'hose_checks'``).
    Plateaus are grouped by setting (``by``) and by their tested (nominal) pressure, the measured
    mean pressure rounded to ``pressure_step_bar``; plateaus at the same nominal pressure (repeat
    runs) are averaged. Walking up from the lowest tested pressure, the setting is *sealed* while
    the leak stays below ``threshold_l_min``; ``sealed_up_to_bar`` is the last such pressure.
    The warehouse macro ``seal_envelope_at(threshold)`` (``schemas/ddl``) computes the same table
    in SQL for any threshold.

    Parameters
    ----------
    leakage_map : DataFrame
        Rows of the ``leakage_map`` table (``pressure_bar``, ``leak_l_min`` and the ``by`` columns).
    threshold_l_min : float
        Leak that counts as a leak [l/min ANR].
    by : sequence of str
        Columns identifying a setting.
    pressure_step_bar : float
        Resolution of the nominal (tested) pressure [bar].
    spring_force_max_n : float
        Maximum spring force, for ``spring_force_pct`` [N].
    characterisation_only : bool
        Apply the characterisation-run rule (default). False uses every row given, e.g. with
        ``by`` including ``hose_id`` for one envelope per hose.

    Returns
    -------
    DataFrame
        One row per setting: the ``by`` columns, ``spring_force_pct``, ``threshold_l_min``,
        ``sealed_up_to_bar`` (NULL when already leaking at the lowest tested pressure),
        ``first_leak_bar`` (lowest tested pressure above threshold; NULL if none),
        ``max_tested_bar``, ``sealed_at_max`` (True when no tested pressure leaks),
        ``max_leak_l_min``, ``n_pressures``, ``runs_used`` (``characterisation``,
        ``hose_checks`` or, with ``characterisation_only=False``, ``mixed``), ``n_runs``,
        ``note``: when the leak of a tested pressure (up to the first leaking one) lies within 2
        standard errors (``leak_se_l_min`` of its plateaus) of the threshold, the data cannot
        tell sealed from leaking there: ``sealed_up_to_bar`` and ``first_leak_bar`` are NULL and
        the note says so.
    """
    by = [c for c in by if c in leakage_map.columns]
    cols = list(by) + ["spring_force_pct", "threshold_l_min", "sealed_up_to_bar", "first_leak_bar",
                       "max_tested_bar", "sealed_at_max", "max_leak_l_min", "n_pressures", "runs_used", "n_runs",
                       "note"]
    df = leakage_map.dropna(subset=["pressure_bar", "leak_l_min"])
    if characterisation_only:
        df = characterisation_rows(df, by)
    if df.empty:
        return pd.DataFrame(columns=cols)
    df = df.assign(_check=is_hose_check(df))
    df = df.assign(_nominal=(df["pressure_bar"] / pressure_step_bar).round() * pressure_step_bar)
    rows = []
    for key, g in df.groupby(by, dropna=False, sort=True):
        key = key if isinstance(key, tuple) else (key,)
        levels = g.groupby("_nominal")["leak_l_min"].mean().sort_index()
        leaking = levels.to_numpy() >= threshold_l_min
        first = int(np.argmax(leaking)) if leaking.any() else None
        sealed_up_to = None
        if first is None:
            sealed_up_to = float(levels.index[-1])
        elif first > 0:
            sealed_up_to = float(levels.index[first - 1])
        note = None
        sealed_at_max = first is None
        if "leak_se_l_min" in g.columns:
            se2 = pd.to_numeric(g["leak_se_l_min"], errors="coerce").fillna(0.0) ** 2
            se = (np.sqrt(se2.groupby(g["_nominal"]).sum()) / g.groupby("_nominal").size()).reindex(levels.index)
            undecided = (np.abs(levels - threshold_l_min) <= 2.0 * se).to_numpy() & (se.to_numpy() > 0)
            if undecided.any():
                k = int(np.argmax(undecided))
                if first is None or k <= first:
                    note = (f"the leak at {float(levels.index[k]):.1f} bar cannot be told from the threshold "
                            "(within 2 standard errors)")
                    sealed_up_to, first, sealed_at_max = None, None, None
        row = dict(zip(by, key))
        force = row.get("spring_force_n")
        row.update({
            "spring_force_pct": (100.0 * force / spring_force_max_n) if force is not None and pd.notna(force) else None,
            "threshold_l_min": float(threshold_l_min),
            "sealed_up_to_bar": sealed_up_to,
            "first_leak_bar": None if first is None else float(levels.index[first]),
            "max_tested_bar": float(levels.index[-1]),
            "sealed_at_max": sealed_at_max,
            "max_leak_l_min": float(levels.max()),
            "n_pressures": int(len(levels)),
            "runs_used": (RUNS_HOSE_CHECKS if g["_check"].all() else
                          RUNS_CHARACTERISATION if not g["_check"].any() else RUNS_MIXED),
            "n_runs": int(g["run_id"].nunique()) if "run_id" in g.columns else None,
            "note": note,
        })
        rows.append(row)
    out = pd.DataFrame(rows, columns=cols)
    out["sealed_at_max"] = out["sealed_at_max"].astype("boolean")  # NULL when undecided
    return out


#: The columns of ``leakage_map`` that :func:`seal_envelope` reads besides its ``by`` columns.
ENVELOPE_READS = ("run_id", "hose_id", "pressure_bar", "leak_l_min", "leak_se_l_min")


def seal_envelope_rows(leakage_map: pd.DataFrame, by=SETTING_COLUMNS) -> pd.DataFrame:
    """The rows and columns of ``leakage_map`` that :func:`seal_envelope` reads: those with a pressure
    and a leak, as :func:`characterisation_rows` selects them (a setting's hose checks only when it has
    no characterisation run), the ``by`` columns and :data:`ENVELOPE_READS`, on a new index.

    ``seal_envelope`` of these rows is ``seal_envelope`` of the whole table (the selection is
    idempotent); a stage keys the pooled envelope by them, so a changed hose check of a characterised
    setting leaves the envelope as it was (issue 26).

    Parameters
    ----------
    leakage_map : DataFrame
        Rows of the ``leakage_map`` table.
    by : sequence of str
        Columns identifying a setting.

    Returns
    -------
    DataFrame
    """
    df = leakage_map.dropna(subset=["pressure_bar", "leak_l_min"])
    used = characterisation_rows(df, by)
    cols = [c for c in dict.fromkeys((*by, *ENVELOPE_READS)) if c in used.columns]
    return used[cols].reset_index(drop=True)


_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<", ">")


def _setting_label(adjustment: str, value: float, spring_force_max_n: float) -> str:
    if adjustment == "distance":
        return f"z = {value:.1f} mm"
    return f"F = {value:.0f} N ({100 * value / spring_force_max_n:.0f} %)"


def leakage_map_plot_rows(leakage_map: pd.DataFrame, adjustment: str) -> pd.DataFrame:
    """The rows and columns of ``leakage_map`` that :func:`plot_leakage_map` draws for ``adjustment``.

    The rows of the adjustment with a pressure, a leak and a setting, as
    :func:`characterisation_rows` selects them (a setting's hose checks only when it has no
    characterisation run), and only the columns the figure reads, on a new index. The figure of
    these rows is the figure of the whole table; a stage hands the figure these rows, so that its
    key changes with what it draws (issue 26: a changed hose check redrew both leakage maps).

    Parameters
    ----------
    leakage_map : DataFrame
        Rows of the ``leakage_map`` table.
    adjustment : {"distance", "force"}
        Which settings.

    Returns
    -------
    DataFrame
    """
    setting = "z_rollers_mm" if adjustment == "distance" else "spring_force_n"
    df = leakage_map[(leakage_map["adjustment"] == adjustment)].dropna(subset=["pressure_bar", "leak_l_min", setting])
    used = characterisation_rows(df)
    cols = [c for c in dict.fromkeys((*SETTING_COLUMNS, "pressure_bar", "leak_l_min", "hose_id")) if c in used.columns]
    return used[cols].reset_index(drop=True)


def plot_leakage_map(leakage_map: pd.DataFrame, adjustment: str, threshold_l_min: float | None = LEAK_THRESHOLD_L_MIN,
                     pressure_step_bar: float = 0.1, spring_force_max_n: float = SPRING_FORCE_MAX_N):
    """Leak vs pressure like Figs. 9 (``distance``) and 10 (``force``) of seed 000.

    One panel per chamber (A, B); one curve per roller distance or spring force, from the
    characterisation runs of the setting (:func:`characterisation_rows`; repeat runs averaged per
    tested pressure), each with its own hollow marker so that sealed settings stay visible on the
    zero line. Hose checks are left out; a setting with only hose checks is drawn from them as a
    dashed curve labelled "(hose checks)".

    Parameters
    ----------
    leakage_map : DataFrame
        Rows of the ``leakage_map`` table.
    adjustment : {"distance", "force"}
        Which settings to plot.
    threshold_l_min : float, optional
        Draws the seal-envelope threshold [l/min ANR].
    pressure_step_bar : float
        Resolution of the nominal (tested) pressure [bar].
    spring_force_max_n : float
        Maximum spring force, for the labels [N].

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    setting = "z_rollers_mm" if adjustment == "distance" else "spring_force_n"
    df = characterisation_rows(leakage_map_plot_rows(leakage_map, adjustment))
    fig = Figure(figsize=(10, 4.2))
    axes = fig.subplots(1, 2, sharey=True)
    values = sorted(df[setting].unique())
    cmap = __import__("matplotlib").colormaps["viridis"]
    order = []
    for v in values:
        lab = _setting_label(adjustment, v, spring_force_max_n)
        order += [lab, f"{lab} (hose checks)"]
    for ax, chamber, letter in zip(axes, ("A", "B"), "ab"):
        d = df[df["chamber"] == chamber]
        for i, v in enumerate(values):
            g = d[d[setting] == v]
            if g.empty:
                continue
            checks = bool((g["runs_used"] == RUNS_HOSE_CHECKS).all())
            label = _setting_label(adjustment, v, spring_force_max_n) + (" (hose checks)" if checks else "")
            nominal = (g["pressure_bar"] / pressure_step_bar).round() * pressure_step_bar
            curve = g.groupby(nominal).agg(p=("pressure_bar", "mean"), q=("leak_l_min", "mean")).sort_values("p")
            # sealed settings share the zero line: a hollow marker of its own (growing in size) per
            # setting keeps each of them visible there
            ax.plot(curve["p"], curve["q"], marker=_MARKERS[i % len(_MARKERS)], ms=4 + 0.9 * (i % len(_MARKERS)),
                    mfc="none", mew=1.2, lw=1.3, ls="--" if checks else "-",
                    color=cmap(i / max(1, len(values) - 1) * 0.9), label=label)
        if threshold_l_min is not None:
            ax.axhline(threshold_l_min, color="0.5", lw=0.8, ls=":", label=f"threshold {threshold_l_min:g} l/min")
        ax.set_title(f"({letter}) chamber {chamber}")
        ax.set_xlabel("pressure (gauge) [bar]")
        ax.grid(True, alpha=0.3)
        if d.empty:
            ax.text(0.5, 0.5, "no runs", transform=ax.transAxes, ha="center", color="0.5")
    axes[0].set_ylabel("leak [l/min ANR]")
    legend: dict = {}
    for ax in axes:  # settings from both panels, each once, in setting order (threshold last)
        for h, lab in zip(*ax.get_legend_handles_labels()):
            legend.setdefault(lab, h)
    labels = [lab for lab in order if lab in legend] + [lab for lab in legend if lab not in order]
    handles = [legend[lab] for lab in labels]
    if handles:
        fig.legend(handles, labels, loc="center right", fontsize=8, frameon=False)
    title = "roller distance" if adjustment == "distance" else "spring force"
    fig.suptitle(f"Leakage with {title} adjustment")
    fig.subplots_adjust(left=0.07, right=0.8, bottom=0.13, top=0.85, wspace=0.08)
    return fig


__all__ = ["find_pressure_plateaus", "leakage_plateaus", "leakage_power_law", "is_hose_check",
           "characterisation_rows", "seal_envelope", "seal_envelope_rows",
           "leakage_map_plot_rows", "plot_leakage_map", "RUNS_CHARACTERISATION", "RUNS_HOSE_CHECKS",
           "RUNS_MIXED", "LEAK_THRESHOLD_L_MIN", "SPRING_FORCE_MAX_N", "SETTING_COLUMNS"]
