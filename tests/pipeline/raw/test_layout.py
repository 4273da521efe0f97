"""The raw tree under careless and hostile hands: symlinks, non-UTF-8 names, over-long paths,
broken manifests and rig.toml files, empty files and FIFOs. Each is one quarantine line, the
other runs are ingested (exit 1), and raw/ is byte-identical afterwards."""
import hashlib
import json
import os
import stat

import pyarrow.parquet as pq
import pytest

from pipeline.raw.layout import MAX_RIG_BYTES, PATH_MAX, RawTree, display_name, walk_raw
from pipeline.progress import Progress
from pipeline.rebuild.flow import rebuild
from pipeline.rebuild.options import EXIT_QUARANTINED
from tests.conftest import STEP_META, query

T = [0.0, 0.1, 0.2, 0.3]
COLS = {"t[s]": T, "x[mm]": [0, 1, 2, 3], "x_ref[mm]": [3] * 4}


class Messages(Progress):
    def __init__(self):
        self.lines = []

    def message(self, text):
        self.lines.append(text)


def snapshot(root) -> dict:
    """Every entry under ``root`` (bytes path -> type, mode, size, mtime, content hash or link
    target), read through directory fds so over-long paths are covered too."""
    out = {}
    for folder, dirs, files, dfd in os.fwalk(os.fsencode(root), follow_symlinks=False):
        for name in dirs + files:
            st = os.lstat(name, dir_fd=dfd)
            key = os.path.join(folder, name)
            if stat.S_ISLNK(st.st_mode):
                out[key] = ("link", os.readlink(name, dir_fd=dfd))
            elif stat.S_ISREG(st.st_mode):
                fd = os.open(name, os.O_RDONLY | os.O_NOFOLLOW, dir_fd=dfd)
                with os.fdopen(fd, "rb") as fh:
                    digest = hashlib.sha256(fh.read()).hexdigest()
                out[key] = ("file", st.st_mode, st.st_size, st.st_mtime_ns, digest)
            else:
                out[key] = ("other", st.st_mode, st.st_mtime_ns)
    return out


@pytest.fixture
def tree(raw):
    """Two good runs in two campaigns."""
    raw.csv("c1/a.csv", STEP_META, COLS)
    raw.csv("c2/b.csv", STEP_META, COLS)
    return raw


def rebuild_checked(raw, warehouse, expect_runs=("c1/a", "c2/b"), progress=None):
    """A real rebuild (jobs=1): exit 1, the good runs ingested, raw/ untouched. Returns
    {source_path: [(line, error), ...]} of the quarantine table."""
    before = snapshot(raw.root)
    summary = rebuild(raw.root, warehouse, jobs=1, progress=progress)
    assert snapshot(raw.root) == before
    assert summary.exit_code == EXIT_QUARANTINED
    runs = [r for (r,) in query(warehouse, "SELECT run_id FROM runs ORDER BY run_id")]
    assert set(expect_runs) <= set(runs), runs
    out = {}
    for src, line, err in query(warehouse, "SELECT source_path, line, error FROM quarantine ORDER BY 1, 2"):
        out.setdefault(src, []).append((line, err))
    return out


# -- 1. symlinks --------------------------------------------------------------------------------
def test_symlink_to_a_file_outside_raw_is_quarantined(tree, warehouse, tmp_path):
    outside = tmp_path / "secret.csv"
    outside.write_text("t[s],x[mm],x_ref[mm]\n0,0,0\n")
    os.symlink(outside, tree.root / "c1" / "evil.csv")
    q = rebuild_checked(tree, warehouse)
    assert q == {"c1/evil.csv": [(None, f"symlink to a file outside raw/: {outside}")]}


