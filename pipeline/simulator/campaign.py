"""Synthetic campaigns: every kind with the papers' test matrices, in the formats a lab writes.

``simulate_campaign(out_dir, seed, profile, runs)`` writes, under ``out_dir``::

    plpa-2025/       PLPA characterisation: leakage, breakaway, viscous, identification, step,
                     and the ambient / supply logger (kind ``timeseries``)
    pla-2016/        PLA: the 120 spring tests and pressure steps
    durability-2025/ hose logbook (older hoses with odometer readings only, logged hoses),
                     durability runs and leakage checks of the logged hoses
    durability-2026/ the following campaign: a hose continued from 2025, new hoses
    plan.toml        the lab's test plan (profiles ``demo`` and ``full``: :data:`~pipeline.simulator.profiles.DEMO_PLAN`)
    truth.json       every parameter and every per-run true value

Each of those folders is one campaign when ``out_dir`` is the raw root (``pneubench rebuild --raw
out_dir``, as :func:`simulate_demo` does), or subfolders of one campaign when ``out_dir`` is ``raw/<name>``.
Run ids are explicit (``<folder>/<stem>``), so they do not depend on where ``out_dir`` sits.

The parts: :mod:`~pipeline.simulator.profiles` (sizes), :mod:`~pipeline.simulator.variants`
(formats, rig.toml), :mod:`~pipeline.simulator.plan` and :mod:`~pipeline.simulator.hoses` (which
run goes where and when), :mod:`~pipeline.simulator.runs` (one run simulated and written). This
module plans a campaign, writes its runs (in worker processes), the folders' ``rig.toml``,
``manifest.csv`` and ``hoses.csv``, and ``truth.json``.

Output is byte-identical for a seed: each run draws from its own generator seeded with
``(seed, run id)``, dates are fixed, files are written in a fixed order of content.
"""
from __future__ import annotations

import csv
import io
import json
import os
import shutil
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from pipeline.progress import Progress
from pipeline.simulator import durability as dur
from pipeline.simulator import foreign, pla, plpa
from pipeline.simulator.base import HOSE_AREA_M2, P_ATM_PA, jsonable
from pipeline.simulator.decision import DECISION_CAMPAIGN, DecisionProfile, simulate_decision
from pipeline.simulator.hoses import HOSES_COLUMNS, plan_hoses
from pipeline.simulator.plan import Planner, RunPlan
from pipeline.simulator.profiles import PROFILES, Profile
from pipeline.simulator.rul import RIG_TOML, RUL_CAMPAIGN, RulProfile, plan_rul
from pipeline.simulator.rul import plan_toml as plan_toml_rul
from pipeline.simulator.runs import EMBED_ORDER, write_run
from pipeline.simulator.variants import RIG_TOMLS, VARIANTS


# -- the plan ----------------------------------------------------------------------------------
def plan_campaign(seed: int = 1, profile: str | Profile = "demo", runs: int | None = None) -> tuple[list[RunPlan], Planner]:
    """Every run of a campaign (no file written): the plans and the planner (hoses, logbooks)."""
    prof = PROFILES[profile] if isinstance(profile, str) else profile
    pl = Planner(prof, seed)
    plan_hoses(pl)
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
        pl.plans = _per_variant(pl.plans, prof.limit_per_variant)
    if runs is not None:
        _to_count(pl, runs, n_dur)
    return pl.plans, pl


def _per_variant(plans: list[RunPlan], limit: int) -> list[RunPlan]:
    """The first ``limit`` runs of each kind and format variant (durability and checks all kept)."""
    keep, seen = [], {}
    for plan in plans:
        if plan.group in ("durability", "leakage_check"):
            keep.append(plan)
            continue
        key = (plan.group, VARIANTS[plan.group].index(plan.variant))
        if seen.get(key, 0) < limit:
            seen[key] = seen.get(key, 0) + 1
            keep.append(plan)
    return keep


def _to_count(pl: Planner, runs: int, n_dur: int) -> None:
    """Trim ``pl.plans`` to ``runs`` (the first ``n_dur``, the durability hoses', first, then the
    others interleaved across groups) or pad them with repetitions of the matrices."""
    prof = pl.p
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


