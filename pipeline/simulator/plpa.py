"""PLPA bench generators (seed 000): leakage, breakaway, viscous, identification, step.

Models, defaults and sign conventions are those of ``docs/physics.md``; every function
returns a :class:`~pipeline.simulator.base.SimRun` (see the package docstring for truth keys).
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy import signal

from pipeline.simulator.base import (ENCODER_M, HOSE_AREA_M2, MOVING_MASS_KG, SimRun, encoder,
                                     first_order_steps, l_min_anr_to_kg_s, make_rng, pressure_sensor,
                                     quantise, time_vector)

def position_sensor(x_m, rng: np.random.Generator, resolution_m: float = ENCODER_M, noise_m: float = 0.0):
    """Position reading: Gaussian noise ``noise_m`` (an analog sensor), then quantised to
    ``resolution_m`` (0: not quantised). The defaults are the bench's encoder. [m]

    Draws from ``rng`` only when ``noise_m > 0``, so the default reading uses no random numbers.
    """
    x = np.asarray(x_m, dtype=float)
    if noise_m == 0.0 and resolution_m == ENCODER_M:
        return encoder(x)
    if noise_m > 0:
        x = x + rng.normal(0.0, noise_m, x.shape)
    return quantise(x, resolution_m) if resolution_m > 0 else x + 0.0


# -- leakage -----------------------------------------------------------------------------------
#: Leak coefficient per chamber. [l/min/bar^1.5]
LEAK_C = {"A": 2.0, "B": 2.4}
#: Maximum roller spring force. [N]
SPRING_FORCE_MAX_N = 1300.0
#: The paper's force settings (33 %, 66 %, 100 % of 1300 N). [N]
FORCE_SETTINGS_N = (429.0, 858.0, 1300.0)
#: The paper's distance settings. [mm]
DISTANCE_SETTINGS_MM = (3.0, 3.5, 4.0, 4.5, 5.0, 5.5, 6.0)
#: Leakage plateaus. [bar gauge]
LEAK_PLATEAUS_BAR = (0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0)


def seal_pressure_bar(adjustment: str, z_rollers_mm: float | None = None,
                      spring_force_n: float | None = None) -> float:
    """Pressure below which the rollers seal (physics.md). [bar gauge]

    distance: ``7.5 - 1.5 (z - 3)``; force: ``2.0 + 9.7 F / 1300``.
    """
    if adjustment == "distance":
        return 7.5 - 1.5 * (float(z_rollers_mm) - 3.0)
    if adjustment == "force":
        return 2.0 + 9.7 * float(spring_force_n) / SPRING_FORCE_MAX_N
    raise ValueError(f"adjustment must be 'distance' or 'force', got {adjustment!r}")


def leak_flow_l_min(p_bar, p_seal_bar: float, c: float):
    """Leak model ``q = c (p - p_seal)^1.5`` above ``p_seal``, else 0. [l/min ANR]"""
    excess = np.maximum(np.asarray(p_bar, dtype=float) - p_seal_bar, 0.0)
    return c * excess ** 1.5


def simulate_leakage(chamber: str = "A", adjustment: str = "distance", z_rollers_mm: float | None = 4.0,
                     spring_force_n: float | None = None, rng=None, *, pressures_bar=LEAK_PLATEAUS_BAR,
                     plateau_s: float = 6.0, fs_hz: float = 100.0, tau_s: float = 0.3,
                     p_seal_bar: float | None = None, c: float | None = None,
                     flow_noise_l_min: float = 0.02, flow_noise_rel: float = 0.01,
                     hose_id: str | None = None, **metadata) -> SimRun:
    """Leakage run: one chamber pressurised in plateaus, carriage blocked, the other open.

    The supply pressure follows each set-point with a first-order valve transient
    (time constant ``tau_s``); the leak follows the pressure through the seal model.

    Parameters
    ----------
    chamber : {"A", "B"}
    adjustment : {"distance", "force"}
    z_rollers_mm : float
        Roller distance (distance adjustment). [mm]
    spring_force_n : float
        Roller spring force (force adjustment). [N]
    rng : numpy.random.Generator or int, optional
    pressures_bar : sequence of float
        Plateau set-points. [bar gauge]
    plateau_s : float
        Duration of each plateau. [s]
    p_seal_bar, c : float, optional
        Override the seal pressure [bar] and leak coefficient [l/min/bar^1.5] (worn hoses).
    """
    rng = make_rng(rng)
    if adjustment == "force":
        z_rollers_mm = None
        if spring_force_n is None:
            spring_force_n = FORCE_SETTINGS_N[0]
    else:
        spring_force_n = None
    p_seal = seal_pressure_bar(adjustment, z_rollers_mm, spring_force_n) if p_seal_bar is None else float(p_seal_bar)
    c = LEAK_C[chamber] if c is None else float(c)
    n = int(round(len(pressures_bar) * plateau_s * fs_hz))
    t = time_vector(n, fs_hz)
    starts = [i * plateau_s for i in range(len(pressures_bar))]
    p_true_bar = first_order_steps(t, starts, list(pressures_bar), 0.0, tau_s)
    q_true = leak_flow_l_min(p_true_bar, p_seal, c)
    q_meas = q_true + rng.normal(0.0, 1.0, n) * (flow_noise_l_min + flow_noise_rel * q_true)
    q_meas = quantise(q_meas, 1e-3)  # flow meter logs 0.001 l/min
    data = pd.DataFrame({
        "t_s": t,
        "p_supply_pa": pressure_sensor(p_true_bar * 1e5, rng),
        "q_leak_kg_s": l_min_anr_to_kg_s(q_meas),
    })
    plateaus = []
    for i, p in enumerate(pressures_bar):
        t0, t1 = starts[i], starts[i] + plateau_s
        p_end = float(first_order_steps(np.array([t1 - 1e-9]), starts, list(pressures_bar), 0.0, tau_s)[0])
        plateaus.append({"pressure_bar": float(p), "leak_l_min": float(leak_flow_l_min(p, p_seal, c)),
                         "t_start_s": t0, "t_end_s": t1, "t_settled_s": t0 + 5 * tau_s,
                         "pressure_end_bar": p_end})
    meta = {"kind": "leakage", "rig": "plpa-1", "chamber": chamber, "adjustment": adjustment,
            "hose_area_m2": HOSE_AREA_M2}
    if z_rollers_mm is not None:
        meta["z_rollers_mm"] = float(z_rollers_mm)
    if spring_force_n is not None:
        meta["spring_force_n"] = float(spring_force_n)
    if hose_id is not None:
        meta["hose_id"] = hose_id
    meta.update(metadata)
    truth = {"kind": "leakage", "chamber": chamber, "adjustment": adjustment, "z_rollers_mm": z_rollers_mm,
             "spring_force_n": spring_force_n, "p_seal_bar": p_seal, "c": c, "tau_s": tau_s,
             "plateau_s": plateau_s, "fs_hz": fs_hz, "flow_noise_l_min": flow_noise_l_min,
             "flow_noise_rel": flow_noise_rel, "hose_id": hose_id, "plateaus": plateaus}
    return SimRun(data, meta, truth)


# -- friction ----------------------------------------------------------------------------------
#: Tanh velocity scale of the friction model. [m/s]
VS_M_S = 0.5e-3


def viscous_parameters(backpressure_bar: float) -> tuple[float, float, float]:
    """Friction parameters (Fc [N], ka [N s/m], vs [m/s]) at a backpressure (physics.md)."""
    if backpressure_bar < 0.5:
        return 3.0, 25.0, VS_M_S
    return 3.5, 28.0, VS_M_S


def friction_force(v_m_s, fc_n: float, ka_n_s_m: float, vs_m_s: float = VS_M_S):
    """``F(v) = Fc tanh(v / vs) + ka v``. [N]"""
    v = np.asarray(v_m_s, dtype=float)
    return fc_n * np.tanh(v / vs_m_s) + ka_n_s_m * v


def breakaway_mean_n(backpressure_bar: float) -> float:
    """Mean breakaway force: 10 N at 0 bar, 5 N at >= 1 bar (linear in between). [N]"""
    return 10.0 - 5.0 * min(max(float(backpressure_bar), 0.0), 1.0)


def _chamber_pressures(force_n, backpressure_bar: float, direction_sign=None):
    """Split a drive force into (p_a, p_b): the driving chamber rises above the backpressure."""
    f = np.asarray(force_n, dtype=float)
    base = backpressure_bar * 1e5
    return base + np.maximum(f, 0.0) / HOSE_AREA_M2, base + np.maximum(-f, 0.0) / HOSE_AREA_M2


def simulate_breakaway(direction: str = "P", backpressure_bar: float = 0.0, force_rate_n_s: float = 2.0,
                       rng=None, *, fs_hz: float = 1000.0, hold_s: float = 1.0, post_s: float = 0.3,
                       breakaway_force_n: float | None = None, sigma_n: float = 0.5,
                       creep_m: float = 4e-6, x0_m: float = 0.25, position_resolution_m: float = ENCODER_M,
                       position_noise_m: float = 0.0, **metadata) -> SimRun:
    """Static breakaway: backpressure in one chamber, the other ramped at ``force_rate_n_s``.

    Direction P ramps A (force and motion toward +x); N ramps B (toward -x). Below the
    breakaway force the carriage creeps ``creep_m * (F/Fb)^2`` (pre-sliding); at ``Fb`` it
    breaks loose and accelerates against ``Fc tanh(v/vs) + ka v``, ramp continuing, for
    ``post_s``. Breakaway force: ``breakaway_mean_n(backpressure)`` + N(0, sigma), no rate
    dependence. ``position_resolution_m`` / ``position_noise_m`` describe another position sensor
    (:func:`position_sensor`; default the bench's 5 um encoder).
    """
    rng = make_rng(rng)
    sign = 1.0 if direction == "P" else -1.0
    if direction not in ("P", "N"):
        raise ValueError("direction must be 'P' or 'N'")
    fc, ka, vs = viscous_parameters(backpressure_bar)
    fb = breakaway_mean_n(backpressure_bar) + sigma_n * rng.normal() if breakaway_force_n is None \
        else float(breakaway_force_n)
    fb = max(fb, fc + 0.5)
    t_b = hold_s + fb / force_rate_n_s
    n = int(math.floor((t_b + post_s) * fs_hz)) + 1
    t = time_vector(n, fs_hz)
    f_drive = np.where(t < hold_s, 0.0, force_rate_n_s * (t - hold_s))
    x = np.zeros(n)
    pre = t < t_b
    x[pre] = creep_m * (f_drive[pre] / fb) ** 2
    # gross motion: semi-implicit Euler with substeps, force magnitude along the motion
    idx = np.flatnonzero(~pre)
    sub = 20
    dt = 1.0 / fs_hz / sub
    pos, vel, tt = creep_m, 0.0, t_b
    for k in idx:
        while tt < t[k] - 1e-12:
            h = min(dt, t[k] - tt)
            force = force_rate_n_s * (tt - hold_s) - (fc * math.tanh(vel / vs) + ka * vel)
            vel = max(vel + h * force / MOVING_MASS_KG, 0.0)
            pos += h * vel
            tt += h
        x[k] = pos
    x_true = x0_m + sign * x
    p_a, p_b = _chamber_pressures(sign * f_drive, backpressure_bar)
    data = pd.DataFrame({"t_s": t, "p_a_pa": pressure_sensor(p_a, rng), "p_b_pa": pressure_sensor(p_b, rng)})
    data["x_m"] = position_sensor(x_true, rng, position_resolution_m, position_noise_m)
    meta = {"kind": "breakaway", "rig": "plpa-1", "direction": direction,
            "backpressure_bar": float(backpressure_bar), "force_rate_n_s": float(force_rate_n_s),
            "hose_area_m2": HOSE_AREA_M2, **metadata}
    truth = {"kind": "breakaway", "direction": direction, "backpressure_bar": float(backpressure_bar),
             "force_rate_n_s": float(force_rate_n_s), "breakaway_force_n": float(fb),
             "breakaway_mean_n": breakaway_mean_n(backpressure_bar), "sigma_n": sigma_n,
             "onset_time_s": float(t_b), "ramp_start_s": hold_s, "creep_m": creep_m, "x0_m": x0_m,
             "fc_n": fc, "ka_n_s_m": ka, "vs_m_s": vs, "fs_hz": fs_hz,
             "distance_after_post_m": float(x[-1])}
    return SimRun(data, meta, truth)


#: Default speeds of viscous runs: 0.05 .. 0.5 m/s, each both ways. [m/s]
VISCOUS_SPEEDS_M_S = tuple(s * v for v in (0.05, 0.1, 0.2, 0.3, 0.4, 0.5) for s in (1.0, -1.0))
#: Near-zero speeds: -7 .. 7 mm/s (paper). [m/s]
NEAR_ZERO_SPEEDS_M_S = tuple(s * v / 1e3 for v in (0.5, 1.0, 2.0, 3.0, 5.0, 7.0) for s in (1.0, -1.0))


def motion_profile(speeds_m_s, accel_m_s2: float, cruise_m: float, max_cruise_s: float,
                   min_cruise_s: float, dwell_s: float):
    """Segments of passes: rest, accelerate, cruise at each speed, decelerate, rest.

    Returns a list of ``(t0, duration, x0, v0, a)`` segments and the per-pass cruise windows.
    """
    segs, passes = [], []
    t, x = 0.0, 0.0
    segs.append((t, dwell_s, x, 0.0, 0.0))
    t += dwell_s
    for v in speeds_m_s:
        a = math.copysign(accel_m_s2, v)
        ta = abs(v) / accel_m_s2
        segs.append((t, ta, x, 0.0, a))
        x += 0.5 * a * ta * ta
        t += ta
        tc = min(max(cruise_m / abs(v), min_cruise_s), max_cruise_s)
        segs.append((t, tc, x, v, 0.0))
        passes.append({"velocity_m_s": float(v), "t_start_s": t, "t_end_s": t + tc})
        x += v * tc
        t += tc
        segs.append((t, ta, x, v, -a))
        x += v * ta - 0.5 * a * ta * ta
        t += ta
        segs.append((t, dwell_s, x, 0.0, 0.0))
        t += dwell_s
    return segs, passes, t


def evaluate_profile(segs, t):
    """Position, velocity and acceleration of a segment list at times ``t``."""
    t = np.asarray(t, dtype=float)
    starts = np.array([s[0] for s in segs])
    k = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(segs) - 1)
    arr = np.array(segs)
    t0, x0, v0, a = arr[k, 0], arr[k, 2], arr[k, 3], arr[k, 4]
    dur = arr[k, 1]
    tau = np.minimum(t - t0, dur)
    x = x0 + v0 * tau + 0.5 * a * tau * tau
    v = v0 + a * tau
    acc = np.where(t - t0 <= dur, a, 0.0)
    return x, v, acc


def simulate_viscous(backpressure_bar: float = 0.0, speeds_m_s=VISCOUS_SPEEDS_M_S, use_force_channel: bool = False,
                     rng=None, *, fs_hz: float = 1000.0, accel_m_s2: float = 2.0, cruise_m: float = 0.25,
                     max_cruise_s: float = 2.0, min_cruise_s: float = 0.4, dwell_s: float = 0.3,
                     valve_tau_s: float = 0.02, fc_n: float | None = None, ka_n_s_m: float | None = None,
                     vs_m_s: float | None = None, force_noise_n: float = 0.05, x0_m: float = 0.4,
                     position_resolution_m: float = ENCODER_M, position_noise_m: float = 0.0,
                     mass_kg: float = MOVING_MASS_KG, force_offset_n: float = 0.0, **metadata) -> SimRun:
    """Viscous-friction run: constant-velocity passes at ``speeds_m_s`` (signed), rest between.

    The drive force is ``m a + F(v)``. With pressures, it reaches the chambers through a
    first-order valve lag ``valve_tau_s`` (so at constant velocity ``(p_a - p_b) A = F(v)``);
    with ``use_force_channel`` a load cell logs it directly as ``f`` (no pressures).
    Near-zero runs: ``speeds_m_s=NEAR_ZERO_SPEEDS_M_S`` at 0 bar. Other rigs:
    ``position_resolution_m`` / ``position_noise_m`` (an analog position sensor, or another
    encoder: :func:`position_sensor`), ``mass_kg`` (moving mass) and ``force_offset_n`` (a constant
    offset of the measured drive force, e.g. a load cell's zero).
    """
    rng = make_rng(rng)
    fc0, ka0, vs0 = viscous_parameters(backpressure_bar)
    fc = fc0 if fc_n is None else float(fc_n)
    ka = ka0 if ka_n_s_m is None else float(ka_n_s_m)
    vs = vs0 if vs_m_s is None else float(vs_m_s)
    segs, passes, total = motion_profile(speeds_m_s, accel_m_s2, cruise_m, max_cruise_s, min_cruise_s, dwell_s)
    n = int(math.floor(total * fs_hz)) + 1
    t = time_vector(n, fs_hz)
    x, v, a = evaluate_profile(segs, t)
    force = mass_kg * a + friction_force(v, fc, ka, vs) + force_offset_n
    data = {"t_s": t, "x_m": encoder(x0_m + x)}
    if use_force_channel:
        data["f_n"] = quantise(force + rng.normal(0.0, force_noise_n, n), 1e-3)
    else:
        alpha = math.exp(-1.0 / (fs_hz * valve_tau_s))
        lagged = signal.lfilter([1 - alpha], [1, -alpha], force, zi=[alpha * force[0]])[0]
        p_a, p_b = _chamber_pressures(lagged, backpressure_bar)
        data["p_a_pa"] = pressure_sensor(p_a, rng)
        data["p_b_pa"] = pressure_sensor(p_b, rng)
    if position_noise_m != 0.0 or position_resolution_m != ENCODER_M:
        data["x_m"] = position_sensor(x0_m + x, rng, position_resolution_m, position_noise_m)
    settle = 0.0 if use_force_channel else 6 * valve_tau_s
    for p in passes:
        p["friction_n"] = float(friction_force(p["velocity_m_s"], fc, ka, vs))
        p["t_settled_s"] = p["t_start_s"] + settle
    meta = {"kind": "viscous", "rig": "plpa-1", "backpressure_bar": float(backpressure_bar),
            "hose_area_m2": HOSE_AREA_M2, **metadata}
    truth = {"kind": "viscous", "backpressure_bar": float(backpressure_bar), "fc_n": fc, "ka_n_s_m": ka,
             "vs_m_s": vs, "use_force_channel": bool(use_force_channel), "accel_m_s2": accel_m_s2,
             "valve_tau_s": valve_tau_s, "fs_hz": fs_hz, "x0_m": x0_m, "passes": passes}
    return SimRun(pd.DataFrame(data), meta, truth)


# -- identification and step ------------------------------------------------------------------
#: Plant of Table 1: natural frequency [rad/s], damping [-], gain [m/(V s)].
PLANT_WN, PLANT_ZETA, PLANT_K = 16.7, 0.51, 0.82


def plant_zoh(dt: float, wn: float = PLANT_WN, zeta: float = PLANT_ZETA, k: float = PLANT_K):
    """Exact ZOH discretisation of ``k wn^2 / (s (s^2 + 2 zeta wn s + wn^2))`` (state space)."""
    a = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, -wn * wn, -2 * zeta * wn]])
    b = np.array([[0.0], [0.0], [k * wn * wn]])
    c = np.array([[1.0, 0.0, 0.0]])
    ad, bd, _, _, _ = signal.cont2discrete((a, b, c, np.zeros((1, 1))), dt, method="zoh")
    return ad, bd[:, 0]


def simulate_identification(rng=None, *, kp_v_m: float = 5.0, fs_hz: float = 5000.0, duration_s: float = 30.0,
                            ud_variance_v2: float = 0.25, hold_s: float = 0.02, x_ref_m: float = 0.3,
                            wn: float = PLANT_WN, zeta: float = PLANT_ZETA, k: float = PLANT_K,
                            **metadata) -> SimRun:
    """Closed-loop identification: ``u = kp (x_ref - x_enc) + u_d``, plant of Table 1.

    ``u_d`` is Gaussian (variance ``ud_variance_v2``) held for ``hold_s``. The plant is the
    exact ZOH discretisation at the log rate, driven by the logged ``u`` (1 uV resolution);
    the controller sees the 5 um encoder, as the bench does.
    """
    rng = make_rng(rng)
    n = int(round(duration_s * fs_hz))
    t = time_vector(n, fs_hz)
    per_hold = max(1, int(round(hold_s * fs_hz)))
    levels = rng.normal(0.0, math.sqrt(ud_variance_v2), n // per_hold + 1)
    u_d = quantise(np.repeat(levels, per_hold)[:n], 1e-6)
    ad, bd = plant_zoh(1.0 / fs_hz, wn, zeta, k)
    a = ad.tolist()
    b = bd.tolist()
    s0, s1, s2 = x_ref_m, 0.0, 0.0
    x_true = np.empty(n)
    u = np.empty(n)
    step = ENCODER_M
    for i in range(n):
        x_true[i] = s0
        x_enc = round(s0 / step) * 5.0 / 1e6
        ui = round((kp_v_m * (x_ref_m - x_enc) + u_d[i]) * 1e6) / 1e6
        u[i] = ui
        s0, s1, s2 = (a[0][0] * s0 + a[0][1] * s1 + a[0][2] * s2 + b[0] * ui,
                      a[1][0] * s0 + a[1][1] * s1 + a[1][2] * s2 + b[1] * ui,
                      a[2][0] * s0 + a[2][1] * s1 + a[2][2] * s2 + b[2] * ui)
    data = pd.DataFrame({"t_s": t, "x_m": encoder(x_true), "x_ref_m": np.full(n, x_ref_m), "u_v": u, "u_d_v": u_d})
    meta = {"kind": "identification", "rig": "plpa-1", "kp_v_m": float(kp_v_m), "id_sample_rate_hz": 50.0,
            "hose_area_m2": HOSE_AREA_M2, **metadata}
    truth = {"kind": "identification", "wn_rad_s": wn, "zeta": zeta, "k_lin_m_v_s": k, "kp_v_m": kp_v_m,
             "fs_hz": fs_hz, "id_sample_rate_hz": 50.0, "ud_variance_v2": ud_variance_v2, "hold_s": hold_s,
             "x_ref_m": x_ref_m, "duration_s": duration_s,
             "stable_kp_limit_v_m": 2 * zeta * wn / k}
    return SimRun(data, meta, truth)


#: PID of the closed-loop step (u in V, position in m), two-degree-of-freedom form
#: ``u = kp (b r - y) + ki int(r - y) + kd d/dt(c r - y)`` with set-point weights b = c = 0 (I-PD,
#: no proportional or derivative kick): about 1.2 % overshoot, about 4 s to the 2 % band, and
#: zero steady-state error (integral action).
STEP_PID = {"kp_v_m": 1.85, "ki_v_m_s": 1.08, "kd_v_s_m": 0.0, "derivative_filter_rad_s": 100.0,
            "setpoint_weight_p": 0.0, "setpoint_weight_d": 0.0}


def _pid_loop(n, fs_hz, x_ref, x0, pid, wn, zeta, k, quantised: bool):
    ad, bd = plant_zoh(1.0 / fs_hz, wn, zeta, k)
    a, b = ad.tolist(), bd.tolist()
    dt = 1.0 / fs_hz
    kp, ki, kd, nf = pid["kp_v_m"], pid["ki_v_m_s"], pid["kd_v_s_m"], pid["derivative_filter_rad_s"]
    bw, cw = pid.get("setpoint_weight_p", 1.0), pid.get("setpoint_weight_d", 1.0)
    alpha = math.exp(-nf * dt)
    s0, s1, s2 = x0, 0.0, 0.0
    # bumpless start: the integrator holds the carriage at rest at x0 (u = 0)
    integ, dstate, e_prev = (kp * (x0 - bw * x_ref[0]) / ki if ki else 0.0), 0.0, 0.0
    x = np.empty(n)
    u = np.empty(n)
    for i in range(n):
        x[i] = s0
        xm = round(s0 / ENCODER_M) * 5.0 / 1e6 if quantised else s0
        e = x_ref[i] - xm
        ed = cw * x_ref[i] - xm
        if i == 0:
            e_prev = ed
        dstate = alpha * dstate + (1 - alpha) * (ed - e_prev) / dt
        e_prev = ed
        ui = kp * (bw * x_ref[i] - xm) + ki * integ + kd * dstate
        integ += e * dt
        u[i] = ui
        s0, s1, s2 = (a[0][0] * s0 + a[0][1] * s1 + a[0][2] * s2 + b[0] * ui,
                      a[1][0] * s0 + a[1][1] * s1 + a[1][2] * s2 + b[1] * ui,
                      a[2][0] * s0 + a[2][1] * s1 + a[2][2] * s2 + b[2] * ui)
    return x, u


def step_metrics(t, x, t_step: float, x_from: float, x_to: float, t_end: float) -> dict:
    """Overshoot [%], 2 % settling time [s], 10-90 % rise time [s], steady-state error [mm].

    A reference that does not move (``x_to == x_from``) or a window ``[t_step, t_end)`` without
    samples has no response to measure: every metric is NaN (None in truth.json), as
    :func:`analyses.step_response.step_metrics` reports a zero step.
    """
    m = (t >= t_step) & (t < t_end)
    tt, xx = t[m] - t_step, x[m]
    step = x_to - x_from
    if step == 0 or not tt.size:
        nan = float("nan")
        return {"overshoot_pct": nan, "settling_time_s": nan, "rise_time_s": nan, "steady_state_error_mm": nan}
    y = (xx - x_from) / step
    overshoot = max(0.0, float(y.max() - 1.0) * 100.0)
    out = np.flatnonzero(np.abs(y - 1.0) > 0.02)
    settling = float(tt[out[-1] + 1]) if out.size and out[-1] + 1 < tt.size else (0.0 if not out.size else float("nan"))
    r10 = float(tt[np.argmax(y >= 0.1)])
    r90 = float(tt[np.argmax(y >= 0.9)])
    sse_mm = float((x_to - xx[-1]) * 1e3 * np.sign(step))
    return {"overshoot_pct": overshoot, "settling_time_s": settling, "rise_time_s": r90 - r10,
            "steady_state_error_mm": sse_mm}


def simulate_step(rng=None, *, steps_mm=(20.0, -20.0), fs_hz: float = 1000.0, hold_s: float = 10.0,
                  lead_s: float = 1.0, x0_m: float = 0.2, pid: dict | None = None, wn: float = PLANT_WN,
                  zeta: float = PLANT_ZETA, k: float = PLANT_K, **metadata) -> SimRun:
    """Closed-loop position steps under PID (plant of Table 1, ZOH at the log rate, encoder feedback).

    Truth holds per-step noise-free metrics (same loop with unquantised feedback).
    """
    make_rng(rng)  # the run is deterministic: no noise besides encoder quantisation
    pid = dict(STEP_PID if pid is None else pid)
    n = int(round((lead_s + hold_s * len(steps_mm)) * fs_hz))
    t = time_vector(n, fs_hz)
    x_ref = np.full(n, x0_m)
    level = x0_m
    step_times = []
    for i, s in enumerate(steps_mm):
        t0 = lead_s + i * hold_s
        level = level + s / 1e3
        x_ref[t >= t0] = level
        step_times.append(t0)
    x_ref = quantise(x_ref, 1e-6)
    x, u = _pid_loop(n, fs_hz, x_ref, x0_m, pid, wn, zeta, k, quantised=True)
    x_clean, _ = _pid_loop(n, fs_hz, x_ref, x0_m, pid, wn, zeta, k, quantised=False)
    steps = []
    prev = x0_m
    for i, s in enumerate(steps_mm):
        t0 = step_times[i]
        target = float(x_ref[np.searchsorted(t, t0)])
        t_end = step_times[i + 1] if i + 1 < len(step_times) else t[-1] + 1.0 / fs_hz
        met = step_metrics(t, x_clean, t0, prev, target, t_end)
        steps.append({"t_step_s": t0, "step_mm": float(s), "x_from_m": prev, "x_to_m": target, **met})
        prev = target
    data = pd.DataFrame({"t_s": t, "x_m": encoder(x), "x_ref_m": x_ref, "u_v": quantise(u, 1e-6)})
    meta = {"kind": "step", "rig": "plpa-1", "hose_area_m2": HOSE_AREA_M2, **metadata}
    truth = {"kind": "step", "pid": pid, "wn_rad_s": wn, "zeta": zeta, "k_lin_m_v_s": k, "fs_hz": fs_hz,
             "steps": steps}
    return SimRun(data, meta, truth)
