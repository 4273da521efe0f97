"""The raw tree under careless and hostile hands, as the walk sees it: symlinks, non-UTF-8 names,
over-long paths, empty files and FIFOs. Each is one quarantine line, the other runs are ingested
(exit 1), and raw/ is byte-identical afterwards."""
import json
import os

import pyarrow.parquet as pq

from pipeline.raw.tree import RawTree
from pipeline.raw.walk import PATH_MAX, walk_raw
from pipeline.rebuild.flow import rebuild
from pipeline.rebuild.options import EXIT_QUARANTINED
from tests.conftest import STEP_META, query
from tests.pipeline.raw.conftest import COLS, Messages, rebuild_checked


# -- symlinks -----------------------------------------------------------------------------------
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


# -- names that are not UTF-8 -------------------------------------------------------------------
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


# -- paths longer than the OS limit -------------------------------------------------------------
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


# -- empty and special files --------------------------------------------------------------------
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
