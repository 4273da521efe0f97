"""Viscous friction of the PLPA: friction vs velocity (seed 000, section 3.2.2, Figs. 13 and 14).

A viscous run drives the carriage back and forth at constant velocities. While the velocity is
constant the drive force equals the friction (Eq. 15): ``(p_a - p_b) * A``, or the load-cell
force ``f`` when the run has one. Friction and velocity are signed (+ toward +x), so a
direction ``P`` point has v > 0, F > 0 and a direction ``N`` point v < 0, F < 0.

Constant-velocity passes (:func:`find_constant_velocity_passes`)
----------------------------------------------------------------
The encoder is quantised (5 um) and nothing else in the record marks a pass, so:

1. The record is cut into *strokes*: maximal stretches in which the position moves one way
   (stationary stretches, where the position holds one count for ``still_s``, separate them).
2. Within a stroke of mean speed ``v_m`` the velocity is estimated by central differences over
   a window ``w`` (a twentieth of the stroke, at least ``min_counts`` counts of travel), so the
   quantisation error is at most ``res / w``.
3. A sample is *steady* when the velocities over the window before and after it agree within
   ``rel_tol * |v| + 3 res / w`` (acceleration near zero). The steady centres of a stroke form
   the pass; since every centre is steady, the pass does not include the ramps.
4. A pass must last at least ``3 w`` and travel ``min_counts`` counts. Its velocity is the slope
   of a straight line fitted to the position (exact to a fraction of a count over the pass), its
   friction the mean drive force; the residual acceleration (quadratic fit) is reported.

Models
------
- Coulomb + viscous, per direction: ``F = s Fc + ka v`` (``s`` = sign of v), by linear least
  squares on points with ``|v| >= min_speed_m_s`` (where the ``tanh`` transition has saturated).
  ``coulomb_n`` is reported as a magnitude for both directions.
- Near zero: ``F = Fc tanh(v / vs) + ka v`` (symmetric), by nonlinear least squares; ``vs`` is
  the transition velocity.
- Stribeck test: the near-zero model with an added Stribeck term,
  ``F = tanh(v / vs) (Fc + Fst exp(-(v / v_st)^2)) + ka v``, fitted for a grid of ``v_st``; the
  best ``v_st`` is kept and ``Fst > 0`` is tested with an F test (one extra parameter),
  Bonferroni-corrected for the grid. A dip is reported only when ``Fst > 0`` is significant.
"""
from __future__ import annotations

import numpy as np
import pandas as pd
import scipy  # its submodules load on first use: a rebuild that reuses every stage never pays for them

from analyses.breakaway import ENCODER_RESOLUTION_M, drive_force

#: Below this speed the tanh transition is not saturated; such points are left out of the
#: Coulomb + viscous fit. [m/s]
MIN_SPEED_LINEAR_M_S = 2e-3
#: Runs whose passes are all slower than this are near-zero runs (Fig. 14). [m/s]
NEAR_ZERO_MAX_M_S = 0.01


def nrmse_pct(measured, model) -> float:
    """100 * RMS(measured - model) / (max(measured) - min(measured)) (warehouse.md).

    Returns NaN when the measured values have no range.
    """
    y = np.asarray(measured, dtype=float)
    m = np.asarray(model, dtype=float)
    span = float(np.max(y) - np.min(y)) if y.size else 0.0
    if span <= 0:
        return float("nan")
    return float(100.0 * np.sqrt(np.mean((y - m) ** 2)) / span)


def _strokes(t: np.ndarray, x: np.ndarray, resolution_m: float, still_s: float) -> list[tuple[int, int, float]]:
    """Monotone stretches ``(start, stop, sign)`` separated by reversals or stillness."""
    half = 0.5 * resolution_m
    dx = np.diff(x)
    moves = np.flatnonzero(np.abs(dx) > half)  # sample i -> i+1 changes count
    if moves.size == 0:
        return []
    out = []
    a = moves[0]
    sign = np.sign(dx[a])
    prev = a
    for i in moves[1:]:
        s = np.sign(dx[i])
        if s != sign or t[i] - t[prev + 1] > still_s:
            out.append((int(a), int(prev + 2), float(sign)))
            a, sign = i, s
        prev = i
    out.append((int(a), int(prev + 2), float(sign)))
    return out


