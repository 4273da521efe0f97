"""The reader fuzz harness: a fixed-seed run finds nothing, and the harness sees what it must."""
import sys
from pathlib import Path

import pytest

from tests import fuzz

#: Mutants per CI run (the long run is ``python -m tests.fuzz --mutants 20000 --seed 7``).
CI_MUTANTS = 500


def test_fixed_seed_run_has_no_crash_hang_memory_or_unexplained_reason():
    report = fuzz.run(CI_MUTANTS, seed=11)
    assert sum(report.counts.values()) == CI_MUTANTS
    assert not [f for f in report.findings], report.summary()
    # The mutants reach deep enough to be read as runs, and bad enough to be refused.
    assert report.counts["run"] > 0 and report.counts["quarantined"] > CI_MUTANTS // 2


def test_mutants_are_deterministic_and_cover_every_format(tmp_path):
    seeds = fuzz.make_seeds(tmp_path / "a")
    assert seeds == fuzz.make_seeds(tmp_path / "b")
    assert {name.rsplit(".", 1)[1] for name in seeds} == {"csv", "txt", "lvm", "tdms", "mat", "xlsx", "mf4"}
    a = [fuzz.mutant(seeds, 7, i) for i in range(200)]
    b = [fuzz.mutant(seeds, 7, i) for i in reversed(range(200))][::-1]
    assert [(m.data, m.how) for m in a] == [(m.data, m.how) for m in b]
    assert sum(m.data != seeds[m.seed_name] for m in a) >= 190   # a header byte may be set to itself
    assert {m.seed_name for m in a} == set(seeds)


@pytest.mark.parametrize("run, error, outcome", [
    (True, None, "run"),
    (False, "missing channel `t`", "quarantined"),
    (False, "cannot read file: KeyError: 3", "unexplained"),
    (False, "not a readable TDMS file: MemoryError() in npTDMS", "memory"),
    (False, "two\nlines", "bad-reason"),
    (False, "", "bad-reason"),
])
def test_classify(run, error, outcome):
    assert fuzz.classify(run, error) == outcome


_FAKE = ("import os, signal, sys, time\nprint('{}', flush=True)\nline = sys.stdin.readline()\n"
         "mode = sys.argv[1]\n"
         "if mode == 'segv':\n    os.kill(os.getpid(), signal.SIGSEGV)\n"
         "if mode == 'hang':\n    time.sleep(60)\n"
         "if mode == 'exit':\n    sys.exit(3)\n")


@pytest.mark.parametrize("mode, outcome, reason", [
    ("segv", "crash", "child killed by signal 11"),
    ("exit", "crash", "child exited with code 3"),
    ("hang", "hang", "no answer within 1 s"),
])
def test_child_crash_and_hang_are_seen(tmp_path, mode, outcome, reason):
    child = fuzz._Child(tmp_path, tmp_path, argv=[sys.executable, "-c", _FAKE, mode])
    try:
        assert child.ask(Path("x.csv"), timeout=1.0) == (outcome, reason)
        assert not child.alive()
    finally:
        child.kill()
