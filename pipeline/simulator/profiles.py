"""A campaign's sizes: sample rates, durations, repetitions and hoses per profile.

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
The demo and full campaigns carry the lab's test plan, :data:`DEMO_PLAN` (``raw/plan.toml``, issues
23 and 24): margin 1.5 for FLEXIGOM AIR, its leakage failure (2 l/min at 6 bar: the profiles'
``leak_limit_l_min`` and ``leak_pressure_bar``, which the simulated hoses fail by), the rest the
defaults, two benches at 30 km a day. ``mini`` has no plan.toml (its hoses wear the same way).
``rul`` (hundreds of running hoses with frequent leak checks, for calibrating the remaining-life
predictions of issue 24) is :mod:`pipeline.simulator.rul`'s.
``decision`` (hundreds of hose types known by their odometer, for calibrating the verdict) is
:mod:`pipeline.simulator.decision`'s.
``runs=N`` pads the characterisation matrices with further repetitions (new seeds) to reach N
runs in total, for campaigns of 1,000+ runs; a smaller N keeps the first N runs (interleaved
across kinds, durability hoses first).
"""
from __future__ import annotations

from dataclasses import dataclass, field

from pipeline.simulator.durability import LEAK_LIMIT_L_MIN, LEAK_PRESSURE_BAR

#: The demo's test plan (``raw/plan.toml``; keys in docs/bench-exports.md, "plan.toml").
DEMO_PLAN = f"""\
# The lab's test plan: written before the durability tests (docs/bench-exports.md, "plan.toml")
[defaults]
margin = 1.25                 # the smallest force/distance life ratio worth acting on
alpha = 0.05                  # two-sided error rate of the verdict
power = 0.8
confidence = 0.9
spending = "obrien-fleming"
benches = 2
km_per_day = 30.0

[hose_type."FLEXIGOM AIR"]
margin = 1.5                  # max_failures unset: the sequential design's failures_needed
leak_limit_l_min = {LEAK_LIMIT_L_MIN!r}        # failed by leakage: the leak at leak_pressure_bar reaches this (l/min ANR)
leak_pressure_bar = {LEAK_PRESSURE_BAR!r}       # the working pressure; new hoses are set to seal it exactly
"""


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
    plan: str | None = DEMO_PLAN          # raw/plan.toml (None: no plan)
    leak_limit_l_min: float | None = LEAK_LIMIT_L_MIN   # a hose fails when its leak at ...
    leak_pressure_bar: float | None = LEAK_PRESSURE_BAR  # ... this pressure reaches the limit (or it ruptures)


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
                    check_fs_hz=10.0, check_plateau_s=1.0, log_s=60.0, limit_per_variant=1, plan=None),
}
