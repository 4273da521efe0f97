"""The leak-growth degradation model: each hose's leak path, pooled across its type, run to a leak limit.

Distances are in km, leaks in l/min (ANR) at the plan's test pressure; a hose's leak path is its
leakage plateaus at its distance (``points``: ``hose_id``, ``distance_km``, ``leak_l_min``, one
pressure level, as ``hose_leak_growth`` gives them). This is the ``degradation`` method of
:mod:`analyses.remaining_life`: a median and a two-sided **prediction interval** for the distance a
running hose has left [km], NaN with a one-line ``note`` when the data cannot tell. The other failure
modes enter as a competing risk (:func:`degradation_rul`'s ``rupture``: the models of
:func:`analyses.remaining_life.rupture_model`, drawn by :mod:`analyses.life_posterior`).

``degradation``: each hose's leak path, pooled, run to the limit
----------------------------------------------------------------
A random-effects degradation model (Lu & Meeker 1993, Technometrics 35; Meeker & Escobar 1998,
ch. 13): ``log leak_ij = alpha_i + gamma log d_ij + e_ij``, ``alpha_i ~ N(mu, tau^2)`` from hose
to hose, ``e_ij ~ N(0, sigma^2)``. Equivalently ``leak = (w_i d)^gamma`` l/min with a hose's
**wear rate** ``w_i = exp(alpha_i / gamma)`` [1/km] (``1 / w_i`` is the distance at which its leak
reaches 1 l/min), lognormal across hoses. Why this form: the leak through a worn seal goes as a
power (about 1.5, an orifice) of the seal's pressure deficit, and the deficit grows in proportion
to the wear, i.e. to distance at the hose's own rate; the exponent ``gamma`` is a property of the
seal shared by the hoses of a type and is estimated, not assumed (``gamma = 1`` is a linear path).
The crossing distance of the limit ``L`` is ``D_i = L^(1/gamma) / w_i``: lognormal, so the model
has the closed forms Lu & Meeker recommend. Fit: ``gamma`` and ``sigma`` from the within-hose
regression with one intercept per hose (:func:`analyses.quality.linear_lstsq`), ``mu`` and
``tau`` by maximum likelihood of the hoses' intercepts given their sampling variances
``sigma^2 / n_i`` (a one-way random-effects model with unequal counts). Prediction for a running
hose: its intercept's posterior given its own points (the best linear unbiased predictor and
its variance), truncated to "not crossed by now" (it is running). Parameter uncertainty: draws
of ``gamma`` (normal), ``sigma^2`` (scaled inverse chi-square on its degrees of freedom),
``tau^2`` (scaled inverse chi-square on ``tau^4 sum w_i^2`` effective degrees of freedom, from its
observed information), ``mu`` (normal, recomputed for each ``gamma`` drawn) - a large-sample
approximation of the posterior (Meeker & Escobar 1998, ch. 13, use the bootstrap; these draws
are cheaper and their calibration is measured, not assumed).

Leak points at or below ``floor_multiple`` times the sensor's floor (:meth:`Sensor.floor
<analyses.quality.Sensor.floor>`: the larger of its stated resolution and noise) are left out of
the fit: the log model needs a leak well above the additive sensor noise (at 10 x the floor the
noise adds at most about 0.1 to the log). A hose's prediction is NaN with a note when it has
fewer than :data:`MIN_LEAK_POINTS` points in all, fewer than that above the floor ("noisy at
the sensor floor"), or its own path is falling or flat (its own log-log slope not positive by
twice its standard error, :meth:`Gate.identifiable <analyses.quality.Gate.identifiable>`).

Leak-limit crossing
-------------------
:func:`leak_crossing_life`: the first distance at which a hose's leak path reaches a limit,
linearly interpolated between the two plateaus either side; a path that never reaches it is
censored at its last plateau (the last distance it was known to be below the limit).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
import scipy

from analyses.life_posterior import (MIN_ESS, N_DRAWS, WeibullPosterior, interval_probs, mixture_quantiles,
                                     rul_over_shapes, weibull_survival_at)
from analyses.numerics import fminbound
from analyses.quality import Gate, Sensor, at_bound, linear_lstsq

_NAN = float("nan")
#: Leak points a hose needs above the sensor floor for its own prediction: two to draw a path
#: and one to check it. [-]
MIN_LEAK_POINTS = 3
#: Hoses with leak paths (two points or more) needed to pool a degradation model. [-]
MIN_HOSES = 3
#: A leak point enters the fit when it is above this multiple of the sensor's floor. [-]
FLOOR_MULTIPLE = 10.0
#: Search range of the hose-to-hose variance of the log leak; an estimate at its ends is NaN. [-]
TAU2_BOUNDS = (1e-8, 1e2)


# -- the degradation model ---------------------------------------------------------------------
@dataclass
class DegradationFit:
    """The pooled leak-growth model ``log leak = alpha_i + gamma log d`` of one hose type.

    Attributes
    ----------
    gamma, gamma_se : float
        Growth exponent of the leak with distance and its standard error. [-]
    sigma : float
        Residual standard deviation of the log leak (measurement and path). [-]
    dof : int
        Degrees of freedom of ``sigma``. [-]
    mu, mu_se : float
        Mean of the hoses' log-leak intercepts ``alpha_i`` [log(l/min)] and its standard error.
    tau : float
        Hose-to-hose standard deviation of ``alpha_i``. [-]
    hoses : DataFrame
        Per hose: ``hose_id``, ``n_points`` (all), ``n_used`` (above the floor), ``x_mean`` (mean
        log distance of the used points), ``z_mean`` (their mean log leak), ``leak_now_l_min``
        (the last point), ``note`` (why its own prediction is NaN).
    floor_l_min : float
        Leak below which points are left out [l/min].
    note : str or None
        Why the model has no estimate.
    """

    gamma: float
    gamma_se: float
    sigma: float
    dof: int
    mu: float
    mu_se: float
    tau: float
    hoses: pd.DataFrame
    floor_l_min: float
    note: str | None = None

    @property
    def ok(self) -> bool:
        return self.note is None

    def wear_rate(self) -> tuple[float, float]:
        """Mean and standard deviation across hoses of the wear rate ``w = exp(alpha / gamma)``. [1/km]"""
        if not self.ok:
            return _NAN, _NAN
        m, s = self.mu / self.gamma, self.tau / self.gamma
        mean = math.exp(m + s * s / 2.0)
        return mean, mean * math.sqrt(math.expm1(s * s))


def _hose_gate(x: np.ndarray, z: np.ndarray, n_all: int, floor: float, min_points: int) -> str | None:
    """Why one hose's own path (``x`` log distance, ``z`` log leak of its points above the floor)
    cannot give a prediction (None when it can)."""
    if n_all < min_points:
        return f"too few leak points: {n_all} < {min_points}"
    if len(x) < min_points:
        return (f"noisy at the sensor floor: {len(x)} of {n_all} leak points above {floor:.3g} l/min "
                f"({min_points} needed)")
    sxx = float(np.sum((x - x.mean()) ** 2))
    if not sxx > 0:
        return "leak path flat: its points are at one distance"
    slope = float(np.sum((x - x.mean()) * (z - z.mean())) / sxx)
    resid = z - z.mean() - slope * (x - x.mean())
    se = math.sqrt(float(np.sum(resid ** 2)) / (len(x) - 2) / sxx)
    if slope <= 0:
        return f"leak path falling (log-log slope {slope:.2g})"
    g = Gate().identifiable(beta=[slope], se=[se], names=["its leak growth"])
    return None if g.ok else f"leak path flat: {g.note}"


def _per_hose(points: pd.DataFrame, floor: float, min_points: int) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(usable points with ``x`` = log distance and ``z`` = log leak, one row per hose)."""
    p = points.dropna(subset=["distance_km", "leak_l_min"]).sort_values(["hose_id", "distance_km"], kind="stable")
    hid = p["hose_id"].to_numpy()
    d, y = p["distance_km"].to_numpy(float), p["leak_l_min"].to_numpy(float)
    good = (y > floor) & (d > 0)
    x, z = np.log(np.where(good, d, 1.0)), np.log(np.where(good, y, 1.0))
    ids, first, counts = np.unique(hid, return_index=True, return_counts=True)
    rows = []
    for h, a, n in zip(ids, first, counts):
        sl = slice(a, a + n)
        k = good[sl]
        xs, zs = x[sl][k], z[sl][k]
        rows.append({"hose_id": h, "n_points": int(n), "n_used": int(k.sum()),
                     "x_mean": xs.mean() if k.any() else _NAN, "z_mean": zs.mean() if k.any() else _NAN,
                     "leak_now_l_min": float(y[a + n - 1]), "note": _hose_gate(xs, zs, int(n), floor, min_points)})
    cols = ["hose_id", "n_points", "n_used", "x_mean", "z_mean", "leak_now_l_min", "note"]
    use = p[good].assign(x=x[good], z=z[good])
    return use, pd.DataFrame(rows, columns=cols)