# -- writing -----------------------------------------------------------------------------------
def csv_text(rows: list[dict], columns: list[str]) -> str:
    """Rows as CSV text under ``columns`` (None empty, floats as ``repr``)."""
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
                      jobs: int | None = None, progress=None, campaigns: tuple | None = None) -> CampaignSummary:
    """Write a synthetic campaign (every kind, every format) with ``truth.json`` under ``out_dir``.

    Parameters
    ----------
    out_dir : path-like
        Folder to write (created). Existing files of the same names are overwritten
        (``pneubench simulate`` first refuses a folder that is not empty: :func:`refuse_occupied`).
    seed : int
        Same seed, same bytes.
    profile : {"demo", "full", "mini", "foreign", "decision", "rul"}, DecisionProfile or RulProfile
        ``foreign``: the foreign-rig campaign only; ``decision`` (or a
        :class:`~pipeline.simulator.decision.DecisionProfile` for other sizes and scenarios):
        hundreds of hose types known by their odometer, and a plan.toml (``runs`` and ``jobs``
        do not apply to either); ``rul`` (or a :class:`~pipeline.simulator.rul.RulProfile`):
        hundreds of running hoses with short durability runs and frequent leak checks, and a
        plan.toml with their leakage failure (``runs`` does not apply).
    runs : int, optional
        Total number of runs (pads or trims the characterisation matrices).
    jobs : int, optional
        Worker processes (default: CPU count, at most 4). Output does not depend on it.
    progress : pipeline.progress.Progress, optional
        Where progress goes (silent by default).
    campaigns : tuple of str, optional
        Only the runs, logbooks and rig.toml of these campaign folders (e.g. the demo's hoses:
        ``("durability-2025", "durability-2026")``); plan.toml and truth.json as usual.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if profile == "foreign":
        truth = foreign.simulate_foreign(out, seed)
        return _summary(out, list(truth["runs"].values()))
    if profile == "decision" or isinstance(profile, DecisionProfile):
        return _write_decision(out, seed, profile if isinstance(profile, DecisionProfile) else DecisionProfile())
    if profile == "rul" or isinstance(profile, RulProfile):
        return _write_rul(out, seed, profile if isinstance(profile, RulProfile) else RulProfile(), jobs, progress)
    prof = PROFILES[profile]
    plans, planner = plan_campaign(seed, prof, runs)
    if campaigns is not None:
        plans = [p for p in plans if p.rel_path.split("/")[0] in campaigns]
        planner.logbooks = {c: rows for c, rows in planner.logbooks.items() if c in campaigns}
    records = _write_runs(out, plans, seed, prof.chunk_rows, jobs or min(4, os.cpu_count() or 1),
                          progress or Progress())
    _write_folder_files(out, records, planner, campaigns)
    if prof.plan:
        (out / PLAN_FILE).write_text(prof.plan, encoding="utf-8")
    truth = {
        "generator": "pneubench simulator", "seed": seed, "profile": prof.name, "runs_requested": runs,
        "profile_settings": jsonable({k: getattr(prof, k) for k in prof.__dataclass_fields__}),
        "parameters": parameters(prof.leak_limit_l_min, prof.leak_pressure_bar),
        "runs": {rec["metadata"]["run_id"]: rec for rec in records},
        "hoses": jsonable(planner.hoses),
        "logbooks": {camp: f"{camp}/hoses.csv" for camp, rows in planner.logbooks.items() if rows},
    }
    (out / "truth.json").write_text(json.dumps(jsonable(truth), indent=1, sort_keys=True), encoding="utf-8")
    return _summary(out, records)


def _write_runs(out: Path, plans: list[RunPlan], seed: int, chunk_rows: int, jobs: int,
                progress: Progress) -> list[dict]:
    """Write every plan's export (in ``jobs`` worker processes); their records in plan order."""
    records: list[dict] = [None] * len(plans)  # type: ignore[list-item]
    # biggest first so the pool stays busy
    order = sorted(range(len(plans)), key=lambda i: (plans[i].kind != "durability", i))
    with progress.task("simulate", len(plans)) as task:
        if jobs > 1 and len(plans) > 1:
            with ProcessPoolExecutor(max_workers=jobs) as pool:
                futures = {i: pool.submit(write_run, out, plans[i], seed, chunk_rows) for i in order}
                for i in order:
                    records[i] = futures[i].result()
                    task.advance()
        else:
            for i in order:
                records[i] = write_run(out, plans[i], seed, chunk_rows)
                task.advance()
    return records