def test_dangling_looping_and_folder_symlinks_are_quarantined_not_skipped(tree, warehouse, tmp_path):
    os.symlink("gone.csv", tree.root / "c1" / "dangling.csv")
    os.symlink("loop2.csv", tree.root / "c1" / "loop1.csv")
    os.symlink("loop1.csv", tree.root / "c1" / "loop2.csv")
    (tmp_path / "elsewhere").mkdir()
    tree.csv(str(tmp_path / "elsewhere" / "x.csv"), STEP_META, COLS)
    os.symlink(tmp_path / "elsewhere", tree.root / "c3")
    os.symlink("..", tree.root / "c1" / "up")  # a folder loop: the walk must end
    q = rebuild_checked(tree, warehouse)
    assert q["c1/dangling.csv"] == [(None, "dangling symlink: its target gone.csv does not exist")]
    assert q["c1/loop1.csv"] == [(None, "symlink loop (-> loop2.csv): not read")]
    assert q["c1/loop2.csv"] == [(None, "symlink loop (-> loop1.csv): not read")]
    assert q["c3"] == [(None, f"symlink to a folder outside raw/ ({tmp_path / 'elsewhere'}): folders are not "
                              "followed; copy or move the files into raw/")]
    assert "c1/up" not in q  # a link to a folder inside raw/: its files are read under their own paths
    assert query(warehouse, "SELECT count(*) FROM runs") == [(2,)]


def test_symlink_inside_raw_is_read_once(tree, warehouse):
    """A link to a run the walk reaches is skipped with a note (no duplicate run); a link to a
    file the walk does not reach (a dotted folder) is read under the link's own path."""
    os.symlink("../c1/a.csv", tree.root / "c2" / "alias.csv")
    tree.csv(".stash/hidden.csv", STEP_META, COLS)
    os.symlink("../.stash/hidden.csv", tree.root / "c2" / "shown.csv")
    tree.write("c2/manifest.csv", "file,notes\nshown.csv,via link\nalias.csv,wrong place\n")
    msgs = Messages()
    q = rebuild_checked(tree, warehouse, expect_runs=("c1/a", "c2/b", "c2/shown"), progress=msgs)
    assert q == {"c2/manifest.csv": [(3, "entry `alias.csv` is a symlink to c1/a.csv, which is read under its own "
                                         "path; name that file instead")]}
    assert query(warehouse, "SELECT run_id, source_path, json_extract_string(params, '$.notes') FROM runs "
                            "ORDER BY 1") == [("c1/a", "c1/a.csv", None), ("c2/b", "c2/b.csv", None),
                                              ("c2/shown", "c2/shown.csv", "via link")]
    assert "skipped c2/alias.csv: symlink to c1/a.csv, which is read under its own path" in msgs.lines


# -- 2. manifests -------------------------------------------------------------------------------
@pytest.mark.parametrize("body,line,error", [
    (b"file,notes\na.csv,fine\nb.csv,x\x00y\n", 3, "NUL byte (a binary or UTF-16 file?); save it as UTF-8 CSV"),
    (b'file,notes\na.csv,fine\nb.csv,"oops\nc.csv,more\n', 3,
     "unclosed quote (the quoted field runs to the end of the file)"),
    (b"file,notes\na.csv," + b"x" * 200_000 + b"\n", 2,
     "a field is longer than 131072 characters (the csv module's limit)"),
])
def test_a_manifest_that_cannot_be_parsed_is_quarantined_with_its_line(tree, warehouse, body, line, error):
    tree.write("c1/manifest.csv", body)
    tree.csv("c1/sub/c.csv", STEP_META, COLS)
    q = rebuild_checked(tree, warehouse, expect_runs=("c2/b",))
    assert q["c1/manifest.csv"] == [(line, error)]
    # the runs under it: their metadata cannot be known, so they wait for the manifest to be fixed
    for run in ("c1/a.csv", "c1/sub/c.csv"):
        assert q[run] == [(None, f"cannot use c1/manifest.csv: line {line}: {error}")]
    assert query(warehouse, "SELECT run_id FROM runs") == [("c2/b",)]


def test_a_manifest_entry_that_cannot_be_a_file_name_is_one_line(tree, warehouse):
    tree.write("c1/manifest.csv", "file,notes\n" + "d/" * 2100 + "x.csv,long\na.csv,fine\n")
    q = rebuild_checked(tree, warehouse)
    assert q == {"c1/manifest.csv": [(2, "entry `" + "d/" * 2100 + "x.csv`: no such file")]}
    assert query(warehouse, "SELECT json_extract_string(params, '$.notes') FROM runs WHERE run_id = 'c1/a'") == [
        ("fine",)]