def find_constant_velocity_passes(t_s, x_m, *, resolution_m: float = ENCODER_RESOLUTION_M, rel_tol: float = 0.02,
                                  min_counts: float = 20.0, still_s: float = 0.5,
                                  window_fraction: float = 0.05) -> list[tuple[int, int]]:
    """Sample ranges ``[start, stop)`` of the constant-velocity passes of a run.

    Parameters
    ----------
    t_s : array_like
        Time [s].
    x_m : array_like
        Position [m] (encoder).
    resolution_m : float
        Encoder count [m].
    rel_tol : float
        Relative velocity change allowed between neighbouring windows.
    min_counts : float
        Least travel of a velocity window and of a pass [counts].
    still_s : float
        A position held this long ends a stroke [s].
    window_fraction : float
        Velocity window as a fraction of the stroke duration.

    Returns
    -------
    list of (start, stop)
    """
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(x_m, dtype=float)
    ok = np.isfinite(t) & np.isfinite(x)
    if not ok.all():
        t, x = t[ok], x[ok]
    if t.size < 10:
        return []
    dt = float(np.median(np.diff(t)))
    out = []
    for a, b, _sign in _strokes(t, x, resolution_m, still_s):
        dur = t[b - 1] - t[a]
        travel = abs(x[b - 1] - x[a])
        if dur <= 0 or travel < 2 * min_counts * resolution_m:
            continue
        v_m = travel / dur
        w = max(window_fraction * dur, min_counts * resolution_m / v_m, 5 * dt)
        if 3 * w > dur:
            continue
        h = max(1, int(round(w / 2 / dt)))
        ts, xs = t[a:b], x[a:b]
        n = xs.size
        if n < 4 * h + 3:
            continue
        # v over [i-h, i+h]; steady at i if v at i-h and at i+h agree
        vc = np.full(n, np.nan)
        vc[h:n - h] = (xs[2 * h:] - xs[:n - 2 * h]) / (ts[2 * h:] - ts[:n - 2 * h])
        steady = np.zeros(n, dtype=bool)
        before, after = vc[:n - 2 * h], vc[2 * h:]
        wt = ts[2 * h:] - ts[:n - 2 * h]
        tol = rel_tol * np.abs(0.5 * (before + after)) + 3 * resolution_m / wt
        steady[h:n - h] = np.abs(after - before) <= tol
        steady &= np.isfinite(vc) | steady
        edges = np.flatnonzero(np.diff(np.concatenate(([0], steady.astype(np.int8), [0]))))
        for s0, s1 in zip(edges[0::2], edges[1::2]):
            if ts[s1 - 1] - ts[s0] < max(3 * w, w + 5 * dt) or abs(xs[s1 - 1] - xs[s0]) < min_counts * resolution_m:
                continue
            out.append((a + int(s0), a + int(s1)))
    return out


def viscous_points(t_s, x_m, force_n, **kwargs) -> pd.DataFrame:
    """One row per constant-velocity pass: signed mean velocity and signed mean friction.

    Parameters
    ----------
    t_s, x_m : array_like
        Time [s], position [m].
    force_n : array_like
        Drive force toward +x [N]: ``(p_a - p_b) A`` or the load cell.
    **kwargs
        Passed to :func:`find_constant_velocity_passes`.

    Returns
    -------
    DataFrame
        ``pass_index``, ``t_start_s``, ``t_end_s``, ``n_samples``, ``velocity_m_s`` (line fit),
        ``friction_n`` (mean), ``friction_std_n``, ``accel_m_s2`` (quadratic fit, diagnostic),
        ``direction`` (P for v > 0, N for v < 0).
    """
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(x_m, dtype=float)
    f = np.asarray(force_n, dtype=float)
    ok = np.isfinite(t) & np.isfinite(x) & np.isfinite(f)
    t, x, f = t[ok], x[ok], f[ok]
    rows = []
    for i, (a, b) in enumerate(find_constant_velocity_passes(t, x, **kwargs)):
        tt = t[a:b] - t[a:b].mean()
        v = float(np.polyfit(tt, x[a:b], 1)[0])
        acc = float(2 * np.polyfit(tt, x[a:b], 2)[0]) if b - a > 3 else float("nan")
        rows.append({"pass_index": i, "t_start_s": float(t[a]), "t_end_s": float(t[b - 1]), "n_samples": b - a,
                     "velocity_m_s": v, "friction_n": float(np.mean(f[a:b])),
                     "friction_std_n": float(np.std(f[a:b])), "accel_m_s2": acc,
                     "direction": "P" if v > 0 else "N"})
    return pd.DataFrame(rows, columns=["pass_index", "t_start_s", "t_end_s", "n_samples", "velocity_m_s",
                                       "friction_n", "friction_std_n", "accel_m_s2", "direction"])


