"""One run: its own generator, its columns, its export and its truth record (with the manifest row
of a file that embeds no metadata)."""
from __future__ import annotations

import types

import numpy as np
import pandas as pd

from pipeline.readers import read_export
from pipeline.simulator.campaign import plan_campaign
from pipeline.simulator.runs import EMBED_ORDER, channels_of, run_rng, simulate_plan, write_run

PLANS, _ = plan_campaign(3, "mini")


def _first(**match):
    return next(p for p in PLANS if all(getattr(p, k) == v for k, v in match.items()))


def test_run_rng_depends_on_seed_and_run_id_only():
    assert run_rng(3, "c/a").random() == run_rng(3, "c/a").random()
    assert len({run_rng(s, i).random() for s, i in [(3, "c/a"), (3, "c/b"), (4, "c/a")]}) == 3


def test_simulate_plan_is_the_same_for_the_same_seed_and_chunks_durability():
    plan = _first(kind="step")
    a, b = simulate_plan(plan, 3), simulate_plan(plan, 3)
    pd.testing.assert_frame_equal(a[0], b[0])
    assert a[1]["run_id"] == plan.run_id and a[1]["operator"] == plan.metadata["operator"]
    dur = _first(kind="durability")
    frames, meta, truth = simulate_plan(dur, 3, chunk_rows=10)
    chunks = list(frames)
    assert len(chunks) > 1 and all(len(c) <= 10 for c in chunks)
    assert sum(map(len, chunks)) == truth["n_samples"] and meta["rig"] == "plpa-2"


def test_channels_of_follow_the_kind_and_variant():
    assert channels_of(_first(kind="leakage")) == ["p_supply_pa", "q_leak_kg_s"]
    force = _first(group="viscous_force")
    assert channels_of(force) == ["x_m", "f_n"]
    headerless = next(p for p in PLANS if p.variant.get("headerless"))
    assert channels_of(headerless) == ["x_m", "x_ref_m"]
    logger = types.SimpleNamespace(kind="timeseries", variant={"channels": ("temperature_degc",)}, kwargs={})
    assert channels_of(logger) == ["temperature_degc"]


def test_write_run_embeds_metadata_in_order_and_records_the_truth(tmp_path):
    plan = next(p for p in PLANS if p.variant.get("embed") and p.fmt == "csv" and p.kind == "step")
    rec = write_run(tmp_path, plan, 3)
    assert rec["file"] == plan.rel_path and rec["format"] == "csv" and rec["embedded"] is True
    assert "manifest_row" not in rec and rec["truth"]["steps"]
    keys = list(rec["metadata"])
    head = [k for k in EMBED_ORDER if k in rec["metadata"]]
    assert len(head) == len(EMBED_ORDER) and keys[:len(head)] == head
    assert keys[len(head):] == sorted(keys[len(head):])
    export = read_export(tmp_path / plan.rel_path)
    assert export.metadata["run_id"] == plan.run_id and [c.name for c in export.columns] == ["t", "x", "x_ref", "u"]


def test_a_file_without_metadata_gets_a_manifest_row(tmp_path):
    plan = next(p for p in PLANS if not p.variant.get("embed") and p.fmt == "lvm")
    rec = write_run(tmp_path, plan, 3)
    row = rec["manifest_row"]
    assert row["run_id"] == plan.run_id and "operator" not in row and "hose_area_m2" not in row
    assert read_export(tmp_path / plan.rel_path).metadata.get("operator") == plan.metadata["operator"]


def test_the_headerless_step_writes_encoder_counts_and_names_its_operator_in_the_manifest(tmp_path):
    plan = next(p for p in PLANS if p.variant.get("headerless"))
    rec = write_run(tmp_path, plan, 3)
    assert "kind" not in rec["manifest_row"] and rec["manifest_row"]["operator"] == plan.metadata["operator"]
    frame = simulate_plan(plan, 3)[0]
    first = (tmp_path / plan.rel_path).read_text().splitlines()[0].split()
    assert first == [repr(float(frame["t_s"][0])), str(int(np.round(frame["x_m"][0] / 5e-6))),
                     repr(float(frame["x_ref_m"][0] * 1e3))]
