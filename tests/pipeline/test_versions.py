"""Versions of the project's own code: the ingest's, a stage's and a memoised function's (what their
module imports, read as text), and the whole project's."""
import pipeline.versions as versions
from pipeline.versions import ROOT, function_code_version, project_imports, stage_code_version


def test_a_functions_version_is_its_modules_stage_version_and_none_without_a_module_file():
    from pipeline.stages import plpa_characterisation as plpa

    assert function_code_version(plpa.analyse_run) == stage_code_version(plpa.__file__)
    assert len(stage_code_version(plpa.__file__)) == 16
    assert function_code_version(len) is None  # builtins: no module file, not memoisable


def test_a_stage_version_covers_the_project_modules_it_imports():
    # the durability stage reads hose logbooks through pipeline.raw.logbook: a change there must
    # re-run it (incremental == full), as must a unit change under an analysis (schemas.units)
    files = {f.relative_to(ROOT).as_posix() for f in project_imports(ROOT / "pipeline/stages/durability.py")}
    assert {"pipeline/stages/durability.py", "pipeline/raw/logbook.py", "analyses/service_life.py",
            "analyses/durability.py"} <= files
    files = {f.relative_to(ROOT).as_posix() for f in project_imports(ROOT / "analyses/leakage.py")}
    assert "schemas/units.py" in files
    assert not any(f.startswith(("numpy", "pandas")) for f in files)


def test_project_imports_follows_imports_transitively(tmp_path, monkeypatch):
    (tmp_path / "pipeline").mkdir()
    (tmp_path / "pipeline" / "a.py").write_text("import numpy\nfrom pipeline.b import thing\n")
    (tmp_path / "pipeline" / "b.py").write_text("from pipeline import c\nthing = 1\n")
    (tmp_path / "pipeline" / "c.py").write_text("x = 1\n")
    (tmp_path / "pipeline" / "d.py").write_text("x = 2\n")
    monkeypatch.setattr(versions, "ROOT", tmp_path)
    got = {f.name for f in project_imports(tmp_path / "pipeline" / "a.py")}
    assert got == {"a.py", "b.py", "c.py"}
