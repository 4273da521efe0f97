"""`pneubench simulate` and the demo's simulate step."""
import json

import pytest
from click.testing import CliRunner

from pipeline.cli import main
from pipeline.simulator.campaign import simulate_demo


def test_simulate_command_writes_campaign_and_truth(tmp_path):
    out = tmp_path / "sim"
    res = CliRunner().invoke(main, ["simulate", str(out), "--seed", "2", "--profile", "mini", "--jobs", "1", "-q"])
    assert res.exit_code == 0, res.output
    assert "runs" in res.output and "truth.json" in res.output
    truth = json.loads((out / "truth.json").read_text())
    assert truth["seed"] == 2 and truth["profile"] == "mini"
    for rec in truth["runs"].values():
        assert (out / rec["file"]).is_file()


def test_simulate_runs_pads_to_the_requested_count(tmp_path):
    out = tmp_path / "sim"
    res = CliRunner().invoke(main, ["simulate", str(out), "--profile", "mini", "--runs", "60", "--jobs", "2", "-q"])
    assert res.exit_code == 0, res.output
    truth = json.loads((out / "truth.json").read_text())
    assert len(truth["runs"]) == 60


def test_simulate_foreign_profile_writes_the_foreign_campaign(tmp_path):
    out = tmp_path / "sim"
    res = CliRunner().invoke(main, ["simulate", str(out), "--profile", "foreign", "-q"])
    assert res.exit_code == 0, res.output
    truth = json.loads((out / "truth.json").read_text())
    assert truth["profile"] == "foreign" and truth["runs"]
    assert [p.name for p in out.iterdir() if p.is_dir()] == ["foreign-2026"]
    for rec in truth["runs"].values():
        assert (out / rec["file"]).is_file()


def test_simulate_rejects_unknown_profile(tmp_path):
    res = CliRunner().invoke(main, ["simulate", str(tmp_path / "x"), "--profile", "huge"])
    assert res.exit_code == 2


def test_demo_simulates_only_when_absent(tmp_path):
    raw = tmp_path / "raw"
    assert simulate_demo(raw, jobs=1, profile="mini") is True
    marker = raw / "truth.json"
    before = marker.stat().st_mtime_ns
    assert simulate_demo(raw, jobs=1, profile="mini") is False
    assert marker.stat().st_mtime_ns == before
    assert not [p for p in raw.iterdir() if p.name.startswith(".")]


def test_the_demo_accepts_and_keeps_the_labs_own_plan(tmp_path):
    """A raw tree that holds only a plan.toml is the lab's plan for the demo: not refused, not replaced."""
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "plan.toml").write_text("[defaults]\nmargin = 2.0\n")
    assert simulate_demo(raw, jobs=1, profile="mini") is True
    assert (raw / "plan.toml").read_text() == "[defaults]\nmargin = 2.0\n"


def test_simulate_decision_profile_writes_a_logbook_a_plan_and_the_truth(tmp_path):
    out = tmp_path / "sim"
    res = CliRunner().invoke(main, ["simulate", str(out), "--profile", "decision", "-q"])
    assert res.exit_code == 0, res.output
    truth = json.loads((out / "truth.json").read_text())
    assert truth["profile"] == "decision" and len(truth["hose_types"]) == 300
    assert sorted(p.name for p in out.iterdir()) == ["decision-2026", "plan.toml", "truth.json"]
    assert "no runs (hose logbooks only)" in res.output   # not "0 runs ()"


# -- session 29 (clifix): simulate refuses a folder that holds files, a negative seed, a file in the way ----
def test_simulate_refuses_a_folder_that_holds_files_and_writes_nothing(tmp_path):
    """A raw tree (or a warehouse) given as OUT_DIR: its logbook would be replaced, its runs pooled."""
    raw = tmp_path / "raw"
    (raw / "durability-2025").mkdir(parents=True)
    (raw / "durability-2025" / "hoses.csv").write_text("the lab's logbook\n")
    res = CliRunner().invoke(main, ["simulate", str(raw), "--profile", "mini", "--jobs", "1", "-q"])
    assert res.exit_code == 2
    assert f"{raw} already holds durability-2025: simulate writes only into a new or empty folder" in res.stderr
    assert "Traceback" not in res.output
    assert (raw / "durability-2025" / "hoses.csv").read_text() == "the lab's logbook\n"
    assert sorted(p.name for p in raw.rglob("*")) == ["durability-2025", "hoses.csv"]


def test_simulate_writes_into_an_empty_folder_and_one_with_hidden_files_only(tmp_path):
    out = tmp_path / "sim"
    out.mkdir()
    (out / ".keep").write_text("")
    res = CliRunner().invoke(main, ["simulate", str(out), "--profile", "foreign", "-q"])
    assert res.exit_code == 0, res.output
    assert (out / "truth.json").is_file()


@pytest.mark.parametrize("option", ["--seed", "--runs", "--jobs"])
def test_simulate_refuses_negative_numbers_as_usage_errors(tmp_path, option):
    res = CliRunner().invoke(main, ["simulate", str(tmp_path / "x"), option, "-5", "--profile", "mini", "-q"])
    assert res.exit_code == 2 and f"Invalid value for '{option}'" in res.stderr
    assert not (tmp_path / "x").exists()


def test_simulate_under_a_file_is_one_line(tmp_path):
    (tmp_path / "afile").write_text("")
    res = CliRunner().invoke(main, ["simulate", str(tmp_path / "afile" / "x"), "--profile", "mini", "-q"])
    assert res.exit_code == 2 and "cannot create" in res.stderr and "afile" in res.stderr
    assert res.exception is None or isinstance(res.exception, SystemExit)
