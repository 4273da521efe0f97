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

from analyses.breakaway import drive_force
from analyses.quality import Gate, Sensor, describe_sensor, linear_lstsq, nrmse_pct

#: Below this speed the tanh transition is not saturated; such points are left out of the
#: Coulomb + viscous fit. [m/s]
MIN_SPEED_LINEAR_M_S = 2e-3
#: Runs whose passes are all slower than this are near-zero runs (Fig. 14). [m/s]
NEAR_ZERO_MAX_M_S = 0.01
#: A friction model that misses its points by more than this NRMSE (and by more than 3 times the
#: points' own noise) is not reported. [%]
NRMSE_LIMIT_PCT = 5.0


def _effective_sensor(x: np.ndarray, sensor: Sensor | None) -> tuple[Sensor, float, float]:
    """The position sensor and its two floors: ``(sensor, resolution, noise)``.

    ``noise`` is 0 when quantisation dominates (noise under half a count: the reading dithers by
    at most one count, a bounded error that the resolution terms cover); otherwise the noise
    sigma, and motion is judged against it.
    """
    s = sensor if sensor is not None else describe_sensor(x)
    res = float(s.resolution) if np.isfinite(s.resolution) and s.resolution > 0 else 0.0
    noise = float(s.noise) if np.isfinite(s.noise) and s.noise > 0 else 0.0
    if res > 0 and noise <= 0.5 * res:
        noise = 0.0
    return s, res, noise


def _virtual_counts(x: np.ndarray, band: float) -> np.ndarray:
    """Position tracked with hysteresis: a level that moves in steps of ``band`` only when the
    reading leaves it by more than ``band`` (a Schmitt trigger on a noisy analog position)."""
    out = np.empty_like(x)
    level = float(x[0])
    for i, xi in enumerate(x.tolist()):
        d = xi - level
        if d > band or d < -band:
            level += band * np.trunc(d / band)
        out[i] = level
    return out


def _strokes(t: np.ndarray, x: np.ndarray, resolution_m: float, still_s: float) -> list[tuple[int, int, float]]:
    """Monotone stretches ``(start, stop, sign)`` separated by reversals or stillness.

    ``x`` changes only in steps of at least ``resolution_m`` (encoder counts or the virtual
    counts of :func:`_virtual_counts`).
    """
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


def velocity_uncertainty(sensor: Sensor, window_s: float, dt_s: float) -> float:
    """Uncertainty of a velocity estimated over a window of ``window_s`` from a position sensor. [m/s]

    Quantisation: a difference of two readings over the window is off by at most one count,
    ``res / w``. White noise of sigma ``s``: the slope of a straight line fitted to the
    ``N = w / dt + 1`` samples of the window has standard deviation
    ``s sqrt(12 / (N (N^2 - 1))) / dt`` (about ``s sqrt(12 / N^3) / dt``). The larger applies.
    """
    _, res, noise = _effective_sensor(np.zeros(1), sensor)
    w = max(float(window_s), float(dt_s))
    n = max(2.0, round(w / dt_s) + 1)
    return float(max(res / w, noise * np.sqrt(12.0 / (n * (n * n - 1))) / dt_s))


#: Motion on a noisy (analog) position is a departure of more than this many noise sigmas from
#: the tracked level: at rest a reading leaves a level by this much about once in 10^9 samples.
MOTION_N_SIGMA = 6.0
#: Two velocity windows agree when they differ by less than this many standard deviations of
#: their difference (plus the relative tolerance and the quantisation bound).
STEADY_N_SIGMA = 4.0


