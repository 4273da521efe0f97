"""Foreign rigs: runs as other labs' benches export them, with their ground truth.

The campaign ``foreign-2026`` (``pneubench simulate OUT --profile foreign``) holds one folder per
lab, each with its own ``rig.toml``, so that ingest and the analyses meet sensors and exports
they were not tuned to:

=================  =========================================================================
folder             what it exercises
=================  =========================================================================
``analog``         viscous runs, analog position sensor (Gaussian noise 5 / 20 / 50 um, not
                   quantised) at 100 Hz; CSV **without a time column**, ``sample_rate_hz`` in
                   the manifest; the 20 um run states ``sensor_x_noise`` there, the others not
``encoder/fine``   viscous, 1 um encoder, LVM; ``[sensors.x] resolution = "1 um"`` in rig.toml
``encoder/coarse`` viscous, 50 um encoder, TDMS with waveform timing; no sensor metadata
``loadcell``       viscous with a load cell ``f_cell`` [N] that also carries the passive
                   chamber's force: ``[derived] f = "f_cell - p_b * hose_area_m2"``
``trapezoid``      one-speed trapezoid friction run (+-0.12 m/s); MAT **without** ``t``, the
                   rate as a scalar ``Fs``
``lowspeed``       low-speed passes (5, 10, 15 mm/s both ways), 1 um encoder
``pla``            first-order pressure responses (kind ``pressure_step``) of a closed-loop
                   regulator, set-point sweeps in 5 kPa and 10 kPa steps at 20 Hz; the 10 kPa
                   run states ``sensor_p_noise = "2 mbar"`` in the manifest
``accel``          kind ``timeseries`` with a channel ``F`` in ``g`` (an accelerometer, not the
                   force): kept as the non-canonical ``f_g``
``pinch-valve``    a ventilator's roller pinch valve on peristaltic tubing (kind
                   ``pressure_step``, chamber ``patient``, pressures in mbar at 1 kHz): the
                   same valve ``RPV-2`` new (``age_h = 0``) and after 594 h of life testing
                   (``age_h = 594``), PEEP <-> PIP steps answered in second order with a lower
                   ``wn`` and more damping once the tubing has aged (:data:`PINCH_VALVE`)
``ventilator``     a ventilator's pressure set-point at 1 kHz (kind ``pressure_step``, in mbar):
                   PEEP, a 100 ms ramp to PIP in one-sample plateaus, PIP, back to PEEP; each
                   breath is one charge and one discharge step
``laser``          viscous runs of a 3D-printed cylinder, laser position sensor at 100 Hz
                   (white noise 0.05-0.2 mm, 10 um steps; the 0.15 mm run loses 0.5 % of its
                   samples, written `nan`): short fast strokes one way (20, 50, 80 mm/s over
                   60 mm), slow returns the other (4 and 8 mm/s)
``lineardrive``    a linear motor axis at 1 kHz (:func:`linear_drive`): multi-sine motion, 1 um
                   encoder, drive force ``f`` [N] from the motor current, no pressures; the force
                   leads the motion by 0.57 ms (``linear-drive``, under a sample) or by 3 ms
                   (``linear-drive-fieldbus``: the position comes over a fieldbus 3 samples late)
``kpa-logger``     a regulator's pressure steps logged by a script (:data:`LOGGER_HEADERS`):
                   headers ``time(sec)``, ``pressure(kPa)``, ``setpoint(kPa)`` mapped by
                   ``[channels."time(sec)"]`` ... in its rig.toml, and a comment line
                   ``# Captured <date time.us> by unknown user`` above the header
=================  =========================================================================

truth.json (same layout as the main campaigns) holds per run the true values (``fc_n``
Coulomb [N], ``ka_n_s_m`` viscous [N s/m], ``moving_mass_kg``, ``x0_m`` offset, ``tau_s``,
sensor noise / resolution, time base) and, under ``expected``, what ingest must produce
(time base, derived channel, columns and units). Same seed, same bytes.
"""
from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.simulator import pla, plpa
from pipeline.simulator.base import HOSE_AREA_M2, SimRun, jsonable, make_rng, quantise, time_vector
from pipeline.simulator.writers import ColumnOut, meta_text, write_csv, write_lvm, write_mat, write_tdms
from schemas.channels import CHANNELS, noncanonical_column