def _write_folder_files(out: Path, records: list[dict], planner: Planner, campaigns: tuple | None = None) -> None:
    """The folders' ``rig.toml`` (of ``campaigns`` only when given), ``manifest.csv`` (taking the
    records' manifest rows) and the campaigns' ``hoses.csv``."""
    for rel, text in RIG_TOMLS.items():
        if campaigns is not None and rel.split("/")[0] not in campaigns:
            continue
        (out / rel).parent.mkdir(parents=True, exist_ok=True)
        (out / rel).write_text(text, encoding="utf-8")
    manifests: dict[Path, list[dict]] = {}
    for rec in records:
        if "manifest_row" in rec:
            folder = (out / rec["file"]).parent
            manifests.setdefault(folder, []).append({"file": Path(rec["file"]).name, **rec.pop("manifest_row")})
    for folder, rows in sorted(manifests.items()):
        keys = ["file"] + sorted({k for r in rows for k in r if k != "file"}, key=lambda k: (k not in EMBED_ORDER, k))
        (folder / "manifest.csv").write_text(csv_text(rows, keys), encoding="utf-8")
    for camp, rows in planner.logbooks.items():
        rows = sorted(rows, key=lambda r: (r["at"], r["hose_id"]))
        if rows:
            (out / camp).mkdir(parents=True, exist_ok=True)
            (out / camp / "hoses.csv").write_text(csv_text(rows, HOSES_COLUMNS), encoding="utf-8")


def _write_decision(out: Path, seed: int, profile: DecisionProfile) -> CampaignSummary:
    """A ``decision`` campaign (:mod:`pipeline.simulator.decision`): its logbook, plan.toml and truth.json."""
    rows, plan, truth = simulate_decision(seed, profile)
    (out / DECISION_CAMPAIGN).mkdir(parents=True, exist_ok=True)
    rows = sorted(rows, key=lambda r: (r["at"], r["hose_id"]))
    (out / DECISION_CAMPAIGN / "hoses.csv").write_text(csv_text(rows, HOSES_COLUMNS), encoding="utf-8")
    (out / PLAN_FILE).write_text(plan, encoding="utf-8")
    (out / "truth.json").write_text(json.dumps(jsonable(truth), indent=1, sort_keys=True), encoding="utf-8")
    return _summary(out, [])


def _write_rul(out: Path, seed: int, profile: RulProfile, jobs: int | None, progress) -> CampaignSummary:
    """A ``rul`` campaign (:mod:`pipeline.simulator.rul`): its runs, rig.toml, logbook, plan.toml and truth.json."""
    planner, rows, truth = plan_rul(seed, profile)
    records = _write_runs(out, planner.plans, seed, 2_000_000, jobs or min(4, os.cpu_count() or 1),
                          progress or Progress())
    (out / RUL_CAMPAIGN / "rig.toml").write_text(RIG_TOML, encoding="utf-8")
    rows = sorted(rows, key=lambda r: (r["at"], r["hose_id"]))
    (out / RUL_CAMPAIGN / "hoses.csv").write_text(csv_text(rows, HOSES_COLUMNS), encoding="utf-8")
    (out / PLAN_FILE).write_text(plan_toml_rul(profile), encoding="utf-8")
    truth["runs"] = {rec["metadata"]["run_id"]: rec for rec in records}
    (out / "truth.json").write_text(json.dumps(jsonable(truth), indent=1, sort_keys=True), encoding="utf-8")
    return _summary(out, records)


def _summary(out: Path, records: list[dict]) -> CampaignSummary:
    """What is under ``out`` now: runs by kind and format (from their records), files, bytes."""
    files = [f for f in out.rglob("*") if f.is_file()]
    by_kind, by_format = {}, {}
    for rec in records:
        by_kind[rec["kind"]] = by_kind.get(rec["kind"], 0) + 1
        by_format[rec["format"]] = by_format.get(rec["format"], 0) + 1
    return CampaignSummary(out, len(records), len(files), sum(f.stat().st_size for f in files), by_kind, by_format)


