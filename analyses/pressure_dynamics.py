"""PLA chamber pressure after set-point steps: first or second order, chosen by the data (seed 001,
Eq. 11, Table 2).

physics.md's standard form of Eq. 11 (the seed's Eq. 11 also carries a ``-Pref'`` term, which for a
step would be an impulse; it is not used):

    P'' = -2 xi wn P' - wn^2 (P - Pref)          (second order)

A pressure loop under closed-loop control often answers set-point steps as a first-order lag

    tau P' = Pref - P                            (first order)

which the second-order form only reaches at ``xi -> inf`` (an over-damped fit runs to the
optimiser's bound on ``xi``). Both are fitted per chamber and direction, over all the steps at
once, and the one with the lower Bayesian information criterion on the residuals,
``n ln(RSS / n) + k ln(n)``, among those that pass the quality gates is reported (``model``);
the second order needs a BIC lower by ``BIC_MARGIN`` (otherwise the simpler model is kept),
and a fit with a parameter at its bound never passes.

Steps: a pressure-step run logs the chamber pressure ``p`` and the set-point ``p_ref`` (gauge).
A change of ``p_ref`` is a step when it exceeds what ``p_ref``'s own sensor can produce (one
count of its resolution, and ``N_SIGMA_REF`` noise sigmas of a difference of two samples),
never a constant in pascals; the new level must differ from the old one by more than the
resolution and ``N_SIGMA_REF`` noise sigmas too. Steps are taken between the set-point's settled
levels (:func:`analyses.quality.setpoint_levels`), not at every change: a ramp is one step from
the first sample off the old level. A step is a *charge* when the set-point rises
and a *discharge* when it falls; it lasts until the next step. It starts from the pressure
measured just before the jump, with zero rate of change. A step smaller than ``STEP_SNR_MIN``
times the pressure sensor's floor is listed but not fitted (its ``note`` says why).

Quality gates (:class:`analyses.quality.Gate`): enough samples, no parameter at a bound, the
parameters identifiable from the Jacobian (standard error under half the value), the model
follows the data (NRMSE within ``NRMSE_LIMIT_PCT`` or residuals within three sigmas of the
pressure noise), and physical values (``tau > 0``, ``wn > 0``, ``xi > 0``). Otherwise NULL
parameters and a ``note``.

Grouping (issue 25, :mod:`analyses.pressure_groups`): a fit pools the steps of one group. :func:`group_pressure_steps` makes a
``rig`` group per (campaign, rig, chamber, direction) with every step of that rig, and, for runs
that name the part under test (``valve_id`` or ``hose_id``), a ``part`` group per (campaign, rig,
chamber, direction, part, age): the same valve new and after 594 h are two groups. The chamber is
any name the rig gives it. :func:`age_changes` gives each later age's change of ``wn`` /
``zeta`` / ``tau`` from the part's youngest fitted age, and :func:`plot_pressure_ageing` draws
them against the part's hours (or distance).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy  # its submodules load on first use: a rebuild that reuses every stage never pays for them

from analyses.quality import (Gate, Sensor, describe_sensor, jacobian_se, nrmse_pct, setpoint_jumps,
                              setpoint_thresholds, settle_points)
from schemas.papers import PLA_NRMSE_LIMIT_PCT
from analyses.pressure_groups import (RunPart, StepGroup, age_changes, group_pressure_steps,  # noqa: F401
                                       plot_pressure_ageing)  # grouping and ageing: their own module

__all__ = ["second_order_step", "first_order_step", "PressureStep", "step_threshold", "split_pressure_steps",
           "PressureFit", "fit_pressure_dynamics", "plot_pressure_steps", "NRMSE_LIMIT_PCT", "STEP_SNR_MIN",
           "N_SIGMA_REF", "ZETA_BOUNDS", "BIC_MARGIN", "RunPart", "StepGroup", "group_pressure_steps", "age_changes",
           "plot_pressure_ageing"]

#: Detection margin on the set-point: a change must exceed this many noise sigmas (of a
#: difference of two samples for a jump, of one sample for a level). [-]
N_SIGMA_REF = 5.0
#: A step is fitted when its size is at least this many times the pressure sensor's floor. [-]
STEP_SNR_MIN = 5.0
#: The model's stated limit on NRMSE: the PLA paper's models reproduce its data under it
#: (:data:`schemas.papers.PLA_NRMSE_LIMIT_PCT`); residuals at the sensor noise pass too
#: (:meth:`analyses.quality.Gate.follows_data`). [%]
NRMSE_LIMIT_PCT = PLA_NRMSE_LIMIT_PCT
#: The second order (one more parameter) is chosen only when its BIC is lower than the first
#: order's by more than this: "strong" evidence on Kass & Raftery's (1995) scale; a smaller
#: difference is a tie the data cannot break, and the simpler model is kept. [-]
BIC_MARGIN = 6.0
#: Damping ratio bounds of the second-order fit (physical: positive). [-]
ZETA_BOUNDS = (0.02, 50.0)


def second_order_step(t, p_start, p_ref, wn: float, zeta: float):
    """Response of ``P'' = -2 zeta wn P' - wn^2 (P - Pref)`` to a constant ``Pref``.

    Parameters
    ----------
    t : array_like
        Time since the step (>= 0). [s]
    p_start : float or ndarray
        Pressure at the step, with zero rate of change (or one per sample of ``t``). [Pa]
    p_ref : float or ndarray
        Set-point after the step (or one per sample of ``t``). [Pa]
    wn : float
        Natural frequency. [rad/s]
    zeta : float
        Damping ratio (any positive value; 1 is handled without loss of precision). [-]

    Returns
    -------
    ndarray
        Pressure. [Pa]
    """
    decay, h = _second_order_shape(t, wn, zeta)
    if decay is None:
        return p_ref + (p_start - p_ref) * h
    return p_ref + (p_start - p_ref) * decay * h


def _second_order_shape(t, wn: float, zeta: float):
    """The factors of :func:`second_order_step` that depend on time alone: ``(decay, h)``, the
    response ``p_ref + (p_start - p_ref) * decay * h`` (under-damped), or ``(None, h)`` and
    ``p_ref + (p_start - p_ref) * h`` (over-damped, critical). [-]"""
    t = np.maximum(np.asarray(t, float), 0.0)
    a = zeta * wn
    disc = zeta * zeta - 1.0
    wd = wn * np.sqrt(abs(disc))
    x = wd * t
    if disc < 0:       # under-damped: cos(wd t) + a sin(wd t) / wd
        return np.exp(-a * t), np.cos(x) + a * t * np.sinc(x / np.pi)
    # over-damped / critical: e^(-a t) (cosh(x) + a t sinh(x) / x), x = wd t
    up, down = np.exp(x - a * t), np.exp(-x - a * t)   # x <= a t: no overflow
    small = x < 1e-6
    shx = np.where(small, np.exp(-a * t), (up - down) / (2 * np.where(small, 1.0, x)))
    return None, 0.5 * (up + down) + a * t * shx


def first_order_step(t, p_start, p_ref, tau: float):
    """Response of ``tau P' = Pref - P`` to a constant ``Pref``.

    Parameters
    ----------
    t : array_like
        Time since the step (>= 0). [s]
    p_start : float or ndarray
        Pressure at the step (or one per sample of ``t``). [Pa]
    p_ref : float or ndarray
        Set-point after the step (or one per sample of ``t``). [Pa]
    tau : float
        Time constant (> 0). [s]

    Returns
    -------
    ndarray
        Pressure. [Pa]
    """
    t = np.maximum(np.asarray(t, float), 0.0)
    return p_ref + (p_start - p_ref) * np.exp(-t / tau)


@dataclass
class PressureStep:
    """One set-point step of a pressure-step run (gauge pressures)."""

    run_id: str
    chamber: str
    direction: str            # charge / discharge
    t_step_s: float
    p_ref_before_pa: float
    p_ref_pa: float
    p_start_pa: float
    t: np.ndarray             # since the step [s]
    p: np.ndarray             # measured [Pa]
    noise_pa: float = float("nan")   # pressure sensor noise of the run [Pa]
    note: str | None = None   # why the step is not fitted (None: it is)

    @property
    def usable(self) -> bool:
        return self.note is None


def step_threshold(p_ref, sensor: Sensor | None = None) -> tuple[float, float]:
    """Smallest set-point jump and level change that count as a step: one count of the
    set-point's resolution and ``N_SIGMA_REF`` noise sigmas (:func:`analyses.quality.setpoint_thresholds`).

    Parameters
    ----------
    p_ref : array_like
        Set-point record. [Pa]
    sensor : Sensor, optional
        The set-point's resolution and noise (run metadata); estimated from ``p_ref`` when absent.

    Returns
    -------
    (jump, level) : tuple of float
        [Pa]
    """
    return setpoint_thresholds(p_ref, sensor, N_SIGMA_REF)


def split_pressure_steps(t, p, p_ref, run_id: str = "", chamber: str = "", min_step_pa: float | None = None,
                         min_points: int = 5, pre_samples: int = 10, ref_sensor: Sensor | None = None,
                         p_sensor: Sensor | None = None) -> list[PressureStep]:
    """Cut a pressure-step run into its steps.

    Parameters
    ----------
    t : array_like
        Time. [s]
    p : array_like
        Chamber pressure, gauge. [Pa]
    p_ref : array_like
        Set-point, gauge. [Pa]
    run_id, chamber : str
        Carried into the steps.
    min_step_pa : float, optional
        Smallest set-point change that counts as a step; default from the set-point's sensor
        (:func:`step_threshold`). [Pa]
    min_points : int
        Fewest samples a step needs.
    pre_samples : int
        Samples before the jump averaged for the starting pressure (at most a fifth of the
        previous step).
    ref_sensor, p_sensor : Sensor, optional
        Resolution and noise of ``p_ref`` and ``p`` (run metadata); estimated from the records
        when absent.

    Returns
    -------
    list of PressureStep
        Steps smaller than ``STEP_SNR_MIN`` times the pressure sensor's floor carry a ``note``.
    """
    t = np.asarray(t, float)
    p = np.asarray(p, float)
    r = np.asarray(p_ref, float)
    if len(t) < 2:
        return []
    settle, ref_noise = min_points, 0.0
    if min_step_pa is None:
        ref_sensor = ref_sensor if ref_sensor is not None else describe_sensor(r)
        jump_thr, level_thr = step_threshold(r, ref_sensor)
        settle, ref_noise = settle_points(ref_sensor, min_points), ref_sensor.noise
    else:
        jump_thr = level_thr = float(min_step_pa)
    if p_sensor is None:
        p_sensor = describe_sensor(p)
    jumps = setpoint_jumps(r, jump_thr, level_thr, min_points, settle_points=settle, noise=ref_noise)
    bounds = jumps + [len(r)]
    floor = p_sensor.floor()
    out = []
    for j, i0 in enumerate(jumps):
        i1 = bounds[j + 1]
        if i1 - i0 < min_points:
            continue
        prev0 = jumps[j - 1] if j > 0 else 0
        before, after = float(np.median(r[prev0:i0])), float(np.median(r[i0:i1]))
        n_pre = max(1, min(pre_samples, (i0 - prev0) // 5))
        p_start = float(np.mean(p[i0 - n_pre:i0]))
        size = abs(after - p_start)
        note = None
        if not size >= STEP_SNR_MIN * floor:
            note = (f"step of {size:.3g} Pa is under {STEP_SNR_MIN:g} x the pressure sensor floor "
                    f"({floor:.3g} Pa): not fitted")
        out.append(PressureStep(run_id, chamber, "charge" if after > before else "discharge", float(t[i0]),
                                before, after, p_start, t[i0:i1] - t[i0], p[i0:i1], float(p_sensor.noise), note))
    return out


@dataclass
class PressureFit:
    """Fit of one (chamber, direction): the chosen model's parameters, NaN when not reported.

    ``model`` is ``"first_order"`` (``tau_s``) or ``"second_order"`` (``wn_rad_s``, ``zeta``), or
    None when neither is reported; ``note`` says why (None when the result is sound). ``bic``
    holds the information criterion of each model tried.
    """

    chamber: str
    direction: str
    wn_rad_s: float = float("nan")
    zeta: float = float("nan")
    nrmse_pct: float = float("nan")
    n_steps: int = 0
    step_nrmse_pct: list = field(default_factory=list)
    message: str = ""
    tau_s: float = float("nan")
    model: str | None = None
    note: str | None = None
    bic: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return bool(np.isfinite(self.wn_rad_s) or np.isfinite(self.tau_s))

    def predict(self, step: PressureStep):
        """The chosen model's pressure over one step (NaN without a model). [Pa]"""
        if self.model == "first_order" and np.isfinite(self.tau_s):
            return first_order_step(step.t, step.p_start_pa, step.p_ref_pa, self.tau_s)
        if self.model == "second_order" and np.isfinite(self.wn_rad_s):
            return second_order_step(step.t, step.p_start_pa, step.p_ref_pa, self.wn_rad_s, self.zeta)
        return np.full(len(step.t), np.nan)

    def rate(self) -> float:
        """Decay rate of the slowest mode (``1/tau`` or ``zeta wn``), NaN without a model. [1/s]"""
        if self.model == "first_order":
            return 1.0 / self.tau_s
        if self.model == "second_order":
            return self.zeta * self.wn_rad_s if self.zeta <= 1 else self.wn_rad_s * (
                self.zeta - np.sqrt(self.zeta ** 2 - 1))
        return float("nan")