CAMPAIGN = "foreign-2026"
START = datetime(2026, 2, 2, 9, 0, 0)

#: Per lab folder: its rig.toml.
RIG_TOMLS = {
    "analog/rig.toml": '[metadata]\nrig = "analog-rig"\nhose_area_m2 = 4.9e-4\n',
    "encoder/fine/rig.toml": ('[metadata]\nrig = "encoder-rig-1um"\nhose_area_m2 = 4.9e-4\n\n'
                              '[sensors.x]\nresolution = "1 um"\n\n[sensors.p_a]\nnoise = "300 Pa"\n\n'
                              '[sensors.p_b]\nnoise = "3 mbar"\n'),
    "encoder/coarse/rig.toml": '[metadata]\nrig = "encoder-rig-50um"\nhose_area_m2 = 4.9e-4\n',
    "loadcell/rig.toml": ('[metadata]\nrig = "loadcell-rig"\nhose_area_m2 = 4.9e-4\n\n'
                          '# the load cell also feels the passive chamber: the drive force is\n'
                          '[derived]\nf = "f_cell - p_b * hose_area_m2"\n\n[sensors.f]\nnoise = "0.05 N"\n'),
    "trapezoid/rig.toml": '[metadata]\nrig = "trapezoid-rig"\nhose_area_m2 = 4.9e-4\n',
    "lowspeed/rig.toml": '[metadata]\nrig = "lowspeed-rig"\nhose_area_m2 = 4.9e-4\n',
    "pla/rig.toml": '[metadata]\nrig = "pla-regulator"\n',
    "accel/rig.toml": '[metadata]\nrig = "shaker"\n',
    "pinch-valve/rig.toml": '[metadata]\nrig = "vent-pinch"\n\n[sensors.p]\nnoise = "0.05 mbar"\n',
    "ventilator/rig.toml": '[metadata]\nrig = "ventilator-pinch-valve"\n',
    "laser/rig.toml": ('[metadata]\nrig = "printed-cylinder-laser"\nhose_area_m2 = 4.9e-4\n\n'
                       '[sensors.x]\nresolution = "10 um"\n'),
    "lineardrive/rig.toml": '[metadata]\nrig = "linear-drive"\n',
}

LOW_SPEEDS_M_S = tuple(s * v for v in (0.005, 0.010, 0.015) for s in (1.0, -1.0))
#: The laser rig's strokes: fast one way, a slow return the other. [m/s]
LASER_SPEEDS_M_S = (0.02, -0.004, 0.05, -0.008, 0.08, -0.004)
#: The laser sensor's white noise per run. [m]
LASER_NOISES_M = (0.05e-3, 0.1e-3, 0.15e-3, 0.2e-3)
#: Share of the 0.15 mm laser run's position samples lost (no reflection), written `nan`. [-]
LASER_DROPOUTS = 0.005
TRAPEZOID_SPEEDS_M_S = (0.12, -0.12, 0.12, -0.12)


@dataclass
class ForeignRun:
    """One run of the foreign campaign: how it is simulated and exported."""

    index: int
    stem: str
    folder: str
    fmt: str
    kind: str
    sim: dict                      # keyword arguments of the generator
    units: dict                    # raw unit per column written
    time_column: bool = True
    manifest: dict = field(default_factory=dict)   # keys in the folder's manifest.csv
    sensors: dict = field(default_factory=dict)    # true sensor characteristics [SI]
    stated: dict = field(default_factory=dict)     # sensor params ingest must store [SI]
    dropouts: float = 0.0                          # share of position samples lost (NaN)

    @property
    def run_id(self) -> str:
        return f"{CAMPAIGN}/{self.stem}"

    @property
    def rel_path(self) -> str:
        return f"{CAMPAIGN}/{self.folder}/{self.stem}.{self.fmt}"


