"""Publishing the report folder whole: unchanged run pages taken over, others' files kept, and a
file system without symlinks swapped by rename."""
from pipeline.rebuild.flow import rebuild
from tests.conftest import STEP_META


def test_a_new_report_reuses_unchanged_run_pages_and_keeps_what_others_put_in_the_report_folder(raw, warehouse):
    """The report folder is swapped whole (issue 21.4): an unchanged run's page is the same file
    (a hard link, not drawn again); a report/ folder of the old layout becomes the first
    generation; files and folders a user put there stay readable under report/."""
    import os

    from pipeline.serve.report.folders import page_name

    meta = {"t[s]": [0, 0.1], "x[mm]": [0, 1], "x_ref[mm]": [1, 1]}
    raw.csv("c/a.csv", STEP_META, meta)
    raw.csv("c/b.csv", STEP_META, meta)
    rebuild(raw.root, warehouse, jobs=1)
    report = warehouse / "report"
    assert os.path.islink(report)
    # back to the old layout: report/ a real folder, with a user's notes in it
    folder = report.resolve()
    report.unlink()
    folder.rename(report)
    (report / "notes.txt").write_text("mine")
    (report / "extra").mkdir()
    (report / "extra" / "x.txt").write_text("also mine")
    (report / "runs" / "README").write_text("mine too")
    ino = {r: os.stat(report / "runs" / page_name(r)).st_ino for r in ("c/a", "c/b")}
    raw.csv("c/b.csv", STEP_META, {**meta, "x[mm]": [0, 2]})
    rebuild(raw.root, warehouse, jobs=1)
    assert os.path.islink(report)
    assert os.stat(report / "runs" / page_name("c/a")).st_ino == ino["c/a"]  # taken over, not redrawn
    assert os.stat(report / "runs" / page_name("c/b")).st_ino != ino["c/b"]
    assert (report / "notes.txt").read_text() == "mine" and (report / "extra" / "x.txt").read_text() == "also mine"
    assert (report / "runs" / "README").read_text() == "mine too"
    assert [p.name for p in warehouse.iterdir() if p.name.startswith(".report")] == [os.readlink(report)]
    # a no-op rebuild: the same pages again, the same files
    ino = {r: os.stat(report / "runs" / page_name(r)).st_ino for r in ("c/a", "c/b")}
    rebuild(raw.root, warehouse, jobs=1)
    assert {r: os.stat(report / "runs" / page_name(r)).st_ino for r in ("c/a", "c/b")} == ino
    assert (report / "notes.txt").read_text() == "mine" and (report / "extra" / "x.txt").read_text() == "also mine"
    assert [p.name for p in warehouse.iterdir() if p.name.startswith(".report")] == [os.readlink(report)]


def test_on_a_file_system_without_symlinks_the_report_folder_is_swapped_by_rename(raw, warehouse, monkeypatch):
    import os

    from pipeline.serve.report.folders import page_name

    real_symlink = os.symlink

    def no_symlinks(src, dst, *a, **k):  # the warehouse's file system has none (raw/'s links live elsewhere)
        if str(dst).startswith(str(warehouse)):
            raise PermissionError(1, "Operation not permitted")
        return real_symlink(src, dst, *a, **k)

    monkeypatch.setattr(os, "symlink", no_symlinks)
    meta = {"t[s]": [0, 0.1], "x[mm]": [0, 1], "x_ref[mm]": [1, 1]}
    raw.csv("c/a.csv", STEP_META, meta)
    raw.csv("c/b.csv", STEP_META, meta)
    rebuild(raw.root, warehouse, jobs=1)
    (raw.root / "c/b.csv").unlink()
    raw.csv("c/c.csv", STEP_META, meta)
    s = rebuild(raw.root, warehouse, jobs=1)
    report = warehouse / "report"
    assert report.is_dir() and not os.path.islink(report)
    assert f"generation {s.generation}" in (report / "index.html").read_text()
    assert {p.name for p in (report / "runs").iterdir()} == {page_name("c/a"), page_name("c/c")}
    assert not [p.name for p in warehouse.iterdir() if p.name.startswith(".report")]