@dataclass
class _Stacked:
    """The steps of one fit laid end to end, for a model over all of them in one call (issue 26: the
    grid seeds evaluate it ~150 times). ``times``: each distinct time vector of the steps once, end
    to end [s] (the steps of a rig share a few: one sample rate, one hold time); ``at``: where each
    sample's time is in ``times``; ``p_start``, ``p_ref``: each sample's step's start pressure and
    set-point [Pa]. The factors that depend on time alone are computed once per distinct vector and
    taken by sample: the same operations on the same numbers, element by element, as one call of
    :func:`second_order_step` / :func:`first_order_step` per step, so the same bits."""

    times: np.ndarray
    at: np.ndarray
    p_start: np.ndarray
    p_ref: np.ndarray

    @classmethod
    def of(cls, steps) -> "_Stacked":
        n = [len(s.t) for s in steps]
        seen: dict[bytes, int] = {}
        parts, at, offset = [], [], 0
        for s in steps:
            t = np.asarray(s.t, float)
            start = seen.get(t.tobytes())
            if start is None:
                start = seen[t.tobytes()] = offset
                parts.append(t)
                offset += len(t)
            at.append(np.arange(start, start + len(t)))
        return cls(np.concatenate(parts) if parts else np.empty(0),
                   np.concatenate(at) if at else np.empty(0, np.intp),
                   np.repeat(np.array([s.p_start_pa for s in steps], float), n),
                   np.repeat(np.array([s.p_ref_pa for s in steps], float), n))