def plan() -> list[ForeignRun]:
    """Every run of the foreign campaign, in a fixed order."""
    runs: list[ForeignRun] = []

    def add(**kw):
        runs.append(ForeignRun(index=len(runs), **kw))

    vis_units = {"x_m": "mm", "p_a_pa": "bar", "p_b_pa": "bar"}
    for um in (5, 20, 50):
        add(stem=f"analog-{um:02d}um", folder="analog", fmt="csv", kind="viscous", time_column=False,
            sim=dict(backpressure_bar=1.0, fs_hz=100.0, position_noise_m=um / 1e6, position_resolution_m=0.0),
            units=vis_units, manifest={"sample_rate_hz": 100, **({"sensor_x_noise": "20 um"} if um == 20 else {})},
            sensors={"x_noise_m": um / 1e6, "p_noise_pa": 300.0},
            stated={"sensor_x_noise": 2e-05} if um == 20 else {})
    add(stem="encoder-1um", folder="encoder/fine", fmt="lvm", kind="viscous",
        sim=dict(backpressure_bar=2.0, fs_hz=500.0, position_resolution_m=1e-6), units=vis_units,
        sensors={"x_resolution_m": 1e-6, "p_noise_pa": 300.0},
        stated={"sensor_x_resolution": 1e-06, "sensor_p_a_noise": 300.0, "sensor_p_b_noise": 300.0})
    add(stem="encoder-50um", folder="encoder/coarse", fmt="tdms", kind="viscous",
        sim=dict(backpressure_bar=2.0, fs_hz=500.0, position_resolution_m=50e-6),
        units={"x_m": "um", "p_a_pa": "kPa", "p_b_pa": "kPa"}, sensors={"x_resolution_m": 50e-6, "p_noise_pa": 300.0})
    add(stem="loadcell", folder="loadcell", fmt="csv", kind="viscous",
        sim=dict(backpressure_bar=2.0, fs_hz=500.0, use_force_channel=True, mass_kg=3.5,
                 position_resolution_m=1e-6),
        units={"x_m": "mm", "f_cell_n": "N", "p_b_pa": "bar"},
        sensors={"f_noise_n": 0.05, "x_resolution_m": 1e-6, "p_noise_pa": 300.0}, stated={"sensor_f_noise": 0.05})
    add(stem="trapezoid", folder="trapezoid", fmt="mat", kind="viscous", time_column=False,
        sim=dict(backpressure_bar=0.0, fs_hz=500.0, speeds_m_s=TRAPEZOID_SPEEDS_M_S, cruise_m=0.3),
        units={"x_m": "mm", "p_a_pa": "kPa", "p_b_pa": "kPa"}, sensors={"x_resolution_m": 5e-6, "p_noise_pa": 300.0})
    add(stem="lowspeed", folder="lowspeed", fmt="csv", kind="viscous",
        sim=dict(backpressure_bar=0.0, fs_hz=200.0, speeds_m_s=LOW_SPEEDS_M_S, position_resolution_m=1e-6,
                 cruise_m=0.02), units=vis_units, sensors={"x_resolution_m": 1e-6, "p_noise_pa": 300.0})
    for kpa, n_up in ((5, 8), (10, 6)):
        up = [2.0 + k * kpa / 100.0 for k in range(n_up + 1)]
        levels = tuple(round(v, 4) for v in up + up[-2::-1])
        add(stem=f"pressure-sweep-{kpa:02d}kpa", folder="pla", fmt="csv", kind="pressure_step",
            sim=dict(chamber="rear", levels_bar=levels, hold_s=1.5, fs_hz=20.0, tau_s=0.25, noise_pa=200.0),
            units={"p_pa": "bar", "p_ref_pa": "bar"},
            manifest={"sensor_p_noise": "2 mbar"} if kpa == 10 else {},
            sensors={"p_noise_pa": 200.0, "step_pa": kpa * 1e3}, stated={"sensor_p_noise": 200.0} if kpa == 10 else {})
    add(stem="shaker-accel", folder="accel", fmt="csv", kind="timeseries", sim=dict(fs_hz=200.0, duration_s=5.0),
        units={"f_g": "g"})
    _pinch_valve_runs(add)
    _plan_ramps_and_laser(add)
    for stem, lead in (("linear-drive", 0.57e-3), ("linear-drive-fieldbus", 3e-3)):
        add(stem=stem, folder="lineardrive", fmt="csv", kind="viscous", sim=dict(force_lead_s=lead),
            units={"x_m": "mm", "f_n": "N"},
            sensors={"x_resolution_m": LINEAR_DRIVE["position_resolution_m"], "f_noise_n": LINEAR_DRIVE["force_noise_n"]})
    _plan_logger_headers(add)
    return runs


