"""PLA bench generators (seed 001): spring (closed chamber, harmonic displacement), pressure steps.

Models and Table 1 / Table 2 values from ``docs/physics.md``.
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy.linalg import expm

from pipeline.simulator.base import P_ATM_PA, PRESSURE_RES_PA, SimRun, make_rng, pressure_sensor, quantise, time_vector

#: Table 1 of the paper, per chamber: polytropic index n [-], effective area Ae [m2],
#: eps [m2], delta [N/m].
TABLE1 = {
    "front": {"n": 1.123, "ae_m2": 1.541e-3, "eps_m2": 2.143e-5, "delta_n_m": 3.509e3},
    "rear": {"n": 1.063, "ae_m2": 1.795e-3, "eps_m2": 2.136e-5, "delta_n_m": 2.963e3},
}
#: Sign of d in the chamber volume (s) and of the dissipative terms (s_f).
CHAMBER_SIGNS = {"rear": (1.0, -1.0), "front": (-1.0, 1.0)}
#: Test matrix (paper): amplitudes [mm], frequencies [Hz], initial pressures [bar abs].
AMPLITUDES_MM = (3.0, 5.0, 7.0)
FREQUENCIES_HZ = (0.5, 1.0, 1.5, 2.0, 4.0)
P0_BAR_ABS = (2.0, 3.0, 4.0, 5.0)
#: Stroke of the cylinder. [mm]
STROKE_MM = 40.0
#: Pressure dynamics (Table 2): natural frequency [rad/s] and damping per direction.
PRESSURE_WN = 52.0
PRESSURE_XI = {"charge": 1.00, "discharge": 0.69}


def chamber_pressure(d_m, p0_pa_abs: float, n: float, s: float, stroke_m: float = STROKE_MM / 1e3):
    """Polytropic chamber ``P = P0 ((C/2) / (C/2 + s d))^n``. [Pa abs]"""
    half = stroke_m / 2.0
    return p0_pa_abs * (half / (half + s * np.asarray(d_m, dtype=float))) ** n


def spring_force(p_pa_abs, d_dot_m_s, frequency_hz: float, ae_m2: float, eps_m2: float, delta_n_m: float,
                 s_f: float, p_atm_pa: float = P_ATM_PA):
    """``F = (P - Pa) Ae + s_f [sign(d') eps (P - Pa) + delta d' / (2 pi f)]``. [N]"""
    gauge = np.asarray(p_pa_abs, dtype=float) - p_atm_pa
    dd = np.asarray(d_dot_m_s, dtype=float)
    return gauge * ae_m2 + s_f * (np.sign(dd) * eps_m2 * gauge + delta_n_m * dd / (2 * math.pi * frequency_hz))


def simulate_spring(chamber: str = "rear", p0_bar_abs: float = 3.0, amplitude_mm: float = 5.0,
                    frequency_hz: float = 1.0, rng=None, *, cycles: float = 3.0, fs_hz: float = 1000.0,
                    params: dict | None = None, force_noise_n: float = 2.0, pressure_noise_pa: float = 300.0,
                    displacement_noise_m: float = 1e-6, **metadata) -> SimRun:
    """Spring test: closed chamber at ``P0``, rod driven ``d = D sin(2 pi f t)`` for ``cycles``.

    Load cell noise ``force_noise_n`` (logged at 0.01 N), pressure noise (1 Pa), LVDT noise
    ``displacement_noise_m`` (logged at 1 um).
    """
    rng = make_rng(rng)
    par = dict(TABLE1[chamber], **(params or {}))
    s, s_f = CHAMBER_SIGNS[chamber]
    amp = amplitude_mm / 1e3
    p0 = p0_bar_abs * 1e5
    n_samples = int(round(cycles / frequency_hz * fs_hz)) + 1
    t = time_vector(n_samples, fs_hz)
    w = 2 * math.pi * frequency_hz
    d = amp * np.sin(w * t)
    d_dot = amp * w * np.cos(w * t)
    p_abs = chamber_pressure(d, p0, par["n"], s)
    force = spring_force(p_abs, d_dot, frequency_hz, par["ae_m2"], par["eps_m2"], par["delta_n_m"], s_f)
    data = pd.DataFrame({
        "t_s": t,
        "d_m": quantise(d + rng.normal(0.0, displacement_noise_m, n_samples), 1e-6),
        "f_n": quantise(force + rng.normal(0.0, force_noise_n, n_samples), 1e-2),
        "p_pa": pressure_sensor(p_abs - P_ATM_PA, rng, pressure_noise_pa),
    })
    meta = {"kind": "spring", "rig": "pla-1", "chamber": chamber, "amplitude_mm": float(amplitude_mm),
            "frequency_hz": float(frequency_hz), "stroke_mm": STROKE_MM, "p0_bar_abs": float(p0_bar_abs),
            **metadata}
    truth = {"kind": "spring", "chamber": chamber, "n": par["n"], "Ae": par["ae_m2"], "eps": par["eps_m2"],
             "delta": par["delta_n_m"], "P0": p0, "p0_bar_abs": float(p0_bar_abs), "Pa": P_ATM_PA,
             "D": amp, "amplitude_mm": float(amplitude_mm), "frequency_hz": float(frequency_hz), "s": s,
             "s_f": s_f, "stroke_m": STROKE_MM / 1e3, "cycles": cycles, "fs_hz": fs_hz,
             "force_noise_n": force_noise_n, "pressure_noise_pa": pressure_noise_pa,
             "force_range_n": float(force.max() - force.min())}
    return SimRun(data, meta, truth)


#: Default set-point sequence of a pressure-step run. [bar gauge]
PRESSURE_STEPS_BAR = (1.0, 3.0, 1.0, 4.0, 2.0, 5.0, 3.0)


def simulate_pressure_step(chamber: str = "rear", rng=None, *, levels_bar=PRESSURE_STEPS_BAR, hold_s: float = 1.0,
                           fs_hz: float = 1000.0, wn: float = PRESSURE_WN, xi: dict | None = None,
                           noise_pa: float = 300.0, tau_s: float | dict | None = None, ref_noise_pa: float = 0.0,
                           **metadata) -> SimRun:
    """Pressure steps: ``P'' = -2 xi wn P' - wn^2 (P - Pref)``, xi by charge / discharge.

    The first level is the initial steady state; every later level is a step of ``p_ref``
    held for ``hold_s``. Solved exactly (matrix exponential) between set-point changes.

    Optional (defaults keep the demo's bytes): ``tau_s`` (a time constant [s], or one per
    direction ``{"charge": .., "discharge": ..}``) makes the response first order,
    ``tau P' = Pref - P``, as a pressure loop under closed-loop control answers set-point steps;
    ``ref_noise_pa`` adds Gaussian noise to the logged set-point (a read-back signal).
    A closed-loop set-point sweep is ``levels_bar`` with small steps (e.g. 0.05 and 0.1 bar)
    at ``fs_hz = 20``.
    """
    rng = make_rng(rng)
    if tau_s is not None:
        return _first_order_pressure_steps(chamber, rng, levels_bar, hold_s, fs_hz, tau_s, noise_pa, ref_noise_pa,
                                           metadata)
    xi = dict(PRESSURE_XI if xi is None else xi)
    levels = [lv * 1e5 for lv in levels_bar]
    n_per = int(round(hold_s * fs_hz))
    n = n_per * len(levels)
    t = time_vector(n, fs_hz)
    dt = 1.0 / fs_hz
    p = np.empty(n)
    ref = np.empty(n)
    state = np.array([0.0, 0.0])  # [P - Pref, P']
    steps = []
    prev = levels[0]
    for i, level in enumerate(levels):
        sl = slice(i * n_per, (i + 1) * n_per)
        direction = "charge" if level >= prev else "discharge"
        z = xi[direction]
        a = np.array([[0.0, 1.0], [-wn * wn, -2 * z * wn]])
        phi = expm(a * dt)
        state = np.array([prev + state[0] - level, state[1]])  # same P, new reference
        seg = np.empty((n_per, 2))
        for k in range(n_per):
            seg[k] = state
            state = phi @ state
        p[sl] = seg[:, 0] + level
        ref[sl] = level
        state = np.array([state[0], state[1]])
        if i > 0:
            steps.append({"t_step_s": float(t[sl][0]), "p_from_pa": prev, "p_to_pa": level,
                          "direction": direction, "wn_rad_s": wn, "xi": z})
        prev = level
    data = pd.DataFrame({"t_s": t, "p_pa": pressure_sensor(p, rng, noise_pa), "p_ref_pa": ref})
    meta = {"kind": "pressure_step", "rig": "pla-1", "chamber": chamber, **metadata}
    truth = {"kind": "pressure_step", "chamber": chamber, "wn_rad_s": wn, "xi_charge": xi["charge"],
             "xi_discharge": xi["discharge"], "noise_pa": noise_pa, "fs_hz": fs_hz, "hold_s": hold_s,
             "steps": steps}
    return SimRun(data, meta, truth)


def _first_order_pressure_steps(chamber, rng, levels_bar, hold_s, fs_hz, tau_s, noise_pa, ref_noise_pa, metadata):
    """First-order response ``tau P' = Pref - P`` to the set-point levels (exact between steps)."""
    taus = dict(tau_s) if isinstance(tau_s, dict) else {"charge": float(tau_s), "discharge": float(tau_s)}
    levels = [lv * 1e5 for lv in levels_bar]
    n_per = int(round(hold_s * fs_hz))
    n = n_per * len(levels)
    t = time_vector(n, fs_hz)
    p = np.empty(n)
    ref = np.empty(n)
    steps = []
    prev, value = levels[0], levels[0]
    tk = np.arange(n_per) / fs_hz
    for i, level in enumerate(levels):
        sl = slice(i * n_per, (i + 1) * n_per)
        direction = "charge" if level >= prev else "discharge"
        tau = taus[direction]
        p[sl] = level + (value - level) * np.exp(-tk / tau)
        ref[sl] = level
        if i > 0:
            steps.append({"t_step_s": float(t[sl][0]), "p_from_pa": prev, "p_to_pa": level,
                          "direction": direction, "tau_s": tau})
        value = level + (value - level) * np.exp(-n_per / fs_hz / tau)
        prev = level
    p_ref = ref + rng.normal(0.0, ref_noise_pa, n) if ref_noise_pa > 0 else ref
    data = pd.DataFrame({"t_s": t, "p_pa": pressure_sensor(p, rng, noise_pa),
                         "p_ref_pa": quantise(p_ref, PRESSURE_RES_PA) if ref_noise_pa > 0 else p_ref})
    meta = {"kind": "pressure_step", "rig": "pla-1", "chamber": chamber, **metadata}
    truth = {"kind": "pressure_step", "chamber": chamber, "model": "first_order", "tau_charge_s": taus["charge"],
             "tau_discharge_s": taus["discharge"], "noise_pa": noise_pa, "ref_noise_pa": ref_noise_pa,
             "fs_hz": fs_hz, "hold_s": hold_s, "steps": steps}
    return SimRun(data, meta, truth)