def _model(steps: _Stacked, wn, zeta):
    decay, h = _second_order_shape(steps.times, wn, zeta)
    if decay is None:
        return steps.p_ref + (steps.p_start - steps.p_ref) * h[steps.at]
    return steps.p_ref + (steps.p_start - steps.p_ref) * decay[steps.at] * h[steps.at]


def _model1(steps: _Stacked, tau):
    return steps.p_ref + (steps.p_start - steps.p_ref) * np.exp(-np.maximum(steps.times, 0.0) / tau)[steps.at]


@dataclass
class _Candidate:
    name: str
    x: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    names: tuple
    rss: float
    jac: np.ndarray
    resid: np.ndarray
    model: np.ndarray
    success: bool
    message: str


def _bic(rss: float, n: int, k: int) -> float:
    """Bayesian information criterion of a least-squares fit with Gaussian residuals."""
    return float(n * np.log(max(rss / n, 1e-300)) + k * np.log(n))


def _fit_first(steps, y, scale, dt, t_max) -> _Candidate:
    """``tau`` over ``[dt / 100, 100 t_max]``: faster than the sampling or slower than the record
    cannot be told, and shows as a bound."""
    lo, hi = np.array([dt / 100.0]), np.array([100.0 * t_max])

    def res(x):
        return (_model1(steps, x[0]) - y) / scale

    grid = np.geomspace(lo[0] * 1.5, hi[0] / 1.5, 40)
    x0 = min(grid, key=lambda v: float(np.sum(res([v]) ** 2)))
    sol = scipy.optimize.least_squares(res, [x0], bounds=(lo, hi), x_scale=[x0], xtol=1e-12, ftol=1e-12)
    r = sol.fun
    return _Candidate("first_order", sol.x, lo, hi, ("tau_s",), float(r @ r), sol.jac, r,
                      _model1(steps, sol.x[0]), bool(sol.success), str(sol.message))


