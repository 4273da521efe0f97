"""One run of a campaign: simulate its plan and write its export (the run's file and truth record).

Each run draws from its own generator seeded with the campaign's seed and the run's id
(:func:`run_rng`), so a run's bytes depend neither on the order the runs are written in, nor on
the number of workers, nor on how many other runs the campaign plans (a hose more in the
durability campaigns leaves the characterisation runs as they were).
"""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.simulator import ambient, pla, plpa
from pipeline.simulator import durability as dur
from pipeline.simulator.base import HOSE_AREA_M2, jsonable
from pipeline.simulator.plan import RunPlan
from pipeline.simulator.writers import (ColumnOut, default_columns, write_csv, write_lvm, write_mat, write_mf4, write_tdms,
                                         write_xlsx)

#: The generator of each kind (durability runs are written in chunks: see :func:`simulate_plan`).
GENERATORS = {
    "leakage": plpa.simulate_leakage, "breakaway": plpa.simulate_breakaway, "viscous": plpa.simulate_viscous,
    "identification": plpa.simulate_identification, "step": plpa.simulate_step, "spring": pla.simulate_spring,
    "pressure_step": pla.simulate_pressure_step, "timeseries": ambient.simulate_timeseries,
}

#: Metadata keys first in an export (and in a manifest's columns), in this order; the rest sorted.
EMBED_ORDER = ("kind", "run_id", "started_at", "rig", "operator")


def run_rng(seed: int, run_id: str) -> np.random.Generator:
    """The generator of run ``run_id`` of a campaign: independent of order, parallelism and the
    other runs planned (128 bits of the id's SHA-256 beside the seed)."""
    words = np.frombuffer(hashlib.sha256(str(run_id).encode()).digest()[:16], dtype="<u4")
    return np.random.default_rng([int(seed), *(int(w) for w in words)])


def simulate_plan(plan: RunPlan, seed: int, chunk_rows: int = 2_000_000):
    """Simulate a plan: ``(frames, metadata, truth)``.

    ``frames`` is one DataFrame in SI under warehouse column names, or for a durability run an
    iterator of chunks of ``chunk_rows`` rows (GB-scale runs); ``metadata`` is the run's
    metadata (the plan's over the generator's); ``truth`` every true value used.
    """
    rng = run_rng(seed, plan.run_id)
    if plan.kind == "durability":
        kw = dict(plan.kwargs)
        p_mean = kw.pop("p_mean_bar", 2.0)
        sp = dur.stroke_plan(**kw)
        truth = dur.durability_truth(sp, plan.metadata["hose_id"], plan.metadata.get("adjustment"), p_mean)
        meta = {"kind": "durability", "rig": "plpa-2", "hose_area_m2": HOSE_AREA_M2, **plan.metadata}
        return dur.iter_durability_chunks(sp, rng, p_mean_bar=p_mean, chunk_rows=chunk_rows), meta, truth
    run = GENERATORS[plan.kind](rng=rng, **plan.kwargs)
    meta = {**run.metadata, **plan.metadata}
    return run.data, meta, run.truth


def channels_of(plan: RunPlan) -> list[str]:
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


def write_run(out_dir: Path, plan: RunPlan, seed: int, chunk_rows: int = 2_000_000) -> dict:
    """Simulate one plan and write its export; returns its truth.json record (and manifest row)."""
    frames, meta, truth = simulate_plan(plan, seed, chunk_rows)
    meta = _ordered(jsonable(meta))
    v = plan.variant
    embedded = meta if v.get("embed") else {k: meta[k] for k in ("operator",) if k in meta}
    fs = (truth.get("fs_hz") if isinstance(truth, dict) else None) or plan.kwargs.get("fs_hz")
    _write_export(out_dir / plan.rel_path, frames, plan, meta, embedded, fs)
    record = {"file": plan.rel_path, "format": v["fmt"], "kind": plan.kind, "metadata": meta,
              "embedded": bool(v.get("embed")), "truth": jsonable(truth)}
    if not v.get("embed"):
        record["manifest_row"] = _manifest_row(meta, v)
    return record


def _ordered(meta: dict) -> dict:
    """``meta`` with the :data:`EMBED_ORDER` keys first, the others sorted."""
    head = {k: meta[k] for k in EMBED_ORDER if k in meta}
    return {**head, **{k: meta[k] for k in sorted(meta) if k not in head}}


def _manifest_row(meta: dict, variant: dict) -> dict:
    """The metadata a run's folder manifest carries for a file that embeds none."""
    # hose_area_m2 comes from the campaign's rig.toml, operator from the file itself
    row = {k: val for k, val in meta.items() if k not in ("hose_area_m2", "operator")}
    if variant.get("headerless"):
        row.pop("kind", None)  # the headerless folder's rig.toml says kind = step
        row["operator"] = meta["operator"]  # nothing can be embedded in it
    return row


def _variant_columns(kind_columns: list[str], variant: dict) -> list[ColumnOut]:
    """The export columns of a variant: its raw units and names over the canonical ones."""
    return default_columns(kind_columns, variant.get("units"), variant.get("names"))


def _write_export(path: Path, frames, plan: RunPlan, meta: dict, embedded: dict, fs: float | None) -> None:
    """Write the run's samples in its variant's format: ``embedded`` (the part of the run's
    ``meta`` the file carries) in the file if any, ``fs`` the sample rate [Hz]."""
    v = plan.variant
    cols = _variant_columns(channels_of(plan), v)
    opts = dict(v.get("opts", {}))
    if v["fmt"] in ("csv", "txt"):
        if v.get("headerless"):
            _write_headerless_step(path, frames)
        else:
            write_csv(path, frames, [ColumnOut("t_s", "t", "s")] + cols, embedded or None, **opts)
    elif v["fmt"] == "lvm":
        started = meta["started_at"]
        write_lvm(path, frames, cols, embedded or None, fs_hz=fs,
                  date=started[:10].replace("-", "/"), time=started[11:] + ".000000", **opts)
    elif v["fmt"] == "tdms":
        if opts.get("extra_group"):
            embedded = {**embedded, "group": "Data"}
        write_tdms(path, frames, cols, embedded or None, fs_hz=fs, **opts)
    elif v["fmt"] == "mat":
        write_mat(path, frames, cols, embedded or None, **opts)
    elif v["fmt"] == "xlsx":
        write_xlsx(path, frames, cols, embedded or None, **opts)
    elif v["fmt"] == "mf4":
        write_mf4(path, frames, cols, embedded or None, **opts)
    else:
        raise ValueError(v["fmt"])


def _write_headerless_step(path: Path, frames) -> None:
    """Whitespace text, no header: t [s], encoder counts (rig.toml scales 0.005 mm), x_ref [mm]."""
    frame = frames if isinstance(frames, pd.DataFrame) else pd.concat(list(frames), ignore_index=True)
    counts = np.round(frame["x_m"].to_numpy() / 5e-6).astype(np.int64)
    x_ref_mm = frame["x_ref_m"].to_numpy() * 1e3
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        for t, c, r in zip(frame["t_s"].to_numpy(), counts, x_ref_mm):
            fh.write(f"{float(t)!r}  {int(c):d}  {float(r)!r}\n")

