"""Synthetic campaigns: every kind with the papers' test matrices, in the formats a lab writes.

``simulate_campaign(out_dir, seed, profile, runs)`` writes, under ``out_dir``::

    plpa-2025/       PLPA characterisation: leakage, breakaway, viscous, identification, step,
                     and the ambient / supply logger (kind ``timeseries``)
    pla-2016/        PLA: the 120 spring tests and pressure steps
    durability-2025/ hose logbook (older hoses with odometer readings only, logged hoses),
                     durability runs and leakage checks of the logged hoses
    durability-2026/ the following campaign: a hose continued from 2025, new hoses
    truth.json       every parameter and every per-run true value

Each of those folders is one campaign when ``out_dir`` is the raw root (``pneubench rebuild --raw
out_dir``, as :func:`simulate_demo` does), or subfolders of one campaign when ``out_dir`` is ``raw/<name>``.
Run ids are explicit (``<folder>/<stem>``), so they do not depend on where ``out_dir`` sits.

Formats are mixed as in a real lab (see :data:`VARIANTS`): every kind in at least two formats,
metadata embedded in some files and given by ``manifest.csv`` in others (with ``rig.toml``
defaults under both), a ``;`` + decimal-comma CSV with kPa and Nl/min, absolute pressures
(``bara``, ``bar(a)``), LVM with two segments and LVM with waveform timing (no X column), TDMS
with waveform timing and TDMS with two groups, MAT with a ``meta`` struct or numeric scalars,
a headerless whitespace text export described by ``rig.toml`` (encoder counts scaled there),
CSV columns renamed by ``rig.toml``, Excel workbooks (``meta`` sheet; a units row under the names,
described by ``rig.toml``) and ASAM MDF 4 files (metadata in the header comment) for every
characterisation kind, and non-canonical channels kept with their units (the
logger's ``temperature[degC]`` and ``rel_humidity[%]``, in CSV beside ``p_supply[bar]`` and in
TDMS with waveform timing, where ``t`` is the only canonical channel).

Output is byte-identical for a seed: each run draws from its own generator seeded with
``(seed, index)``, dates are fixed, files are written in a fixed order of content.

Profiles
--------
``demo`` keeps the papers' matrices (leakage all settings and chambers, breakaway 5 x 5 x 2 with
2 repetitions, viscous 0-3 bar + near-zero + load-cell runs, 120 spring tests ...) at modest
sample rates, two 30 min ambient logger runs at 1 Hz, and
keeps the logbook's kilometres realistic (Weibull lives of tens of km) while logging durability
runs at 5 Hz with 1 m strokes at 1 m/s and 0.25 s dwells: every turn is still sampled, so
distance and stroke counts are exact, at about 40 samples per 100 m instead of 8,000. Older
hoses carry odometer readings only (no runs), as bench-exports.md allows.
``full`` logs durability at 1 kHz in runs of about 8 h (10 km of 0.5 m strokes: about 29 M samples,
~0.7 GB TDMS / ~1 GB CSV per run, written in 2 M-row chunks), breakaway with 3 repetitions at
1 kHz, identification 60 s at 5 kHz.
``mini`` is for tests: one run per kind and format variant, tiny durability, 1 min logger runs.
``foreign`` writes only the campaign ``foreign-2026``: other labs' rigs and exports (analog
position sensors, 1 um / 50 um encoders, a load cell with a stated force balance, exports without
a time column, a look-alike channel ``F`` in ``g``), see :mod:`pipeline.simulator.foreign`. It is
not part of the demo, which stays about a minute.
``runs=N`` pads the characterisation matrices with further repetitions (new seeds) to reach N
runs in total, for campaigns of 1,000+ runs; a smaller N keeps the first N runs (interleaved
across kinds, durability hoses first).
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.progress import Progress
from pipeline.simulator import ambient, pla, plpa
from pipeline.simulator import durability as dur
from pipeline.simulator.base import HOSE_AREA_M2, P_ATM_PA, SimRun, jsonable
from pipeline.simulator.writers import (ColumnOut, default_columns, write_csv, write_lvm, write_mat, write_mf4, write_tdms,
                                         write_xlsx)

PROFILES_AVAILABLE = ("demo", "full", "mini", "foreign")


@dataclass(frozen=True)
class Profile:
    """Sizes of a campaign (sample rates, durations, repetitions, hoses)."""

    name: str
    leak_fs_hz: float = 50.0
    leak_plateau_s: float = 4.0
    breakaway_fs_hz: float = 200.0
    breakaway_reps: int = 2              # repetitions of the 5 x 5 x 2 matrix (mean +/- std)
    viscous_fs_hz: float = 500.0
    identification_runs: int = 2
    identification_s: float = 20.0
    step_runs: int = 3
    step_fs_hz: float = 1000.0
    spring_fs_hz: float = 500.0
    spring_cycles: float = 3.0
    pressure_step_runs: int = 1          # per chamber
    dur_fs_hz: float = 5.0
    dur_stroke_m: float = 1.0
    dur_speed_m_s: float = 1.0
    dur_accel_m_s2: float = 4.0
    dur_dwell_s: float = 0.25
    dur_run_km: float = 8.0
    logged_hoses: int = 6                # hoses with durability runs
    odometer_hoses: int = 10             # older hoses: logbook with odometer km only
    stop_km: dict = field(default_factory=lambda: {"distance": 45.0, "force": 35.0})
    odometer_stop_km: float = 150.0
    check_every: int = 2                 # leakage check after every n runs
    check_fs_hz: float = 20.0
    check_plateau_s: float = 3.0
    log_runs: int = 2                    # ambient / supply logger (kind timeseries)
    log_fs_hz: float = 1.0
    log_s: float = 1800.0
    limit_per_variant: int | None = None  # mini: runs per kind and format variant
    chunk_rows: int = 2_000_000


PROFILES = {
    "demo": Profile("demo"),
    "full": Profile("full", leak_fs_hz=200.0, leak_plateau_s=8.0, breakaway_fs_hz=1000.0, breakaway_reps=3,
                    viscous_fs_hz=1000.0, identification_runs=5, identification_s=60.0, step_runs=6,
                    spring_fs_hz=1000.0, pressure_step_runs=3, dur_fs_hz=1000.0, dur_stroke_m=0.5,
                    dur_speed_m_s=0.5, dur_accel_m_s2=2.0, dur_dwell_s=0.2, dur_run_km=10.0, logged_hoses=4,
                    odometer_hoses=20, stop_km={"distance": 20.0, "force": 15.0}, check_every=1,
                    check_fs_hz=100.0, check_plateau_s=6.0),
    "mini": Profile("mini", leak_fs_hz=20.0, leak_plateau_s=2.0, breakaway_fs_hz=100.0, viscous_fs_hz=200.0,
                    identification_runs=2, identification_s=2.0, step_runs=3, step_fs_hz=200.0,
                    spring_fs_hz=200.0, spring_cycles=1.5, dur_run_km=0.6, logged_hoses=2, odometer_hoses=3,
                    stop_km={"distance": 1.0, "force": 1.0}, odometer_stop_km=150.0, check_every=1,
                    check_fs_hz=10.0, check_plateau_s=1.0, log_s=60.0, limit_per_variant=1),
}

# -- format variants ---------------------------------------------------------------------------
#: Per kind, the ways its runs are exported (cycled over the runs of the kind). ``units``:
#: raw unit per channel; ``names``: raw channel names (mapped back by the folder's rig.toml);
#: ``embed``: metadata in the file (else in the folder's manifest.csv).
VARIANTS: dict[str, list[dict]] = {
    "leakage": [
        dict(fmt="csv", folder="leakage", units={"p_supply": "bar", "q_leak": "l/min"}, embed=True),
        dict(fmt="csv", folder="leakage/eu", units={"p_supply": "kPa", "q_leak": "Nl/min"}, embed=False,
             opts=dict(delimiter=";", decimal=",")),
        dict(fmt="tdms", folder="leakage", units={"p_supply": "bar", "q_leak": "l/min"}, embed=True,
             opts=dict(waveform=True)),
        dict(fmt="mat", folder="leakage", units={"p_supply": "Pa", "q_leak": "g/s"}, embed=True),
        dict(fmt="xlsx", folder="leakage/workbooks", units={"p_supply": "bar", "q_leak": "l/min"}, embed=True,
             opts=dict(units_row=True)),
    ],
    "breakaway": [
        dict(fmt="lvm", folder="breakaway", units={"p_a": "bar", "p_b": "bar", "x": "mm"}, embed=True,
             opts=dict(segments=2, x_columns="One")),
        dict(fmt="csv", folder="breakaway", units={"p_a": "bara", "p_b": "bara", "x": "mm"}, embed=True),
        dict(fmt="tdms", folder="breakaway", units={"p_a": "kPa", "p_b": "kPa", "x": "um"}, embed=True,
             opts=dict(extra_group="Settings")),
        dict(fmt="lvm", folder="breakaway", units={"p_a": "bar", "p_b": "bar", "x": "mm"}, embed=False,
             opts=dict(x_columns="No")),
        dict(fmt="mf4", folder="breakaway", units={"p_a": "bar", "p_b": "bar", "x": "mm"}, embed=True),
    ],
    "viscous": [
        dict(fmt="csv", folder="viscous", units={"p_a": "bar", "p_b": "bar", "x": "mm"}, embed=True),
        dict(fmt="lvm", folder="viscous", units={"p_a": "bar", "p_b": "bar", "x": "mm"}, embed=True,
             opts=dict(x_columns="No")),
        dict(fmt="mf4", folder="viscous", units={"p_a": "kPa", "p_b": "kPa", "x": "mm"}, embed=True),
    ],
    "viscous_force": [
        dict(fmt="mat", folder="viscous", units={"f": "N", "x": "mm"}, embed=True, opts=dict(scalars=True)),
        dict(fmt="csv", folder="viscous", units={"f": "N", "x": "mm"}, embed=False),
    ],
    "identification": [
        dict(fmt="tdms", folder="identification", units={"x": "mm", "x_ref": "mm", "u": "V", "u_d": "mV"},
             embed=True, opts=dict(waveform=True)),
        dict(fmt="mat", folder="identification", units={"x": "m", "x_ref": "m", "u": "V", "u_d": "V"}, embed=True,
             opts=dict(scalars=True)),
        dict(fmt="mf4", folder="identification", units={"x": "mm", "x_ref": "mm", "u": "V", "u_d": "V"}, embed=True),
    ],
    "step": [
        dict(fmt="csv", folder="step", units={"x": "mm", "x_ref": "mm", "u": "V"}, embed=True),
        dict(fmt="lvm", folder="step", units={"x": "mm", "x_ref": "mm", "u": "mV"}, embed=True,
             opts=dict(x_columns="One")),
        dict(fmt="txt", folder="step/headerless", units={}, embed=False, headerless=True),
        dict(fmt="xlsx", folder="step", units={"x": "mm", "x_ref": "mm", "u": "V"}, embed=True),
    ],
    "spring": [
        dict(fmt="mat", folder="spring", units={"d": "mm", "f": "kN", "p": "bar(a)"}, embed=True),
        dict(fmt="csv", folder="spring/bench-pc", units={"d": "mm", "f": "N", "p": "bar(a)"}, embed=False,
             names={"d": "Displacement", "f": "Force", "p": "Pressure"}, opts=dict(delimiter="\t")),
        dict(fmt="xlsx", folder="spring", units={"d": "mm", "f": "N", "p": "bar(a)"}, embed=True),
    ],
    "pressure_step": [
        dict(fmt="lvm", folder="pressure_step", units={"p": "bar", "p_ref": "bar"}, embed=True,
             opts=dict(x_columns="One")),
        dict(fmt="csv", folder="pressure_step", units={"p": "bara", "p_ref": "bara"}, embed=True),
        dict(fmt="mf4", folder="pressure_step", units={"p": "bar", "p_ref": "bar"}, embed=True),
    ],
    "durability": [
        dict(fmt="tdms", folder="runs", units={"x": "mm", "p_a": "bar", "p_b": "bar"}, embed=True,
             opts=dict(waveform=True)),
        dict(fmt="csv", folder="runs", units={"x": "mm", "p_a": "bar", "p_b": "bar"}, embed=True),
    ],
    "timeseries": [
        dict(fmt="csv", folder="ambient", units={"p_supply": "bar", "temperature_degc": "degC",
                                                  "rel_humidity_pct": "%"},
             names={"temperature_degc": "temperature", "rel_humidity_pct": "rel_humidity"},
             embed=True, channels=["p_supply_pa", "temperature_degc", "rel_humidity_pct"]),
        dict(fmt="tdms", folder="ambient", units={"temperature_degc": "degC", "rel_humidity_pct": "%"}, embed=False,
             names={"temperature_degc": "Temperature", "rel_humidity_pct": "Rel. Humidity"},
             channels=["temperature_degc", "rel_humidity_pct"], opts=dict(waveform=True)),
    ],
    "leakage_check": [
        dict(fmt="csv", folder="leakage-checks", units={"p_supply": "bar", "q_leak": "l/min"}, embed=True),
        dict(fmt="tdms", folder="leakage-checks", units={"p_supply": "bar", "q_leak": "l/min"}, embed=False,
             opts=dict(waveform=True)),
    ],
}

#: rig.toml written per folder: campaign defaults, the headerless export, the renamed channels.
RIG_TOMLS = {
    "plpa-2025/rig.toml": '# PLPA bench, characterisation campaign\n[metadata]\nrig = "plpa-1"\n'
                          'hose_area_m2 = 4.9e-4\noperator = "lab"\n',
    "plpa-2025/step/headerless/rig.toml": (
        '# Old controller PC: whitespace text, no header. Column 2 is the encoder count (5 um).\n'
        '[read]\ndelimiter = "whitespace"\ndecimal = "."\nskip_rows = 0\nheader = false\n\n'
        '[channels."1"]\nchannel = "t"\nunit = "s"\n\n'
        '[channels."2"]\nchannel = "x"\nunit = "mm"\nscale = 0.005\noffset = 0.0\n\n'
        '[channels."3"]\nchannel = "x_ref"\nunit = "mm"\n\n'
        '[metadata]\nkind = "step"\n'),
    "pla-2016/rig.toml": '# PLA cylinder on the hydraulic test machine\n[metadata]\nrig = "pla-1"\nstroke_mm = 40\n',
    "plpa-2025/leakage/workbooks/rig.toml": '# Spreadsheet exports: units in the row under the names\n[read]\nunits_row = 2\n',
    "pla-2016/spring/bench-pc/rig.toml": (
        '# The bench PC names channels in words\n[channels.Displacement]\nchannel = "d"\n\n'
        '[channels.Force]\nchannel = "f"\n\n[channels.Pressure]\nchannel = "p"\n'),
    # the endurance rig's encoder is stated (docs/inputs.md): at 5 Hz logging, 1 m strokes move
    # 200 mm between samples, too coarse for the record to show its 5 um quantisation
    "durability-2025/rig.toml": '[metadata]\nrig = "plpa-2"\nhose_area_m2 = 4.9e-4\n\n[sensors.x]\nresolution = "5 um"\n',
    "durability-2026/rig.toml": '[metadata]\nrig = "plpa-2"\nhose_area_m2 = 4.9e-4\n\n[sensors.x]\nresolution = "5 um"\n',
}

CAMPAIGN_START = {"plpa-2025": datetime(2025, 3, 3, 8, 0), "pla-2016": datetime(2016, 5, 9, 9, 0),
                  "durability-2025": datetime(2025, 2, 3, 7, 30), "durability-2026": datetime(2026, 1, 12, 7, 30),
                  "odometer": datetime(2023, 4, 3, 8, 0)}
OPERATORS = ("ana", "joao", "rui")
HOSE_TYPE = "FLEXIGOM AIR"


# -- run plans ---------------------------------------------------------------------------------
@dataclass
class RunPlan:
    """One run to simulate and write."""

    index: int
    run_id: str
    kind: str
    rel_path: str
    variant: dict
    gen: str
    kwargs: dict
    metadata: dict
    group: str = ""   # variant group (e.g. "viscous_force"), for coverage reports

    @property
    def fmt(self) -> str:
        return self.variant["fmt"]


GENERATORS = {
    "leakage": plpa.simulate_leakage, "breakaway": plpa.simulate_breakaway, "viscous": plpa.simulate_viscous,
    "identification": plpa.simulate_identification, "step": plpa.simulate_step, "spring": pla.simulate_spring,
    "pressure_step": pla.simulate_pressure_step, "timeseries": ambient.simulate_timeseries,
}


def run_rng(seed: int, index: int) -> np.random.Generator:
    """The generator of run ``index`` of a campaign: independent of order and parallelism."""
    return np.random.default_rng([int(seed), int(index)])


def _iso(dt: datetime) -> str:
    return dt.strftime("%Y-%m-%dT%H:%M:%S")


def generate(plan: RunPlan, seed: int) -> SimRun:
    """The SimRun of a plan as exported: the columns its file carries, in memory.

    ``data`` is what ingest must give back for the file (durability: all chunks concatenated).
    """
    frames, meta, truth = _frames(plan, seed)
    data = frames if isinstance(frames, pd.DataFrame) else pd.concat(list(frames), ignore_index=True)
    return SimRun(data[["t_s"] + _channels_of(plan)], meta, truth)


def _frames(plan: RunPlan, seed: int, chunk_rows: int = 2_000_000):
    rng = run_rng(seed, plan.index)
    if plan.gen == "durability":
        kw = dict(plan.kwargs)
        p_mean = kw.pop("p_mean_bar", 2.0)
        sp = dur.stroke_plan(**kw)
        truth = dur.durability_truth(sp, plan.metadata["hose_id"], plan.metadata.get("adjustment"), p_mean)
        meta = {"kind": "durability", "rig": "plpa-2", "hose_area_m2": HOSE_AREA_M2, **plan.metadata}
        return dur.iter_durability_chunks(sp, rng, p_mean_bar=p_mean, chunk_rows=chunk_rows), meta, truth
    run = GENERATORS[plan.gen](rng=rng, **plan.kwargs)
    meta = {**run.metadata, **plan.metadata}
    return run.data, meta, run.truth


def _variant_columns(kind_columns: list[str], variant: dict) -> list[ColumnOut]:
    return default_columns(kind_columns, variant.get("units"), variant.get("names"))


def _channels_of(plan: RunPlan) -> list[str]:
    """Warehouse columns a plan's run has (besides t_s), in export order."""
    k = plan.kind
    if k == "leakage":
        return ["p_supply_pa", "q_leak_kg_s"]
    if k == "breakaway":
        return ["p_a_pa", "p_b_pa", "x_m"]
    if k == "viscous":
        return ["x_m", "f_n"] if plan.kwargs.get("use_force_channel") else ["p_a_pa", "p_b_pa", "x_m"]
    if k == "identification":
        return ["x_m", "x_ref_m", "u_v", "u_d_v"]
    if k == "step":
        return ["x_m", "x_ref_m"] if plan.variant.get("headerless") else ["x_m", "x_ref_m", "u_v"]
    if k == "spring":
        return ["d_m", "f_n", "p_pa"]
    if k == "pressure_step":
        return ["p_pa", "p_ref_pa"]
    if k == "durability":
        return ["x_m", "p_a_pa", "p_b_pa"]
    if k == "timeseries":
        return list(plan.variant["channels"])
    raise KeyError(k)