def _fit_second(steps, y, scale, dt, t_max) -> _Candidate:
    """``wn`` over ``[0.1 / t_max, 20 pi / dt]`` (ten times the sampling frequency), ``zeta`` over
    :data:`ZETA_BOUNDS`, from a coarse grid seed."""
    lo = np.array([0.1 / t_max, ZETA_BOUNDS[0]])
    hi = np.array([20.0 * np.pi / dt, ZETA_BOUNDS[1]])

    def res(x):
        return (_model(steps, x[0], x[1]) - y) / scale

    best = (np.inf, None)
    for wn in np.geomspace(max(2 * lo[0], 1.0 / t_max), min(hi[0] / 2, 2 * np.pi / dt), 16):
        for zeta in (0.2, 0.4, 0.6, 0.8, 1.0, 1.4, 2.5):
            c = float(np.sum(res((wn, zeta)) ** 2))
            if c < best[0]:
                best = (c, np.array([wn, zeta]))
    sol = scipy.optimize.least_squares(res, best[1], bounds=(lo, hi), x_scale=best[1], xtol=1e-10, ftol=1e-10)
    r = sol.fun
    return _Candidate("second_order", sol.x, lo, hi, ("wn_rad_s", "zeta"), float(r @ r), sol.jac, r,
                      _model(steps, *sol.x), bool(sol.success), str(sol.message))