def _plan_ramps_and_laser(add) -> None:
    """Issue 25, items 2 and 6: a ventilator's ramped set-point; a laser position sensor."""
    add(stem="ventilator-ramp", folder="ventilator", fmt="csv", kind="pressure_step",
        sim=dict(fs_hz=1000.0, breaths=3, peep_pa=500.0, pip_pa=2000.0, ramp_s=0.1, insp_s=1.0, exp_s=1.5,
                 tau_s=0.05, noise_pa=20.0),
        units={"p_pa": "mbar", "p_ref_pa": "mbar"}, sensors={"p_noise_pa": 20.0})
    for noise in LASER_NOISES_M:
        add(stem=f"laser-{noise * 1e6:03.0f}um", folder="laser", fmt="csv", kind="viscous",
            sim=dict(backpressure_bar=1.0, fs_hz=100.0, speeds_m_s=LASER_SPEEDS_M_S, cruise_m=0.06,
                     max_cruise_s=30.0, position_noise_m=noise, position_resolution_m=10e-6),
            dropouts=LASER_DROPOUTS if noise == 0.15e-3 else 0.0,
            units={"x_m": "mm", "p_a_pa": "bar", "p_b_pa": "bar"},
            sensors={"x_noise_m": noise, "x_resolution_m": 10e-6, "p_noise_pa": 300.0},
            stated={"sensor_x_resolution": 1e-05})


def _drop_samples(data: pd.DataFrame, column: str, share: float, rng: np.random.Generator) -> pd.DataFrame:
    """A laser sensor's dropouts: ``share`` of the samples of ``column`` lost (NaN)."""
    lost = rng.choice(len(data), int(round(share * len(data))), replace=False)
    out = data.copy()
    out.loc[out.index[lost], column] = np.nan
    return out


@dataclass(frozen=True)
class Ventilator:
    """A ventilator's breaths: set-point PEEP ``peep_pa`` held ``exp_s``, a ramp of ``ramp_s`` to PIP
    ``pip_pa`` held until ``insp_s`` after the ramp's start; the pressure lags the set-point by
    ``tau_s`` with white noise ``noise_pa``, logged at ``fs_hz``. [Pa gauge, s, Hz]"""

    fs_hz: float
    breaths: int
    peep_pa: float
    pip_pa: float
    ramp_s: float
    insp_s: float
    exp_s: float
    tau_s: float
    noise_pa: float


def _ventilator(rng: np.random.Generator, v: Ventilator) -> SimRun:
    """A ventilator's pressure loop: the set-point holds PEEP for ``exp_s``, rises to PIP over ``ramp_s``
    in one-sample plateaus (a new value every sample), holds PIP until ``insp_s`` after the ramp's
    start, drops to PEEP; the pressure follows it as a first-order lag ``tau_s`` (exact for a set-point
    held over each sample), with white noise ``noise_pa``, logged at 1 Pa. [Pa gauge]"""
    n_exp, n_ramp, n_insp = (int(round(d * v.fs_hz)) for d in (v.exp_s, v.ramp_s, v.insp_s))
    ramp = v.peep_pa + (v.pip_pa - v.peep_pa) * np.arange(1, n_ramp + 1) / n_ramp
    breath = np.concatenate([np.full(n_exp, v.peep_pa), ramp, np.full(n_insp - n_ramp, v.pip_pa)])
    ref = np.round(np.concatenate([np.tile(breath, v.breaths), np.full(n_exp, v.peep_pa)]), 6)
    t = time_vector(ref.size, v.fs_hz)
    alpha = np.exp(-1.0 / (v.fs_hz * v.tau_s))
    p = np.empty(ref.size)
    p[0] = v.peep_pa
    for i in range(1, ref.size):
        p[i] = ref[i - 1] + (p[i - 1] - ref[i - 1]) * alpha
    steps = []
    for k in range(v.breaths):
        t0 = (k * breath.size + n_exp) / v.fs_hz
        steps.append({"t_step_s": t0, "p_from_pa": v.peep_pa, "p_to_pa": v.pip_pa, "direction": "charge",
                      "ramp_s": v.ramp_s})
        steps.append({"t_step_s": t0 + v.insp_s, "p_from_pa": v.pip_pa, "p_to_pa": v.peep_pa,
                      "direction": "discharge", "ramp_s": 0.0})
    data = pd.DataFrame({"t_s": t, "p_pa": np.round(p + rng.normal(0.0, v.noise_pa, p.size)), "p_ref_pa": ref})
    meta = {"kind": "pressure_step", "chamber": "front"}
    truth = {"kind": "pressure_step", "chamber": "front", "model": "first_order", "tau_s": v.tau_s,
             "noise_pa": v.noise_pa, "fs_hz": v.fs_hz, "steps": steps}
    return SimRun(data, meta, truth)