EMBED_ORDER = ("kind", "run_id", "started_at", "rig", "operator")


def _ordered(meta: dict) -> dict:
    head = {k: meta[k] for k in EMBED_ORDER if k in meta}
    return {**head, **{k: meta[k] for k in sorted(meta) if k not in head}}


def write_run(out_dir: Path, plan: RunPlan, seed: int, chunk_rows: int = 2_000_000) -> dict:
    """Simulate one plan and write its export; returns its truth.json record (and manifest row)."""
    frames, meta, truth = _frames(plan, seed, chunk_rows)
    meta = _ordered(jsonable(meta))
    v = plan.variant
    path = out_dir / plan.rel_path
    cols = _channels_of(plan)
    opts = dict(v.get("opts", {}))
    manifest_row = None
    embedded = meta if v.get("embed") else {k: meta[k] for k in ("operator",) if k in meta}
    if not v.get("embed"):
        # hose_area_m2 comes from the campaign's rig.toml, operator from the file itself
        manifest_row = {k: val for k, val in meta.items() if k not in ("hose_area_m2", "operator")}
        if v.get("headerless"):
            manifest_row.pop("kind", None)  # the headerless folder's rig.toml says kind = step
            manifest_row["operator"] = meta["operator"]  # nothing can be embedded in it
    fs = (truth.get("fs_hz") if isinstance(truth, dict) else None) or plan.kwargs.get("fs_hz")
    if v["fmt"] in ("csv", "txt"):
        if v.get("headerless"):
            _write_headerless_step(path, frames)
        else:
            write_csv(path, frames, [ColumnOut("t_s", "t", "s")] + _variant_columns(cols, v),
                      embedded or None, **opts)
    elif v["fmt"] == "lvm":
        write_lvm(path, frames, _variant_columns(cols, v), embedded or None, fs_hz=fs,
                  date=meta["started_at"][:10].replace("-", "/"), time=meta["started_at"][11:] + ".000000", **opts)
    elif v["fmt"] == "tdms":
        if opts.get("extra_group"):
            embedded = {**embedded, "group": "Data"}
        write_tdms(path, frames, _variant_columns(cols, v), embedded or None, fs_hz=fs, **opts)
    elif v["fmt"] == "mat":
        write_mat(path, frames, _variant_columns(cols, v), embedded or None, **opts)
    elif v["fmt"] == "xlsx":
        write_xlsx(path, frames, _variant_columns(cols, v), embedded or None, **opts)
    elif v["fmt"] == "mf4":
        write_mf4(path, frames, _variant_columns(cols, v), embedded or None, **opts)
    else:
        raise ValueError(v["fmt"])
    record = {"file": plan.rel_path, "format": v["fmt"], "kind": plan.kind, "metadata": meta,
              "embedded": bool(v.get("embed")), "truth": jsonable(truth)}
    if manifest_row is not None:
        record["manifest_row"] = manifest_row
    return record