def friction_from_run(samples: pd.DataFrame, hose_area_m2: float | None = None) -> np.ndarray:
    """Drive force of a viscous run [N]: the ``f_n`` channel if present, else ``(p_a - p_b) A``.

    Raises
    ------
    ValueError
        When neither the force nor (both pressures and the hose area) are available.
    """
    if "f_n" in samples.columns and samples["f_n"].notna().any():
        return samples["f_n"].to_numpy(float)
    if {"p_a_pa", "p_b_pa"} <= set(samples.columns):
        if hose_area_m2 is None or not np.isfinite(hose_area_m2) or hose_area_m2 <= 0:
            raise ValueError("pressures without a valid hose_area_m2")
        return drive_force(samples["p_a_pa"], samples["p_b_pa"], hose_area_m2)
    raise ValueError("neither a force channel f nor both chamber pressures")


def coulomb_viscous(v_m_s, coulomb_n: float, viscous_n_s_m: float):
    """Coulomb + viscous friction ``Fc sign(v) + ka v`` [N].

    Parameters
    ----------
    v_m_s : array_like
        Velocity [m/s].
    coulomb_n : float
        Coulomb friction (magnitude) [N].
    viscous_n_s_m : float
        Viscous coefficient [N s/m].
    """
    v = np.asarray(v_m_s, dtype=float)
    return coulomb_n * np.sign(v) + viscous_n_s_m * v


def tanh_viscous(v_m_s, coulomb_n: float, viscous_n_s_m: float, transition_m_s: float):
    """Smooth friction of physics.md: ``Fc tanh(v / vs) + ka v`` [N].

    Parameters
    ----------
    v_m_s : array_like
        Velocity [m/s].
    coulomb_n : float
        Coulomb level [N].
    viscous_n_s_m : float
        Viscous coefficient [N s/m].
    transition_m_s : float
        Transition velocity ``vs`` [m/s].
    """
    v = np.asarray(v_m_s, dtype=float)
    return coulomb_n * np.tanh(v / transition_m_s) + viscous_n_s_m * v


def fit_coulomb_viscous(v_m_s, friction_n, min_speed_m_s: float = MIN_SPEED_LINEAR_M_S,
                        confidence: float = 0.95) -> dict:
    """Coulomb + viscous fit of one direction's points by linear least squares.

    Parameters
    ----------
    v_m_s, friction_n : array_like
        Signed velocity [m/s] and friction [N] of one direction (all v of one sign).
    min_speed_m_s : float
        Points slower than this are left out [m/s].

    Returns
    -------
    dict
        ``coulomb_n`` (magnitude), ``viscous_n_s_m``, ``nrmse_pct`` (over the points fitted),
        ``n_points``, ``coulomb_se_n``, ``viscous_se_n_s_m``; None values with fewer than 3
        points or a single velocity.
    """
    v = np.asarray(v_m_s, dtype=float)
    f = np.asarray(friction_n, dtype=float)
    m = np.isfinite(v) & np.isfinite(f) & (np.abs(v) >= min_speed_m_s)
    v, f = v[m], f[m]
    out = {"coulomb_n": None, "viscous_n_s_m": None, "nrmse_pct": None, "n_points": int(v.size),
           "coulomb_se_n": None, "viscous_se_n_s_m": None}
    if v.size < 3 or np.ptp(v) <= 0:
        return out
    s = np.sign(np.median(v))
    X = np.column_stack([np.full_like(v, s), v])
    beta, *_ = np.linalg.lstsq(X, f, rcond=None)
    model = X @ beta
    resid = f - model
    dof = v.size - 2
    cov = (resid @ resid / dof) * np.linalg.inv(X.T @ X)
    out.update({"coulomb_n": float(beta[0]), "viscous_n_s_m": float(beta[1]), "nrmse_pct": nrmse_pct(f, model),
                "coulomb_se_n": float(np.sqrt(cov[0, 0])), "viscous_se_n_s_m": float(np.sqrt(cov[1, 1]))})
    return out