# Every way a manifest (or rig.toml) is refused as a whole: the refusal is its own quarantine line
# and every run under it waits for it to be fixed, none is published with the remaining sources.
MANIFEST_REFUSALS = [
    ("c1/manifest.csv", "File,notes\na.csv,2\n", None,
     "no `file` column in the header (`File` is not `file`: the column is named in lower case)"),
    ("c1/manifest.csv", "name,notes\na.csv,2\n", None, "no `file` column in the header"),
    ("c1/manifest.csv", "", None, "no header row (an empty manifest: a header naming the `file` column "
                                  "comes first)"),
    ("c1/manifest.csv", "\n \n", None, "no header row (an empty manifest: a header naming the `file` column "
                                        "comes first)"),
    ("c1/manifest.csv", "file,notes,Notes\na.csv,x,y\n", 1,
     "column `Notes` appears twice in the header (columns 2 and 3; names are matched case-insensitively)"),
    ("c1/Manifest.csv", "file,notes\na.csv,x\n", None,
     "named `Manifest.csv`: a manifest must be named `manifest.csv` (lower case); it is not read"),
    ("c1/MANIFEST.CSV", "file,notes\na.csv,x\n", None,
     "named `MANIFEST.CSV`: a manifest must be named `manifest.csv` (lower case); it is not read"),
    ("c1/Rig.toml", "[metadata]\nrig = \"other\"\n", None,
     "named `Rig.toml`: a rig.toml must be named `rig.toml` (lower case); it is not read"),
]


@pytest.mark.parametrize("name,body,line,error", MANIFEST_REFUSALS, ids=[
    "header-File", "no-file-column", "empty", "blank", "duplicate-column", "Manifest.csv", "MANIFEST.CSV",
    "Rig.toml"])
def test_a_refused_manifest_quarantines_every_run_under_it(tree, warehouse, name, body, line, error):
    tree.write(name, body)
    tree.csv("c1/sub/c.csv", STEP_META, COLS)
    q = rebuild_checked(tree, warehouse, expect_runs=("c2/b",))
    assert q.pop(name) == [(line, error)]
    reason = f"cannot use {name}: line {line}: {error}" if line else f"cannot use {name}: {error}"
    assert q == {"c1/a.csv": [(None, reason)], "c1/sub/c.csv": [(None, reason)]}
    assert query(warehouse, "SELECT run_id FROM runs") == [("c2/b",)]


def test_a_wrong_case_header_does_not_publish_its_runs_with_fallback_metadata(raw, warehouse):
    """Issue 21 item 14: `File` instead of `file` published the run with the rig.toml's
    backpressure 0 instead of the manifest's 2; it waits now, and is published with 2 once the
    header is fixed."""
    raw.write("c/rig.toml", "[metadata]\nbackpressure_bar = 0\n")
    raw.csv("c/a.csv", STEP_META, COLS)
    raw.write("c/manifest.csv", "File,backpressure_bar\na.csv,2\n")
    summary = rebuild(raw.root, warehouse, jobs=1)
    assert summary.exit_code == EXIT_QUARANTINED
    assert query(warehouse, "SELECT count(*) FROM runs") == [(0,)]
    raw.write("c/manifest.csv", "file,backpressure_bar\na.csv,2\n")
    assert rebuild(raw.root, warehouse, jobs=1).exit_code == 0
    assert query(warehouse, "SELECT json_extract(params, '$.backpressure_bar')::DOUBLE FROM runs") == [(2.0,)]


def test_a_manifest_row_with_cells_beyond_the_header_quarantines_its_run_only(tree, warehouse):
    """A row with more cells than the header (an unquoted `,` in a note) has its values shifted:
    the run it names waits; the manifest's other rows apply."""
    tree.csv("c1/c.csv", STEP_META, COLS)
    tree.csv("c1/d.csv", STEP_META, COLS)
    tree.write("c1/manifest.csv", "file,operator,notes,\na.csv,Smith, J.,ok,\nc.csv,Lee,fine,\n"
                                  "d.csv,Lee,fine,,\n")
    q = rebuild_checked(tree, warehouse, expect_runs=("c1/c", "c1/d", "c2/b"))
    msg = "row has a value in column 4 (`ok`), which the header does not name (an unquoted delimiter in a value?)"
    assert q == {"c1/manifest.csv": [(2, msg)], "c1/a.csv": [(None, f"cannot use c1/manifest.csv: line 2: {msg}")]}
    assert query(warehouse, "SELECT run_id, json_extract_string(params, '$.operator') FROM runs ORDER BY 1") == [
        ("c1/c", "Lee"), ("c1/d", "Lee"), ("c2/b", None)]