def _random_intercepts(a: np.ndarray, s2: np.ndarray) -> tuple[float, float, float, bool]:
    """ML of ``a_i ~ N(mu, tau^2 + s2_i)``: (mu, se of mu, tau^2, tau^2 at a search bound)."""
    def neg(log_t2):
        v = np.exp(log_t2) + s2
        w = 1.0 / v
        mu = np.sum(w * a) / np.sum(w)
        return 0.5 * float(np.sum(np.log(v) + (a - mu) ** 2 / v))

    lo, hi = (math.log(b) for b in TAU2_BOUNDS)
    t2 = math.exp(float(fminbound(neg, lo, hi, xatol=1e-8)))
    w = 1.0 / (t2 + s2)
    return float(np.sum(w * a) / np.sum(w)), float(1.0 / math.sqrt(np.sum(w))), t2, at_bound(t2, *TAU2_BOUNDS)


def degradation_fit(points: pd.DataFrame, sensor: Sensor, floor_multiple: float = FLOOR_MULTIPLE,
                    min_points: int = MIN_LEAK_POINTS) -> DegradationFit:
    """Fit the pooled random-effects leak-growth model to the leak paths of one hose type.

    Parameters
    ----------
    points : DataFrame
        ``hose_id``, ``distance_km`` [km], ``leak_l_min`` [l/min]: the leak paths at one pressure.
    sensor : Sensor
        The leak channel's stated resolution and noise [l/min] (:mod:`analyses.quality`).
    floor_multiple : float
        Points at or below this multiple of ``sensor.floor()`` are left out. [-]
    min_points : int
        Points above the floor a hose needs for its own prediction. [-]

    Returns
    -------
    DegradationFit
        NaN parameters and a ``note`` with fewer than :data:`MIN_HOSES` hoses with two points
        above the floor, a growth exponent the data do not separate from zero or not positive,
        or a hose-to-hose spread at its search bound.
    """
    floor = floor_multiple * sensor.floor()
    use, hoses = _per_hose(points, floor, min_points)
    nan = DegradationFit(_NAN, _NAN, _NAN, 0, _NAN, _NAN, _NAN, hoses, floor)
    paths = hoses.loc[hoses["n_used"] >= 2, "hose_id"].tolist()
    if len(paths) < MIN_HOSES:
        nan.note = f"too few hoses with a leak path above the floor to pool: {len(paths)} < {MIN_HOSES}"
        return nan
    u = use[use["hose_id"].isin(paths)]
    within = u.groupby("hose_id")[["x", "z"]].transform("mean")
    xt, zt = (u["x"] - within["x"]).to_numpy(), (u["z"] - within["z"]).to_numpy()
    fit = linear_lstsq(xt[:, None], zt)            # the within-hose regression (one intercept per hose)
    dof = len(u) - len(paths) - 1
    sigma = float(np.sqrt(np.sum((zt - fit.fitted) ** 2) / dof)) if dof > 0 else _NAN
    gamma, gamma_se = float(fit.beta[0]), sigma / math.sqrt(float(np.sum(xt ** 2)))
    gate = Gate().enough_points(dof, 1, "degrees of freedom for the pooled path's scatter")
    gate.identifiable(beta=[gamma], se=[gamma_se], names=["growth exponent"])
    gate.physical("growth exponent", gamma, lo=0.0)
    if not gate.ok:
        nan.note = f"the pooled leak path: {gate.note}"
        return nan
    h = hoses[hoses["n_used"] >= 1]
    a = (h["z_mean"] - gamma * h["x_mean"]).to_numpy()
    mu, mu_se, t2, bound = _random_intercepts(a, sigma ** 2 / h["n_used"].to_numpy())
    if bound:
        return DegradationFit(gamma, gamma_se, sigma, dof, _NAN, _NAN, _NAN, hoses, floor,
                              note=f"the hose-to-hose spread of the wear rate ran to its search bound "
                                   f"(variance {t2:.2g}): the data cannot tell it")
    return DegradationFit(gamma, gamma_se, sigma, int(dof), mu, mu_se, math.sqrt(t2), hoses, floor)


