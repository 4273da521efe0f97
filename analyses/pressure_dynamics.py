"""PLA chamber pressure after set-point steps: a second-order response (seed 001, Eq. 11, Table 2).

physics.md's standard form (the seed's Eq. 11 also carries a ``-Pref'`` term, which for a step
would be an impulse; it is not used):

    P'' = -2 xi wn P' - wn^2 (P - Pref)

A pressure-step run logs the chamber pressure ``p`` and the set-point ``p_ref`` (gauge). Every
jump of ``p_ref`` starts a step lasting until the next jump; it is a *charge* when the set-point
rises and a *discharge* when it falls. Each step starts from the measured pressure just before
the jump with zero rate of change; ``wn`` and ``xi`` are fitted per chamber and direction over
all those steps at once (:func:`scipy.optimize.least_squares`, bounded, from a coarse grid seed).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy  # its submodules load on first use: a rebuild that reuses every stage never pays for them

__all__ = ["second_order_step", "PressureStep", "split_pressure_steps", "PressureFit", "fit_pressure_dynamics",
           "plot_pressure_steps"]


def second_order_step(t, p_start, p_ref, wn: float, zeta: float):
    """Response of ``P'' = -2 zeta wn P' - wn^2 (P - Pref)`` to a constant ``Pref``.

    Parameters
    ----------
    t : array_like
        Time since the step (>= 0). [s]
    p_start : float
        Pressure at the step, with zero rate of change. [Pa]
    p_ref : float
        Set-point after the step. [Pa]
    wn : float
        Natural frequency. [rad/s]
    zeta : float
        Damping ratio (any positive value; 1 is handled without loss of precision). [-]

    Returns
    -------
    ndarray
        Pressure. [Pa]
    """
    t = np.maximum(np.asarray(t, float), 0.0)
    a = zeta * wn
    disc = zeta * zeta - 1.0
    wd = wn * np.sqrt(abs(disc))
    x = wd * t
    if disc < 0:       # under-damped: cos(wd t) + a sin(wd t) / wd
        h = np.cos(x) + a * t * np.sinc(x / np.pi)
    else:              # over-damped / critical: e^(-a t) (cosh(x) + a t sinh(x) / x), x = wd t
        up, down = np.exp(x - a * t), np.exp(-x - a * t)   # x <= a t: no overflow
        small = x < 1e-6
        shx = np.where(small, np.exp(-a * t), (up - down) / (2 * np.where(small, 1.0, x)))
        h = 0.5 * (up + down) + a * t * shx
        return p_ref + (p_start - p_ref) * h
    return p_ref + (p_start - p_ref) * np.exp(-a * t) * h


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


def split_pressure_steps(t, p, p_ref, run_id: str = "", chamber: str = "", min_step_pa: float = 5000.0,
                         min_points: int = 10, pre_samples: int = 10) -> list[PressureStep]:
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
    min_step_pa : float
        Smallest set-point jump that counts as a step. [Pa]
    min_points : int
        Fewest samples a step needs.
    pre_samples : int
        Samples before the jump averaged for the starting pressure.

    Returns
    -------
    list of PressureStep
    """
    t = np.asarray(t, float)
    p = np.asarray(p, float)
    r = np.asarray(p_ref, float)
    if len(t) < 2:
        return []
    jumps = np.flatnonzero(np.abs(np.diff(r)) > min_step_pa) + 1
    bounds = list(jumps) + [len(r)]
    out = []
    for j, i0 in enumerate(jumps):
        i1 = bounds[j + 1]
        if i1 - i0 < min_points:
            continue
        before, after = float(r[i0 - 1]), float(np.median(r[i0:i1]))
        if abs(after - before) <= min_step_pa:
            continue
        lo = max(bounds[j - 1] if j > 0 else 0, i0 - pre_samples)
        p_start = float(np.mean(p[lo:i0]))
        out.append(PressureStep(run_id, chamber, "charge" if after > before else "discharge", float(t[i0]),
                                before, after, p_start, t[i0:i1] - t[i0], p[i0:i1]))
    return out


@dataclass
class PressureFit:
    """Second-order fit of one (chamber, direction)."""

    chamber: str
    direction: str
    wn_rad_s: float = float("nan")
    zeta: float = float("nan")
    nrmse_pct: float = float("nan")
    n_steps: int = 0
    step_nrmse_pct: list = field(default_factory=list)
    message: str = ""

    @property
    def ok(self) -> bool:
        return bool(np.isfinite(self.wn_rad_s))