def parameters(leak_limit_l_min: float | None = dur.LEAK_LIMIT_L_MIN,
               leak_pressure_bar: float | None = dur.LEAK_PRESSURE_BAR) -> dict:
    """The physics defaults every run was drawn from (physics.md), for truth.json; the hoses'
    true B10 life for the profile's leakage failure (``leak_limit_l_min`` at ``leak_pressure_bar``)."""
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
        "durability": {"rupture_life": {k: {"shape": s, "scale_km": c} for k, (s, c) in dur.RUPTURE_LIFE.items()},
                       "seal_wear_bar_km": dur.SEAL_WEAR_BAR_KM, "wear_cv": dur.WEAR_CV,
                       "seating_log_sd": dur.SEATING_LOG_SD, "leak_limit_l_min": leak_limit_l_min,
                       "leak_pressure_bar": leak_pressure_bar,
                       "settings": {a: dur.sealing_setting(a, leak_pressure_bar or dur.LEAK_PRESSURE_BAR)
                                    for a in ("distance", "force")},
                       "life_b10_km": {a: dur.life_b10_km(a, leak_limit_l_min, leak_pressure_bar)
                                       for a in ("distance", "force")},
                       "wall_new_mm": dur.WALL_NEW_MM, "wall_wear_mm_km": dur.WALL_WEAR_MM_KM},
    })


#: The demo's campaigns: the first folders of the raw tree it fills (with ``truth.json`` beside them).
DEMO_CAMPAIGNS = ("plpa-2025", "pla-2016", "durability-2025", "durability-2026")
#: The lab's test plan at the top of raw/ (docs/bench-exports.md, "plan.toml").
PLAN_FILE = "plan.toml"


class DemoError(Exception):
    """The simulator cannot write into the folder given: it holds other files, or it is not a
    folder (one line, names the folder; ``pneubench demo`` and ``simulate`` refuse it)."""


def refuse_occupied(folder, why: str, allowed: tuple = ()) -> None:
    """Raise :class:`DemoError` when ``folder`` exists and holds anything but hidden entries (a
    name starting with ".") and the names ``allowed``: what the simulator writes would replace or
    mix with them. A folder that does not exist yet, or is empty, passes.

    Parameters
    ----------
    folder : path-like
        The folder the simulator is to write into.
    why : str
        The end of the line: what the caller writes only into an empty folder, and what to do.
    allowed : tuple of str
        Names the caller accepts in ``folder`` (the demo's own campaigns and the lab's plan.toml).
    """
    folder = Path(folder)
    try:
        if not os.path.lexists(folder):
            return
        other = sorted(p.name for p in folder.iterdir() if not p.name.startswith(".") and p.name not in allowed)
    except OSError as exc:
        raise DemoError(f"{folder} cannot be listed ({exc.strerror or exc}): {why}") from None
    if other:
        raise DemoError(f"{folder} already holds {', '.join(other[:3])}{', ...' if len(other) > 3 else ''}: {why}")


def simulate_demo(raw, seed: int = 1, jobs: int | None = None, progress=None, profile: str = "demo") -> bool:
    """Simulate the demo campaigns as the campaigns of ``raw`` unless they are there; returns
    whether they were written.

    ``raw`` gets ``plpa-2025/``, ``pla-2016/``, ``durability-2025/``, ``durability-2026/``, the
    lab's ``plan.toml`` (kept when ``raw`` already has one: it is the lab's) and ``truth.json``
    (written last: it marks a complete demo), so a rebuild of ``raw`` sees exactly the simulated
    campaigns under their own names. A tree that holds anything else is refused
    (:class:`DemoError`): its runs would be pooled with the simulated ones and the results would
    no longer be those of ``truth.json``. Nothing already in ``raw`` is modified or deleted. The
    campaigns are written to a hidden folder first and renamed into place one by one; an
    interrupted demo is completed by the next one (same seed, same bytes).
    """
    raw = Path(raw)
    if (raw / "truth.json").is_file():
        return False
    refuse_occupied(raw, "the demo writes its campaigns only into an empty raw folder (give another one with --raw)",
                    allowed=(*DEMO_CAMPAIGNS, PLAN_FILE))
    raw.mkdir(parents=True, exist_ok=True)
    tmp = raw / f".demo-{os.getpid()}.partial"
    if tmp.exists():
        shutil.rmtree(tmp)
    simulate_campaign(tmp, seed=seed, profile=profile, jobs=jobs, progress=progress)
    for name in (*DEMO_CAMPAIGNS, PLAN_FILE):
        if (tmp / name).exists() and not (raw / name).exists():
            os.replace(tmp / name, raw / name)
    os.replace(tmp / "truth.json", raw / "truth.json")
    shutil.rmtree(tmp, ignore_errors=True)
    return True