# -- 3. names that are not UTF-8 -----------------------------------------------------------------
def test_file_and_folder_names_that_are_not_utf8_are_ingested_with_escaped_bytes(tree, warehouse):
    root = os.fsencode(tree.root)
    tree.csv("c1/tmp.csv", STEP_META, COLS)
    os.rename(root + b"/c1/tmp.csv", root + b"/c1/m\xe9sure.csv")
    os.mkdir(root + b"/caf\xe9")
    tree.csv("c1/tmp2.csv", STEP_META, COLS)
    os.rename(root + b"/c1/tmp2.csv", root + b"/caf\xe9/r\xfcn.csv")
    os.symlink(b"nowhere\xff", root + b"/c1/bad\xff.csv")  # and one quarantine line with such a name
    q = rebuild_checked(tree, warehouse, expect_runs=("c1/a", "c2/b", "c1/m\\xe9sure", "caf\\xe9/r\\xfcn"))
    assert q == {"c1/bad\\xff.csv": [(None, "dangling symlink: its target nowhere\\xff does not exist")]}
    rows = query(warehouse, "SELECT run_id, campaign, source_path, samples_path FROM runs ORDER BY 1")
    assert [r[:3] for r in rows] == [("c1/a", "c1", "c1/a.csv"), ("c1/m\\xe9sure", "c1", "c1/m\\xe9sure.csv"),
                                     ("c2/b", "c2", "c2/b.csv"), ("caf\\xe9/r\\xfcn", "caf\\xe9", "caf\\xe9/r\\xfcn.csv")]
    assert query(warehouse, "SELECT count(*) FROM samples_step WHERE run_id = 'caf\\xe9/r\\xfcn'") == [(4,)]
    footer = json.loads(pq.read_metadata(warehouse / rows[3][3]).metadata[b"pneubench"])
    assert footer["run"]["source_path"] == "caf\\xe9/r\\xfcn.csv"
    assert "caf\\xe9/r\\xfcn.csv" in (warehouse / "report" / "index.html").read_text(encoding="utf-8")
    # deterministic: the next rebuild finds every file unchanged under the same names
    again = rebuild(tree.root, warehouse, jobs=1)
    assert (again.n_new, again.n_changed, again.n_unchanged) == (0, 0, 4)


def test_an_escaped_name_that_collides_with_a_real_name_is_quarantined(tree, warehouse):
    root = os.fsencode(tree.root)
    tree.csv("c1/m\\xe9.csv", {**STEP_META, "run_id": "literal"}, COLS)  # a real backslash in the name
    tree.csv("c1/tmp.csv", STEP_META, COLS)
    os.rename(root + b"/c1/tmp.csv", root + b"/c1/m\xe9.csv")
    q = rebuild_checked(tree, warehouse, expect_runs=("c1/a", "c2/b", "literal"))
    assert q == {"c1/m\\xe9.csv": [(None, "name is not valid UTF-8 and its escaped form `m\\xe9.csv` is the name "
                                          "of another entry in the same folder; rename one of them")]}


def test_a_newline_in_a_file_name_stays_on_one_line(tree, warehouse):
    tree.csv("c1/two\nlines.csv", STEP_META, COLS)
    tree.write("c1/bad\tname.csv", b"")
    q = rebuild_checked(tree, warehouse, expect_runs=("c1/a", "c2/b", "c1/two\\x0alines"))
    assert q == {"c1/bad\\x09name.csv": [(None, "empty file (0 bytes)")]}


def test_display_name_escapes_only_bytes_that_are_not_utf8():
    assert display_name("café/ü.csv") == "café/ü.csv"
    assert display_name(os.fsdecode(b"m\xe9sure.csv")) == "m\\xe9sure.csv"
    assert display_name("\ud800x") == "\\ud800x"
    assert display_name("a\nb\x7f") == "a\\x0ab\\x7f"
    for text in (os.fsdecode(b"a\xff\xfe/b\x80"), "\udce9"):
        display_name(text).encode("utf-8")  # valid UTF-8 whatever it gets


# -- 4. rig.toml --------------------------------------------------------------------------------
def test_a_rig_toml_nested_too_deeply_is_quarantined(tree, warehouse):
    tree.write("c1/rig.toml", "[metadata]\nx = " + "[" * 1000 + "]" * 1000 + "\n")
    q = rebuild_checked(tree, warehouse, expect_runs=("c2/b",))
    msg = "invalid TOML: too deeply nested (arrays or inline tables inside each other)"
    assert q == {"c1/rig.toml": [(None, msg)], "c1/a.csv": [(None, f"cannot use c1/rig.toml: {msg}")]}


