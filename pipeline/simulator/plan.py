"""A campaign's run plans: which run goes where, when, in which format, with which generator arguments.

:class:`Planner` holds a campaign under planning: the runs planned so far (:class:`RunPlan`, in
the order of their seeds), each campaign's clock, and the durability hoses and logbooks that
:func:`pipeline.simulator.hoses.plan_hoses` fills. Its methods lay out the papers' test
matrices; :func:`pipeline.simulator.campaign.plan_campaign` calls them in a fixed order. Nothing
is simulated or written here.
"""
from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta

from pipeline.simulator import pla, plpa
from pipeline.simulator.profiles import Profile
from pipeline.simulator.variants import VARIANTS

CAMPAIGN_START = {"plpa-2025": datetime(2025, 3, 3, 8, 0), "pla-2016": datetime(2016, 5, 9, 9, 0),
                  "durability-2025": datetime(2025, 2, 3, 7, 30), "durability-2026": datetime(2026, 1, 12, 7, 30),
                  "odometer": datetime(2023, 4, 3, 8, 0)}
OPERATORS = ("ana", "joao", "rui")


@dataclass
class RunPlan:
    """One run to simulate and write."""

    index: int
    run_id: str
    kind: str
    rel_path: str
    variant: dict
    kwargs: dict
    metadata: dict
    group: str = ""   # variant group (e.g. "viscous_force"), for coverage reports

    @property
    def fmt(self) -> str:
        """The export format (the variant's ``fmt``: ``csv``, ``lvm`` ...)."""
        return self.variant["fmt"]


@dataclass(frozen=True)
class RunSpec:
    """What a run is, before the planner gives it a place and a time.

    ``group`` names its variants in :data:`VARIANTS` (``viscous_force``, ``leakage_check`` ...),
    ``kind`` its generator and kind; ``stem`` its file name without extension (run id
    ``<campaign>/<stem>``); ``kwargs`` the generator's arguments; ``meta`` metadata beside them.
    """

    campaign: str
    group: str
    kind: str
    stem: str
    kwargs: dict
    meta: dict | None = None


def iso(dt: datetime) -> str:
    """A time as the exports write it (``YYYY-MM-DDTHH:MM:SS``)."""
    return dt.strftime("%Y-%m-%dT%H:%M:%S")