@dataclass
class _DegradationDraws:
    """Parameter draws of a :class:`DegradationFit` (one value per draw)."""

    gamma: np.ndarray
    sigma2: np.ndarray
    tau2: np.ndarray
    mu_noise: np.ndarray


def _degradation_draws(fit: DegradationFit, n_draws: int, rng: np.random.Generator) -> _DegradationDraws:
    h = fit.hoses[fit.hoses["n_used"] >= 1]
    s2 = fit.sigma ** 2 / h["n_used"].to_numpy()
    nu_tau = max(fit.tau ** 4 * float(np.sum(1.0 / (fit.tau ** 2 + s2) ** 2)), 1.0)
    return _DegradationDraws(gamma=fit.gamma + fit.gamma_se * rng.standard_normal(n_draws),
                             sigma2=fit.sigma ** 2 * fit.dof / rng.chisquare(fit.dof, n_draws),
                             tau2=fit.tau ** 2 * nu_tau / rng.chisquare(nu_tau, n_draws),
                             mu_noise=rng.standard_normal(n_draws))


def _crossing_survival(fit: DegradationFit, dr: _DegradationDraws, hose_id, d: float, log_limit: float):
    """Per draw: ``r -> P(no crossing by d + r | not crossed by d, its points)``, and the
    probability the path says it has not crossed by ``d`` (median over draws)."""
    h = fit.hoses[fit.hoses["n_used"] >= 1]
    a_all = h["z_mean"].to_numpy()[None, :] - dr.gamma[:, None] * h["x_mean"].to_numpy()[None, :]
    v_all = dr.tau2[:, None] + dr.sigma2[:, None] / h["n_used"].to_numpy()[None, :]
    w = 1.0 / v_all
    mu = np.sum(w * a_all, axis=1) / np.sum(w, axis=1) + dr.mu_noise / np.sqrt(np.sum(w, axis=1))
    i = int(np.flatnonzero(h["hose_id"].to_numpy() == hose_id)[0])
    n_i = float(h["n_used"].iloc[i])
    prec = 1.0 / dr.tau2 + n_i / dr.sigma2
    m = (mu / dr.tau2 + n_i * a_all[:, i] / dr.sigma2) / prec
    sd = 1.0 / np.sqrt(prec)
    log_now = scipy.special.log_ndtr((log_limit - dr.gamma * math.log(d) - m) / sd)

    def survival(r):
        r = np.atleast_1d(np.asarray(r, float))[None, :]
        num = scipy.special.log_ndtr((log_limit - dr.gamma[:, None] * np.log(d + r) - m[:, None]) / sd[:, None])
        return np.exp(np.minimum(num - log_now[:, None], 0.0))

    return survival, float(np.exp(np.median(log_now)))