def test_a_rig_toml_over_the_size_cap_is_not_parsed(tree, warehouse):
    tree.write("c1/rig.toml", "[metadata]\nnotes = \"" + "x" * MAX_RIG_BYTES + "\"\n")
    q = rebuild_checked(tree, warehouse, expect_runs=("c2/b",))
    size = (tree.root / "c1" / "rig.toml").stat().st_size
    msg = f"{size} bytes, larger than the {MAX_RIG_BYTES} bytes a rig.toml may have"
    assert q == {"c1/rig.toml": [(None, msg)], "c1/a.csv": [(None, f"cannot use c1/rig.toml: {msg}")]}


def test_a_rig_toml_linked_from_outside_raw_is_not_read(tree, warehouse, tmp_path):
    (tmp_path / "shared-rig.toml").write_text('[metadata]\nrig = "other"\n')
    os.symlink(tmp_path / "shared-rig.toml", tree.root / "c1" / "rig.toml")
    q = rebuild_checked(tree, warehouse, expect_runs=("c2/b",))
    msg = f"symlink to a file outside raw/: {tmp_path / 'shared-rig.toml'}"
    assert q == {"c1/rig.toml": [(None, msg)], "c1/a.csv": [(None, f"cannot use c1/rig.toml: {msg}")]}


# -- 5. paths longer than the OS limit ----------------------------------------------------------
def test_a_path_longer_than_the_os_limit_is_quarantined(tree, warehouse):
    fd = os.open(tree.root / "c1", os.O_RDONLY)
    names = []
    try:
        while len(os.fsencode(tree.root / "c1")) + sum(len(n) + 1 for n in names) < PATH_MAX:
            name = f"d{len(names):02d}" + "x" * 247
            os.mkdir(name, dir_fd=fd)
            nfd = os.open(name, os.O_RDONLY, dir_fd=fd)
            os.close(fd)
            fd, names = nfd, names + [name]
        out = os.open("deep.csv", os.O_WRONLY | os.O_CREAT, 0o644, dir_fd=fd)
        os.write(out, b"t[s],x[mm],x_ref[mm]\n0,0,0\n")
        os.close(out)
    finally:
        os.close(fd)
    q = rebuild_checked(tree, warehouse)
    (src, [(line, err)]), = q.items()
    assert src == "c1/" + "/".join(names) + "/deep.csv" and line is None  # the run, not only its folder
    assert err.startswith(f"path is {len(os.fsencode(tree.root / src))} bytes, longer than the OS limit "
                          f"({PATH_MAX - 1} bytes): it cannot be opened")


def test_every_run_under_a_folder_beyond_the_os_limit_is_named(tree, warehouse):
    """Folders nested past PATH_MAX (made through folder fds, as a share or an archive can):
    each run and side file below the first over-long folder, however deep, is a quarantine row
    naming its own path; files that are not runs are not rows; the other runs are ingested."""
    fd = os.open(tree.root / "c1", os.O_RDONLY)
    names = []

    def put(dfd, name, data=b"t[s],x[mm],x_ref[mm]\n0,0,0\n"):
        out = os.open(name, os.O_WRONLY | os.O_CREAT, 0o644, dir_fd=dfd)
        os.write(out, data)
        os.close(out)

    try:
        while len(names) < 20:  # 20 x 251 bytes: well past PATH_MAX
            name = f"d{len(names):02d}" + "y" * 248
            os.mkdir(name, dir_fd=fd)
            nfd = os.open(name, os.O_RDONLY, dir_fd=fd)
            os.close(fd)
            fd, names = nfd, names + [name]
            if len(names) == 17:
                put(fd, "mid.csv")
                put(fd, "manifest.csv", b"file,notes\nmid.csv,x\n")
                put(fd, "photo.png", b"\x89PNG")
        put(fd, "deepest.lvm")
        os.mkdir(b"caf\xe9", dir_fd=fd)  # an empty folder with a Latin-1 name: nothing to name
    finally:
        os.close(fd)
    q = rebuild_checked(tree, warehouse)
    base = "c1/" + "/".join(names[:17])
    expect = {base + "/manifest.csv", base + "/mid.csv", "c1/" + "/".join(names) + "/deepest.lvm"}
    assert set(q) == expect
    for src, [(line, err)] in q.items():
        assert line is None and err.startswith(f"path is {len(os.fsencode(tree.root / src))} bytes, longer than "
                                               "the OS limit"), (src, err)


