"""benchmarks/bench_decision_stage.py: the stage times read from a rebuild's log, the odometer-only campaign."""
from benchmarks import bench_decision_stage as bench

LOG = ("stage durability ran: hose_life 560 rows (27.4 s)\n"
       "stage decision ran: decision_look_hoses 5351 rows, life_verdict 20 rows (19.7 s; per-run results: 0 from the memo)\n"
       "stage findings ran: findings 28 rows (828 ms)\n")


def test_stage_seconds_reads_the_rebuilds_progress_lines():
    assert bench.stage_seconds(LOG, "decision") == 19.7
    assert abs(bench.stage_seconds(LOG, "findings") - 0.828) < 1e-12
    assert bench.stage_seconds(LOG, "test_plan") is None     # not re-run: no line


def test_the_odometer_only_campaign_has_no_runs_and_every_hose_placed(tmp_path):
    life, runs = bench.campaign(3, 5, tmp_path, (8, 6), varied=True, odometer_only=True)
    assert runs.empty and set(life["hose_type"]) == {"TYPE 000", "TYPE 001", "TYPE 002"}
    assert set(life["status"]) == {"failed", "running"}
    on_test = life[life["distance_km"] > 0]             # hoses installed after the stop have run nothing
    assert len(on_test) > len(life) / 3 and (on_test["distance_source"] == "odometer").all()
    running = on_test[on_test["status"] == "running"]
    assert len(running) and running["odometer_at"].notna().all()   # read at the stop: placed in the looks
    assert (life[life["status"] == "failed"].groupby("hose_type").size() >= 6).all()


def test_same_as_compares_both_stages_tables_with_another_versions(capsys):
    """--same-as: HEAD's code (git archive) and this checkout on two designed hose types, each in its own
    process; every table of both stages and the schedule's hose-km compared, one line each."""
    assert bench.same_as("HEAD", 2, 1)
    lines = capsys.readouterr().out.splitlines()
    names = {line.split(":")[0].strip() for line in lines}
    assert {"life_effect", "life_verdict", "decision_looks", "decision_look_hoses", "test_plan",
            "test_plan decision_km"} <= names
    assert all(": same (" in line for line in lines)


def test_ref_mode_rebuilds_each_version_with_its_own_code_alternately(tmp_path, monkeypatch):
    """--ref: each version's warehouses are rebuilt by its own tree (PYTHONPATH), the plan changed once a round
    for both, the versions' order reversed every round; with and without the stages per version."""
    import benchmarks.proc as proc

    calls, changes = [], []

    class M:
        wall_s, cpu_s, stdout, stderr = 1.0, 1.0, "stage decision ran: x (2.0 s)\n", ""

    def measure(cmd, cwd=None, env=None, **kw):
        calls.append((None if env is None else env["PYTHONPATH"], cmd[-1]))
        return M()

    monkeypatch.setattr(proc, "measure", measure)
    ref = tmp_path / "ref-tree"
    warm = {"ref": (ref, tmp_path / "a"), "this": (None, tmp_path / "b")}
    for _, wh in warm.values():
        wh.mkdir()
    res = bench.added_by_trees(tmp_path, warm, changes.append, ("decision", "test_plan"), 2)
    assert changes == [True, False, False]
    rounds = [(c[0], c[1].rsplit("/", 1)[-1]) for c in calls[2:]]
    assert rounds == [(str(ref), "a"), (str(ref), "a-without"), (None, "b"), (None, "b-without"),
                      (None, "b"), (None, "b-without"), (str(ref), "a"), (str(ref), "a-without")]
    assert all(len(res[k]["with"].runs) == len(res[k]["without"].runs) == 2 for k in warm)
    assert res["this"]["own"]["decision"] == [2.0, 2.0]
    assert bench.tree_env(None) is None and bench.tree_env(ref)["PYTHONPATH"] == str(ref)