def _gate(c: _Candidate, y, noise: float | None) -> Gate:
    g = Gate()
    g.enough_points(len(y), 3 * len(c.x) + 2, "samples")
    for name, v in zip(c.names, c.x):
        g.physical(name, float(v), lo=0.0)
    g.within_bounds(c.x, c.lo, c.hi, c.names)
    se, cond = jacobian_se(c.jac, c.resid)
    g.identifiable(cond=cond, beta=c.x, se=se, names=c.names)
    rms = float(np.sqrt(np.mean((y - c.model) ** 2)))
    g.follows_data(nrmse_pct(y, c.model), NRMSE_LIMIT_PCT, rms=rms, noise=noise)
    return g


def fit_pressure_dynamics(steps: list[PressureStep], chamber: str = "", direction: str = "") -> PressureFit:
    """Fit the first- and second-order models over the steps of one chamber and direction; keep one.

    Parameters
    ----------
    steps : list of PressureStep
        Steps with a ``note`` (too small for the pressure sensor) are left out of the fit.
    chamber, direction : str
        Labels of the result (default: those of the first step).

    Returns
    -------
    PressureFit
        The model with the lower BIC among the fits that pass the quality gates (the second
        order by more than :data:`BIC_MARGIN`), its
        parameters, ``nrmse_pct`` over all the fitted steps' pressure (warehouse.md) and per
        step in ``step_nrmse_pct`` (each over its own range; NaN for a step not fitted). NaN
        parameters and a ``note`` when neither model passes or no step can be fitted.
    """
    chamber = chamber or (steps[0].chamber if steps else "")
    direction = direction or (steps[0].direction if steps else "")
    used = [s for s in steps if s.usable]
    nan_steps = [float("nan")] * len(steps)
    if not used:
        note = "no steps" if not steps else f"no step large enough for the pressure sensor ({steps[0].note})"
        return PressureFit(chamber, direction, n_steps=0, step_nrmse_pct=nan_steps, message=note, note=note)
    y = np.concatenate([s.p for s in used])
    scale = float(np.median([abs(s.p_ref_pa - s.p_start_pa) for s in used])) or 1.0
    dts = [float(np.median(np.diff(s.t))) for s in used if len(s.t) > 1]
    dt = min(dts) if dts else 1e-3
    t_max = max(float(s.t[-1]) + dt for s in used)
    noises = [s.noise_pa for s in used if np.isfinite(s.noise_pa)]
    noise = float(np.median(noises)) if noises else None
    stacked = _Stacked.of(used)
    cands = [_fit_first(stacked, y, scale, dt, t_max), _fit_second(stacked, y, scale, dt, t_max)]
    gates = {c.name: _gate(c, y, noise) for c in cands}
    fit = PressureFit(chamber, direction, n_steps=len(used), step_nrmse_pct=nan_steps,
                      bic={c.name: _bic(c.rss, len(y), len(c.x)) for c in cands})
    passing = [c for c in cands if gates[c.name].ok]
    if not passing:
        fit.note = "; ".join(f"{c.name.replace('_', ' ')}: {gates[c.name].note}" for c in cands)
        fit.message = fit.note
        return fit
    best = passing[0]
    if len(passing) == 2 and fit.bic["second_order"] < fit.bic["first_order"] - BIC_MARGIN:
        best = passing[1]
    fit.model = best.name
    if best.name == "first_order":
        fit.tau_s = float(best.x[0])
    else:
        fit.wn_rad_s, fit.zeta = map(float, best.x)
    fit.nrmse_pct = nrmse_pct(y, best.model)
    fit.step_nrmse_pct = [nrmse_pct(s.p, fit.predict(s)) if s.usable else float("nan") for s in steps]
    fit.message = "" if best.success else f"least_squares: {best.message}"
    return fit