# -- 6. empty and special files -----------------------------------------------------------------
def test_an_empty_file_says_so_before_any_reader_runs(tree, warehouse):
    for name in ("c1/e.csv", "c1/e.lvm", "c1/e.tdms", "c1/e.mat"):
        tree.write(name, b"")
    q = rebuild_checked(tree, warehouse)
    assert q == {f"c1/e.{ext}": [(None, "empty file (0 bytes)")] for ext in ("csv", "lvm", "mat", "tdms")}


def test_a_fifo_is_quarantined_not_opened(tree, warehouse):
    os.mkfifo(tree.root / "c1" / "pipe.csv")  # opening it would block the rebuild forever
    q = rebuild_checked(tree, warehouse)
    assert q == {"c1/pipe.csv": [(None, "not a regular file (a FIFO (named pipe)): not read")]}


def test_walk_lists_side_files_and_never_leaves_raw(tree, tmp_path):
    tree.write("c1/rig.toml", "[metadata]\n")
    tree.write("c1/hoses.csv", "hose_id,event,at\n")
    os.symlink(tmp_path, tree.root / "c2" / "all")
    listing = walk_raw(tree.root)
    assert [p.relative_to(tree.root).as_posix() for p in listing.runs] == ["c1/a.csv", "c2/b.csv"]
    assert [p.relative_to(tree.root).as_posix() for p in listing.side] == ["c1/hoses.csv", "c1/rig.toml"]
    assert [(p.source_path, p.error.split(" (")[0]) for p in listing.problems] == [
        ("c2/all", "symlink to a folder outside raw/")]
    assert RawTree(tree.root).rel(tree.root / "c1" / "a.csv") == "c1/a.csv"


def test_the_cli_exits_1_and_prints_one_line_per_hostile_entry(tree, warehouse, tmp_path):
    from click.testing import CliRunner

    from pipeline.cli import main

    (tmp_path / "secret.csv").write_text("x\n")
    os.symlink(tmp_path / "secret.csv", tree.root / "c1" / "evil.csv")
    tree.write("c2/empty.csv", b"")
    res = CliRunner().invoke(main, ["rebuild", "--raw", str(tree.root), "--warehouse", str(warehouse), "--jobs", "1"])
    assert res.exit_code == EXIT_QUARANTINED, res.output
    lines = [ln for ln in res.output.splitlines() if "quarantined c" in ln]
    assert len(lines) == 2
    assert any(f"quarantined c1/evil.csv: symlink to a file outside raw/: {tmp_path / 'secret.csv'}" in ln
               for ln in lines)
    assert any("quarantined c2/empty.csv: empty file (0 bytes)" in ln for ln in lines)
    assert query(warehouse, "SELECT run_id FROM runs ORDER BY 1") == [("c1/a",), ("c2/b",)]


def test_manifest_rows_for_one_sheet_are_kept_apart_from_the_file_row(raw):
    raw.write("c/b.xlsx", b"x")
    raw.write("c/odd#name.csv", b"x")          # a real file with `#` in its name is that file
    raw.write("manifest.csv", "file,kind\nc/b.xlsx#S1,step\nc/b.xlsx#S2,leakage\n")
    raw.write("c/manifest.csv", "file,kind,rig\nb.xlsx,spring,r1\nb.xlsx#S1,identification,\n"
                                "odd#name.csv,step,\n../c/b.xlsx#S3,step,\n")
    tree = RawTree(raw.root)
    assert tree.manifest_metadata(raw.root / "c/b.xlsx") == {"kind": "spring", "rig": "r1"}
    # nearer manifests override farther ones, part by part
    assert tree.manifest_parts(raw.root / "c/b.xlsx") == {
        "S1": {"kind": "identification"}, "S2": {"kind": "leakage"}, "S3": {"kind": "step"}}
    assert tree.manifest_metadata(raw.root / "c/odd#name.csv") == {"kind": "step"}
    assert tree.manifest_parts(raw.root / "c/odd#name.csv") == {}
    assert tree.problems == []
