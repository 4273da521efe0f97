"""Static (breakaway) friction of the PLPA (seed 000, section 3.2.1, Fig. 12).

In a breakaway run one chamber holds a constant backpressure while the pressure in the other is
ramped, so the drive force rises at a set rate until the carriage moves. The breakaway force is
the friction at that instant, Eq. 15: ``F = (p_a - p_b) * A``.

Sign convention
---------------
Direction ``P`` is driven by chamber A toward +x, so its drive force ``(p_a - p_b) A`` is
positive; direction ``N`` is driven by B toward -x, its drive force is negative. The breakaway
force reported is a magnitude: ``s * (p_a - p_b) * A`` with ``s = +1`` for P and ``-1`` for N,
and motion is only accepted in the direction ``s`` (toward +x for P, -x for N).

Motion onset (:func:`detect_motion_onset`)
-----------------------------------------
The encoder is quantised (5 um counts) and the carriage may creep by a few um before it breaks
away, so a single count of motion is not evidence of breakaway. The detector

1. takes the pre-ramp *baseline*: the median position over the first ``baseline_s`` seconds;
2. finds the first sample at which the position has left the baseline, in the drive direction,
   by more than ``threshold_counts`` counts and stays beyond that for ``persist_s`` seconds (or
   to the end of the record): this is gross motion, not creep or a glitch;
3. walks back from there along the monotone rise to the *first departure*: the last sample at
   which the position was still at its pre-motion level. The walk stops where the position was
   not rising (a count back, i.e. creep dither), where it had been flat for longer than
   ``flat_s`` (the creep level before breakaway), or at the baseline. Within a flat stretch a
   lone sample one count off the level (encoder dither) does not end the stretch.

Limits: pre-sliding creep must stay below the gross-motion threshold (``threshold_counts`` = 4
counts = 20 um by default); creep of 20 um or more is taken for the breakaway itself and the
onset comes too early (tested: creep of 2 counts = 10 um with dither and pressure noise is
found to the sample). A creep level of one count that dithers down to the baseline looks like
the baseline: the onset can then be up to ``flat_s`` early.

The breakaway force is then read at that instant from a straight line fitted to the force over
the ``fit_s`` seconds before it (the force is a ramp), which averages out the pressure noise
(300 Pa per sensor is about 0.2 N per sample) instead of reading one noisy sample.
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from analyses.numerics import fminbound, student_t_ppf, student_t_sf, welch_t_test_p
from analyses.quality import Gate, Sensor, describe_sensor, linear_lstsq

#: Gross motion on a noisy (analog) position: a departure of more than this many noise sigmas. [-]
GROSS_N_SIGMA = 6.0
#: Pre-sliding creep of the carriage stays under this (rolling and sliding contacts creep a few
#: micrometres before they break away); a larger departure is gross sliding. [m]
CREEP_MAX_M = 20e-6

_SIGN = {"P": 1.0, "N": -1.0}


def drive_force(p_a_pa, p_b_pa, hose_area_m2: float):
    """Drive force of the PLPA, Eq. 15 of seed 000: ``(p_a - p_b) * A``.

    At rest or at constant velocity it equals the friction force.

    Parameters
    ----------
    p_a_pa, p_b_pa : array_like
        Chamber pressures [Pa] (gauge or absolute, the same for both).
    hose_area_m2 : float
        Hose cross-section [m2].

    Returns
    -------
    ndarray
        Force toward +x [N].
    """
    return (np.asarray(p_a_pa, dtype=float) - np.asarray(p_b_pa, dtype=float)) * float(hose_area_m2)


def _position_floor(x, sensor: Sensor | None) -> tuple[float, float]:
    """``(step, noise)`` of the position: ``step`` its quantisation (or, for a signal that is not
    quantised, the float round-off), ``noise`` its sigma when it exceeds half a step (0 otherwise)."""
    s = sensor if sensor is not None else describe_sensor(x)
    res = float(s.resolution) if np.isfinite(s.resolution) and s.resolution > 0 else 0.0
    noise = float(s.noise) if np.isfinite(s.noise) and s.noise > 0.5 * res else 0.0
    if res <= 0:
        xa = np.asarray(x, dtype=float)
        res = max(float(np.nanmax(np.abs(xa))) if xa.size else 0.0, 1e-300) * 1e-12
    return res, noise


def detect_motion_onset(t_s, x_m, direction: str | None = None, sensor: Sensor | None = None, *,
                        baseline_s: float = 0.2, threshold_counts: float = 4.0, persist_s: float = 0.05,
                        flat_s: float = 0.1, creep_max_m: float = CREEP_MAX_M) -> int | None:
    """Index of the last sample before the carriage breaks away, or None if it never does.

    Parameters
    ----------
    t_s : array_like
        Time [s].
    x_m : array_like
        Carriage position [m] (quantised encoder reading).
    direction : {"P", "N", None}
        Expected direction of motion (+x for P, -x for N); None accepts either.
    sensor : analyses.quality.Sensor, optional
        Resolution and noise of the position [m]; estimated from ``x_m`` when not given.
    baseline_s : float
        Length of the pre-ramp baseline [s].
    threshold_counts : float
        Departure from the baseline that counts as gross motion [counts of the encoder]; larger
        than the pre-sliding creep. On a noisy (analog) position the threshold is also at least
        :data:`GROSS_N_SIGMA` noise sigmas, and the walk back ends at the last sample within
        3 sigmas of the baseline.
    creep_max_m : float
        Largest pre-sliding creep [m]: a physical bound, so a fine encoder that resolves the
        creep does not take it for the breakaway (gross motion is the largest of this,
        ``threshold_counts`` counts and :data:`GROSS_N_SIGMA` noise sigmas).
    persist_s : float
        How long the departure must persist [s].
    flat_s : float
        A flat stretch longer than this ends the walk back to the first departure [s].

    Returns
    -------
    int or None
        Index of the last sample at the pre-motion position (the onset).
    """
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(x_m, dtype=float)
    n = t.size
    if n < 3:
        return None
    nb = max(3, int(np.searchsorted(t, t[0] + baseline_s)))
    base = float(np.median(x[:nb]))
    resolution_m, noise = _position_floor(x, sensor)
    gross = max(threshold_counts * resolution_m, GROSS_N_SIGMA * noise, creep_max_m)
    if direction is None:
        up = _gross_index(t, x - base, gross, persist_s)
        down = _gross_index(t, base - x, gross, persist_s)
        cands = [(i, s) for i, s in ((up, 1.0), (down, -1.0)) if i is not None]
        if not cands:
            return None
        i_c, sign = min(cands)
    else:
        sign = _SIGN[direction]
        i_c = _gross_index(t, sign * (x - base), gross, persist_s)
        if i_c is None:
            return None
    d = sign * (x - base)
    if noise > 0:  # analog: back to the last sample within the noise of the baseline
        near = np.flatnonzero(d[:i_c] <= 3.0 * noise)
        return int(near[-1]) if near.size else 0
    half = 0.5 * resolution_m
    j = i_c
    flat_since = None
    while j > 0:
        prev = d[j - 1]
        if prev <= half:  # back at the baseline: j - 1 is the last sample there
            return int(j - 1)
        level = d[j] if flat_since is None else d[flat_since]
        dither = (flat_since is not None and j >= 2 and abs(prev - level) <= resolution_m + half
                  and abs(d[j - 2] - level) <= half)
        if abs(prev - level) <= half or dither:  # flat (a lone sample one count off is encoder dither)
            if flat_since is None:
                flat_since = j
            if t[flat_since] - t[j - 1] > flat_s:  # the creep level held before breakaway
                return int(flat_since)
        elif prev > level + half:  # back above the level: the pre-motion level ends here
            return int(j if flat_since is None else flat_since)
        else:  # lower: still on the rise
            flat_since = None
        j -= 1
    return 0


def _gross_index(t, d, threshold_m, persist_s) -> int | None:
    """First index from which ``d`` stays above the gross-motion threshold for ``persist_s``."""
    above = d > threshold_m
    if not above.any():
        return None
    edges = np.flatnonzero(np.diff(np.concatenate(([0], above.astype(np.int8), [0]))))
    starts, stops = edges[0::2], edges[1::2]
    for a, b in zip(starts, stops):
        if b == len(d) or t[b - 1] - t[a] >= persist_s:
            return int(a)
    return None


def force_at(t_s, f_n, t0: float, fit_s: float = 0.25, t_min: float | None = None) -> tuple[float, float]:
    """Force at ``t0`` from a straight line fitted to the ``fit_s`` seconds before it.

    Parameters
    ----------
    t_s, f_n : array_like
        Time [s] and force [N].
    t0 : float
        Instant to evaluate at [s].
    fit_s : float
        Window length [s].
    t_min : float, optional
        The window does not start before this [s].

    Returns
    -------
    (force [N], slope [N/s])
    """
    t = np.asarray(t_s, dtype=float)
    f = np.asarray(f_n, dtype=float)
    lo = t0 - fit_s if t_min is None else max(t0 - fit_s, t_min)
    m = (t >= lo) & (t <= t0) & np.isfinite(f)
    if m.sum() < 3:
        last = f[(t <= t0) & np.isfinite(f)][-3:]
        return (float(np.mean(last)) if last.size else float("nan")), float("nan")
    slope, icpt = np.polyfit(t[m] - t0, f[m], 1)
    return float(icpt), float(slope)


class _Hinge:
    """Residual sum of squares of ``F = f0 + rate * max(t - tr, 0)`` for any ``tr``, in O(1)
    per ``tr`` from suffix sums over the (sorted) samples."""

    def __init__(self, t, f):
        self.t0 = float(t[0])
        self.t = t - self.t0
        self.fc = f - f.mean()
        self.n = t.size
        rev = lambda a: np.concatenate([np.cumsum(a[::-1])[::-1], [0.0]])  # noqa: E731  suffix sums
        self.s0 = rev(np.ones_like(self.t))
        self.s1, self.s2 = rev(self.t), rev(self.t * self.t)
        self.sy, self.sty = rev(self.fc), rev(self.t * self.fc)
        self.syy = float(self.fc @ self.fc)

    def rss(self, tr):
        tr = np.atleast_1d(np.asarray(tr, dtype=float)) - self.t0
        j = np.searchsorted(self.t, tr, side="right")  # samples j.. lie after tr
        m, s1, s2, sy, sty = self.s0[j], self.s1[j], self.s2[j], self.sy[j], self.sty[j]
        sz = s1 - m * tr
        szz = s2 - 2 * tr * s1 + m * tr * tr - sz * sz / self.n
        szy = sty - tr * sy
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(szz > 1e-300, self.syy - szy * szy / szz, self.syy)


def ramp_rate(t_s, f_n, t_end: float) -> dict:
    """Rate of a force ramp from its start to ``t_end``: a hinge fitted by least squares.

    Model ``F = f0`` before the ramp start ``t_r``, ``f0 + rate (t - t_r)`` after; ``t_r`` is
    profiled over every sample instant up to ``t_end`` (then refined between samples) and the
    rate's standard error is that of the linear fit at the best ``t_r``.

    Parameters
    ----------
    t_s, f_n : array_like
        Time [s] and drive force [N].
    t_end : float
        End of the ramp to use (the motion onset) [s].

    Returns
    -------
    dict
        ``rate_n_s``, ``rate_se_n_s``, ``ramp_start_s``, ``note`` (values None, and why, when
        the ramp start sits at an end of its range, the rate is not distinguishable from zero or
        is negative, or there are too few samples).
    """
    t = np.asarray(t_s, dtype=float)
    f = np.asarray(f_n, dtype=float)
    m = (t <= t_end) & np.isfinite(f) & np.isfinite(t)
    t, f = t[m], f[m]
    out = {"rate_n_s": None, "rate_se_n_s": None, "ramp_start_s": None, "note": None}
    g = Gate()
    if g.enough_points(t.size, 10, "samples before the onset").reasons:
        out["note"] = g.note
        return out
    grid = t[1:-1]  # every sample instant, then refined between the neighbours of the best
    hinge = _Hinge(t, f)
    k = int(np.argmin(hinge.rss(grid)))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
    tr = float(fminbound(lambda z: float(hinge.rss(z)[0]), lo, hi, xatol=1e-3 * float(hi - lo) + 1e-12))
    if float(hinge.rss(grid[k])[0]) < float(hinge.rss(tr)[0]):
        tr = float(grid[k])
    fit = linear_lstsq(np.column_stack([np.ones_like(t), np.clip(t - tr, 0.0, None)]), f)
    out.update({"rate_n_s": float(fit.beta[1]), "rate_se_n_s": float(fit.se[1]) if np.isfinite(fit.se[1]) else None,
                "ramp_start_s": float(tr)})
    g.within_bounds([tr], [grid[0]], [grid[-1]], ("ramp start",), rtol=1e-6)
    g.identifiable(fit, names=("force level", "force rate"), check=("force rate",))
    g.physical("force rate", float(fit.beta[1]), lo=0.0)
    return g.apply(out, ("rate_n_s", "rate_se_n_s", "ramp_start_s"))


def breakaway_force(t_s, x_m, p_a_pa, p_b_pa, hose_area_m2: float, direction: str, sensor: Sensor | None = None, *,
                    fit_s: float = 0.25, **onset_kwargs) -> dict:
    """Breakaway force of one run (a magnitude, see the module's sign convention).

    Parameters
    ----------
    t_s, x_m, p_a_pa, p_b_pa : array_like
        Time [s], position [m], chamber pressures [Pa].
    hose_area_m2 : float
        Hose cross-section [m2].
    direction : {"P", "N"}
        P: driven by A toward +x; N: driven by B toward -x.
    sensor : analyses.quality.Sensor, optional
        Position sensor [m]; estimated from ``x_m`` when not given.
    fit_s : float
        Window of the force line fit before the onset [s].
    **onset_kwargs
        Passed to :func:`detect_motion_onset`.

    Returns
    -------
    dict
        ``breakaway_force_n`` (None if no motion the sensor can tell), ``onset_t_s``,
        ``measured_rate_n_s`` and ``measured_rate_se_n_s`` (the drive force's rate over the whole
        ramp, from its start to the onset: :func:`ramp_rate`), ``note`` (why a value is None),
        ``warning`` (text or None).
    """
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(x_m, dtype=float)
    sign = _SIGN[direction]
    force = sign * drive_force(p_a_pa, p_b_pa, hose_area_m2)
    if sensor is None and x.size:
        sensor = describe_sensor(x)
    onset = detect_motion_onset(t, x, direction, sensor, **onset_kwargs)
    out = {"breakaway_force_n": None, "onset_t_s": None, "measured_rate_n_s": None, "measured_rate_se_n_s": None,
           "note": None, "warning": None}
    if onset is None:
        other = detect_motion_onset(t, x, "N" if direction == "P" else "P", sensor, **onset_kwargs)
        if other is not None:
            out["warning"] = (f"carriage moved against direction {direction} at t = {t[other]:.3f} s; "
                              "no breakaway force")
            out["note"] = f"carriage moved against direction {direction}"
        else:
            span = (np.nanmax(x) - np.nanmin(x)) * 1e6 if x.size else 0.0
            floor = sensor.describe() if sensor is not None else "unknown sensor"
            out["warning"] = (f"carriage never moved (position span {span:.0f} um, peak drive force "
                              f"{np.nanmax(force):.2f} N); no breakaway force")
            out["note"] = f"no motion the position sensor can tell (span {span:.0f} um; {floor})"
        return out
    nb = max(3, int(np.searchsorted(t, t[0] + onset_kwargs.get("baseline_s", 0.2))))
    f0, _slope = force_at(t, force, float(t[onset]), fit_s=fit_s, t_min=float(t[min(nb, onset)]))
    rate = ramp_rate(t, force, float(t[onset]))
    out.update({"breakaway_force_n": f0, "onset_t_s": float(t[onset]), "measured_rate_n_s": rate["rate_n_s"],
                "measured_rate_se_n_s": rate["rate_se_n_s"], "note": rate["note"]})
    if not np.isfinite(f0):
        out["breakaway_force_n"] = None
        out["warning"] = "no force samples before the motion onset"
        out["note"] = "no force samples before the motion onset"
    elif f0 <= 0:
        out["warning"] = f"drive force at motion onset is {f0:.2f} N (not in direction {direction})"
    return out


def breakaway_summary(breakaway: pd.DataFrame) -> pd.DataFrame:
    """Mean and scatter per (direction, backpressure_bar, force_rate_n_s).

    Returns
    -------
    DataFrame
        ``direction``, ``backpressure_bar``, ``force_rate_n_s``, ``n`` (events with a force),
        ``mean_force_n``, ``std_force_n`` (sample standard deviation; NULL when n < 2).
    """
    cols = ["direction", "backpressure_bar", "force_rate_n_s", "n", "mean_force_n", "std_force_n"]
    df = breakaway.dropna(subset=["breakaway_force_n"])
    if df.empty:
        return pd.DataFrame(columns=cols)
    g = df.groupby(["direction", "backpressure_bar", "force_rate_n_s"], sort=True)["breakaway_force_n"]
    out = g.agg(n="count", mean_force_n="mean", std_force_n="std").reset_index()
    out["n"] = out["n"].astype("int64")
    return out[cols]


def backpressure_ratio(breakaway: pd.DataFrame, direction: str | None = None, confidence: float = 0.95,
                       high_bar: float = 1.0) -> dict:
    """Ratio of the mean breakaway force at 0 bar to that at >= ``high_bar`` backpressure.

    The confidence interval is the delta method on the log of the ratio of two means, with the
    Welch-Satterthwaite degrees of freedom (deterministic, no resampling).

    Returns
    -------
    dict
        ``estimate``, ``ci_low``, ``ci_high``, ``n`` (events used), ``p_value`` (Welch t test
        of equal means), ``note`` (None, or why the estimate is None).
    """
    df = breakaway.dropna(subset=["breakaway_force_n"])
    if direction is not None:
        df = df[df["direction"] == direction]
    lo = df.loc[df["backpressure_bar"].abs() < 0.05, "breakaway_force_n"].to_numpy(float)
    hi = df.loc[df["backpressure_bar"] >= high_bar - 0.05, "breakaway_force_n"].to_numpy(float)
    out = {"estimate": None, "ci_low": None, "ci_high": None, "n": int(lo.size + hi.size), "p_value": None,
           "note": None}
    if lo.size < 2 or hi.size < 2:
        out["note"] = (f"too few breakaway forces for a ratio: {lo.size} at 0 bar and {hi.size} at >= "
                       f"{high_bar:g} bar (2 of each needed)")
        return out
    if lo.mean() <= 0 or hi.mean() <= 0:
        out["note"] = "a mean breakaway force is not positive: no ratio"
        return out
    m0, m1 = lo.mean(), hi.mean()
    v0 = lo.var(ddof=1) / (lo.size * m0**2)
    v1 = hi.var(ddof=1) / (hi.size * m1**2)
    se = np.sqrt(v0 + v1)
    dof = (v0 + v1) ** 2 / (v0**2 / (lo.size - 1) + v1**2 / (hi.size - 1)) if se > 0 else np.inf
    q = student_t_ppf(0.5 + confidence / 2, dof)
    r = m0 / m1
    out.update({"estimate": float(r), "ci_low": float(r * np.exp(-q * se)), "ci_high": float(r * np.exp(q * se)),
                "p_value": welch_t_test_p(lo, hi)})
    return out


def force_rate_slope(breakaway: pd.DataFrame, direction: str | None = None, confidence: float = 0.95) -> dict:
    """Effect of the force rate on the breakaway force: a common slope [N per N/s].

    Ordinary least squares of ``breakaway_force_n`` on ``force_rate_n_s`` with one intercept per
    (direction, backpressure_bar) group, so the backpressure effect does not leak into the
    slope. The interval is the t interval of the slope.

    Returns
    -------
    dict
        ``estimate`` [N/(N/s)], ``ci_low``, ``ci_high``, ``n``, ``p_value`` (slope = 0), ``note``
        (None, or why the estimate is None).
    """
    df = breakaway.dropna(subset=["breakaway_force_n", "force_rate_n_s", "backpressure_bar"])
    if direction is not None:
        df = df[df["direction"] == direction]
    out = {"estimate": None, "ci_low": None, "ci_high": None, "n": int(len(df)), "p_value": None, "note": None}
    if df.empty:
        out["note"] = "no breakaway forces"
        return out
    if df["force_rate_n_s"].nunique() < 2:
        out["note"] = "one force rate only: no slope"
        return out
    groups = df.groupby(["direction", "backpressure_bar"], sort=True).ngroup().to_numpy()
    ng = groups.max() + 1
    X = np.zeros((len(df), ng + 1))
    X[np.arange(len(df)), groups] = 1.0
    X[:, ng] = df["force_rate_n_s"].to_numpy(float)
    y = df["breakaway_force_n"].to_numpy(float)
    dof = len(df) - np.linalg.matrix_rank(X)
    if dof < 1:
        out["note"] = f"too few breakaway forces for a slope ({len(df)} events, no degree of freedom left)"
        return out
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    resid = y - X @ beta
    s2 = resid @ resid / dof
    cov = s2 * np.linalg.pinv(X.T @ X)
    se = float(np.sqrt(cov[ng, ng]))
    b = float(beta[ng])
    q = student_t_ppf(0.5 + confidence / 2, dof)
    p = float(2 * student_t_sf(abs(b) / se, dof)) if se > 0 else (0.0 if b != 0 else 1.0)
    out.update({"estimate": b, "ci_low": b - q * se, "ci_high": b + q * se, "p_value": p})
    return out


def breakaway_findings(breakaway: pd.DataFrame, confidence: float = 0.95) -> pd.DataFrame:
    """The two findings of section 3.2.1 as numbers with confidence intervals.

    ``backpressure_ratio``: mean breakaway force at 0 bar over the mean at >= 1 bar (the paper:
    about 2). ``force_rate_slope``: change of breakaway force per N/s of force rate (the paper:
    no significant effect). One row per finding and direction (``P``, ``N``, ``all``).

    Returns
    -------
    DataFrame
        ``finding``, ``direction``, ``estimate``, ``ci_low``, ``ci_high``, ``confidence``,
        ``p_value``, ``n``, ``unit``, ``significant`` (p < 1 - confidence), ``note`` (NULL when
        the estimate stands, else why it is NULL).
    """
    rows = []
    for finding, func, unit in (("backpressure_ratio", backpressure_ratio, "ratio"),
                                ("force_rate_slope", force_rate_slope, "N/(N/s)")):
        for d in ("P", "N", None):
            r = func(breakaway, d, confidence)
            rows.append({"finding": finding, "direction": d or "all", **r, "confidence": confidence, "unit": unit,
                         "significant": None if r["p_value"] is None else bool(r["p_value"] < 1 - confidence)})
    return pd.DataFrame(rows, columns=["finding", "direction", "estimate", "ci_low", "ci_high", "confidence",
                                       "p_value", "n", "unit", "significant", "note"])


def plot_breakaway(breakaway: pd.DataFrame):
    """Breakaway force vs backpressure like Fig. 12 of seed 000.

    One panel per direction (P, N); one series per force rate, each point the mean of the
    events with its standard deviation as error bar (series offset slightly along x).

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 4.2))
    axes = fig.subplots(1, 2, sharey=True)
    summ = breakaway_summary(breakaway)
    rates = sorted(summ["force_rate_n_s"].unique()) if not summ.empty else []
    cmap = matplotlib.colormaps["plasma"]
    for ax, d in zip(axes, ("P", "N")):
        s = summ[summ["direction"] == d]
        for i, r in enumerate(rates):
            g = s[s["force_rate_n_s"] == r].sort_values("backpressure_bar")
            if g.empty:
                continue
            off = (i - (len(rates) - 1) / 2) * 0.06
            ax.errorbar(g["backpressure_bar"] + off, g["mean_force_n"], yerr=g["std_force_n"].fillna(0.0),
                        marker="o", ms=5, capsize=3, lw=1, color=cmap(0.85 * i / max(1, len(rates) - 1)),
                        label=f"{r:g} N/s")
        ax.set_title(f"direction {d} ({'A drives toward +x' if d == 'P' else 'B drives toward -x'})")
        ax.set_xlabel("backpressure (gauge) [bar]")
        ax.grid(True, alpha=0.3)
        if not summ.empty:
            top = float((summ["mean_force_n"] + summ["std_force_n"].fillna(0.0)).max())
            ax.set_ylim(0, 1.15 * top if top > 0 else 1.0)
        if s.empty:
            ax.text(0.5, 0.5, "no runs", transform=ax.transAxes, ha="center", color="0.5")
    axes[0].set_ylabel("breakaway force |(p_A - p_B) A| [N]")
    legend: dict = {}
    for ax in axes:  # rates from both panels, each once, in rate order
        for h, lab in zip(*ax.get_legend_handles_labels()):
            legend.setdefault(lab, h)
    labels = [f"{r:g} N/s" for r in rates if f"{r:g} N/s" in legend]
    handles = [legend[lab] for lab in labels]
    if handles:
        fig.legend(handles, labels, title="force rate", loc="center right", fontsize=8, frameon=False)
    fig.suptitle("Static friction: influence of force rate and backpressure (mean +/- std)")
    fig.subplots_adjust(left=0.07, right=0.86, bottom=0.13, top=0.85, wspace=0.08)
    return fig


__all__ = ["drive_force", "detect_motion_onset", "force_at", "breakaway_force", "breakaway_summary",
           "backpressure_ratio", "force_rate_slope", "breakaway_findings", "plot_breakaway",
           "ramp_rate", "CREEP_MAX_M", "GROSS_N_SIGMA"]
