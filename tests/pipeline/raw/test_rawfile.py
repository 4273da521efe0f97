"""A file of raw/ is opened once, without following a symlink out of raw/, and every read (hash,
reader, library) goes through that descriptor: an export or side file replaced by a link to an
outside file between the scan and the read is quarantined, and the outside bytes are nowhere in
the warehouse (issue 21, item 6)."""
import os
import stat

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

import pipeline.raw.logbook as logbook
import pipeline.raw.tree as raw_tree
import pipeline.rebuild.flow as rb
from pipeline.ingest.hashing import sha256_file
from pipeline.raw.rawfile import RawOpenError, open_raw
from pipeline.readers import list_parts, read_export
from pipeline.rebuild.flow import rebuild
from pipeline.rebuild.options import EXIT_QUARANTINED
from pipeline.simulator import writers
from tests.conftest import PROJECT_ROOT, STEP_META, query
from tests.pipeline.readers.generators import mat_v73

T = [0.0, 0.1, 0.2, 0.3]
MARKER = "hunter2-SECRET-7f3a"
SECRET = f"t[s],password\n0,{MARKER}\n1,{MARKER}x\n"


def _good(raw, rel):
    return raw.csv(rel, STEP_META, {"t[s]": T, "x[mm]": [0, 1, 2, 3], "x_ref[mm]": [3] * 4})


def _nowhere(warehouse, marker=MARKER):
    """The marker is in no file of the warehouse (bytes), and in no value or name of any samples
    Parquet file (decompressed)."""
    needle = marker.encode()
    for folder, _dirs, files in os.walk(warehouse):
        for name in files:
            path = os.path.join(folder, name)
            with open(path, "rb") as fh:
                assert needle not in fh.read(), path
            if name.endswith(".parquet"):
                table = pq.read_table(path)
                assert marker not in str(table.schema) and marker not in str(table.to_pylist()), path


def _swap_after_planning(monkeypatch, link, target):
    """Replace ``link`` (a regular file the scan listed) by a symlink to ``target`` once the
    rebuild has planned its reads, before any file is read."""
    real = rb.plan_runs

    def plan_then_swap(*args, **kwargs):
        plans = real(*args, **kwargs)
        os.replace(link, link.with_name(".orig-" + link.name))  # kept in a dotted name: never read
        os.symlink(target, link)
        return plans

    monkeypatch.setattr(rb, "plan_runs", plan_then_swap)


@pytest.mark.raw_written("c1/evil.csv", "c1/.orig-evil.csv")
def test_an_export_swapped_for_a_link_out_of_raw_after_the_scan_is_not_read(raw, warehouse, tmp_path, monkeypatch):
    _good(raw, "c1/a.csv")
    _good(raw, "c2/b.csv")
    evil = _good(raw, "c1/evil.csv")
    raw.write("c1/manifest.csv", "file,kind,started_at,rig\nevil.csv,timeseries,2026-01-02T03:04:05,plpa-1\n")
    outside = tmp_path / "secret.txt"
    outside.write_text(SECRET)
    _swap_after_planning(monkeypatch, evil, outside)
    summary = rebuild(raw.root, warehouse, jobs=1)
    assert summary.exit_code == EXIT_QUARANTINED
    assert query(warehouse, "SELECT run_id FROM runs ORDER BY 1") == [("c1/a",), ("c2/b",)]
    assert query(warehouse, "SELECT source_path, error FROM quarantine") == [
        ("c1/evil.csv", f"symlink to a file outside raw/: {outside}")]
    _nowhere(warehouse)


def test_no_link_for_the_readers_is_a_quarantine_line_never_a_read_by_name(raw, warehouse, monkeypatch):
    """Fail closed: when the private link to the descriptor cannot be made (no symlinks there, a
    full /dev/shm), the file is not read by its name instead; it is one line, read again next time,
    and the rebuild goes on."""
    _good(raw, "c1/a.csv")
    real_symlink = os.symlink

    def no_fd_links(src, dst, *a, **k):
        if str(src).startswith("/proc/self/fd/"):
            raise OSError(28, "No space left on device")
        return real_symlink(src, dst, *a, **k)

    monkeypatch.setattr(os, "symlink", no_fd_links)
    summary = rebuild(raw.root, warehouse, jobs=1)
    assert summary.exit_code == EXIT_QUARANTINED
    assert query(warehouse, "SELECT source_path, error FROM quarantine") == [
        ("c1/a.csv", "cannot read file: OSError: [Errno 28] No space left on device")]
    monkeypatch.setattr(os, "symlink", real_symlink)
    assert rebuild(raw.root, warehouse, jobs=1).exit_code == 0
    assert query(warehouse, "SELECT run_id FROM runs") == [("c1/a",)]