def fit_tanh_viscous(v_m_s, friction_n, confidence: float = 0.95) -> dict:
    """Symmetric ``Fc tanh(v / vs) + ka v`` fit of near-zero points (both directions).

    Returns
    -------
    dict
        ``coulomb_n``, ``viscous_n_s_m``, ``transition_m_s`` with ``transition_ci_low_m_s`` /
        ``transition_ci_high_m_s`` (t interval at ``confidence`` from the Jacobian),
        ``nrmse_pct``, ``n_points``, ``rss``; None values with fewer than 5 points.
    """
    v = np.asarray(v_m_s, dtype=float)
    f = np.asarray(friction_n, dtype=float)
    m = np.isfinite(v) & np.isfinite(f)
    v, f = v[m], f[m]
    keys = ("coulomb_n", "viscous_n_s_m", "transition_m_s", "transition_ci_low_m_s", "transition_ci_high_m_s",
            "nrmse_pct", "rss")
    out = dict.fromkeys(keys)
    out["n_points"] = int(v.size)
    if v.size < 5 or np.all(v > 0) or np.all(v < 0):
        return out
    res = _fit_tanh(v, f)
    if res is None:
        return out
    p, rss, cov = res
    dof = v.size - 3
    q = scipy.stats.t.ppf(0.5 + confidence / 2, dof)
    se_log = float(np.sqrt(cov[2, 2])) if cov is not None and np.isfinite(cov[2, 2]) else float("nan")
    vs = float(np.exp(p[2]))
    out.update({"coulomb_n": float(p[0]), "viscous_n_s_m": float(p[1]), "transition_m_s": vs,
                "transition_ci_low_m_s": vs * float(np.exp(-q * se_log)) if np.isfinite(se_log) else None,
                "transition_ci_high_m_s": vs * float(np.exp(q * se_log)) if np.isfinite(se_log) else None,
                "nrmse_pct": nrmse_pct(f, tanh_viscous(v, p[0], p[1], vs)), "rss": rss})
    return out


def _fit_tanh(v, f, stribeck_v: float | None = None):
    """Least squares of the tanh model (optionally with a Stribeck term); params in log(vs)."""
    speeds = np.abs(v[v != 0])
    lo = max(float(speeds.min()) / 20, 1e-7) if speeds.size else 1e-6
    hi = float(speeds.max()) * 2 if speeds.size else 1.0

    def model(p):
        base = p[0] if stribeck_v is None else p[0] + p[3] * np.exp(-(v / stribeck_v) ** 2)
        return base * np.tanh(v / np.exp(p[2])) + p[1] * v

    fast = np.abs(v) >= np.quantile(np.abs(v), 0.5)
    X = np.column_stack([np.sign(v[fast]), v[fast]]) if fast.sum() >= 2 else np.column_stack([np.sign(v), v])
    y = f[fast] if fast.sum() >= 2 else f
    lin = np.linalg.lstsq(X, y, rcond=None)[0]
    best = None
    for vs0 in np.geomspace(lo * 2, hi / 4, 6):
        x0 = [lin[0], lin[1], np.log(vs0)] + ([0.0] if stribeck_v is not None else [])
        lb = [-np.inf, -np.inf, np.log(lo)] + ([-np.inf] if stribeck_v is not None else [])
        ub = [np.inf, np.inf, np.log(hi)] + ([np.inf] if stribeck_v is not None else [])
        try:
            r = scipy.optimize.least_squares(lambda p: model(p) - f, x0, bounds=(lb, ub), method="trf", x_scale="jac")
        except (ValueError, np.linalg.LinAlgError):
            continue
        rss = float(r.fun @ r.fun)
        if best is None or rss < best[1] - 1e-12:
            best = (r, rss)
    if best is None:
        return None
    r, rss = best
    dof = v.size - len(r.x)
    cov = None
    if dof > 0:
        try:
            cov = np.linalg.pinv(r.jac.T @ r.jac) * rss / dof
        except np.linalg.LinAlgError:
            cov = None
    return r.x, rss, cov