def _write_headerless_step(path: Path, frames) -> None:
    """Whitespace text, no header: t [s], encoder counts (rig.toml scales 0.005 mm), x_ref [mm]."""
    frame = frames if isinstance(frames, pd.DataFrame) else pd.concat(list(frames), ignore_index=True)
    counts = np.round(frame["x_m"].to_numpy() / 5e-6).astype(np.int64)
    x_ref_mm = frame["x_ref_m"].to_numpy() * 1e3
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        for t, c, r in zip(frame["t_s"].to_numpy(), counts, x_ref_mm):
            fh.write(f"{float(t)!r}  {int(c):d}  {float(r)!r}\n")


# -- the campaign plan -------------------------------------------------------------------------
class _Planner:
    def __init__(self, profile: Profile, seed: int):
        self.p = profile
        self.seed = seed
        self.plans: list[RunPlan] = []
        self.counts: dict[str, int] = {}
        self.clock: dict[str, datetime] = dict(CAMPAIGN_START)
        self.hoses: dict[str, dict] = {}
        self.logbooks: dict[str, list[dict]] = {"durability-2025": [], "durability-2026": []}

    def variant(self, group: str, i: int) -> dict:
        vs = VARIANTS[group]
        return vs[i % len(vs)]

    def add(self, campaign: str, group: str, kind: str, stem: str, gen: str, kwargs: dict, meta: dict | None = None,
            minutes: float = 5.0, variant: dict | None = None, when: datetime | None = None) -> RunPlan:
        i = self.counts.get(group, 0)
        self.counts[group] = i + 1
        v = variant or self.variant(group, i)
        ext = v["fmt"]
        rel = f"{campaign}/{v['folder']}/{stem}.{ext}"
        start = when or self.clock[campaign]
        if when is None:
            self.clock[campaign] = start + timedelta(minutes=minutes)
        md = {"run_id": f"{campaign}/{stem}", "started_at": _iso(start),
              "operator": OPERATORS[len(self.plans) % len(OPERATORS)], **(meta or {})}
        plan = RunPlan(len(self.plans), md["run_id"], kind, rel, v, gen, kwargs, md, group)
        self.plans.append(plan)
        return plan

    # PLPA characterisation ---------------------------------------------------------------
    def leakage(self):
        p = self.p
        settings = [("distance", z, None) for z in plpa.DISTANCE_SETTINGS_MM] + \
                   [("force", None, f) for f in plpa.FORCE_SETTINGS_N]
        for chamber in ("A", "B"):
            for adj, z, f in settings:
                tag = f"z{z:.1f}" if z is not None else f"f{f:.0f}"
                self.add("plpa-2025", "leakage", "leakage", f"leak-{chamber}-{tag}", "leakage",
                         dict(chamber=chamber, adjustment=adj, z_rollers_mm=z, spring_force_n=f,
                              fs_hz=p.leak_fs_hz, plateau_s=p.leak_plateau_s), minutes=15)

    def breakaway(self, reps: int | None = None, rep0: int = 0):
        p = self.p
        for rep in range(rep0, rep0 + (reps or p.breakaway_reps)):
            for direction in ("P", "N"):
                for bp in (0.0, 1.0, 2.0, 3.0, 4.0):
                    for rate in (0.25, 0.5, 1.0, 2.0, 4.0):
                        self.add("plpa-2025", "breakaway", "breakaway",
                                 f"brk-{direction}-bp{bp:.0f}-r{rate:g}-{rep + 1:02d}", "breakaway",
                                 dict(direction=direction, backpressure_bar=bp, force_rate_n_s=rate,
                                      fs_hz=p.breakaway_fs_hz), minutes=3)

    def viscous(self, rep: int = 0):
        p = self.p
        sfx = f"-{rep + 1:02d}"
        for bp in (0.0, 1.0, 2.0, 3.0):
            self.add("plpa-2025", "viscous", "viscous", f"visc-bp{bp:.0f}{sfx}", "viscous",
                     dict(backpressure_bar=bp, fs_hz=p.viscous_fs_hz), minutes=10)
        self.add("plpa-2025", "viscous", "viscous", f"visc-nearzero{sfx}", "viscous",
                 dict(backpressure_bar=0.0, speeds_m_s=list(plpa.NEAR_ZERO_SPEEDS_M_S), fs_hz=p.viscous_fs_hz),
                 minutes=10)
        for bp in (0.0, 2.0):
            self.add("plpa-2025", "viscous_force", "viscous", f"visc-loadcell-bp{bp:.0f}{sfx}", "viscous",
                     dict(backpressure_bar=bp, use_force_channel=True, fs_hz=p.viscous_fs_hz), minutes=10)

    def identification(self, n: int | None = None, rep0: int = 0):
        for i in range(rep0, rep0 + (n or self.p.identification_runs)):
            self.add("plpa-2025", "identification", "identification", f"ident-{i + 1:02d}", "identification",
                     dict(duration_s=self.p.identification_s), minutes=5)

    def step(self, n: int | None = None, rep0: int = 0):
        for i in range(rep0, rep0 + (n or self.p.step_runs)):
            self.add("plpa-2025", "step", "step", f"step-{i + 1:02d}", "step",
                     dict(fs_hz=self.p.step_fs_hz, x0_m=0.15 + 0.05 * (i % 4)), minutes=5)

    # PLA -----------------------------------------------------------------------------------
    def spring(self, rep: int = 0):
        p = self.p
        for chamber in ("front", "rear"):
            for p0 in pla.P0_BAR_ABS:
                for amp in pla.AMPLITUDES_MM:
                    for f in pla.FREQUENCIES_HZ:
                        sfx = "" if rep == 0 else f"-{rep + 1:02d}"
                        self.add("pla-2016", "spring", "spring", f"spring-{chamber}-p{p0:.0f}-d{amp:.0f}-f{f:g}{sfx}",
                                 "spring", dict(chamber=chamber, p0_bar_abs=p0, amplitude_mm=amp, frequency_hz=f,
                                                fs_hz=p.spring_fs_hz, cycles=p.spring_cycles), minutes=4)

    def pressure_step(self, n: int | None = None, rep0: int = 0):
        for i in range(rep0, rep0 + (n or self.p.pressure_step_runs)):
            for chamber in ("front", "rear"):
                self.add("pla-2016", "pressure_step", "pressure_step", f"pstep-{chamber}-{i + 1:02d}",
                         "pressure_step", dict(chamber=chamber), minutes=5)

    # ambient / supply logger ---------------------------------------------------------------
    def timeseries(self):
        """Logger runs at 07:30 on successive campaign days (the variant decides the channels)."""
        p = self.p
        for i in range(p.log_runs):
            v = self.variant("timeseries", i)
            when = CAMPAIGN_START["plpa-2025"] - timedelta(minutes=30) + timedelta(days=i)
            self.add("plpa-2025", "timeseries", "timeseries", f"ambient-{i + 1:02d}", "timeseries",
                     dict(duration_s=p.log_s, fs_hz=p.log_fs_hz, supply="p_supply_pa" in v["channels"],
                          temperature_c=round(20.5 + 0.5 * i, 2)), variant=v, when=when)

    # durability ----------------------------------------------------------------------------
    def durability(self):
        p = self.p
        rng = np.random.default_rng([int(self.seed), 987654321])
        # older hoses: odometer only (logbook of durability-2025, dates from 2023)
        when = self.clock["odometer"]
        for j in range(p.odometer_hoses):
            adj = ("distance", "force")[j % 2]
            hose_id = f"H{j + 1:03d}"
            life = dur.weibull_life_km(adj, rng)
            setting = self._setting(adj, j)
            stop = p.odometer_stop_km
            failed = life <= stop
            dist = life if failed else stop
            days = max(1, int(dist / 20.0))  # about 20 km a working day on the old rig
            ev = [self._ev(hose_id, "installed", when, adjustment=adj, hose_type=HOSE_TYPE, **setting,
                           notes="tested before runs were logged")]
            if dist > 10:
                ev.append(self._ev(hose_id, "inspected", when + timedelta(days=days // 2, hours=6),
                                   wall_thickness_mm=round(dur.wall_thickness_mm(adj, dist / 2) + rng.normal(0, 0.01), 2),
                                   notes=f"odometer {dist / 2:.1f} km"))
            end = when + timedelta(days=days, hours=8)
            mode = self._failure_mode(adj, rng)
            if failed:
                ev.append(self._ev(hose_id, "failed", end, failure_mode=mode, distance_km=round(dist, 1)))
            else:
                ev.append(self._ev(hose_id, "removed", end, distance_km=round(dist, 1), notes="test stopped"))
            self.logbooks["durability-2025"] += ev
            self.hoses[hose_id] = {"hose_id": hose_id, "hose_type": HOSE_TYPE, "adjustment": adj, **setting,
                                   "life_km_drawn": life, "status": "failed" if failed else "removed",
                                   "failure_mode": mode if failed else None, "distance_km": round(dist, 1),
                                   "source": "odometer", "n_runs": 0, "strokes": None,
                                   "campaigns": ["durability-2025"]}
            when = end + timedelta(days=1)
        # logged hoses: runs, inspections, leakage checks; the first one spans both campaigns
        for j in range(p.logged_hoses):
            adj = ("distance", "force")[j % 2]
            hose_id = f"H{100 + j + 1:03d}"
            camp = "durability-2025" if j < max(1, p.logged_hoses // 2) else "durability-2026"
            spans = j == 0
            life = dur.weibull_life_km(adj, rng)
            stop = p.stop_km[adj]
            if j == p.logged_hoses - 1:
                outcome = "running"
            elif life <= stop:
                outcome = "failed"
            else:
                outcome = "removed" if j % 3 != 1 else "running"
            end_km = life if outcome == "failed" else stop
            self._logged_hose(hose_id, adj, j, camp, spans, life, end_km, outcome, rng)

    def _setting(self, adj: str, j: int) -> dict:
        if adj == "distance":
            return {"z_rollers_mm": (4.0, 4.5, 5.0)[(j // 2) % 3]}
        return {"spring_force_n": (429.0, 858.0)[(j // 2) % 2]}

    def _failure_mode(self, adj: str, rng) -> str:
        u = rng.random()
        return ("leakage" if u < 0.7 else "rupture") if adj == "distance" else ("rupture" if u < 0.8 else "leakage")

    def _ev(self, hose_id, event, at, **kw) -> dict:
        return {"hose_id": hose_id, "event": event, "at": _iso(at), **kw}

    def _logged_hose(self, hose_id, adj, j, camp, spans, life, end_km, outcome, rng):
        p = self.p
        setting = self._setting(adj, j)
        n_runs = max(1, math.ceil(end_km / p.dur_run_km - 1e-9))
        split = (n_runs + 1) // 2 if spans else n_runs  # runs logged in the first campaign
        if spans and n_runs < 2:
            n_runs, split = 2, 1
        per_run = end_km / n_runs
        hose_campaigns = [camp] + (["durability-2026"] if spans else [])
        clock_key = camp
        when = self.clock[clock_key]
        self.logbooks[camp].append(self._ev(hose_id, "installed", when - timedelta(hours=1), adjustment=adj,
                                            hose_type=HOSE_TYPE, **setting))
        km = 0.0
        strokes = 0
        checks = []

        def check(after_run: int):
            nonlocal when
            cam = self._camp_at(after_run, split, camp, spans)
            p_seal = dur.worn_seal_pressure_bar(adj, km, **setting)
            plan = self.add(cam, "leakage_check", "leakage", f"check-{hose_id}-{after_run:02d}", "leakage",
                            dict(chamber="A", adjustment=adj, z_rollers_mm=setting.get("z_rollers_mm"),
                                 spring_force_n=setting.get("spring_force_n"), p_seal_bar=p_seal,
                                 fs_hz=p.check_fs_hz, plateau_s=p.check_plateau_s, hose_id=hose_id),
                            meta={"hose_id": hose_id, "distance_km_so_far": round(km, 6)}, when=when)
            checks.append({"run_id": plan.run_id, "distance_km": km, "p_seal_bar": p_seal})
            when += timedelta(minutes=30)

        check(0)
        for r in range(n_runs):
            cam = self._camp_at(r + 1, split, camp, spans)
            if spans and r == split:
                self.clock[camp] = when
                when = max(self.clock["durability-2026"], when)
            sp = dur.stroke_plan(distance_m=per_run * 1e3, stroke_m=p.dur_stroke_m, speed_m_s=p.dur_speed_m_s,
                                 accel_m_s2=p.dur_accel_m_s2, dwell_s=p.dur_dwell_s, fs_hz=p.dur_fs_hz)
            self.add(cam, "durability", "durability", f"dur-{hose_id}-{r + 1:02d}", "durability",
                     dict(distance_m=per_run * 1e3, stroke_m=p.dur_stroke_m, speed_m_s=p.dur_speed_m_s,
                          accel_m_s2=p.dur_accel_m_s2, dwell_s=p.dur_dwell_s, fs_hz=p.dur_fs_hz),
                     meta={"hose_id": hose_id, "adjustment": adj, **setting}, when=when)
            km += sp.distance_m / 1e3
            strokes += sp.strokes
            when = when + timedelta(seconds=math.ceil(sp.duration_s)) + timedelta(hours=2)
            last = r == n_runs - 1
            if (r + 1) % p.check_every == 0 or last:
                if not (last and outcome == "failed"):
                    check(r + 1)
            if (r + 1) % 2 == 0 and not last:
                book = self._camp_at(r + 1, split, camp, spans)
                self.logbooks[book].append(self._ev(hose_id, "inspected", when, wall_thickness_mm=round(
                    dur.wall_thickness_mm(adj, km) + rng.normal(0, 0.01), 2)))
                when += timedelta(minutes=20)
        book = self._camp_at(n_runs, split, camp, spans)
        mode = self._failure_mode(adj, rng) if outcome == "failed" else None
        if outcome == "failed":
            extra = {"distance_km": round(km * 1.005, 2), "notes": "odometer read at failure"} if j % 4 == 2 else {}
            self.logbooks[book].append(self._ev(hose_id, "failed", when, failure_mode=mode, **extra))
            if mode == "leakage":
                check(n_runs)
        elif outcome == "removed":
            self.logbooks[book].append(self._ev(hose_id, "removed", when, notes="campaign budget reached"))
        self.clock["durability-2026" if spans else camp] = when + timedelta(days=1)
        self.hoses[hose_id] = {"hose_id": hose_id, "hose_type": HOSE_TYPE, "adjustment": adj, **setting,
                               "life_km_drawn": life, "status": outcome, "failure_mode": mode,
                               "distance_km": km, "strokes": strokes, "source": "runs", "n_runs": n_runs,
                               "campaigns": hose_campaigns, "leakage_checks": checks}

    @staticmethod
    def _camp_at(run_number: int, split: int, camp: str, spans: bool) -> str:
        return "durability-2026" if spans and run_number > split else camp


def plan_campaign(seed: int = 1, profile: str | Profile = "demo", runs: int | None = None) -> tuple[list[RunPlan], _Planner]:
    """Every run of a campaign (no file written): the plans and the planner (hoses, logbooks)."""
    prof = PROFILES[profile] if isinstance(profile, str) else profile
    pl = _Planner(prof, seed)
    pl.durability()
    n_dur = len(pl.plans)
    pl.leakage()
    pl.breakaway()
    pl.viscous()
    pl.identification()
    pl.step()
    pl.spring()
    pl.pressure_step()
    pl.timeseries()
    if prof.limit_per_variant:
        keep, seen = [], {}
        for plan in pl.plans:
            if plan.group in ("durability", "leakage_check"):
                keep.append(plan)
                continue
            key = (plan.group, VARIANTS[plan.group].index(plan.variant))
            if seen.get(key, 0) < prof.limit_per_variant:
                seen[key] = seen.get(key, 0) + 1
                keep.append(plan)
        pl.plans = keep
    if runs is not None:
        if runs < len(pl.plans):
            dur_plans, rest = pl.plans[:n_dur], pl.plans[n_dur:]
            by_group: dict[str, list] = {}
            for plan in rest:
                by_group.setdefault(plan.group, []).append(plan)
            order = []
            while any(by_group.values()):
                for g in list(by_group):
                    if by_group[g]:
                        order.append(by_group[g].pop(0))
            pl.plans = (dur_plans + order)[:max(runs, 0)]
        rep = 1
        while len(pl.plans) < runs:
            pl.breakaway(reps=1, rep0=prof.breakaway_reps + rep - 1)
            pl.viscous(rep=rep)
            pl.spring(rep=rep)
            pl.identification(n=1, rep0=prof.identification_runs + rep - 1)
            pl.step(n=1, rep0=prof.step_runs + rep - 1)
            pl.pressure_step(n=1, rep0=prof.pressure_step_runs + rep - 1)
            rep += 1
        pl.plans = pl.plans[:runs] if len(pl.plans) > runs else pl.plans
    return pl.plans, pl


# -- writing -----------------------------------------------------------------------------------
HOSES_COLUMNS = ["hose_id", "event", "at", "hose_type", "adjustment", "z_rollers_mm", "spring_force_n",
                 "failure_mode", "wall_thickness_mm", "distance_km", "notes"]


def _csv_text(rows: list[dict], columns: list[str]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n", extrasaction="ignore")
    w.writeheader()
    for row in rows:
        w.writerow({k: ("" if row.get(k) is None else (repr(row[k]) if isinstance(row[k], float) else row[k]))
                    for k in columns})
    return buf.getvalue()


@dataclass
class CampaignSummary:
    """What :func:`simulate_campaign` wrote."""

    out_dir: Path
    n_runs: int
    n_files: int
    bytes: int
    by_kind: dict
    by_format: dict


def simulate_campaign(out_dir, seed: int = 1, profile: str = "demo", runs: int | None = None,
                      jobs: int | None = None, progress=None) -> CampaignSummary:
    """Write a synthetic campaign (every kind, every format) with ``truth.json`` under ``out_dir``.

    Parameters
    ----------
    out_dir : path-like
        Folder to write (created). Existing files of the same names are overwritten.
    seed : int
        Same seed, same bytes.
    profile : {"demo", "full", "mini", "foreign"}
        ``foreign``: the foreign-rig campaign only (``runs`` and ``jobs`` do not apply).
    runs : int, optional
        Total number of runs (pads or trims the characterisation matrices).
    jobs : int, optional
        Worker processes (default: CPU count, at most 4). Output does not depend on it.
    progress : pipeline.progress.Progress, optional
        Where progress goes (silent by default).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if profile == "foreign":
        return _simulate_foreign(out, seed)
    prof = PROFILES[profile]
    plans, planner = plan_campaign(seed, prof, runs)
    jobs = jobs or min(4, os.cpu_count() or 1)
    progress = progress or Progress()
    records: list[dict] = [None] * len(plans)  # type: ignore[list-item]
    # biggest first so the pool stays busy
    order = sorted(range(len(plans)), key=lambda i: (plans[i].kind != "durability", i))
    with progress.task("simulate", len(plans)) as task:
        if jobs > 1 and len(plans) > 1:
            with ProcessPoolExecutor(max_workers=jobs) as pool:
                futures = {i: pool.submit(write_run, out, plans[i], seed, prof.chunk_rows) for i in order}
                for i in order:
                    records[i] = futures[i].result()
                    task.advance()
        else:
            for i in order:
                records[i] = write_run(out, plans[i], seed, prof.chunk_rows)
                task.advance()
    # rig.toml, manifests, logbooks
    for rel, text in RIG_TOMLS.items():
        (out / rel).parent.mkdir(parents=True, exist_ok=True)
        (out / rel).write_text(text, encoding="utf-8")
    manifests: dict[Path, list[dict]] = {}
    for rec in records:
        if "manifest_row" in rec:
            folder = (out / rec["file"]).parent
            manifests.setdefault(folder, []).append({"file": Path(rec["file"]).name, **rec.pop("manifest_row")})
    for folder, rows in sorted(manifests.items()):
        keys = ["file"] + sorted({k for r in rows for k in r if k != "file"}, key=lambda k: (k not in EMBED_ORDER, k))
        (folder / "manifest.csv").write_text(_csv_text(rows, keys), encoding="utf-8")
    for camp, rows in planner.logbooks.items():
        rows = sorted(rows, key=lambda r: (r["at"], r["hose_id"]))
        if rows:
            (out / camp).mkdir(parents=True, exist_ok=True)
            (out / camp / "hoses.csv").write_text(_csv_text(rows, HOSES_COLUMNS), encoding="utf-8")
    truth = {
        "generator": "pneubench simulator", "seed": seed, "profile": prof.name, "runs_requested": runs,
        "profile_settings": jsonable({k: getattr(prof, k) for k in prof.__dataclass_fields__}),
        "parameters": parameters(),
        "runs": {rec["metadata"]["run_id"]: rec for rec in records},
        "hoses": jsonable(planner.hoses),
        "logbooks": {camp: f"{camp}/hoses.csv" for camp, rows in planner.logbooks.items() if rows},
    }
    (out / "truth.json").write_text(json.dumps(jsonable(truth), indent=1, sort_keys=True), encoding="utf-8")
    files = [f for f in out.rglob("*") if f.is_file()]
    by_kind, by_format = {}, {}
    for rec in records:
        by_kind[rec["kind"]] = by_kind.get(rec["kind"], 0) + 1
        by_format[rec["format"]] = by_format.get(rec["format"], 0) + 1
    return CampaignSummary(out, len(records), len(files), sum(f.stat().st_size for f in files), by_kind, by_format)


def _simulate_foreign(out: Path, seed: int) -> CampaignSummary:
    from pipeline.simulator import foreign

    truth = foreign.simulate_foreign(out, seed)
    files = [f for f in out.rglob("*") if f.is_file()]
    by_kind, by_format = {}, {}
    for rec in truth["runs"].values():
        by_kind[rec["kind"]] = by_kind.get(rec["kind"], 0) + 1
        by_format[rec["format"]] = by_format.get(rec["format"], 0) + 1
    return CampaignSummary(out, len(truth["runs"]), len(files), sum(f.stat().st_size for f in files), by_kind,
                           by_format)


def parameters() -> dict:
    """The physics defaults every run was drawn from (physics.md), for truth.json."""
    return jsonable({
        "plpa": {"hose_area_m2": HOSE_AREA_M2, "moving_mass_kg": 2.0, "encoder_m": 5e-6, "pressure_noise_pa": 300.0,
                 "leak_c": plpa.LEAK_C, "p_seal_distance": "7.5 - 1.5 (z - 3) bar",
                 "p_seal_force": "2.0 + 9.7 F / 1300 bar", "force_settings_n": plpa.FORCE_SETTINGS_N,
                 "distance_settings_mm": plpa.DISTANCE_SETTINGS_MM,
                 "breakaway_mean_n": {"0": 10.0, ">=1": 5.0}, "breakaway_sigma_n": 0.5,
                 "viscous": {"0": dict(zip(("fc_n", "ka_n_s_m", "vs_m_s"), plpa.viscous_parameters(0.0))),
                             "1-3": dict(zip(("fc_n", "ka_n_s_m", "vs_m_s"), plpa.viscous_parameters(1.0)))},
                 "plant": {"wn_rad_s": plpa.PLANT_WN, "zeta": plpa.PLANT_ZETA, "k_lin_m_v_s": plpa.PLANT_K},
                 "identification_kp_v_m": 5.0, "step_pid": plpa.STEP_PID},
        "pla": {"table1": pla.TABLE1, "p_atm_pa": P_ATM_PA, "stroke_mm": pla.STROKE_MM,
                "pressure_wn_rad_s": pla.PRESSURE_WN, "pressure_xi": pla.PRESSURE_XI},
        "durability": {"weibull_life": {k: {"shape": s, "scale_km": c} for k, (s, c) in dur.WEIBULL_LIFE.items()},
                       "seal_wear_bar_km": dur.SEAL_WEAR_BAR_KM, "wall_new_mm": dur.WALL_NEW_MM,
                       "wall_wear_mm_km": dur.WALL_WEAR_MM_KM},
    })


#: The demo's campaigns: the first folders of the raw tree it fills (with ``truth.json`` beside them).
DEMO_CAMPAIGNS = ("plpa-2025", "pla-2016", "durability-2025", "durability-2026")


class DemoError(Exception):
    """The demo cannot write its campaigns into the raw tree given (one line, names the folder)."""


def simulate_demo(raw, seed: int = 1, jobs: int | None = None, progress=None, profile: str = "demo") -> bool:
    """Simulate the demo campaigns as the campaigns of ``raw`` unless they are there; returns
    whether they were written.

    ``raw`` gets ``plpa-2025/``, ``pla-2016/``, ``durability-2025/``, ``durability-2026/`` and
    ``truth.json`` (written last: it marks a complete demo), so a rebuild of ``raw`` sees exactly
    the simulated campaigns under their own names. A tree that holds anything else is refused
    (:class:`DemoError`): its runs would be pooled with the simulated ones and the results would
    no longer be those of ``truth.json``. Nothing already in ``raw`` is modified or deleted. The
    campaigns are written to a hidden folder first and renamed into place one by one; an
    interrupted demo is completed by the next one (same seed, same bytes).
    """
    raw = Path(raw)
    if (raw / "truth.json").is_file():
        return False
    raw.mkdir(parents=True, exist_ok=True)
    other = sorted(p.name for p in raw.iterdir() if not p.name.startswith(".") and p.name not in DEMO_CAMPAIGNS)
    if other:
        raise DemoError(f"{raw} already holds {', '.join(other[:3])}{', ...' if len(other) > 3 else ''}: the demo "
                        "writes its campaigns only into an empty raw folder (give another one with --raw)")
    tmp = raw / f".demo-{os.getpid()}.partial"
    if tmp.exists():
        import shutil

        shutil.rmtree(tmp)
    simulate_campaign(tmp, seed=seed, profile=profile, jobs=jobs, progress=progress)
    for name in DEMO_CAMPAIGNS:
        if (tmp / name).exists() and not (raw / name).exists():
            os.replace(tmp / name, raw / name)
    os.replace(tmp / "truth.json", raw / "truth.json")
    import shutil

    shutil.rmtree(tmp, ignore_errors=True)
    return True
