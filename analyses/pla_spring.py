"""PLA as a pneumatic spring: polytropic chamber plus Coulomb and structural damping (seed 001).

A closed pressurised chamber (``rear`` or ``front``) under a harmonic rod displacement
``d = D sin(2 pi f t)`` (+ = extension), stroke ``C`` (test at mid-stroke). physics.md, Eqs. 3-9:

    P = P0 ((C/2) / (C/2 + s d))^n                       s = +1 rear, -1 front
    F = (P - Pa) Ae + s_f [sign(d') eps (P - Pa) + delta d' / (2 pi f)]
                                                          s_f = -1 rear, +1 front

``P`` and ``P0`` are absolute, ``Pa`` ambient. The dissipative terms always widen the loop with the
upper branch on compression. ``P0`` is read from each run (the pressure at mid-stroke, ``d = 0``).

The chamber's parameters fitted over all its runs are in :mod:`analyses.pla_spring_fit`, the
paper's figures in :mod:`analyses.pla_spring_plots`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from analyses.numerics import savgol_derivative
from analyses.quality import Sensor, describe_sensor
from schemas.papers import PLA_NRMSE_LIMIT_PCT

__all__ = ["P_ATM_PA", "PRESSURE_SIGN", "FORCE_SIGN", "spring_pressure", "spring_force", "read_p0",
           "rod_velocity", "loop_energy", "cycle_span", "SpringRun", "prepare_spring_run", "NRMSE_LIMIT_PCT", "PARAM_BOUNDS"]

#: The model's stated limit: NRMSE below it on every test (:data:`schemas.papers.PLA_NRMSE_LIMIT_PCT`). [%]
NRMSE_LIMIT_PCT = PLA_NRMSE_LIMIT_PCT
#: Optimiser bounds of (n, Ae [m2], eps [m2], delta [N/m]).
PARAM_BOUNDS = ((0.5, 1e-6, 0.0, 0.0), (2.5, 1.0, 1e-2, 1e7))
#: A run moves when its displacement range exceeds this many times the displacement sensor's floor. [-]
MOTION_N_FLOOR = 10.0

P_ATM_PA = 101325.0
#: ``s`` of the polytropic pressure: +1 rear (extension enlarges it), -1 front.
PRESSURE_SIGN = {"rear": 1.0, "front": -1.0}
#: ``s_f`` of the dissipative terms: -1 rear, +1 front.
FORCE_SIGN = {"rear": -1.0, "front": 1.0}


def _chamber(chamber: str) -> str:
    c = str(chamber).strip().lower()
    if c not in PRESSURE_SIGN:
        raise ValueError(f"chamber must be 'front' or 'rear', got {chamber!r}")
    return c


def spring_pressure(d, p0_abs, n: float, chamber: str, stroke_m: float = 0.040):
    """Polytropic chamber pressure, Eqs. 3-5.

    Parameters
    ----------
    d : array_like
        Rod displacement from mid-stroke (+ = extension). [m]
    p0_abs : float or array_like
        Absolute pressure at mid-stroke. [Pa]
    n : float
        Polytropic index. [-]
    chamber : {'rear', 'front'}
    stroke_m : float
        Stroke ``C``. [m]

    Returns
    -------
    ndarray
        Absolute chamber pressure. [Pa]
    """
    s = PRESSURE_SIGN[_chamber(chamber)]
    half = 0.5 * stroke_m
    return np.asarray(p0_abs) * (half / (half + s * np.asarray(d, float))) ** n


def spring_force(d, d_dot, p0_abs, frequency_hz, n: float, ae: float, eps: float, delta: float, chamber: str,
                 stroke_m: float = 0.040, p_atm: float = P_ATM_PA):
    """Force of the PLA as a pneumatic spring, Eq. 9 with the signs of physics.md.

    Parameters
    ----------
    d : array_like
        Rod displacement (+ = extension). [m]
    d_dot : array_like
        Rod velocity. [m/s]
    p0_abs : float or array_like
        Absolute pressure at mid-stroke. [Pa]
    frequency_hz : float or array_like
        Excitation frequency ``f``. [Hz]
    n : float
        Polytropic index. [-]
    ae : float
        Effective area. [m2]
    eps : float
        Coulomb friction parameter. [m2]
    delta : float
        Structural damping parameter. [N/m]
    chamber : {'rear', 'front'}
    stroke_m : float
        Stroke. [m]
    p_atm : float
        Ambient pressure. [Pa]

    Returns
    -------
    ndarray
        Force. [N]
    """
    sf = FORCE_SIGN[_chamber(chamber)]
    pg = spring_pressure(d, p0_abs, n, chamber, stroke_m) - p_atm
    v = np.asarray(d_dot, float)
    return pg * ae + sf * (np.sign(v) * eps * pg + delta * v / (2 * np.pi * np.asarray(frequency_hz)))


def _zero_crossings(d):
    """Fractional indices where ``d`` crosses zero, and the direction (+1 up, -1 down)."""
    d = np.asarray(d, float)
    s = np.signbit(d)
    i = np.flatnonzero(s[:-1] != s[1:])
    frac = d[i] / (d[i] - d[i + 1])
    return i + frac, np.where(d[i + 1] > d[i], 1.0, -1.0)


def read_p0(d, p_gauge, p_atm: float = P_ATM_PA) -> float:
    """Absolute pressure at mid-stroke: the measured pressure where ``d`` crosses zero.

    Parameters
    ----------
    d : array_like
        Rod displacement. [m]
    p_gauge : array_like
        Measured chamber pressure, gauge. [Pa]
    p_atm : float
        Ambient pressure of the run. [Pa]

    Returns
    -------
    float
        Pressure at ``d = 0`` plus ``p_atm``: the intercept of a quadratic in ``d`` fitted to the
        samples within 20 % of the amplitude around mid-stroke (every pass through mid-stroke
        contributes, which averages the sensor noise), or the median of the pressure interpolated
        at the zero crossings when there are too few such samples; NaN if ``d`` never crosses
        zero. [Pa]
    """
    d = np.asarray(d, float)
    p = np.asarray(p_gauge, float)
    idx, _ = _zero_crossings(d)
    if len(idx) == 0:
        return float("nan")
    near = np.abs(d) <= 0.2 * np.max(np.abs(d))
    if np.count_nonzero(near) >= 20 and np.ptp(d[near]) > 0:
        return float(np.polynomial.polynomial.polyfit(d[near], p[near], 2)[0] + p_atm)
    return float(np.median(np.interp(idx, np.arange(len(p)), p)) + p_atm)


def rod_velocity(t, d, frequency_hz: float | None = None):
    """Rod velocity by a Savitzky-Golay derivative (cubic, about 1/20 of a period wide).

    Parameters
    ----------
    t : array_like
        Time, uniform. [s]
    d : array_like
        Displacement. [m]
    frequency_hz : float, optional
        Excitation frequency; sets the window. [Hz]

    Returns
    -------
    ndarray
        Velocity. [m/s]
    """
    t = np.asarray(t, float)
    d = np.asarray(d, float)
    dt = float(np.median(np.diff(t)))
    if frequency_hz and np.isfinite(frequency_hz) and frequency_hz > 0:
        w = int(round(1.0 / (20 * frequency_hz * dt)))
    else:
        w = 11
    w = max(5, w | 1)
    if len(d) <= w:
        return np.gradient(d, t)
    return savgol_derivative(d, w, dt)


def loop_energy(d, f, chamber: str) -> tuple[float, int]:
    """Energy dissipated per cycle: the area of the force-displacement loop.

    Over the whole cycles between the first and the last zero crossing of ``d`` in one direction
    (upward or downward, whichever spans more cycles): ``s_f * (closed integral of F dd) / cycles``
    (positive when the loop is traversed as the model says, upper branch on compression).

    Parameters
    ----------
    d : array_like
        Displacement. [m]
    f : array_like
        Force. [N]
    chamber : {'rear', 'front'}

    Returns
    -------
    (float, int)
        Energy per cycle [J] (NaN without a whole cycle) and the number of cycles.
    """
    sf = FORCE_SIGN[_chamber(chamber)]
    span = cycle_span(d)
    if span is None:
        return float("nan"), 0
    a, b, cycles = span
    d = np.asarray(d, float)[a:b + 1]
    f = np.asarray(f, float)[a:b + 1]
    work = float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(d)))
    return sf * work / cycles, cycles


def cycle_span(d):
    """(first index, last index, cycles) of the whole cycles of ``d``, or None without one."""
    idx, direction = _zero_crossings(d)
    best = None
    for sense in (1.0, -1.0):
        at = np.ceil(idx[direction == sense]).astype(int)
        if len(at) >= 2 and (best is None or len(at) - 1 > best[2]):
            best = (int(at[0]), int(at[-1]), len(at) - 1)
    return best


@dataclass
class SpringRun:
    """A spring run ready for fitting (SI)."""

    run_id: str
    chamber: str
    p0_abs: float
    amplitude_m: float
    frequency_hz: float
    t: np.ndarray
    d: np.ndarray
    v: np.ndarray
    f: np.ndarray
    p_gauge: np.ndarray
    stroke_m: float = 0.040
    p_atm: float = P_ATM_PA
    static_force_n: float = float("nan")
    loop_energy_j: float = float("nan")
    cycles: int = 0
    message: str = ""
    f_noise_n: float = float("nan")

    @property
    def ok(self) -> bool:
        return not self.message


def prepare_spring_run(run_id: str, t, d, f, p_gauge, chamber: str, frequency_hz: float | None = None,
                       amplitude_m: float | None = None, stroke_m: float = 0.040,
                       p_atm: float = P_ATM_PA, d_sensor: Sensor | None = None,
                       f_sensor: Sensor | None = None) -> SpringRun:
    """Read P0, velocity, static force and loop energy of one run.

    Parameters
    ----------
    run_id : str
    t : array_like
        Time. [s]
    d : array_like
        Rod displacement. [m]
    f : array_like
        Force. [N]
    p_gauge : array_like
        Chamber pressure, gauge. [Pa]
    chamber : {'rear', 'front'}
    frequency_hz : float, optional
        Excitation frequency (metadata); estimated from the zero crossings when missing. [Hz]
    amplitude_m : float, optional
        Displacement amplitude (metadata); half the peak-to-peak of ``d`` when missing. [m]
    stroke_m : float
        Stroke. [m]
    p_atm : float
        Ambient pressure. [Pa]
    d_sensor, f_sensor : Sensor, optional
        Resolution and noise of ``d`` and ``f`` (run metadata); estimated from the records when
        absent. The rod moves when ``d`` spans more than ``MOTION_N_FLOOR`` times its floor; the
        force noise is kept for the fit's noise-level test.

    Returns
    -------
    SpringRun
        ``message`` is non-empty when the run cannot be used (too short, no motion, no whole
        cycle).
    """
    chamber = _chamber(chamber)
    arrays = [np.asarray(a, float) for a in (t, d, f, p_gauge)]
    t, d, f, p = arrays
    keep = np.all([np.isfinite(a) for a in arrays], axis=0)
    t, d, f, p = t[keep], d[keep], f[keep], p[keep]
    nan = float("nan")
    empty = SpringRun(run_id, chamber, nan, amplitude_m or nan, frequency_hz or nan, t, d, np.zeros_like(d), f, p,
                      stroke_m, p_atm)
    if len(t) < 20:
        empty.message = f"too short ({len(t)} samples)"
        return empty
    d_floor = (d_sensor or describe_sensor(d)).floor()
    empty.f_noise_n = float((f_sensor or describe_sensor(f)).noise) if len(f) else nan
    if not np.ptp(d) > MOTION_N_FLOOR * d_floor:
        empty.message = "no displacement"
        return empty
    idx, direction = _zero_crossings(d)
    if len(idx) < 2:
        empty.message = "the displacement does not pass mid-stroke both ways"
        return empty
    if not frequency_hz or not np.isfinite(frequency_hz):
        # crossings are half a period apart
        tc = np.interp(idx, np.arange(len(t)), t)
        frequency_hz = float((len(idx) - 1) / (2 * (tc[-1] - tc[0])))
    if not amplitude_m or not np.isfinite(amplitude_m):
        amplitude_m = 0.5 * float(np.ptp(d))
    p0 = read_p0(d, p, p_atm)
    v = rod_velocity(t, d, frequency_hz)
    fx = np.interp(idx, np.arange(len(f)), f)
    # at mid-stroke the dissipative terms flip with the direction: the mean of the upward and
    # downward crossings is the static force
    static = 0.5 * (np.mean(fx[direction > 0]) + np.mean(fx[direction < 0])) if (np.any(direction < 0) and np.any(direction > 0)) else nan
    energy, cycles = loop_energy(d, f, chamber)
    return SpringRun(run_id, chamber, p0, float(amplitude_m), float(frequency_hz), t, d, v, f, p, stroke_m, p_atm,
                     float(static), energy, cycles, f_noise_n=empty.f_noise_n)