@pytest.mark.raw_written("c1/evil.csv", "c1/.orig-evil.csv")
def test_an_export_swapped_for_another_file_after_the_scan_is_read_next_time(raw, warehouse, monkeypatch):
    """A file replaced inside raw/ (another inode than the scan saw) is not read this night and
    is read again by the next rebuild."""
    _good(raw, "c1/a.csv")
    evil = _good(raw, "c1/evil.csv")
    other = raw.write("c1/.other.csv", SECRET.replace("password", "x[mm]").replace(MARKER, "1"))
    real = rb.plan_runs

    def plan_then_swap(*args, **kwargs):
        plans = real(*args, **kwargs)
        os.replace(evil, evil.with_name(".orig-evil.csv"))
        os.link(other, evil)
        return plans

    monkeypatch.setattr(rb, "plan_runs", plan_then_swap)
    assert rebuild(raw.root, warehouse, jobs=1).exit_code == EXIT_QUARANTINED
    (err,), = query(warehouse, "SELECT error FROM quarantine WHERE source_path = 'c1/evil.csv'")
    assert err == "file was replaced after raw/ was listed; will be read again at the next rebuild"
    monkeypatch.setattr(rb, "plan_runs", real)
    rebuild(raw.root, warehouse, jobs=1)
    assert query(warehouse, "SELECT error FROM quarantine WHERE source_path = 'c1/evil.csv'") != [(err,)]


@pytest.mark.raw_written("c1/manifest.csv", "c1/.orig-manifest.csv", "c2/rig.toml", "c2/.orig-rig.toml",
                         "c3/hoses.csv", "c3/.orig-hoses.csv")
def test_side_files_swapped_for_links_out_of_raw_after_the_walk_are_not_read(raw, warehouse, tmp_path, monkeypatch):
    for c in ("c1", "c2", "c3", "c4"):
        _good(raw, f"{c}/a.csv")
    raw.write("c1/manifest.csv", "file,notes\na.csv,ours\n")
    raw.write("c2/rig.toml", '[metadata]\nnotes = "ours"\n')
    raw.write("c3/hoses.csv", "hose_id,event,at\nH1,installed,2026-01-01\n")
    outside = {"c1/manifest.csv": f"file,notes\na.csv,{MARKER}\n",
               "c2/rig.toml": f'[metadata]\nnotes = "{MARKER}"\n',
               "c3/hoses.csv": f"hose_id,event,at\n{MARKER},installed,2026-01-01\n"}
    def walk_then_swap(module, names):
        real = module.walk_raw

        def walk(root):  # the rebuild's walk (manifest, rig.toml, hoses.csv)
            listing = real(root)
            for rel in names:
                target = tmp_path / rel.replace("/", "-")
                target.write_text(outside[rel])
                link = raw.root / rel
                if not link.is_symlink():
                    os.replace(link, link.with_name(".orig-" + link.name))
                    os.symlink(target, link)
            return listing

        monkeypatch.setattr(module, "walk_raw", walk)

    # the rebuild's walk is the only one: the stages read the logbooks it listed (logbook.walked)
    walk_then_swap(raw_tree, ["c1/manifest.csv", "c2/rig.toml", "c3/hoses.csv"])
    assert rebuild(raw.root, warehouse, jobs=1).exit_code == EXIT_QUARANTINED
    q = dict(query(warehouse, "SELECT source_path, error FROM quarantine WHERE source_path NOT LIKE '%/a.csv'"))
    assert q == {rel: ("cannot read logbook: " if rel.endswith("hoses.csv") else "cannot read: ")
                 + f"symlink to a file outside raw/: {tmp_path / rel.replace('/', '-')}" for rel in outside}
    runs = [r for (r,) in query(warehouse, "SELECT run_id FROM runs ORDER BY 1")]
    assert runs == ["c3/a", "c4/a"]  # c1, c2: their metadata cannot be known; the logbook is no run's
    _nowhere(warehouse)