# -- a ventilator's roller pinch valve, new and aged (issue 25 item 3) -------------------------------
PINCH_FOLDER = "pinch-valve"
#: The valve's pressure dynamics per age [h]: (wn [rad/s], zeta per direction). Aged peristaltic
#: tubing is softer (lower wn) and more lossy (more damping).
PINCH_VALVE = {0.0: (40.0, {"charge": 0.50, "discharge": 0.70}),
               594.0: (31.0, {"charge": 0.65, "discharge": 0.85})}
#: PEEP <-> PIP set-point levels of the pinch valve runs: 5 to 20-30 mbar. [bar gauge]
PINCH_LEVELS_BAR = (0.005, 0.025, 0.005, 0.020, 0.005, 0.030, 0.005, 0.025, 0.005)


def _pinch_valve_runs(add) -> None:
    """The pinch valve ``RPV-2`` new and after 594 h: second-order steps at 1 kHz in mbar, chamber
    ``patient``, the valve and its age in the file's metadata."""
    for age, (wn, xi) in PINCH_VALVE.items():
        add(stem=f"pinch-valve-{age:g}h", folder=PINCH_FOLDER, fmt="csv", kind="pressure_step",
            sim=dict(chamber="patient", levels_bar=PINCH_LEVELS_BAR, hold_s=1.0, fs_hz=1000.0, wn=wn, xi=dict(xi),
                     noise_pa=5.0, valve_id="RPV-2", age_h=age),
            units={"p_pa": "mbar", "p_ref_pa": "mbar"}, sensors={"p_noise_pa": 5.0},
            stated={"sensor_p_noise": 5.0})


def _pinch_valve(run: ForeignRun, rng: np.random.Generator) -> SimRun:
    """One pinch valve run: :func:`pipeline.simulator.pla.simulate_pressure_step` in second order."""
    sim = pla.simulate_pressure_step(rng=rng, **run.sim)
    return SimRun(sim.data, sim.metadata, {**sim.truth, "valve_id": run.sim["valve_id"], "age_h": run.sim["age_h"]})


#: The linear drive: a linear motor axis (moving mass, Coulomb and viscous friction of its guides,
#: a force offset from the current sensor's zero), excited by a sum of sines as inverse-dynamics
#: identification does; logged at 1 kHz with a 1 um encoder and the force from the motor current
#: (noise 0.4 N, 0.01 N steps). [SI]
LINEAR_DRIVE = {"fs_hz": 1000.0, "duration_s": 20.0, "mass_kg": 3.8, "fc_n": 9.5, "ka_n_s_m": 42.0,
                "force_offset_n": -1.2, "force_noise_n": 0.4, "force_step_n": 0.01, "position_resolution_m": 1e-6,
                "x0_m": 0.2, "vs_m_s": plpa.VS_M_S,
                "sines": ((0.05, 0.7, 0.0), (0.02, 2.3, 1.0), (0.006, 5.9, 2.0))}   # (amplitude m, Hz, phase rad)


