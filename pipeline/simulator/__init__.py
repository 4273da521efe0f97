"""The bench simulator: synthetic runs with ground truth, and whole campaigns as benches write them.

Every generator returns a :class:`SimRun` (``data``: DataFrame with warehouse column names in SI,
gauge pressures [Pa], flows [kg/s], exactly what ingest must produce; ``metadata``: run metadata
keyed as in bench-exports.md; ``truth``: every true value used). ``rng`` is a
``numpy.random.Generator`` or an int seed; keyword overrides change any default of physics.md.

Generators and their truth keys
-------------------------------
``simulate_leakage(chamber, adjustment, z_rollers_mm, spring_force_n, rng, ...)``
    columns t_s, p_supply_pa, q_leak_kg_s. Truth: p_seal_bar, c [l/min/bar^1.5], tau_s, plateaus
    (list of pressure_bar, leak_l_min [ANR], t_start_s, t_settled_s, t_end_s, pressure_end_bar),
    hose_id, flow noise.
``simulate_breakaway(direction, backpressure_bar, force_rate_n_s, rng, ...)``
    columns t_s, p_a_pa, p_b_pa, x_m. Truth: breakaway_force_n (magnitude), breakaway_mean_n,
    onset_time_s, ramp_start_s, creep_m, fc_n, ka_n_s_m, vs_m_s.
``simulate_viscous(backpressure_bar, speeds_m_s, use_force_channel, rng, ...)``
    columns t_s, x_m and p_a_pa, p_b_pa (or f_n). Truth: fc_n, ka_n_s_m, vs_m_s, passes (list of
    velocity_m_s, friction_n (signed), t_start_s, t_settled_s, t_end_s). Near-zero runs:
    ``speeds_m_s=NEAR_ZERO_SPEEDS_M_S``.
``simulate_identification(rng, ...)``
    columns t_s, x_m, x_ref_m, u_v, u_d_v. Truth: wn_rad_s, zeta, k_lin_m_v_s, kp_v_m, fs_hz,
    id_sample_rate_hz, ud_variance_v2, hold_s, x_ref_m.
``simulate_step(rng, ...)``
    columns t_s, x_m, x_ref_m, u_v. Truth: pid, steps (list of t_step_s, step_mm, x_from_m,
    x_to_m, overshoot_pct, settling_time_s (2 %), rise_time_s (10-90 %), steady_state_error_mm),
    all noise-free.
``simulate_spring(chamber, p0_bar_abs, amplitude_mm, frequency_hz, rng, ...)``
    columns t_s, d_m, f_n, p_pa. Truth: n, Ae, eps, delta, P0 [Pa abs], p0_bar_abs, Pa, D [m],
    amplitude_mm, frequency_hz, s, s_f, stroke_m, force_range_n.
``simulate_pressure_step(chamber, rng, ...)``
    columns t_s, p_pa, p_ref_pa. Truth: wn_rad_s, xi_charge, xi_discharge, steps (list of
    t_step_s, p_from_pa, p_to_pa, direction, wn_rad_s, xi).
``simulate_durability(hose_id, adjustment, distance_m or duration_s, fs_hz, rng, ...)``
    columns t_s, x_m, p_a_pa, p_b_pa. Truth: distance_m, distance_km, strokes (one-way moves),
    duration_s, stroke_m, speed_m_s, accel_m_s2, dwell_s, n_samples. For GB-scale runs:
    ``stroke_plan(...)`` + ``iter_durability_chunks(plan, rng)``.
``simulate_timeseries(rng, duration_s, fs_hz, supply, ...)``
    kind ``timeseries`` (ambient / supply logger): columns t_s, (p_supply_pa,) and the
    non-canonical temperature_degc [degC], rel_humidity_pct [%]. Truth: fs_hz, duration_s, n_samples,
    temperature_c, drift_c_h, humidity_pct, units, supply cycle, channels (mean, min, max).

Campaigns (every kind, every format, hoses.csv, manifest, rig.toml, truth.json):
:func:`pipeline.simulator.campaign.simulate_campaign`.
"""
from pipeline.simulator.ambient import simulate_timeseries
from pipeline.simulator.base import SimRun
from pipeline.simulator.durability import (RUPTURE_LIFE, WearPath, draw_wear_path, iter_durability_chunks,
                                           simulate_durability, stroke_plan)
from pipeline.simulator.pla import simulate_pressure_step, simulate_spring
from pipeline.simulator.plpa import (NEAR_ZERO_SPEEDS_M_S, VISCOUS_SPEEDS_M_S, simulate_breakaway,
                                     simulate_identification, simulate_leakage, simulate_step, simulate_viscous)

__all__ = ["SimRun", "simulate_leakage", "simulate_breakaway", "simulate_viscous", "simulate_identification",
           "simulate_step", "simulate_spring", "simulate_pressure_step", "simulate_durability", "stroke_plan",
           "iter_durability_chunks", "WearPath", "draw_wear_path", "RUPTURE_LIFE", "NEAR_ZERO_SPEEDS_M_S",
           "VISCOUS_SPEEDS_M_S", "simulate_timeseries"]