def _model(steps, wn, zeta):
    return np.concatenate([second_order_step(s.t, s.p_start_pa, s.p_ref_pa, wn, zeta) for s in steps])


def fit_pressure_dynamics(steps: list[PressureStep], chamber: str = "", direction: str = "") -> PressureFit:
    """Fit ``wn`` and ``xi`` of Eq. 11 over steps of one chamber and direction.

    Parameters
    ----------
    steps : list of PressureStep
    chamber, direction : str
        Labels of the result (default: those of the first step).

    Returns
    -------
    PressureFit
        ``nrmse_pct`` over all the steps' pressure (warehouse.md), and per step in
        ``step_nrmse_pct`` (each over its own range). NaN with ``message`` without steps.
    """
    chamber = chamber or (steps[0].chamber if steps else "")
    direction = direction or (steps[0].direction if steps else "")
    if not steps:
        return PressureFit(chamber, direction, message="no steps")
    y = np.concatenate([s.p for s in steps])
    scale = float(np.median([abs(s.p_ref_pa - s.p_start_pa) for s in steps])) or 1.0

    def res(x):
        return (_model(steps, x[0], x[1]) - y) / scale

    best = (np.inf, None)
    for wn in np.geomspace(2.0, 2000.0, 16):
        for zeta in (0.2, 0.4, 0.6, 0.8, 1.0, 1.4, 2.5):
            c = float(np.sum(res((wn, zeta)) ** 2))
            if c < best[0]:
                best = (c, np.array([wn, zeta]))
    sol = scipy.optimize.least_squares(res, best[1], bounds=([0.1, 0.02], [1e5, 50.0]), x_scale=best[1],
                                 xtol=1e-10, ftol=1e-10)
    wn, zeta = map(float, sol.x)
    model = _model(steps, wn, zeta)
    rng = float(np.ptp(y))
    nrmse = 100 * float(np.sqrt(np.mean((y - model) ** 2))) / rng if rng > 0 else float("nan")
    per = []
    for s in steps:
        m = second_order_step(s.t, s.p_start_pa, s.p_ref_pa, wn, zeta)
        r = float(np.ptp(s.p))
        per.append(100 * float(np.sqrt(np.mean((s.p - m) ** 2))) / r if r > 0 else float("nan"))
    return PressureFit(chamber, direction, wn, zeta, nrmse, len(steps), per,
                       "" if sol.success else f"least_squares: {sol.message}")


def plot_pressure_steps(steps: list[PressureStep], fits: dict, window_s: float | None = None, title: str = ""):
    """Measured vs model pressure of every step, charge and discharge (like Fig. 14 of seed 001).

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
        rates = [f.zeta * f.wn_rad_s for f in fits.values() if f.ok]
        window_s = 10.0 / min(rates) if rates else None
    for direction, ax in axes.items():
        fit = fits.get(direction)
        group = [s for s in steps if s.direction == direction]
        for i, s in enumerate(group):
            m = s.t <= window_s if window_s else slice(None)
            ax.plot(s.t[m] * 1e3, (s.p[m] + 101325) / 1e5, color="0.25", lw=0.9,
                    label="experimental" if i == 0 else None)
            if fit is not None and fit.ok:
                ax.plot(s.t[m] * 1e3, (second_order_step(s.t[m], s.p_start_pa, s.p_ref_pa, fit.wn_rad_s, fit.zeta)
                                       + 101325) / 1e5, color="tab:red", ls="--", lw=1.0,
                        label="model" if i == 0 else None)
        head = f"{direction}"
        if fit is not None and fit.ok:
            head += f": wn={fit.wn_rad_s:.1f} rad/s, xi={fit.zeta:.3f}, NRMSE {fit.nrmse_pct:.2f} % ({fit.n_steps} steps)"
        ax.set_title(head, fontsize=9)
        ax.set_xlabel("time since the step [ms]")
        ax.set_ylabel("pressure [bar abs] (at 101325 Pa ambient)")
        ax.grid(alpha=0.3)
        if group:
            ax.legend(fontsize=8)
    chamber = steps[0].chamber if steps else ""
    fig.suptitle(title or f"PLA {chamber} chamber: pressure steps, experiment vs second-order model (Eq. 11)")
    fig.tight_layout()
    return fig