def _sines_kinematics(sines, t):
    """Position, velocity and acceleration of a sum of ``(amplitude, frequency, phase)`` sines."""
    x, v, a = (np.zeros_like(t) for _ in range(3))
    for amp, f_hz, phase in sines:
        w = 2 * np.pi * f_hz
        x = x + amp * np.sin(w * t + phase)
        v = v + amp * w * np.cos(w * t + phase)
        a = a - amp * w * w * np.sin(w * t + phase)
    return x, v, a


def linear_drive(rng=None, *, force_lead_s: float = 0.0, **overrides) -> SimRun:
    """A linear drive's record: ``f = m a + Fc tanh(v / vs) + ka v + offset`` evaluated
    ``force_lead_s`` later than the position (a force that leads the motion: a position read late,
    or channels scanned one after another; negative: the force lags), with sensor noise.

    Parameters are those of :data:`LINEAR_DRIVE`, each overridable by keyword. The truth holds them
    (``moving_mass_kg``, ``fc_n``, ``ka_n_s_m``, ``force_offset_n``, ``force_lead_s``) and ``lag_s``
    (the lag as :func:`analyses.friction_dynamic.friction_dynamic` reports it: ``-force_lead_s``).
    """
    p = {**LINEAR_DRIVE, **overrides}
    rng = make_rng(rng)
    n = int(round(p["duration_s"] * p["fs_hz"]))
    t = time_vector(n, p["fs_hz"])
    x = _sines_kinematics(p["sines"], t)[0]
    _, v, a = _sines_kinematics(p["sines"], t + force_lead_s)
    force = p["mass_kg"] * a + plpa.friction_force(v, p["fc_n"], p["ka_n_s_m"], p["vs_m_s"]) + p["force_offset_n"]
    data = pd.DataFrame({"t_s": t, "x_m": quantise(p["x0_m"] + x, p["position_resolution_m"]),
                         "f_n": quantise(force + rng.normal(0.0, p["force_noise_n"], n), p["force_step_n"])})
    truth = {"kind": "viscous", "moving_mass_kg": p["mass_kg"], "fc_n": p["fc_n"], "ka_n_s_m": p["ka_n_s_m"],
             "vs_m_s": p["vs_m_s"], "force_offset_n": p["force_offset_n"], "force_lead_s": float(force_lead_s),
             "lag_s": -float(force_lead_s), "fs_hz": p["fs_hz"], "x0_m": p["x0_m"], "sines": p["sines"],
             "position_step_m": p["position_resolution_m"], "force_noise_n": p["force_noise_n"], "passes": []}
    # a viscous run states its backpressure; an electric drive has no chamber: 0 bar
    return SimRun(data, {"kind": "viscous", "rig": "linear-drive", "backpressure_bar": 0.0}, truth)


def _accelerometer(rng: np.random.Generator, fs_hz: float, duration_s: float) -> SimRun:
    """A shaker's accelerometer: a 12 Hz sine of 0.8 g with 0.02 g noise. [g]"""
    n = int(round(duration_s * fs_hz))
    t = time_vector(n, fs_hz)
    acc = 0.8 * np.sin(2 * np.pi * 12.0 * t) + rng.normal(0.0, 0.02, n)
    return SimRun(pd.DataFrame({"t_s": t, "f_g": np.round(acc, 5) + 0.0}), {"kind": "timeseries"},
                  {"kind": "timeseries", "amplitude_g": 0.8, "frequency_hz": 12.0, "noise_g": 0.02, "fs_hz": fs_hz})


# -- a script's log: `time(sec)` headers, a `# Captured ...` comment (issue 25 items 1 and 4) ----------
LOGGER_FOLDER = "kpa-logger"
#: The logger's header text per samples column: the unit in parentheses, `sec` for seconds.
LOGGER_HEADERS = {"t_s": "time(sec)", "p_pa": "pressure(kPa)", "p_ref_pa": "setpoint(kPa)"}
RIG_TOMLS[f"{LOGGER_FOLDER}/rig.toml"] = (
    '[metadata]\nrig = "kpa-logger"\n\n'
    '# the logger\'s headers as written\n'
    '[channels."time(sec)"]\nchannel = "t"\nunit = "s"\n\n'
    '[channels."pressure(kPa)"]\nchannel = "p"\nunit = "kPa"\n\n'
    '[channels."setpoint(kPa)"]\nchannel = "p_ref"\nunit = "kPa"\n')