def plot_pressure_steps(steps: list[PressureStep], fits: dict, window_s: float | None = None, title: str = ""):
    """Measured vs model pressure of every step, charge and discharge (like Fig. 14 of seed 001).

    Pressures are drawn gauge, in bar, as the warehouse stores them (``pressure_steps.p_from_bar``).

    Parameters
    ----------
    steps : list of PressureStep
        Steps of one chamber.
    fits : dict of str to PressureFit
        Keyed by direction.
    window_s : float, optional
        Time shown after each step; default ten time constants of the slower fit. [s]
    title : str

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4.5))
    axes = dict(zip(("charge", "discharge"), fig.subplots(1, 2)))
    if window_s is None:
        rates = [f.rate() for f in fits.values() if f.ok]
        window_s = 10.0 / min(rates) if rates else None
    for direction, ax in axes.items():
        fit = fits.get(direction)
        group = [s for s in steps if s.direction == direction]
        for i, s in enumerate(group):
            m = s.t <= window_s if window_s else slice(None)
            ax.plot(s.t[m] * 1e3, s.p[m] / 1e5, color="0.25" if s.usable else "0.7", lw=0.9,
                    marker="." if len(s.t[m]) < 60 else None, ms=3,
                    label="experimental" if i == 0 else None)
            if fit is not None and fit.ok and s.usable:
                ax.plot(s.t[m] * 1e3, fit.predict(s)[m] / 1e5, color="tab:red", ls="--", lw=1.0,
                        label="model" if i == 0 else None)
        head = f"{direction}"
        if fit is not None and fit.model == "second_order":
            head += (f": 2nd order, wn={fit.wn_rad_s:.1f} rad/s, xi={fit.zeta:.3f}, "
                     f"NRMSE {fit.nrmse_pct:.2f} % ({fit.n_steps} steps)")
        elif fit is not None and fit.model == "first_order":
            head += f": 1st order, tau={fit.tau_s * 1e3:.1f} ms, NRMSE {fit.nrmse_pct:.2f} % ({fit.n_steps} steps)"
        elif fit is not None and fit.note:
            head += f": no model ({fit.note[:60]})"
        ax.set_title(head, fontsize=9)
        ax.set_xlabel("time since the step [ms]")
        ax.set_ylabel("pressure [bar gauge]")
        ax.grid(alpha=0.3)
        if group:
            ax.legend(fontsize=8)
    chamber = steps[0].chamber if steps else ""
    fig.suptitle(title or f"PLA {chamber} chamber: pressure after set-point steps, experiment vs the chosen model "
                          "(first order or Eq. 11)")
    fig.tight_layout()
    return fig