@pytest.mark.raw_written("c3/hoses.csv", "c3/.orig-hoses.csv")
def test_a_logbook_swapped_for_a_link_out_of_raw_after_its_own_walk_is_not_read(raw, tmp_path, monkeypatch):
    """Outside a rebuild (``pneubench decision``, a notebook) read_logbooks walks raw/ itself: a logbook
    swapped for a link out of raw/ after that walk is a problem line, its text never read."""
    raw.write("c3/hoses.csv", "hose_id,event,at\nH1,installed,2026-01-01\n")
    target = tmp_path / "outside-hoses.csv"
    target.write_text(f"hose_id,event,at\n{MARKER},installed,2026-01-01\n")
    real = logbook.walk_raw

    def walk(root):
        listing = real(root)
        link = raw.root / "c3/hoses.csv"
        os.replace(link, link.with_name(".orig-hoses.csv"))
        os.symlink(target, link)
        return listing

    monkeypatch.setattr(logbook, "walk_raw", walk)
    events, problems = logbook.read_logbooks(raw.root)
    assert [(p.source_path, p.error) for p in problems] == [
        ("c3/hoses.csv", f"cannot read logbook: symlink to a file outside raw/: {target}")]
    assert MARKER not in events.to_csv()


# -- every reader reads the opened file, whatever its name points at by then ---------------------
def _frame(scale):
    t = np.arange(8) * 0.1
    return pd.DataFrame({"t_s": t, "x_m": t * scale, "x_ref_m": np.full(8, scale)})


def _write(fmt, path, scale):
    cols = writers.default_columns(["x_m", "x_ref_m"] if fmt == "tdms" else ["t_s", "x_m", "x_ref_m"])
    meta = {"kind": "step", "started_at": "2026-01-02T03:04:05"}
    if fmt == "mat73":
        t = np.arange(8) * 0.1
        return mat_v73(path, {"t": t, "x": t * scale, "x_ref": np.full(8, scale)})
    return getattr(writers, f"write_{fmt}")(path, _frame(scale), cols, meta)


FORMATS = {"csv": ".csv", "lvm": ".lvm", "tdms": ".tdms", "mat": ".mat", "mat73": ".mat", "xlsx": ".xlsx",
           "mf4": ".mf4"}


def _values(export):
    tables = [b.to_pandas() for b in export.batches()]
    df = pd.concat(tables, ignore_index=True)
    return sorted(float(v) for v in df.select_dtypes("number").to_numpy().ravel() if np.isfinite(v))


@pytest.mark.parametrize("fmt", sorted(FORMATS))
def test_each_reader_reads_the_opened_descriptor_not_the_name(fmt, tmp_path):
    """npTDMS, h5py, scipy, calamine, asammdf, pyarrow and pandas get ``RawFile.source``: after
    the name in raw/ is replaced by a link to another file of the same format, they still read
    the file that was opened (the hash too)."""
    root = tmp_path / "raw"
    (root / "c1").mkdir(parents=True)
    path = _write(fmt, root / "c1" / f"run{FORMATS[fmt]}", 1.0)
    outside = _write(fmt, tmp_path / f"outside{FORMATS[fmt]}", 7.0)
    want = _values(read_export(path))
    want_sha = sha256_file(path)
    assert want != _values(read_export(outside))
    with open_raw(root, path) as opened:
        os.replace(path, tmp_path / f"moved{FORMATS[fmt]}")
        os.symlink(outside, path)
        assert opened.source.name == path.name
        assert _values(read_export(opened.source)) == want
        if fmt in ("xlsx", "mf4"):
            assert list_parts(opened.source) == list_parts(tmp_path / f"moved{FORMATS[fmt]}")
        assert sha256_file(opened.source) == want_sha
        source = opened.source
    assert not os.path.lexists(source)  # removed with the descriptor
    with pytest.raises(RawOpenError, match=f"symlink to a file outside raw/: {outside}"):
        open_raw(root, path)