def _plan_logger_headers(add) -> None:
    """Issue 25, items 1 and 4: first-order pressure steps of a regulator (0.5-1.5 bar gauge,
    tau 80 ms) at 100 Hz, written by a logging script (:func:`_write_logger_csv`)."""
    add(stem="kpa-logger-steps", folder=LOGGER_FOLDER, fmt="csv", kind="pressure_step",
        sim=dict(chamber="rear", levels_bar=(0.5, 1.0, 0.5, 1.5, 0.5), hold_s=2.0, fs_hz=100.0, tau_s=0.08,
                 noise_pa=100.0),
        units={"p_pa": "kPa", "p_ref_pa": "kPa"}, sensors={"p_noise_pa": 100.0})


def _logger_comment(run: ForeignRun) -> str:
    """The logger's comment line (without ``#``): capture time to the microsecond, no user."""
    captured = START + timedelta(hours=run.index, microseconds=57076 + 1000 * run.index)
    return f"Captured {captured:%Y-%m-%d %H:%M:%S.%f} by unknown user"


def _write_logger_csv(path: Path, frame: pd.DataFrame, columns: list[ColumnOut], metadata: dict,
                      comment: str) -> None:
    """The script's CSV: ``# key: value`` lines, ``# <comment>`` right above the header, the header
    as :data:`LOGGER_HEADERS`, then the rows exactly as :func:`write_csv` writes them."""
    write_csv(path, frame, columns, None, header=False)
    head = [f"# {k}: {meta_text(v)}" for k, v in metadata.items()] + [f"# {comment}"]
    head.append(",".join(LOGGER_HEADERS[c.column] for c in columns))
    path.write_bytes(("\n".join(head) + "\n").encode("utf-8") + path.read_bytes())


def simulate(run: ForeignRun, seed: int) -> SimRun:
    """The run as ingest must give it back: ``data`` in SI under warehouse column names (the
    load-cell run's ``f_n`` is the derived drive force, ``f_cell_n`` the cell's reading)."""
    rng = np.random.default_rng([int(seed), 1000 + run.index])
    if run.stem == "ventilator-ramp":
        return _ventilator(rng, Ventilator(**run.sim))
    if run.folder == "lineardrive":
        return linear_drive(rng, **run.sim)
    if run.kind == "viscous":
        sim = plpa.simulate_viscous(rng=rng, **run.sim)
        data = sim.data
        if run.stem == "loadcell":
            # the passive chamber B at the backpressure pushes on the cell too
            p_b = plpa.pressure_sensor(np.full(len(data), run.sim["backpressure_bar"] * 1e5), rng)
            data = data.assign(p_b_pa=p_b, f_cell_n=data["f_n"] + p_b * HOSE_AREA_M2)
        if run.dropouts:
            data = _drop_samples(data, "x_m", run.dropouts, rng)
        truth = {**sim.truth, "moving_mass_kg": run.sim.get("mass_kg", plpa.MOVING_MASS_KG),
                 "position_noise_m": run.sim.get("position_noise_m"),
                 "position_step_m": run.sim.get("position_resolution_m") or None}
        return SimRun(data, sim.metadata, truth)
    if run.folder == PINCH_FOLDER:
        return _pinch_valve(run, rng)
    if run.kind == "pressure_step":
        sim = pla.simulate_pressure_step(rng=rng, **run.sim)
        return SimRun(sim.data, sim.metadata, {**sim.truth, "tau_s": run.sim["tau_s"]})
    return _accelerometer(rng, **run.sim)


def _export_columns(run: ForeignRun) -> list[ColumnOut]:
    names = {"f_g": "F", "f_cell_n": "f_cell"}
    out = []
    for col, unit in run.units.items():
        name = names.get(col, col.rsplit("_", 1)[0])
        out.append(ColumnOut(col, name, unit))
    return out