class Planner:
    """A campaign under planning: plans, clocks per campaign, hoses and logbooks."""

    def __init__(self, profile: Profile, seed: int):
        self.p = profile
        self.seed = seed
        self.plans: list[RunPlan] = []
        self.counts: dict[str, int] = {}
        self.clock: dict[str, datetime] = dict(CAMPAIGN_START)
        self.hoses: dict[str, dict] = {}
        self.logbooks: dict[str, list[dict]] = {"durability-2025": [], "durability-2026": []}

    def variant(self, group: str, i: int) -> dict:
        """The export variant of run ``i`` of ``group`` (the group's variants cycle)."""
        vs = VARIANTS[group]
        return vs[i % len(vs)]

    def add(self, spec: RunSpec, minutes: float = 5.0, variant: dict | None = None,
            when: datetime | None = None) -> RunPlan:
        """Plan a run: at ``when``, or at its campaign's clock, which then moves on ``minutes``;
        in ``variant``, or the group's next one. Returns the plan."""
        i = self.counts.get(spec.group, 0)
        self.counts[spec.group] = i + 1
        v = variant or self.variant(spec.group, i)
        ext = v["fmt"]
        rel = f"{spec.campaign}/{v['folder']}/{spec.stem}.{ext}"
        start = when or self.clock[spec.campaign]
        if when is None:
            self.clock[spec.campaign] = start + timedelta(minutes=minutes)
        md = {"run_id": f"{spec.campaign}/{spec.stem}", "started_at": iso(start),
              "operator": OPERATORS[len(self.plans) % len(OPERATORS)], **(spec.meta or {})}
        plan = RunPlan(len(self.plans), md["run_id"], spec.kind, rel, v, spec.kwargs, md, spec.group)
        self.plans.append(plan)
        return plan

    # PLPA characterisation ---------------------------------------------------------------
    def leakage(self):
        """Leakage of both chambers at every roller distance and spring force setting."""
        p = self.p
        settings = [("distance", z, None) for z in plpa.DISTANCE_SETTINGS_MM] + \
                   [("force", None, f) for f in plpa.FORCE_SETTINGS_N]
        for chamber in ("A", "B"):
            for adj, z, f in settings:
                tag = f"z{z:.1f}" if z is not None else f"f{f:.0f}"
                self.add(RunSpec("plpa-2025", "leakage", "leakage", f"leak-{chamber}-{tag}",
                                 dict(chamber=chamber, adjustment=adj, z_rollers_mm=z, spring_force_n=f,
                                      fs_hz=p.leak_fs_hz, plateau_s=p.leak_plateau_s)), minutes=15)

    def breakaway(self, reps: int | None = None, rep0: int = 0):
        """The 5 x 5 x 2 breakaway matrix (backpressure, force rate, direction), ``reps`` times."""
        p = self.p
        for rep in range(rep0, rep0 + (reps or p.breakaway_reps)):
            for direction in ("P", "N"):
                for bp in (0.0, 1.0, 2.0, 3.0, 4.0):
                    for rate in (0.25, 0.5, 1.0, 2.0, 4.0):
                        self.add(RunSpec("plpa-2025", "breakaway", "breakaway",
                                         f"brk-{direction}-bp{bp:.0f}-r{rate:g}-{rep + 1:02d}",
                                         dict(direction=direction, backpressure_bar=bp, force_rate_n_s=rate,
                                              fs_hz=p.breakaway_fs_hz)), minutes=3)

    def viscous(self, rep: int = 0):
        """Viscous friction at 0-3 bar, a near-zero speed run and two load-cell runs."""
        p = self.p
        sfx = f"-{rep + 1:02d}"
        for bp in (0.0, 1.0, 2.0, 3.0):
            self.add(RunSpec("plpa-2025", "viscous", "viscous", f"visc-bp{bp:.0f}{sfx}",
                             dict(backpressure_bar=bp, fs_hz=p.viscous_fs_hz)), minutes=10)
        self.add(RunSpec("plpa-2025", "viscous", "viscous", f"visc-nearzero{sfx}",
                         dict(backpressure_bar=0.0, speeds_m_s=list(plpa.NEAR_ZERO_SPEEDS_M_S),
                              fs_hz=p.viscous_fs_hz)), minutes=10)
        for bp in (0.0, 2.0):
            self.add(RunSpec("plpa-2025", "viscous_force", "viscous", f"visc-loadcell-bp{bp:.0f}{sfx}",
                             dict(backpressure_bar=bp, use_force_channel=True, fs_hz=p.viscous_fs_hz)), minutes=10)

    def identification(self, n: int | None = None, rep0: int = 0):
        """``n`` closed-loop identification runs."""
        for i in range(rep0, rep0 + (n or self.p.identification_runs)):
            self.add(RunSpec("plpa-2025", "identification", "identification", f"ident-{i + 1:02d}",
                             dict(duration_s=self.p.identification_s)), minutes=5)

    def step(self, n: int | None = None, rep0: int = 0):
        """``n`` position step response runs."""
        for i in range(rep0, rep0 + (n or self.p.step_runs)):
            self.add(RunSpec("plpa-2025", "step", "step", f"step-{i + 1:02d}",
                             dict(fs_hz=self.p.step_fs_hz, x0_m=0.15 + 0.05 * (i % 4))), minutes=5)

    # PLA -----------------------------------------------------------------------------------
    def spring(self, rep: int = 0):
        """The 120 spring tests: both chambers x initial pressures x amplitudes x frequencies."""
        p = self.p
        for chamber in ("front", "rear"):
            for p0 in pla.P0_BAR_ABS:
                for amp in pla.AMPLITUDES_MM:
                    for f in pla.FREQUENCIES_HZ:
                        sfx = "" if rep == 0 else f"-{rep + 1:02d}"
                        self.add(RunSpec("pla-2016", "spring", "spring",
                                         f"spring-{chamber}-p{p0:.0f}-d{amp:.0f}-f{f:g}{sfx}",
                                         dict(chamber=chamber, p0_bar_abs=p0, amplitude_mm=amp, frequency_hz=f,
                                              fs_hz=p.spring_fs_hz, cycles=p.spring_cycles)), minutes=4)

    def pressure_step(self, n: int | None = None, rep0: int = 0):
        """``n`` pressure step runs per chamber."""
        for i in range(rep0, rep0 + (n or self.p.pressure_step_runs)):
            for chamber in ("front", "rear"):
                self.add(RunSpec("pla-2016", "pressure_step", "pressure_step", f"pstep-{chamber}-{i + 1:02d}",
                                 dict(chamber=chamber)), minutes=5)

    # ambient / supply logger ---------------------------------------------------------------
    def timeseries(self):
        """Logger runs at 07:30 on successive campaign days (the variant decides the channels)."""
        p = self.p
        for i in range(p.log_runs):
            v = self.variant("timeseries", i)
            when = CAMPAIGN_START["plpa-2025"] - timedelta(minutes=30) + timedelta(days=i)
            self.add(RunSpec("plpa-2025", "timeseries", "timeseries", f"ambient-{i + 1:02d}",
                             dict(duration_s=p.log_s, fs_hz=p.log_fs_hz, supply="p_supply_pa" in v["channels"],
                                  temperature_c=round(20.5 + 0.5 * i, 2))), variant=v, when=when)
