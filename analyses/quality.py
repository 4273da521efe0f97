"""What the data can tell: sensor resolution and noise, and quality gates on fitted results.

Every analysis shares two questions, answered here once:

1. *How fine is this signal?* A channel is described by its quantisation step (``resolution``)
   and the standard deviation of its noise (``noise``), both in the channel's SI unit. They are
   read from run metadata when the rig states them (ingest stores ``sensor_<channel>_resolution``
   and ``sensor_<channel>_noise`` in a run's params, in SI) and estimated from the record
   otherwise (:func:`describe_sensor`). Detection thresholds (motion, passes, strokes, plateaus,
   steps, onsets) are multiples of :meth:`Sensor.floor`, the smallest change the sensor can
   tell from its own noise, never constants tuned to one bench.

2. *Can this fit be believed?* A fitted result is reported only when the design separates its
   parameters (full rank, a bounded condition number, standard errors smaller than the values
   they qualify), no parameter sits at an optimiser bound, the model follows the data (NRMSE
   within the model's stated limit, or residuals at the noise level), there are enough points,
   and the values are physically possible. Otherwise the parameters are NULL and a one-line
   ``note`` says why (:class:`Gate`).

Nothing here imports the pipeline: usable from a notebook.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Normal-consistency factor of the median absolute deviation.
_MAD_TO_SIGMA = 1.4826
#: At most this many differences are examined to estimate a quantisation step or noise
#: (a long record is subsampled in contiguous blocks; the estimate does not need more).
_MAX_DIFFS = 200_000
#: A condition number above this (columns scaled to unit norm) means the design cannot
#: separate its parameters in float64 arithmetic, whatever the noise. [-]
COND_MAX = 1e8
#: A record goes onto a uniform time grid (of its median step) only when the grid has at most
#: this many points per sample the record holds: the others would be interpolated, not measured,
#: and the grid's size would follow from the time span (one jump of the clock) instead of from
#: the data. [-]
MAX_GRID_PER_SAMPLE = 2.0


# -- sensors --------------------------------------------------------------------------------
@dataclass(frozen=True)
class Sensor:
    """Resolution and noise of one channel, in the channel's SI unit.

    Attributes
    ----------
    resolution : float
        Quantisation step; 0 for a signal that is not visibly quantised. [SI unit of the channel]
    noise : float
        Standard deviation of the noise. [SI unit of the channel]
    source : str
        Where the values came from: ``"metadata"``, ``"estimated"`` or ``"metadata+estimated"``.
    """

    resolution: float
    noise: float
    source: str = "estimated"

    def floor(self) -> float:
        """Smallest change the sensor tells apart from itself: ``max(resolution, noise)``.

        Returns 0 only for an ideal (noise-free, unquantised) signal.
        """
        return float(max(self.resolution, self.noise))

    def threshold(self, n_sigma: float = 4.0) -> float:
        """A detection threshold: ``max(resolution, n_sigma * noise)``.

        A single sample of Gaussian noise exceeds 4 sigma about once in 16,000 samples; callers
        that test many samples at once use a run of samples or a larger ``n_sigma``.
        """
        return float(max(self.resolution, n_sigma * self.noise))

    def describe(self) -> str:
        """One line for result rows: ``resolution 5e-06, noise 1.2e-06 (metadata+estimated)``."""
        return f"resolution {self.resolution:.3g}, noise {self.noise:.3g} ({self.source})"


def _diff_sample(values) -> np.ndarray:
    """First differences of a record, at most :data:`_MAX_DIFFS` of them, finite only."""
    y = np.asarray(values, dtype=float)
    y = y[np.isfinite(y)]
    if y.size > _MAX_DIFFS + 1:
        # contiguous blocks spread over the record: differences stay between neighbours
        n_blocks = 20
        block = _MAX_DIFFS // n_blocks
        starts = np.linspace(0, y.size - block - 1, n_blocks).astype(int)
        return np.concatenate([np.diff(y[s:s + block + 1]) for s in starts])
    return np.diff(y)


def _on_value_lattice(values: np.ndarray, q: float, rel_tol: float) -> bool:
    """Whether 99 % of a record's values sit on one lattice ``offset + k q``.

    A quantised record dwells on its lattice values; sampled motion whose differences happen to
    be multiples of ``q`` (a constant speed times the sample period, coarse sampling of a
    stroke) does not: its ramps and turning points put the values at other phases.
    """
    phase = np.mod(values / q, 1.0)
    ref = np.angle(np.mean(np.exp(2j * np.pi * phase))) / (2 * np.pi)
    dev = np.mod(phase - ref + 0.5, 1.0) - 0.5
    return bool(np.mean(np.abs(dev) <= rel_tol) >= 0.99)


def quantisation_step(values, rel_tol: float = 0.02) -> float:
    """Quantisation step of a record from the lattice of its differences and values.

    A quantised signal only ever changes by integer multiples of its step ``q`` and only ever
    takes values ``offset + k q``. The step is the smallest candidate -- among the smallest
    non-zero absolute differences between samples and between distinct values (the eight
    smallest of each) and the differences of those -- of which at least 99 % of the non-zero differences are integer
    multiples within ``rel_tol`` and on whose lattice at least 99 % of the values sit. The value
    test keeps sampled motion out: passes at a constant speed, or strokes sampled at a few hertz,
    change by multiples of their per-sample travel, but their ramps and reversals leave the
    values off that lattice.

    Parameters
    ----------
    values : array-like
        The record. [any unit]
    rel_tol : float
        Tolerance on "integer multiple", as a fraction of the step. [-]

    Returns
    -------
    float
        The step [unit of ``values``], or 0 when the record is not visibly quantised (noise
        finer than the ADC, a continuous sensor, sampled motion with no lattice under it) or
        never changes.
    """
    d = np.abs(_diff_sample(values))
    y = np.asarray(values, dtype=float)
    y = y[np.isfinite(y)]
    span = float(np.max(np.abs(y), initial=0.0))
    tiny = max(span, 1e-300) * 1e-12  # float round-off of unit conversion is not a change
    nz = d[d > tiny]
    if nz.size < 10:
        return 0.0
    if y.size > _MAX_DIFFS:  # the value test on an evenly spread sample of the record
        y = y[np.linspace(0, y.size - 1, _MAX_DIFFS).astype(int)]
    gaps = np.diff(np.unique(y))
    gaps = gaps[gaps > tiny]
    # candidates: the smallest distinct differences and value gaps, smallest first; a spurious
    # one (a lone rounding step) puts the others off its lattice and is passed over
    cands = np.concatenate([np.unique(np.round(a / a.min(), 6))[:8] * a.min() for a in (nz, gaps) if a.size])
    # and their differences (a step of Euclid's algorithm): changes of 2 and 3 counts, none of 1
    pair = np.abs(np.subtract.outer(cands, cands)).ravel()
    cands = np.concatenate([cands, pair[pair > 1e-3 * cands.min()]])
    for q in np.unique(cands):
        k = nz / q
        on_lattice = np.abs(k - np.round(k)) <= rel_tol
        if np.mean(on_lattice) >= 0.99 and np.median(k) <= 1e4:
            kr = np.round(k[on_lattice])  # refine: the least-squares step over the lattice points
            q_ls = float(np.sum(nz[on_lattice] * kr) / np.sum(kr * kr))
            if _on_value_lattice(y, q_ls, rel_tol):
                return q_ls
    return 0.0


def noise_std(values) -> float:
    """Standard deviation of the white noise on a record, from its third differences.

    For white noise of standard deviation ``s`` on a smooth signal, the third difference has
    standard deviation ``sqrt(20) s``; the median absolute deviation makes the estimate robust
    to steps, reversals and other rare large changes. Third rather than second differences:
    a constant acceleration (every ramp of a trapezoidal motion) vanishes from them, while in
    second differences it is ``a dt^2`` -- on a 100 Hz record with 2 m/s2 ramps, 200 um on a
    share of the samples large enough to lift the median by a quarter.

    Parameters
    ----------
    values : array-like
        The record, sampled uniformly. [any unit]

    Returns
    -------
    float
        The noise [unit of ``values``]; 0 for a record too short or without noise.
    """
    d1 = _diff_sample(values)
    if d1.size < 8:
        return 0.0
    d3 = np.diff(d1, 2)
    mad = float(np.median(np.abs(d3 - np.median(d3))))
    return _MAD_TO_SIGMA * mad / np.sqrt(20.0)


def describe_sensor(values, resolution: float | None = None, noise: float | None = None) -> Sensor:
    """A channel's :class:`Sensor`: stated values where given, estimates from ``values`` otherwise.

    Parameters
    ----------
    values : array-like
        The record (may be empty when both values are stated). [SI]
    resolution, noise : float, optional
        Stated by the rig (metadata). [SI]
    """
    stated = [v is not None and np.isfinite(v) for v in (resolution, noise)]
    res = float(resolution) if stated[0] else quantisation_step(values)
    sig = float(noise) if stated[1] else noise_std(values)
    if not stated[1] and res > 0:
        # on a quantised record the difference estimator sees quantisation, not noise: a
        # record whose differences are mostly zero has noise below half a step
        sig = min(sig, res / np.sqrt(12.0)) if sig < res else sig
    source = "metadata" if all(stated) else ("estimated" if not any(stated) else "metadata+estimated")
    return Sensor(resolution=res, noise=float(sig), source=source)


def describe_sensor_at_rest(values, rest_fraction: float = 0.01, resolution: float | None = None,
                            noise: float | None = None) -> Sensor:
    """A channel's :class:`Sensor` estimated from the samples where the signal rests.

    :func:`describe_sensor` assumes the sampling resolves the motion (second differences of the
    motion well under the noise). A record logged too slowly for its motion (strokes of a metre
    at a few hertz) breaks that: its differences are the motion. Here only consecutive changes
    within ``rest_fraction`` of the record's range enter the estimate (rests, dwells, slow
    travel), so the noise and resolution are those of the sensor, not of the motion.

    Parameters
    ----------
    values : array-like
        The record. [SI]
    rest_fraction : float
        Largest sample-to-sample change counted as rest, as a fraction of the range. [-]
    resolution, noise : float, optional
        Stated by the rig: used as given.

    Returns
    -------
    Sensor
        As :func:`describe_sensor` on the rest samples (``source`` unchanged).
    """
    y = np.asarray(values, dtype=float)
    y = y[np.isfinite(y)]
    if y.size < 3:
        return describe_sensor(y, resolution, noise)
    d1 = np.diff(y)
    thr = rest_fraction * float(np.ptp(y))
    rest = np.abs(d1) <= thr
    both = rest[:-1] & rest[1:]
    # a synthetic record made of the rest differences only: its differences are the rest changes
    # (resolution lattice) and its second differences those between two rest changes (noise)
    d2 = np.diff(d1)[both]
    res_rec = np.concatenate([[0.0], np.cumsum(d1[rest])])
    stated = [v is not None and np.isfinite(v) for v in (resolution, noise)]
    res = float(resolution) if stated[0] else quantisation_step(res_rec)
    if stated[1]:
        sig = float(noise)
    elif d2.size >= 8:
        sig = _MAD_TO_SIGMA * float(np.median(np.abs(d2 - np.median(d2)))) / np.sqrt(6.0)
        if res > 0 and sig < res:
            sig = min(sig, res / np.sqrt(12.0))
    else:
        sig = 0.0
    source = "metadata" if all(stated) else ("estimated" if not any(stated) else "metadata+estimated")
    return Sensor(resolution=res, noise=float(sig), source=source)


def sensor_from_params(params: dict | None, channel: str, values=()) -> Sensor:
    """The :class:`Sensor` of a run's channel from its params (``sensor_<channel>_resolution`` /
    ``sensor_<channel>_noise``, SI, as ingest stores them), estimated from ``values`` where absent.
    """
    params = params or {}

    def num(key):
        v = params.get(f"sensor_{channel}_{key}")
        try:
            v = float(v)
        except (TypeError, ValueError):
            return None
        return v if np.isfinite(v) and v >= 0 else None

    return describe_sensor(values, resolution=num("resolution"), noise=num("noise"))


# -- time base -------------------------------------------------------------------------------
def time_base_gap(t, dt: float, max_per_sample: float = MAX_GRID_PER_SAMPLE) -> str | None:
    """Why a record cannot go onto a uniform time grid of step ``dt``; None when it can.

    The grid over ``[t[0], t[-1]]`` holds ``(t[-1] - t[0]) / dt + 1`` points; a gap in the time
    base (a clock that jumped, two records logged into one file) makes it as large as the span
    says, whatever the number of samples. Call this before building such a grid.

    Parameters
    ----------
    t : array-like
        Time, sorted ascending. [s]
    dt : float
        Step of the grid (the record's median step). [s]
    max_per_sample : float
        Most grid points per sample of the record. [-]

    Returns
    -------
    str or None
        One line naming the largest gap, e.g. ``time base has a gap of 1e+06 s (2e+08 x the
        median step) at t = 10.7 s: a uniform grid would need 2e+08 points for 4284 samples``.
    """
    t = np.asarray(t, dtype=float)
    if t.size < 2 or not (np.isfinite(dt) and dt > 0):
        return None
    points = (float(t[-1]) - float(t[0])) / dt + 1.0
    if points <= max_per_sample * t.size:
        return None
    d = np.diff(t)
    i = int(np.argmax(d))
    return (f"time base has a gap of {d[i]:.3g} s ({d[i] / dt:.3g} x the median step) at t = {t[i]:.6g} s: "
            f"a uniform grid would need {points:.3g} points for {t.size} samples (at most {max_per_sample:g} x)")


# -- set-points -------------------------------------------------------------------------------
def setpoint_thresholds(values, sensor: Sensor | None = None, n_sigma: float = 5.0) -> tuple[float, float]:
    """Smallest jump and level change of a set-point (reference) record that count as a step.

    A commanded set-point changes by whole counts of its resolution: one count is a change. A
    read-back set-point is noisy: a jump must exceed ``n_sigma`` sigmas of a difference of two
    samples (``sqrt(2)`` times the noise) and a new level ``n_sigma`` sigmas of one sample.

    Parameters
    ----------
    values : array-like
        The set-point record. [SI]
    sensor : Sensor, optional
        Its resolution and noise (:func:`sensor_from_params`); estimated from ``values`` when absent.
    n_sigma : float
        Detection margin. [-]

    Returns
    -------
    (jump, level) : tuple of float
        Thresholds [unit of ``values``]; a record with neither noise nor resolution gets 1e-9 of
        its magnitude (float round-off is not a step).
    """
    r = np.asarray(values, dtype=float)
    r = r[np.isfinite(r)]
    if sensor is None:
        sensor = describe_sensor(r)
    tiny = 1e-9 * max(float(np.max(np.abs(r), initial=0.0)), 1e-300)
    count = 0.999 * sensor.resolution
    jump = max(count, n_sigma * np.sqrt(2.0) * sensor.noise, tiny)
    level = max(count, n_sigma * sensor.noise, tiny)
    return float(jump), float(level)


#: Fewest samples a noisy set-point must hold a level to count as settled: over ``N`` samples the
#: change across a fitted line has a standard error of ``sigma sqrt(12 / N)``, within one noise
#: sigma from 12 samples on, so a level's drift is told at the same n-sigma margin as the level. [-]
SETTLE_SAMPLES_NOISY = 12


def settle_points(sensor: Sensor, min_points: int = 1) -> int:
    """Fewest samples a set-point must hold a level, within its band, to be a settled level.

    A clean commanded set-point (no noise) shows every change: ``min_points``. A noisy read-back
    must hold :data:`SETTLE_SAMPLES_NOISY` samples, so that a ramp slower than the jump threshold
    per sample is not taken for a run of short levels.
    """
    noisy = np.isfinite(sensor.noise) and sensor.noise > 0 and sensor.noise > sensor.resolution / np.sqrt(12.0)
    return int(max(min_points, SETTLE_SAMPLES_NOISY if noisy else 1))


def _drift(y: np.ndarray) -> float:
    """Change across a stretch of a line fitted to it by least squares (0 under 3 samples)."""
    m = y.size
    if m < 3:
        return 0.0
    x = np.arange(m) - (m - 1) / 2.0
    return float(abs(np.dot(x, y - y.mean()) / np.dot(x, x)) * (m - 1))


def setpoint_levels(values, level: float, settle: int = 1, noise: float = 0.0) -> list[tuple[int, int, float]]:
    """The settled levels of a set-point record: stretches that hold within ``level`` of their median.

    A level starts at the first window of ``settle`` samples whose range is within ``2 level``
    (every sample within ``level`` of its middle) and lasts while the samples stay within
    ``level`` of that window's median, and only when a line fitted across it changes by no more
    than ``level`` (a ramp slow for the band drifts through it: no level). The level ends at the
    first sample off it, walked back over the samples just before that already lie more than
    ``noise`` (one sigma) on the side it leaves for (where a noisy ramp starts). Samples between
    two levels (a ramp, a glitch, the overshoot of a read-back) belong to no level. Consecutive
    levels whose medians differ by no more than ``level`` are one level (a glitch inside a hold).

    Returns
    -------
    list of (i_start, i_end, median)
        ``i_end`` is one past the last sample held.
    """
    r = np.asarray(values, dtype=float)
    n = int(max(1, settle))
    if r.size < n:
        return []
    win = np.lib.stride_tricks.sliding_window_view(r, n)
    flat = np.flatnonzero(np.max(win, axis=1) - np.min(win, axis=1) <= 2 * level)
    out: list[list] = []
    pos = 0
    while True:
        k = int(np.searchsorted(flat, pos))
        if k >= flat.size:
            break
        i = int(flat[k])
        lev = float(np.median(r[i:i + n]))
        j, chunk = i + n, 1024
        while j < r.size:   # the first sample off the level, searched in growing chunks
            off = np.flatnonzero(np.abs(r[j:j + chunk] - lev) > level)
            if off.size:
                j += int(off[0])
                break
            j += chunk
            chunk *= 2
        j = min(j, r.size)
        pos = j
        if _drift(r[i:j]) > level:
            continue        # a stretch of a ramp slow for the band, not a level
        if j < r.size:      # the departure starts at the run of samples already on its side
            side = np.sign(r[j] - lev)
            while j - 1 > i + n and side * (r[j - 1] - lev) > noise:
                j -= 1
        if out and abs(lev - out[-1][2]) <= level:
            out[-1][1] = j      # same level again after a glitch: one hold
        else:
            out.append([i, j, lev])
    return [(a, b, float(np.median(r[a:b]))) for a, b, _ in out]


def setpoint_jumps(values, jump: float, level: float, min_points: int = 1, settle_points: int | None = None,
                   noise: float = 0.0) -> list[int]:
    """Indices where a set-point record steps to a new settled level.

    Steps are found on the set-point's settled levels (:func:`setpoint_levels`), not on every
    change: a step starts at the first sample that leaves one level (where a ramp starts) and
    ends where the next level begins; a ramp in one-sample plateaus, a glitch or a noisy
    read-back between two levels is one step or none. A level must hold ``settle_points``
    samples (default ``min_points``; :func:`settle_points` from the set-point's sensor) and differ
    from the previous one by more than ``level``; ``noise`` is the set-point's noise sigma.
    ``jump`` (the smallest sample-to-sample change of the former rule) is kept for the callers'
    signature and not used: leaving a level by more than ``level`` is what starts a step.

    Returns
    -------
    list of int
        The first sample of each step.
    """
    r = np.asarray(values, dtype=float)
    if r.size < 2:
        return []
    settle = int(max(1, min_points if settle_points is None else settle_points))
    levels = setpoint_levels(r, level, settle, noise)
    return [int(levels[k - 1][1]) for k in range(1, len(levels))]


# -- fit quality ----------------------------------------------------------------------------
def nrmse_pct(measured, model) -> float:
    """``100 * RMS(measured - model) / (max(measured) - min(measured))`` (warehouse.md).

    Returns NaN when the measured values have no range.
    """
    y = np.asarray(measured, dtype=float)
    m = np.asarray(model, dtype=float)
    span = float(np.max(y) - np.min(y)) if y.size else 0.0
    if span <= 0:
        return float("nan")
    return float(100.0 * np.sqrt(np.mean((y - m) ** 2)) / span)


def scaled_condition(X) -> float:
    """Condition number of a design matrix with its columns scaled to unit norm.

    Column scaling removes the effect of units (a column in m/s beside one in N); what is left
    measures how nearly one column is a combination of the others. ``inf`` for a zero column or
    a rank-deficient design.
    """
    X = np.asarray(X, dtype=float)
    if X.ndim != 2 or X.shape[0] < X.shape[1] or X.shape[1] == 0:
        return float("inf")
    norms = np.linalg.norm(X, axis=0)
    if np.any(norms == 0) or not np.all(np.isfinite(norms)):
        return float("inf")
    s = np.linalg.svd(X / norms, compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")


@dataclass
class LinearFit:
    """Ordinary least squares ``y = X beta`` with standard errors and the design's conditioning.

    Attributes
    ----------
    beta, se : numpy.ndarray
        Estimates and their standard errors (NaN when the design is rank-deficient).
    cond : float
        :func:`scaled_condition` of ``X``.
    rank : int
        Numerical rank of ``X``.
    sigma : float
        Residual standard deviation (``dof`` degrees of freedom).
    fitted : numpy.ndarray
        ``X beta``.
    """

    beta: np.ndarray
    se: np.ndarray
    cond: float
    rank: int
    sigma: float
    dof: int
    fitted: np.ndarray


def linear_lstsq(X, y) -> LinearFit:
    """Least squares with standard errors from ``sigma^2 (X'X)^-1`` and the design's condition."""
    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=float)
    n, p = X.shape
    beta, _, rank, _ = np.linalg.lstsq(X, y, rcond=None)
    fitted = X @ beta
    dof = n - p
    sigma = float(np.sqrt(np.sum((y - fitted) ** 2) / dof)) if dof > 0 else float("nan")
    cond = scaled_condition(X)
    se = np.full(p, np.nan)
    if rank == p and dof > 0 and np.isfinite(cond):
        try:
            cov = sigma ** 2 * np.linalg.inv(X.T @ X)
            se = np.sqrt(np.clip(np.diag(cov), 0, None))
        except np.linalg.LinAlgError:
            pass
    return LinearFit(beta=beta, se=se, cond=cond, rank=int(rank), sigma=sigma, dof=dof, fitted=fitted)


def jacobian_se(jac, residuals, n_params: int | None = None) -> tuple[np.ndarray, float]:
    """Standard errors of a nonlinear least-squares solution from its Jacobian at the optimum.

    Returns ``(se, cond)``: ``se`` NaN where the Jacobian is singular; ``cond`` the scaled
    condition number of the Jacobian (as :func:`scaled_condition`).
    """
    J = np.asarray(jac, dtype=float)
    r = np.asarray(residuals, dtype=float)
    p = J.shape[1] if n_params is None else n_params
    dof = r.size - p
    cond = scaled_condition(J)
    se = np.full(p, np.nan)
    if dof > 0 and np.isfinite(cond):
        s2 = float(np.sum(r ** 2) / dof)
        try:
            se = np.sqrt(np.clip(np.diag(s2 * np.linalg.inv(J.T @ J)), 0, None))
        except np.linalg.LinAlgError:
            pass
    return se, cond


def gram_se(jtj, sum_sq: float, dof: int) -> tuple[np.ndarray, float]:
    """Standard errors and scaled condition number from ``J^T J`` (a fit kept as sums, not samples).

    Parameters
    ----------
    jtj : array_like
        ``J^T J`` at the optimum, (p, p).
    sum_sq : float
        Sum of squared residuals at the optimum.
    dof : int
        Residual degrees of freedom (observations minus parameters).

    Returns
    -------
    (ndarray, float)
        As :func:`jacobian_se`: ``se`` NaN where ``J^T J`` is singular; ``cond`` the condition
        number of J with unit-norm columns (square root of that of the scaled ``J^T J``).
    """
    A = np.asarray(jtj, dtype=float)
    p = A.shape[0]
    se = np.full(p, np.nan)
    dg = np.diag(A)
    if not (np.all(np.isfinite(A)) and np.all(dg > 0)):
        return se, float("inf")
    sc = 1.0 / np.sqrt(dg)
    ev = np.linalg.eigvalsh(A * sc[:, None] * sc[None, :])
    cond = float(np.sqrt(ev[-1] / ev[0])) if ev[0] > 0 else float("inf")
    if dof > 0 and np.isfinite(cond):
        try:
            se = np.sqrt(np.clip(np.diag(sum_sq / dof * np.linalg.inv(A)), 0, None))
        except np.linalg.LinAlgError:
            pass
    return se, cond


def at_bound(value: float, lo: float, hi: float, rtol: float = 1e-3) -> bool:
    """Whether ``value`` sits at (within ``rtol`` of the range of) the bound ``lo`` or ``hi``.

    Bounds spanning more than two decades of positive values are compared in log space, so a
    bound of 1e5 is not "reached" by 1e3.
    """
    if not np.isfinite(value):
        return True
    if lo > 0 and np.isfinite(hi) and hi / lo > 100:
        v, a, b = np.log(max(value, 1e-300)), np.log(lo), np.log(hi)
    else:
        v, a, b = value, lo, hi
    span = (b - a) if np.isfinite(a) and np.isfinite(b) else max(abs(v), 1.0)
    tol = rtol * span
    return bool((np.isfinite(a) and v <= a + tol) or (np.isfinite(b) and v >= b - tol))


@dataclass
class Gate:
    """Collects the reasons a fitted result cannot be believed; the first one is its ``note``.

    Use one per result row::

        g = Gate()
        g.enough_points(n, 5)
        g.identifiable(fit, names=("coulomb_n", "viscous_n_s_m"))
        g.within_bounds(sol.x, lo, hi, names)
        g.follows_data(nrmse, limit_pct=5.0)
        g.physical("coulomb_n", fc, lo=0)
        row = g.apply(row, fields=("coulomb_n", "viscous_n_s_m"))

    Every check returns ``self`` and only records a reason; :meth:`apply` sets the fields to
    None and the row's ``note`` when there is one.
    """

    reasons: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.reasons

    @property
    def note(self) -> str | None:
        return self.reasons[0] if self.reasons else None

    def fail(self, reason: str) -> "Gate":
        self.reasons.append(reason)
        return self

    def enough_points(self, n: int, minimum: int, what: str = "points") -> "Gate":
        if n < minimum:
            self.fail(f"too few {what}: {n} < {minimum}")
        return self

    def identifiable(self, fit: LinearFit | None = None, *, cond: float | None = None, rank: int | None = None,
                     n_params: int | None = None, beta=None, se=None, names=(), max_rel_se: float = 0.5,
                     check: tuple[str, ...] | None = None) -> "Gate":
        """The design separates the parameters: full rank, condition under :data:`COND_MAX`,
        and for the parameters in ``check`` (default: all) a standard error under
        ``max_rel_se`` of the value (the value is distinguishable from zero at about 2 sigma).
        """
        if fit is not None:
            cond, rank, beta, se = fit.cond, fit.rank, fit.beta, fit.se
            n_params = len(fit.beta)
        if rank is not None and n_params is not None and rank < n_params:
            return self.fail(f"design is rank-deficient (rank {rank} < {n_params} parameters): "
                             "the data cannot separate them")
        if cond is not None and not (cond < COND_MAX):
            return self.fail(f"design is ill-conditioned (condition number {cond:.2g}): "
                             "the data cannot separate the parameters")
        if beta is not None and se is not None:
            names = list(names) or [f"parameter {i}" for i in range(len(beta))]
            for name, b, s in zip(names, beta, se):
                if check is not None and name not in check:
                    continue
                if not np.isfinite(s) or abs(s) > max_rel_se * abs(b):
                    return self.fail(f"{name} not identifiable from the data "
                                     f"(estimate {b:.3g} +- {s:.2g})")
        return self

    def within_bounds(self, x, lo, hi, names=(), rtol: float = 1e-3) -> "Gate":
        """No parameter at an optimiser bound (:func:`at_bound`)."""
        x = np.atleast_1d(np.asarray(x, dtype=float))
        lo = np.broadcast_to(np.asarray(lo, dtype=float), x.shape)
        hi = np.broadcast_to(np.asarray(hi, dtype=float), x.shape)
        names = list(names) or [f"parameter {i}" for i in range(x.size)]
        for name, v, a, b in zip(names, x, lo, hi):
            if at_bound(float(v), float(a), float(b), rtol):
                side = "lower" if abs(v - a) <= abs(v - b) else "upper"
                return self.fail(f"{name} ran to the optimiser's {side} bound ({v:.3g})")
        return self

    def follows_data(self, nrmse: float, limit_pct: float, *, rms: float | None = None,
                     noise: float | None = None, n_sigma: float = 3.0) -> "Gate":
        """The model follows the data: NRMSE within the model's stated limit, or (when the
        noise is known) residuals within ``n_sigma`` times the noise."""
        if not np.isfinite(nrmse):
            return self.fail("fit quality undefined (the data have no range)")
        if nrmse > limit_pct:
            if rms is not None and noise is not None and noise > 0 and rms <= n_sigma * noise:
                return self
            return self.fail(f"model misses the data (NRMSE {nrmse:.2g} % > {limit_pct:g} %)")
        return self

    def physical(self, name: str, value, lo: float = -np.inf, hi: float = np.inf) -> "Gate":
        """The value is physically possible (finite and within ``[lo, hi]``)."""
        if value is None or not np.isfinite(value):
            return self.fail(f"{name} is not finite")
        if value < lo or value > hi:
            return self.fail(f"{name} = {value:.3g} is physically impossible "
                             f"(must be in [{lo:g}, {hi:g}])")
        return self

    def apply(self, row: dict, fields, note_key: str = "note") -> dict:
        """``row`` with ``fields`` set to None and ``note_key`` set when a check failed."""
        out = dict(row)
        if self.reasons:
            for f in fields:
                out[f] = None
            prior = out.get(note_key)
            out[note_key] = self.note if not prior else f"{prior}; {self.note}"
        else:
            out.setdefault(note_key, None)
        return out


__all__ = ["COND_MAX", "Gate", "LinearFit", "Sensor", "at_bound", "describe_sensor", "describe_sensor_at_rest",
           "jacobian_se", "linear_lstsq",
           "noise_std", "nrmse_pct", "quantisation_step", "scaled_condition", "sensor_from_params",
           "setpoint_jumps", "setpoint_levels", "setpoint_thresholds", "settle_points", "SETTLE_SAMPLES_NOISY",
           "time_base_gap"]