def stribeck_test(v_m_s, friction_n, alpha: float = 0.01, n_grid: int = 6) -> dict:
    """Test near-zero friction points for a Stribeck dip (see the module docstring).

    Parameters
    ----------
    v_m_s, friction_n : array_like
        Signed velocity [m/s] and friction [N], both directions.
    alpha : float
        Significance level (family-wise over the ``v_st`` grid).
    n_grid : int
        Number of Stribeck velocities tried, log-spaced over the measured speeds.

    Returns
    -------
    dict
        ``stribeck_amplitude_n`` (Fst at the best v_st), ``stribeck_amplitude_se_n`` (its
        standard error from the least-squares covariance), ``stribeck_velocity_m_s``,
        ``stribeck_p_value`` (Bonferroni-corrected), ``stribeck_dip`` (bool), or None values when
        there are too few points.
    """
    v = np.asarray(v_m_s, dtype=float)
    f = np.asarray(friction_n, dtype=float)
    m = np.isfinite(v) & np.isfinite(f)
    v, f = v[m], f[m]
    out = {"stribeck_amplitude_n": None, "stribeck_amplitude_se_n": None, "stribeck_velocity_m_s": None,
           "stribeck_p_value": None, "stribeck_dip": None}
    if v.size < 7 or np.all(v > 0) or np.all(v < 0):
        return out
    base = _fit_tanh(v, f)
    if base is None:
        return out
    rss0 = base[1]
    speeds = np.abs(v[v != 0])
    grid = np.geomspace(max(np.quantile(speeds, 0.1), 1e-7), np.quantile(speeds, 0.9), n_grid)
    best = None
    for vst in grid:
        r = _fit_tanh(v, f, stribeck_v=float(vst))
        if r is not None and (best is None or r[1] < best[1][1]):
            best = (vst, r)
    if best is None:
        return out
    vst, (p, rss1, cov) = best
    dof = v.size - 4
    if dof < 1 or rss1 <= 0:
        return out
    fstat = max(rss0 - rss1, 0.0) / (rss1 / dof)
    pval = min(1.0, float(scipy.stats.f.sf(fstat, 1, dof)) * n_grid)
    se = float(np.sqrt(cov[3, 3])) if cov is not None and np.isfinite(cov[3, 3]) and cov[3, 3] >= 0 else None
    out.update({"stribeck_amplitude_n": float(p[3]), "stribeck_amplitude_se_n": se,
                "stribeck_velocity_m_s": float(vst), "stribeck_p_value": pval,
                "stribeck_dip": bool(p[3] > 0 and pval < alpha)})
    return out


def viscous_fits(points: pd.DataFrame, min_speed_m_s: float = MIN_SPEED_LINEAR_M_S) -> pd.DataFrame:
    """Coulomb + viscous fit per (backpressure_bar, direction) of ``viscous_points`` rows.

    Returns
    -------
    DataFrame
        ``backpressure_bar``, ``direction`` (P: v > 0, N: v < 0), ``coulomb_n`` (magnitude),
        ``viscous_n_s_m``, ``nrmse_pct``, ``n_points``, ``coulomb_se_n``, ``viscous_se_n_s_m``,
        ``min_speed_m_s``.
    """
    cols = ["backpressure_bar", "direction", "coulomb_n", "viscous_n_s_m", "nrmse_pct", "n_points",
            "coulomb_se_n", "viscous_se_n_s_m", "min_speed_m_s"]
    df = points.dropna(subset=["velocity_m_s", "friction_n", "backpressure_bar"])
    rows = []
    for bp, g in df.groupby("backpressure_bar", sort=True):
        for d, sel in (("P", g["velocity_m_s"] > 0), ("N", g["velocity_m_s"] < 0)):
            gg = g[sel]
            if gg.empty:
                continue
            r = fit_coulomb_viscous(gg["velocity_m_s"], gg["friction_n"], min_speed_m_s)
            rows.append({"backpressure_bar": float(bp), "direction": d, **r, "min_speed_m_s": min_speed_m_s})
    out = pd.DataFrame(rows, columns=cols)
    if not out.empty:
        out["n_points"] = out["n_points"].astype("int64")
    return out