def write_run(out_dir: Path, run: ForeignRun, seed: int) -> dict:
    """Write one run's export; returns its truth.json record."""
    sim = simulate(run, seed)
    started = (START + timedelta(hours=run.index)).strftime("%Y-%m-%dT%H:%M:%S")
    meta = {k: v for k, v in sim.metadata.items() if k not in ("rig", "hose_area_m2")}
    meta = {"kind": run.kind, "run_id": run.run_id, "started_at": started, "operator": "guest", **meta}
    embedded = {k: v for k, v in meta.items() if k not in run.manifest}
    path = out_dir / run.rel_path
    cols = _export_columns(run)
    frame = sim.data
    fs = run.sim.get("fs_hz")
    if run.folder == LOGGER_FOLDER:
        _write_logger_csv(path, frame, [ColumnOut("t_s", "t", "s")] + cols, embedded, _logger_comment(run))
    elif run.fmt == "csv":
        time = [ColumnOut("t_s", "t", "s")] if run.time_column else []
        write_csv(path, frame, time + cols, embedded)
    elif run.fmt == "lvm":
        write_lvm(path, frame, cols, embedded, fs_hz=fs, date=started[:10].replace("-", "/"),
                  time=started[11:] + ".000000")
    elif run.fmt == "tdms":
        write_tdms(path, frame, cols, embedded, fs_hz=fs, waveform=True)
    elif run.fmt == "mat":
        write_mat(path, frame, cols, {**embedded, "Fs": float(fs)}, scalars=True, include_time=run.time_column)
    else:
        raise ValueError(run.fmt)
    expected = {
        "time_base": None if run.time_column else {"sample_rate_hz": fs},
        "derived": {"f_n": "f_cell - p_b * hose_area_m2"} if run.stem == "loadcell" else {},
        "columns": _expected_columns(run),
        "params": run.stated,
    }
    if run.folder == LOGGER_FOLDER:
        expected["comments"] = [_logger_comment(run)]   # params["comments"], not a metadata key
    truth = {**sim.truth, "sensors": run.sensors}
    return {"file": run.rel_path, "format": run.fmt, "kind": run.kind, "metadata": meta, "embedded": True,
            "manifest": run.manifest, "truth": jsonable(truth), "expected": jsonable(expected)}


def _expected_columns(run: ForeignRun) -> dict:
    """Samples columns and their stored units, as ingest must write them."""
    by_column = {c.column: c for c in CHANNELS.values()}
    out = {"t_s": "s"}
    for c in _export_columns(run):
        ch = by_column.get(c.column)
        if ch is not None:
            out[c.column] = ch.si_unit
        else:
            out[noncanonical_column(c.name, c.unit)] = c.unit
    if run.stem == "loadcell":
        out["f_n"] = "N"
    return out


def _manifest_text(rows: list[dict]) -> str:
    keys = ["file"] + sorted({k for r in rows for k in r if k != "file"})
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=keys, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow(r)
    return buf.getvalue()


def simulate_foreign(out_dir, seed: int = 1) -> dict:
    """Write ``foreign-2026/`` (exports, rig.toml per lab, manifests) and ``truth.json`` under
    ``out_dir``; returns the truth dict."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    runs = plan()
    records = [write_run(out, r, seed) for r in runs]
    for rel, text in RIG_TOMLS.items():
        p = out / CAMPAIGN / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text, encoding="utf-8")
    manifests: dict[str, list[dict]] = {}
    for r in runs:
        if r.manifest:
            manifests.setdefault(r.folder, []).append({"file": Path(r.rel_path).name, **r.manifest})
    for folder, rows in sorted(manifests.items()):
        (out / CAMPAIGN / folder / "manifest.csv").write_text(_manifest_text(rows), encoding="utf-8")
    truth = {"generator": "pneubench simulator", "seed": seed, "profile": "foreign", "runs_requested": None,
             "runs": {rec["metadata"]["run_id"]: rec for rec in records}}
    (out / "truth.json").write_text(json.dumps(jsonable(truth), indent=1, sort_keys=True), encoding="utf-8")
    return truth


__all__ = ["CAMPAIGN", "ForeignRun", "plan", "simulate", "simulate_foreign", "write_run", "RIG_TOMLS", "PINCH_VALVE", "linear_drive"]