def degradation_rul(fit: DegradationFit, hose_id, distance_km: float, limit_l_min: float,
                    rupture=None, confidence: float = 0.90,
                    n_draws: int = N_DRAWS, seed: int = 0) -> tuple[np.ndarray, str | None]:
    """Median and prediction interval of the distance a running hose has left [km].

    Parameters
    ----------
    fit : DegradationFit
        The hose type's pooled model (its data include this hose's points up to now).
    hose_id : str
        The hose.
    distance_km : float
        Its distance now [km].
    limit_l_min : float
        The leak that ends its life [l/min].
    rupture : WeibullPosterior or sequence of WeibullPosterior, optional
        The other failure modes' life model (a competing risk); several (one per shape,
        :func:`analyses.remaining_life.rupture_model`): the interval holds for each
        (:func:`analyses.life_posterior.rul_over_shapes`); None leaves them out.
    confidence : float
        Two-sided level of the prediction interval. [-]
    n_draws : int
        Parameter draws. [-]
    seed : int
        Seed of the draws.

    Returns
    -------
    (quantiles, note) : (numpy.ndarray, str or None)
        ``[median, lower, upper]`` [km]; NaN with the reason when the model or the hose's own
        path cannot tell.
    """
    nan = np.full(3, _NAN)
    if not fit.ok:
        return nan, fit.note
    row = fit.hoses[fit.hoses["hose_id"] == hose_id]
    if row.empty:
        return nan, "no leak points"
    if isinstance(row["note"].iloc[0], str):
        return nan, row["note"].iloc[0]
    if not (distance_km > 0 and limit_l_min > 0):
        return nan, "no distance or no leak limit"
    dr = _degradation_draws(fit, n_draws, np.random.default_rng(seed))
    survival, p_now = _crossing_survival(fit, dr, hose_id, distance_km, math.log(limit_l_min))
    if p_now < 1e-6:
        return nan, "its leak path is past the limit already (the hose should have failed)"
    weights = np.full(n_draws, 1.0 / n_draws)
    guess = max(distance_km, 1e-3)
    posts = [rupture] if isinstance(rupture, WeibullPosterior) else list(rupture or [])
    posts = [p for p in posts if p.ok]

    def joint(post: WeibullPosterior | None):
        total = survival
        if post is not None:
            w_r, ess = post.weights()
            if ess < MIN_ESS:
                return nan, "the rupture model's draws do not cover its likelihood"
            pick = np.random.default_rng(seed + 1).choice(len(w_r), size=n_draws, p=w_r)
            rupture_survival = weibull_survival_at(post.shape[pick], post.scale[pick], distance_km)
            total = lambda r: survival(r) * rupture_survival(r)  # noqa: E731
        q = mixture_quantiles(total, weights, interval_probs(confidence), guess)
        return q, (None if np.isfinite(q).all() else "the prediction interval is open: the data do not bound it")

    return rul_over_shapes(joint, posts) if posts else joint(None)