def viscous_transition(points: pd.DataFrame, near_zero_max_m_s: float = NEAR_ZERO_MAX_M_S,
                       alpha: float = 0.01) -> pd.DataFrame:
    """Near-zero behaviour per backpressure: tanh transition velocity and the Stribeck test.

    Uses the points with ``|v| <= near_zero_max_m_s``; a backpressure is analysed when it has
    points on both sides of zero and at least two slower than ``MIN_SPEED_LINEAR_M_S``.

    Returns
    -------
    DataFrame
        ``backpressure_bar``, ``coulomb_n``, ``viscous_n_s_m``, ``transition_velocity_mm_s``,
        ``transition_ci_low_mm_s``, ``transition_ci_high_mm_s``, ``nrmse_pct``, ``n_points``,
        ``stribeck_amplitude_n``, ``stribeck_amplitude_se_n``, ``stribeck_velocity_mm_s``,
        ``stribeck_p_value``, ``stribeck_dip``.
    """
    cols = ["backpressure_bar", "coulomb_n", "viscous_n_s_m", "transition_velocity_mm_s", "transition_ci_low_mm_s",
            "transition_ci_high_mm_s", "nrmse_pct", "n_points", "stribeck_amplitude_n", "stribeck_amplitude_se_n",
            "stribeck_velocity_mm_s", "stribeck_p_value", "stribeck_dip"]
    df = points.dropna(subset=["velocity_m_s", "friction_n", "backpressure_bar"])
    df = df[df["velocity_m_s"].abs() <= near_zero_max_m_s]
    rows = []
    for bp, g in df.groupby("backpressure_bar", sort=True):
        v, f = g["velocity_m_s"].to_numpy(float), g["friction_n"].to_numpy(float)
        if (np.abs(v) < MIN_SPEED_LINEAR_M_S).sum() < 2 or not (v > 0).any() or not (v < 0).any():
            continue
        r = fit_tanh_viscous(v, f)
        s = stribeck_test(v, f, alpha=alpha)
        mm = (lambda z: None if z is None else 1e3 * z)
        rows.append({"backpressure_bar": float(bp), "coulomb_n": r["coulomb_n"], "viscous_n_s_m": r["viscous_n_s_m"],
                     "transition_velocity_mm_s": mm(r["transition_m_s"]),
                     "transition_ci_low_mm_s": mm(r["transition_ci_low_m_s"]),
                     "transition_ci_high_mm_s": mm(r["transition_ci_high_m_s"]), "nrmse_pct": r["nrmse_pct"],
                     "n_points": r["n_points"], "stribeck_amplitude_n": s["stribeck_amplitude_n"],
                     "stribeck_amplitude_se_n": s["stribeck_amplitude_se_n"],
                     "stribeck_velocity_mm_s": mm(s["stribeck_velocity_m_s"]),
                     "stribeck_p_value": s["stribeck_p_value"], "stribeck_dip": s["stribeck_dip"]})
    return pd.DataFrame(rows, columns=cols)


#: Marker and fit line style per backpressure series (in backpressure order), so that series with
#: the same friction (e.g. 1, 2 and 3 bar) stay visible on top of each other.
SERIES_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<", ">")
SERIES_LINESTYLES = ("-", "--", ":", "-.")


def _series_style(i: int, n: int) -> dict:
    import matplotlib

    return {"color": matplotlib.colormaps["viridis"](0.85 * i / max(1, n - 1)),
            "marker": SERIES_MARKERS[i % len(SERIES_MARKERS)], "ls": SERIES_LINESTYLES[i % len(SERIES_LINESTYLES)],
            "ms": 5 + 1.5 * (i % 4)}


