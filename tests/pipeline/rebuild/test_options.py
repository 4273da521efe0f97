"""The rebuild's terms: its options (given once, or field by field), the retention of superseded
files, and the summary's exit code."""
import pytest

from pipeline.rebuild.flow import rebuild
from pipeline.rebuild.options import (EXIT_OK, EXIT_QUARANTINED, KEEP_SUPERSEDED_H, RebuildError, RebuildOptions,
                                      RebuildSummary, keep_superseded_h)
from pipeline.raw.problems import Problem
from tests.conftest import STEP_META, query

T = [0.0, 0.1, 0.2, 0.3]
q = query


def test_options_are_frozen_and_overrides_set_their_fields(raw, warehouse):
    with pytest.raises(AttributeError):
        RebuildOptions().jobs = 2
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    s = rebuild(raw.root, warehouse, RebuildOptions(jobs=1, report=False), full=True)
    assert (s.mode, s.report, s.exit_code) == ("full", None, EXIT_OK)
    with pytest.raises(TypeError):
        rebuild(raw.root, warehouse, jobs=1, no_such_option=True)


def test_the_retention_is_the_value_the_environment_or_24_h(monkeypatch):
    monkeypatch.delenv("PNEUBENCH_KEEP_SUPERSEDED_H", raising=False)
    assert keep_superseded_h(None) == KEEP_SUPERSEDED_H == 24.0
    assert keep_superseded_h(0) == 0.0
    monkeypatch.setenv("PNEUBENCH_KEEP_SUPERSEDED_H", " 1.5 ")
    assert keep_superseded_h(None) == 1.5 and keep_superseded_h(3) == 3.0
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(RebuildError, match="--keep-superseded must be a number of hours >= 0") as err:
            keep_superseded_h(bad)
        assert err.value.exit_code == 2


def test_a_summary_with_quarantined_inputs_exits_1(tmp_path):
    s = RebuildSummary(raw=tmp_path, warehouse=tmp_path)
    assert s.exit_code == EXIT_OK
    s.quarantine.append(Problem("c/a.csv", "bad"))
    assert s.exit_code == EXIT_QUARANTINED


def test_keep_superseded_option_and_environment(raw, warehouse, monkeypatch):
    from click.testing import CliRunner

    from pipeline.cli import main

    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    args = ["rebuild", "--raw", str(raw.root), "--warehouse", str(warehouse), "--jobs", "1", "--no-report"]
    assert CliRunner().invoke(main, args).exit_code == 0
    first = q(warehouse, "SELECT samples_path FROM runs")[0][0]
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": [1.0] * 4, "x_ref[m]": T})
    monkeypatch.setenv("PNEUBENCH_KEEP_SUPERSEDED_H", "soon")
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 2 and "--keep-superseded" in res.output and "soon" in res.output
    with pytest.raises(RebuildError, match="PNEUBENCH_KEEP_SUPERSEDED_H='soon' is not a number") as err:
        rebuild(raw.root, warehouse, jobs=1)
    assert err.value.exit_code == 2
    monkeypatch.setenv("PNEUBENCH_KEEP_SUPERSEDED_H", "24")
    assert CliRunner().invoke(main, [*args, "--keep-superseded", "0"]).exit_code == 0  # the option wins
    assert not (warehouse / first).exists()