# -- open_raw itself --------------------------------------------------------------------------------
def test_open_raw_refuses_a_folder_link_a_fifo_and_another_inode_and_opens_an_alias(tmp_path):
    root = tmp_path / "raw"
    (root / "c1").mkdir(parents=True)
    (root / ".stash").mkdir()
    (root / ".stash" / "real.csv").write_text("t\n0\n")
    (root / "c1" / "a.csv").write_text("t\n1\n")
    os.symlink("../.stash/real.csv", root / "c1" / "alias.csv")  # inside raw/: read under its own name
    with open_raw(root, root / "c1" / "alias.csv") as f:
        assert f.read_bytes() == b"t\n0\n" and f.source.name == "alias.csv"
    ino = os.stat(root / "c1" / "a.csv").st_ino
    with open_raw(root, root / "c1" / "a.csv", inode=ino) as f:
        assert f.read_bytes() == b"t\n1\n" and stat.S_ISREG(f.stat.st_mode)
    with pytest.raises(RawOpenError, match="^file was replaced after raw/ was listed"):
        open_raw(root, root / "c1" / "a.csv", inode=ino + 1)
    os.mkfifo(root / "c1" / "pipe.csv")  # opened without blocking, then refused
    with pytest.raises(RawOpenError, match=r"^not a regular file \(a FIFO \(named pipe\)\): not read$"):
        open_raw(root, root / "c1" / "pipe.csv")
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "elsewhere" / "a.csv").write_text("secret\n")
    os.rename(root / "c1", root / ".c1")
    os.symlink(tmp_path / "elsewhere", root / "c1")  # a folder swapped for a link out of raw/
    with pytest.raises(RawOpenError, match="^folder c1 is a symlink: folders are not followed"):
        open_raw(root, root / "c1" / "a.csv")


def test_the_private_link_folder_is_made_once_per_process_and_removed_at_exit(tmp_path):
    """Files of the same name open at once get links in different slots; a process's folder
    (a forked pool worker's too) is removed when it exits."""
    import subprocess
    import sys

    root = tmp_path / "raw"
    for c in ("c1", "c2"):
        (root / c).mkdir(parents=True)
        (root / c / "a.csv").write_text(c)
    with open_raw(root, root / "c1" / "a.csv") as one, open_raw(root, root / "c2" / "a.csv") as two:
        assert one.source != two.source and one.source.parent.parent == two.source.parent.parent
        assert (one.source.read_text(), two.source.read_text()) == ("c1", "c2")
        assert stat.S_IMODE(os.stat(one.source.parent.parent).st_mode) == 0o700
    code = ("import concurrent.futures as cf, multiprocessing as mp, sys\n"
            "from pipeline.raw.rawfile import open_raw\n"
            "def f(p):\n"
            "    with open_raw(sys.argv[1], p) as o:\n"
            "        return str(o.source.parent.parent)\n"
            "if __name__ == '__main__':\n"
            "    import os\n"
            "    parent = f(sys.argv[2])  # made before the fork: the worker's exit leaves it\n"
            "    with cf.ProcessPoolExecutor(1, mp_context=mp.get_context('fork')) as ex:\n"
            "        print(ex.submit(f, sys.argv[2]).result())\n"
            "    print(parent if os.path.isdir(parent) and f(sys.argv[2]) == parent else 'gone')\n")
    out = subprocess.run([sys.executable, "-c", code, str(root), str(root / "c1" / "a.csv")], capture_output=True,
                         text=True, check=True, cwd=PROJECT_ROOT)
    worker, parent = out.stdout.split()
    assert worker != parent and not os.path.exists(worker) and not os.path.exists(parent)
    # a process killed with SIGKILL leaves its folder: the next process to make one removes it
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True).stdout.strip()
    stale = os.path.join(os.path.dirname(parent), f"pneubench-open-{dead}-abc")
    os.makedirs(os.path.join(stale, "1"))
    subprocess.run([sys.executable, "-c", code, str(root), str(root / "c1" / "a.csv")], check=True,
                   capture_output=True, cwd=PROJECT_ROOT)
    assert not os.path.exists(stale)