def plot_viscous(points: pd.DataFrame, fits: pd.DataFrame | None = None):
    """Friction vs velocity per backpressure, like Fig. 13 of seed 000 (with the fitted lines).

    Every backpressure has its own hollow marker (growing in size) and fit line style, so series
    with the same friction remain visible where they overlap.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    fig = Figure(figsize=(7.5, 5))
    ax = fig.subplots()
    df = points.dropna(subset=["velocity_m_s", "friction_n", "backpressure_bar"])
    bps = sorted(df["backpressure_bar"].unique())
    handles = []
    for i, bp in enumerate(bps):
        st = _series_style(i, len(bps))
        g = df[df["backpressure_bar"] == bp]
        fitted = False
        if fits is not None and not fits.empty:
            for _, r in fits[(fits["backpressure_bar"] == bp)].iterrows():
                if r["coulomb_n"] is None or pd.isna(r["coulomb_n"]):
                    continue
                sel = g["velocity_m_s"] > 0 if r["direction"] == "P" else g["velocity_m_s"] < 0
                if not sel.any():
                    continue
                vmax = g.loc[sel, "velocity_m_s"].abs().max()
                vv = np.linspace(r["min_speed_m_s"], vmax, 50) * (1 if r["direction"] == "P" else -1)
                ax.plot(vv, coulomb_viscous(vv, r["coulomb_n"], r["viscous_n_s_m"]), ls=st["ls"], lw=1.2,
                        color=st["color"], zorder=2)
                fitted = True
        marker = {"marker": st["marker"], "ms": st["ms"], "mfc": "none", "mew": 1.3, "color": st["color"]}
        ax.plot(g["velocity_m_s"], g["friction_n"], ls="none", zorder=3, label=f"BP = {bp:g} bar", **marker)
        handles.append(Line2D([], [], ls=st["ls"] if fitted else "none", lw=1.2, label=f"BP = {bp:g} bar", **marker))
    ax.axhline(0, color="0.6", lw=0.6)
    ax.axvline(0, color="0.6", lw=0.6)
    ax.set_xlabel("velocity [m/s]")
    ax.set_ylabel("friction force (drive force at constant v) [N]")
    ax.set_title("Viscous friction at different backpressures (lines: Coulomb + viscous fits)")
    ax.grid(True, alpha=0.3)
    if bps:  # the upper-left quadrant (v < 0, F > 0) holds no data
        ax.legend(handles=handles, fontsize=8, loc="upper left", handlelength=3)
    fig.tight_layout()
    return fig


def plot_near_zero(points: pd.DataFrame, transition: pd.DataFrame | None = None,
                   near_zero_max_m_s: float = NEAR_ZERO_MAX_M_S):
    """Friction around zero velocity, like Fig. 14 of seed 000 (with the tanh fit).

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.5, 5))
    ax = fig.subplots()
    df = points.dropna(subset=["velocity_m_s", "friction_n", "backpressure_bar"])
    df = df[df["velocity_m_s"].abs() <= near_zero_max_m_s]
    bps = sorted(df["backpressure_bar"].unique())
    cmap = matplotlib.colormaps["viridis"]
    for i, bp in enumerate(bps):
        color = cmap(0.85 * i / max(1, len(bps) - 1))
        g = df[df["backpressure_bar"] == bp]
        ax.plot(1e3 * g["velocity_m_s"], g["friction_n"], "o", ms=4, color=color, label=f"BP = {bp:g} bar")
        if transition is not None and not transition.empty:
            r = transition[transition["backpressure_bar"] == bp]
            if not r.empty and pd.notna(r.iloc[0]["transition_velocity_mm_s"]):
                r = r.iloc[0]
                vmax = g["velocity_m_s"].abs().max()
                vv = np.linspace(-vmax, vmax, 400)
                ax.plot(1e3 * vv, tanh_viscous(vv, r["coulomb_n"], r["viscous_n_s_m"],
                                               r["transition_velocity_mm_s"] / 1e3), "-", lw=1.2, color=color,
                        label=f"tanh fit: Fc = {r['coulomb_n']:.2f} N, vs = {r['transition_velocity_mm_s']:.2f} mm/s")
    ax.axhline(0, color="0.6", lw=0.6)
    ax.axvline(0, color="0.6", lw=0.6)
    ax.set_xlabel("velocity [mm/s]")
    ax.set_ylabel("friction force (drive force at constant v) [N]")
    ax.set_title("Friction around zero velocity")
    ax.grid(True, alpha=0.3)
    if bps:
        ax.legend(fontsize=8, loc="upper left")
    else:
        ax.text(0.5, 0.5, "no near-zero passes", transform=ax.transAxes, ha="center", color="0.5")
    fig.tight_layout()
    return fig


__all__ = ["nrmse_pct", "find_constant_velocity_passes", "viscous_points", "friction_from_run", "coulomb_viscous",
           "tanh_viscous", "fit_coulomb_viscous", "fit_tanh_viscous", "stribeck_test", "viscous_fits",
           "viscous_transition", "plot_viscous", "plot_near_zero", "MIN_SPEED_LINEAR_M_S", "NEAR_ZERO_MAX_M_S"]