def find_constant_velocity_passes(t_s, x_m, sensor: Sensor | None = None, *, rel_tol: float = 0.02,
                                  min_counts: float = 20.0, still_s: float = 0.5,
                                  window_fraction: float = 0.05) -> list[tuple[int, int]]:
    """Sample ranges ``[start, stop)`` of the constant-velocity passes of a run.

    Parameters
    ----------
    t_s : array_like
        Time [s].
    x_m : array_like
        Position [m] (encoder or analog sensor).
    sensor : analyses.quality.Sensor, optional
        Resolution and noise of the position [m]; estimated from ``x_m`` when not given.
    rel_tol : float
        Physical criterion of "constant": relative velocity change allowed between
        neighbouring windows [-]. The sensor's own velocity uncertainty over the window
        (:func:`velocity_uncertainty`) is added to it, and the window is made long enough that
        this uncertainty does not exceed ``rel_tol`` of the stroke's speed.
    min_counts : float
        Least travel of a velocity window and of a pass, in sensor floors
        (:meth:`Sensor.floor`: counts of an encoder, noise sigmas of an analog sensor) [-].
    still_s : float
        A position held this long ends a stroke [s].
    window_fraction : float
        Velocity window as a fraction of the stroke duration [-].

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
    sensor, res, noise = _effective_sensor(x, sensor)
    floor = max(res, noise)
    if floor <= 0:  # an ideal record: any change is motion; the float round-off of the values is not
        floor = max(float(np.max(np.abs(x))), 1e-300) * 1e-12
        res = floor
    dt = float(np.median(np.diff(t)))
    if not (np.isfinite(dt) and dt > 0):
        return []
    if noise > 0:
        band = max(res, MOTION_N_SIGMA * noise)
        counts = _virtual_counts(x, band)
    else:
        band, counts = res, x
    out = []
    for a, b, _sign in _strokes(t, counts, band, still_s):
        dur = t[b - 1] - t[a]
        travel = abs(x[b - 1] - x[a])
        if dur <= 0 or travel < 2 * min_counts * floor:
            continue
        v_m = travel / dur
        w = _velocity_window(dur, v_m, floor, dt, sensor, noise, rel_tol, min_counts, window_fraction)
        if 3 * w > dur:
            continue
        h = max(1, int(round(w / 2 / dt)))
        ts, xs = t[a:b], x[a:b]
        n = xs.size
        if n < 4 * h + 3:
            continue
        vc = np.full(n, np.nan)
        if noise > 0:
            # slope of a straight line over [i-h, i+h] (uniform sampling): sum k x[i+k] / (dt sum k^2)
            k = np.arange(-h, h + 1, dtype=float)
            vc[h:n - h] = np.convolve(xs, k[::-1], mode="valid") / (dt * np.sum(k * k))
            sd_v = noise / (dt * np.sqrt(np.sum(k * k)))
        else:
            # v over [i-h, i+h]; exact to one count over the window
            vc[h:n - h] = (xs[2 * h:] - xs[:n - 2 * h]) / (ts[2 * h:] - ts[:n - 2 * h])
            sd_v = 0.0
        steady = np.zeros(n, dtype=bool)
        before, after = vc[:n - 2 * h], vc[2 * h:]
        wt = ts[2 * h:] - ts[:n - 2 * h]
        tol = rel_tol * np.abs(0.5 * (before + after)) + 3 * res / wt + STEADY_N_SIGMA * np.sqrt(2) * sd_v
        steady[h:n - h] = np.abs(after - before) <= tol
        edges = np.flatnonzero(np.diff(np.concatenate(([0], steady.astype(np.int8), [0]))))
        for s0, s1 in zip(edges[0::2], edges[1::2]):
            if ts[s1 - 1] - ts[s0] < max(3 * w, w + 5 * dt) or abs(xs[s1 - 1] - xs[s0]) < min_counts * floor:
                continue
            if noise > 0 and not _constant_over(ts[s0:s1], xs[s0:s1], noise, res, rel_tol):
                continue
            out.append((a + int(s0), a + int(s1)))
    return out


def _velocity_window(dur: float, v_m: float, floor: float, dt: float, sensor: Sensor, noise: float,
                     rel_tol: float, min_counts: float, window_fraction: float) -> float:
    """Velocity window of a stroke of ``dur`` at mean speed ``v_m``: ``window_fraction`` of it, at least
    ``min_counts`` floors of travel and 5 samples; on a noisy sensor long enough that the noise does
    not blur "constant" at ``rel_tol``, as far as the stroke allows: an eighth of it, for a pass of
    3 w, the w at each end that the windows lose, and as much again for the stroke's ends (blurred
    by the motion band and the ramps) and the steady test's noise there. A short, fast stroke on a
    noisy sensor keeps the shorter window and its pass is judged whole (:func:`_constant_over`). [s]"""
    w = max(window_fraction * dur, min_counts * floor / v_m, 5 * dt)
    if noise > 0:
        while (velocity_uncertainty(sensor, w, dt) * STEADY_N_SIGMA * np.sqrt(2) > rel_tol * v_m
               and 8 * w * 1.25 <= dur):
            w *= 1.25
    return float(w)


def missing_directions(t_s, x_m, found=(), sensor: Sensor | None = None, *, rel_tol: float = 0.02,
                       min_counts: float = 20.0, still_s: float = 0.5, window_fraction: float = 0.05) -> dict:
    """Why a direction the carriage moved in has no constant-velocity pass.

    Parameters
    ----------
    t_s, x_m : array_like
        Time [s], position [m].
    found : iterable of str
        Directions that have passes (``"P"``, ``"N"``).
    sensor, rel_tol, min_counts, still_s, window_fraction
        As :func:`find_constant_velocity_passes`.

    Returns
    -------
    dict of str to str
        For each direction with strokes (travel of at least ``2 min_counts`` floors) but not in
        ``found``, one line: ``direction N: no pass of constant velocity longer than 0.62 s at the
        position noise 0.0002 m (resolution 1e-05 m): 3 strokes of up to 0.5 s at up to 0.08 m/s``.
    """
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(x_m, dtype=float)
    ok = np.isfinite(t) & np.isfinite(x)
    t, x = t[ok], x[ok]
    if t.size < 10:
        return {}
    sensor, res, noise = _effective_sensor(x, sensor)
    floor = max(res, noise)
    if floor <= 0:
        floor = max(float(np.max(np.abs(x))), 1e-300) * 1e-12
        res = floor
    dt = float(np.median(np.diff(t)))
    if not (np.isfinite(dt) and dt > 0):
        return {}
    band = max(res, MOTION_N_SIGMA * noise) if noise > 0 else res
    counts = _virtual_counts(x, band) if noise > 0 else x
    strokes: dict[str, list] = {}
    for a, b, sign in _strokes(t, counts, band, still_s):
        dur, travel = float(t[b - 1] - t[a]), abs(float(x[b - 1] - x[a]))
        if dur > 0 and travel >= 2 * min_counts * floor:
            w = _velocity_window(dur, travel / dur, floor, dt, sensor, noise, rel_tol, min_counts, window_fraction)
            strokes.setdefault("P" if sign > 0 else "N", []).append((dur, travel / dur, 3 * w))
    found = set(found)
    out = {}
    for d, st in sorted(strokes.items()):
        if d in found:
            continue
        longest = max(st)
        v_max = max(v for _, v, _ in st)
        out[d] = (f"direction {d}: no pass of constant velocity longer than {longest[2]:.3g} s at the position "
                  f"noise {sensor.noise:.3g} m (resolution {sensor.resolution:.3g} m): {len(st)} stroke"
                  f"{'s' if len(st) > 1 else ''} of up to {longest[0]:.3g} s at up to {v_max:.3g} m/s")
    return out


def _constant_over(t: np.ndarray, x: np.ndarray, noise: float, res: float, rel_tol: float) -> bool:
    """Whether a pass keeps one velocity from end to end: the change of velocity across it, from a
    quadratic fitted to the position (``2 c2 T``), is within ``rel_tol`` of the speed plus
    ``STEADY_N_SIGMA`` standard errors of that change (white noise ``noise`` and the quantisation
    ``res / sqrt(12)`` on every sample). All the pass's samples judge it at once: far finer than
    two windows, so a short pass on a noisy sensor is told from a ramp all the same."""
    n = t.size
    if n < 5:
        return False
    tt = t - t.mean()
    dur = float(tt[-1] - tt[0])
    design = np.column_stack([tt * tt - np.mean(tt * tt), tt, np.ones(n)])
    coef, *_ = np.linalg.lstsq(design, x, rcond=None)
    sigma = float(np.hypot(noise, res / np.sqrt(12.0)))
    try:
        se_c2 = sigma * float(np.sqrt(np.linalg.inv(design.T @ design)[0, 0]))
    except np.linalg.LinAlgError:
        return False
    change, se_change = abs(2 * coef[0] * dur), 2 * se_c2 * dur
    return bool(change <= rel_tol * abs(coef[1]) + STEADY_N_SIGMA * se_change)


def viscous_points(t_s, x_m, force_n, sensor: Sensor | None = None, **kwargs) -> pd.DataFrame:
    """One row per constant-velocity pass: signed mean velocity and signed mean friction.

    Parameters
    ----------
    t_s, x_m : array_like
        Time [s], position [m].
    force_n : array_like
        Drive force toward +x [N]: ``(p_a - p_b) A`` or the load cell.
    sensor : analyses.quality.Sensor, optional
        Position sensor [m]; estimated from ``x_m`` when not given.
    **kwargs
        Passed to :func:`find_constant_velocity_passes`.

    Returns
    -------
    DataFrame
        ``pass_index``, ``t_start_s``, ``t_end_s``, ``n_samples``, ``velocity_m_s`` (line fit),
        ``velocity_se_m_s`` (its standard error, from the residuals of the line and at least
        the quantisation bound ``res / duration``), ``friction_n`` (mean), ``friction_std_n``,
        ``accel_m_s2`` (quadratic fit, diagnostic), ``direction`` (P for v > 0, N for v < 0).
    """
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(x_m, dtype=float)
    f = np.asarray(force_n, dtype=float)
    ok = np.isfinite(t) & np.isfinite(x) & np.isfinite(f)
    t, x, f = t[ok], x[ok], f[ok]
    if sensor is None and x.size:
        sensor = describe_sensor(x)
    rows = []
    for i, (a, b) in enumerate(find_constant_velocity_passes(t, x, sensor, **kwargs)):
        tt = t[a:b] - t[a:b].mean()
        coef = np.polyfit(tt, x[a:b], 1)
        v = float(coef[0])
        resid = x[a:b] - np.polyval(coef, tt)
        sxx = float(np.sum(tt * tt))
        se = float(np.sqrt(np.sum(resid * resid) / max(b - a - 2, 1) / sxx)) if sxx > 0 else float("nan")
        dur = float(t[b - 1] - t[a])
        if sensor is not None and dur > 0:
            se = max(se, float(sensor.resolution) / dur / np.sqrt(3.0))
        acc = float(2 * np.polyfit(tt, x[a:b], 2)[0]) if b - a > 3 else float("nan")
        rows.append({"pass_index": i, "t_start_s": float(t[a]), "t_end_s": float(t[b - 1]), "n_samples": b - a,
                     "velocity_m_s": v, "velocity_se_m_s": se, "friction_n": float(np.mean(f[a:b])),
                     "friction_std_n": float(np.std(f[a:b])), "accel_m_s2": acc,
                     "direction": "P" if v > 0 else "N"})
    return pd.DataFrame(rows, columns=["pass_index", "t_start_s", "t_end_s", "n_samples", "velocity_m_s",
                                       "velocity_se_m_s", "friction_n", "friction_std_n", "accel_m_s2", "direction"])


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


#: Speeds of one direction within this fraction of each other are one speed level (a speed
#: controller's pass-to-pass repeatability); two levels closer than that do not separate
#: Coulomb from viscous friction. Levels are also kept apart by their velocity uncertainty.
SPEED_LEVEL_REL = 0.05


def speed_levels(v_m_s, se_m_s=None, rel: float = SPEED_LEVEL_REL, n_sigma: float = 4.0) -> int:
    """Number of distinct speed levels among pass velocities.

    Sorted speeds start a new level when they exceed the first speed of the current level by
    more than ``rel`` of it and by more than ``n_sigma`` combined standard errors.

    Parameters
    ----------
    v_m_s : array_like
        Pass velocities [m/s] (signs ignored).
    se_m_s : array_like, optional
        Their standard errors [m/s].
    """
    v = np.abs(np.asarray(v_m_s, dtype=float))
    se = np.zeros_like(v) if se_m_s is None else np.nan_to_num(np.asarray(se_m_s, dtype=float), nan=0.0)
    ok = np.isfinite(v)
    v, se = v[ok], se[ok]
    if v.size == 0:
        return 0
    order = np.argsort(v)
    v, se = v[order], se[order]
    levels, ref, ref_se = 1, v[0], se[0]
    for vi, si in zip(v[1:], se[1:]):
        if vi - ref > max(rel * ref, n_sigma * np.hypot(si, ref_se)):
            levels += 1
            ref, ref_se = vi, si
    return levels


def fit_coulomb_viscous(v_m_s, friction_n, min_speed_m_s: float = MIN_SPEED_LINEAR_M_S,
                        confidence: float = 0.95, velocity_se_m_s=None, friction_se_n=None) -> dict:
    """Coulomb + viscous fit of one direction's points by linear least squares, gated.

    Parameters
    ----------
    v_m_s, friction_n : array_like
        Signed velocity [m/s] and friction [N] of one direction (all v of one sign).
    min_speed_m_s : float
        Points slower than this are left out [m/s].
    velocity_se_m_s : array_like, optional
        Standard errors of the velocities [m/s] (to tell speed levels apart).
    friction_se_n : array_like, optional
        Standard errors of the friction points [N] (the noise level the fit may reach).

    Returns
    -------
    dict
        ``coulomb_n`` (magnitude), ``viscous_n_s_m``, ``nrmse_pct`` (over the points fitted),
        ``n_points``, ``coulomb_se_n``, ``viscous_se_n_s_m``, ``n_speed_levels``, ``note``.
        The values are None, with the reason in ``note``, when the points span fewer than two
        speed levels (:func:`speed_levels`: one speed cannot separate Coulomb from viscous
        friction), there are fewer than 3 points, the design does not separate the two
        parameters (standard error over half the value), a value is negative, or the line
        misses the points (NRMSE over 5 % and residuals above 3 times the points' noise).
    """
    v = np.asarray(v_m_s, dtype=float)
    f = np.asarray(friction_n, dtype=float)
    vse = None if velocity_se_m_s is None else np.asarray(velocity_se_m_s, dtype=float)
    fse = None if friction_se_n is None else np.asarray(friction_se_n, dtype=float)
    m = np.isfinite(v) & np.isfinite(f) & (np.abs(v) >= min_speed_m_s)
    v, f = v[m], f[m]
    vse = None if vse is None else vse[m]
    fse = None if fse is None else fse[m]
    fields = ("coulomb_n", "viscous_n_s_m", "coulomb_se_n", "viscous_se_n_s_m")
    n_levels = speed_levels(v, vse)
    out = {"coulomb_n": None, "viscous_n_s_m": None, "nrmse_pct": None, "n_points": int(v.size),
           "coulomb_se_n": None, "viscous_se_n_s_m": None, "n_speed_levels": int(n_levels), "note": None}
    g = Gate()
    if n_levels < 2:
        if v.size:
            g.fail(f"passes at one speed level only (|v| {np.min(np.abs(v)):.3g}-{np.max(np.abs(v)):.3g} m/s): "
                   "one speed cannot separate Coulomb from viscous friction")
        else:
            g.fail(f"no pass at or above {min_speed_m_s:g} m/s")
        return g.apply(out, fields)
    if g.enough_points(v.size, 3).reasons:
        return g.apply(out, fields)
    s = np.sign(np.median(v))
    fit = linear_lstsq(np.column_stack([np.full_like(v, s), v]), f)
    nrmse = nrmse_pct(f, fit.fitted)
    out.update({"coulomb_n": float(fit.beta[0]), "viscous_n_s_m": float(fit.beta[1]),
                "nrmse_pct": nrmse if np.isfinite(nrmse) else None,
                "coulomb_se_n": float(fit.se[0]) if np.isfinite(fit.se[0]) else None,
                "viscous_se_n_s_m": float(fit.se[1]) if np.isfinite(fit.se[1]) else None})
    g.identifiable(fit, names=("coulomb_n", "viscous_n_s_m"))
    g.physical("coulomb_n", float(fit.beta[0]), lo=0.0)
    g.physical("viscous_n_s_m", float(fit.beta[1]), lo=0.0)
    noise = float(np.sqrt(np.mean(fse ** 2))) if fse is not None and np.isfinite(fse).all() and fse.size else None
    rms = float(np.sqrt(np.mean((f - fit.fitted) ** 2)))
    g.follows_data(nrmse, NRMSE_LIMIT_PCT, rms=rms, noise=noise)
    return g.apply(out, fields)


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
            "nrmse_pct", "rss", "note")
    out = dict.fromkeys(keys)
    out["n_points"] = int(v.size)
    fields = keys[:5]
    g = Gate()
    if v.size < 5 or np.all(v > 0) or np.all(v < 0):
        g.enough_points(v.size, 5)
        if g.ok:
            g.fail("near-zero points on one side of zero only: the transition cannot be fitted")
        return g.apply(out, fields)
    res = _fit_tanh(v, f)
    if res is None:
        return g.fail("tanh fit failed").apply(out, fields)
    p, rss, cov = res
    dof = v.size - 3
    q = scipy.stats.t.ppf(0.5 + confidence / 2, dof)
    se_log = float(np.sqrt(cov[2, 2])) if cov is not None and np.isfinite(cov[2, 2]) else float("nan")
    vs = float(np.exp(p[2]))
    out.update({"coulomb_n": float(p[0]), "viscous_n_s_m": float(p[1]), "transition_m_s": vs,
                "transition_ci_low_m_s": vs * float(np.exp(-q * se_log)) if np.isfinite(se_log) else None,
                "transition_ci_high_m_s": vs * float(np.exp(q * se_log)) if np.isfinite(se_log) else None,
                "nrmse_pct": nrmse_pct(f, tanh_viscous(v, p[0], p[1], vs)), "rss": rss})
    lo, hi = _vs_bounds(v)
    g.within_bounds([vs], [lo], [hi], ("transition velocity",))
    se = np.sqrt(np.clip(np.diag(cov), 0, None)) if cov is not None else np.full(3, np.nan)
    g.identifiable(beta=p[:1], se=se[:1], names=("coulomb_n",))
    if not np.isfinite(se_log):
        g.fail("transition velocity not identifiable from the data (no standard error)")
    g.physical("coulomb_n", float(p[0]), lo=0.0)
    g.physical("viscous_n_s_m", float(p[1]), lo=0.0)
    return g.apply(out, fields)


def _vs_bounds(v) -> tuple[float, float]:
    """Bounds of the transition velocity of the tanh fit: a twentieth of the slowest speed to
    twice the fastest. [m/s]"""
    speeds = np.abs(v[v != 0])
    lo = max(float(speeds.min()) / 20, 1e-7) if speeds.size else 1e-6
    hi = float(speeds.max()) * 2 if speeds.size else 1.0
    return lo, hi


def _fit_tanh(v, f, stribeck_v: float | None = None):
    """Least squares of the tanh model (optionally with a Stribeck term); params in log(vs)."""
    speeds = np.abs(v[v != 0])
    lo, hi = _vs_bounds(v)

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
        ``stribeck_p_value`` (Bonferroni-corrected), ``stribeck_dip`` (bool), ``note``; None
        values (and the reason in ``note``) when there are too few points, and amplitude and
        velocity None when the amplitude has no finite standard error (the test itself stands).
    """
    v = np.asarray(v_m_s, dtype=float)
    f = np.asarray(friction_n, dtype=float)
    m = np.isfinite(v) & np.isfinite(f)
    v, f = v[m], f[m]
    out = {"stribeck_amplitude_n": None, "stribeck_amplitude_se_n": None, "stribeck_velocity_m_s": None,
           "stribeck_p_value": None, "stribeck_dip": None, "note": None}
    if v.size < 7 or np.all(v > 0) or np.all(v < 0):
        out["note"] = (f"too few near-zero points for the Stribeck test: {v.size} < 7" if v.size < 7
                       else "near-zero points on one side of zero only: no Stribeck test")
        return out
    base = _fit_tanh(v, f)
    if base is None:
        out["note"] = "Stribeck test: tanh fit failed"
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
        out["note"] = "Stribeck test: fit failed"
        return out
    vst, (p, rss1, cov) = best
    dof = v.size - 4
    if dof < 1 or rss1 <= 0:
        out["note"] = "Stribeck test: no residual degrees of freedom"
        return out
    fstat = max(rss0 - rss1, 0.0) / (rss1 / dof)
    pval = min(1.0, float(scipy.stats.f.sf(fstat, 1, dof)) * n_grid)
    se = float(np.sqrt(cov[3, 3])) if cov is not None and np.isfinite(cov[3, 3]) and cov[3, 3] >= 0 else None
    out.update({"stribeck_amplitude_n": float(p[3]), "stribeck_amplitude_se_n": se,
                "stribeck_velocity_m_s": float(vst), "stribeck_p_value": pval,
                "stribeck_dip": bool(p[3] > 0 and pval < alpha)})
    if se is None:
        out.update({"stribeck_amplitude_n": None, "stribeck_velocity_m_s": None,
                    "note": "Stribeck amplitude not identifiable from the data (no standard error)"})
    return out


def viscous_fits(points: pd.DataFrame, min_speed_m_s: float = MIN_SPEED_LINEAR_M_S,
                 missing: list[dict] | None = None) -> pd.DataFrame:
    """Coulomb + viscous fit per (backpressure_bar, direction) of ``viscous_points`` rows.

    Each direction is fitted by :func:`fit_coulomb_viscous` (gated: at least two speed levels,
    identifiable, non-negative, following the points). Optional ``velocity_se_m_s``,
    ``friction_std_n`` and ``n_samples`` columns tell the speed levels apart and give the
    points' noise.

    Returns
    -------
    DataFrame
        ``backpressure_bar``, ``direction`` (P: v > 0, N: v < 0), ``coulomb_n`` (magnitude),
        ``viscous_n_s_m``, ``nrmse_pct``, ``n_points``, ``coulomb_se_n``, ``viscous_se_n_s_m``,
        ``min_speed_m_s``, ``n_speed_levels``, ``note`` (NULL when sound, else why the values are NULL).
        A (backpressure, direction) named in ``missing`` (dicts with ``backpressure_bar``,
        ``direction``, ``note``: :func:`missing_directions` per run, the run prefixed) that has no
        pass gets a row too: NULL values, ``n_points`` 0 and the notes joined.
    """
    cols = ["backpressure_bar", "direction", "coulomb_n", "viscous_n_s_m", "nrmse_pct", "n_points",
            "coulomb_se_n", "viscous_se_n_s_m", "min_speed_m_s", "n_speed_levels", "note"]
    df = points.dropna(subset=["velocity_m_s", "friction_n", "backpressure_bar"])
    rows = []
    for bp, g in df.groupby("backpressure_bar", sort=True):
        for d, sel in (("P", g["velocity_m_s"] > 0), ("N", g["velocity_m_s"] < 0)):
            gg = g[sel]
            if gg.empty:
                continue
            vse = gg["velocity_se_m_s"] if "velocity_se_m_s" in gg.columns else None
            fse = None
            if {"friction_std_n", "n_samples"} <= set(gg.columns):
                fse = (pd.to_numeric(gg["friction_std_n"], errors="coerce")
                       / np.sqrt(pd.to_numeric(gg["n_samples"], errors="coerce").clip(lower=1))).to_numpy(float)
            r = fit_coulomb_viscous(gg["velocity_m_s"], gg["friction_n"], min_speed_m_s,
                                    velocity_se_m_s=None if vse is None else vse.to_numpy(float), friction_se_n=fse)
            rows.append({"backpressure_bar": float(bp), "direction": d, **r, "min_speed_m_s": min_speed_m_s})
    have = {(r["backpressure_bar"], r["direction"]) for r in rows}
    notes: dict[tuple, list] = {}
    for m in missing or ():
        bp = m.get("backpressure_bar")
        if bp is None or not np.isfinite(float(bp)) or (float(bp), m["direction"]) in have:
            continue
        notes.setdefault((float(bp), m["direction"]), []).append(m["note"])
    for (bp, d), ns in sorted(notes.items()):
        rows.append({"backpressure_bar": bp, "direction": d, "coulomb_n": None, "viscous_n_s_m": None,
                     "nrmse_pct": None, "n_points": 0, "coulomb_se_n": None, "viscous_se_n_s_m": None,
                     "min_speed_m_s": min_speed_m_s, "n_speed_levels": 0, "note": "; ".join(ns)})
    out = pd.DataFrame(rows, columns=cols)
    if not out.empty:
        out["n_points"] = out["n_points"].astype("int64")
        out["n_speed_levels"] = out["n_speed_levels"].astype("int64")
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
            "stribeck_velocity_mm_s", "stribeck_p_value", "stribeck_dip", "note"]
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
                     "stribeck_p_value": s["stribeck_p_value"], "stribeck_dip": s["stribeck_dip"],
                     "note": "; ".join(n for n in (r["note"], s["note"]) if n) or None})
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


__all__ = ["nrmse_pct", "speed_levels", "velocity_uncertainty", "MOTION_N_SIGMA", "STEADY_N_SIGMA", "SPEED_LEVEL_REL",
           "NRMSE_LIMIT_PCT", "find_constant_velocity_passes", "viscous_points", "friction_from_run", "coulomb_viscous",
           "tanh_viscous", "fit_coulomb_viscous", "fit_tanh_viscous", "stribeck_test", "viscous_fits",
           "viscous_transition", "plot_viscous", "plot_near_zero", "MIN_SPEED_LINEAR_M_S", "NEAR_ZERO_MAX_M_S"]