# -- leak-limit crossing ---------------------------------------------------------------------
def leak_crossing_life(distance_km, leak_l_min, limit_l_min: float) -> tuple[float, bool]:
    """First distance at which a leak path reaches ``limit_l_min``, and whether it did.

    Parameters
    ----------
    distance_km : array_like
        Distances of the leak plateaus [km].
    leak_l_min : array_like
        Their leaks [l/min].
    limit_l_min : float
        The limit [l/min].

    Returns
    -------
    (life_km, crossed) : (float, bool)
        Linearly interpolated between the last plateau below and the first at or above the limit;
        the first plateau's distance when that one is already at the limit (the crossing lies
        before it, the path does not say where); the last plateau's distance and False when the
        path never reaches the limit (censored); NaN and False without points.
    """
    d = np.asarray(distance_km, float)
    y = np.asarray(leak_l_min, float)
    keep = np.isfinite(d) & np.isfinite(y)
    d, y = d[keep], y[keep]
    if d.size == 0:
        return _NAN, False
    order = np.argsort(d, kind="stable")
    d, y = d[order], y[order]
    hit = np.flatnonzero(y >= limit_l_min)
    if hit.size == 0:
        return float(d[-1]), False
    j = int(hit[0])
    if j == 0:
        return float(d[0]), True
    frac = (limit_l_min - y[j - 1]) / (y[j] - y[j - 1])
    return float(d[j - 1] + frac * (d[j] - d[j - 1])), True


def leak_crossing_lives(points: pd.DataFrame, limit_l_min: float) -> pd.DataFrame:
    """:func:`leak_crossing_life` of every hose in ``points``.

    Parameters
    ----------
    points : DataFrame
        ``hose_id``, ``distance_km`` [km], ``leak_l_min`` [l/min].
    limit_l_min : float
        The limit [l/min].

    Returns
    -------
    DataFrame
        ``hose_id``, ``life_km`` [km], ``crossed`` (False: censored at ``life_km``).
    """
    rows = [(hid, *leak_crossing_life(g["distance_km"], g["leak_l_min"], limit_l_min))
            for hid, g in points.groupby("hose_id", sort=True)]
    return pd.DataFrame(rows, columns=["hose_id", "life_km", "crossed"])



__all__ = ["DegradationFit", "FLOOR_MULTIPLE", "MIN_HOSES", "MIN_LEAK_POINTS", "degradation_fit", "degradation_rul",
           "leak_crossing_life", "leak_crossing_lives"]
