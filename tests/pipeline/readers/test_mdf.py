"""ASAM MDF reader: scenarios written with asammdf in the test (no binaries committed)."""
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

asammdf = pytest.importorskip("asammdf")
# asammdf's destructor complains about a file it failed to open; the refusal itself is tested
pytestmark = pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
from asammdf import MDF, Signal  # noqa: E402

from pipeline.readers import ReaderError, read_export  # noqa: E402
from pipeline.readers.mdf import list_parts, parse_header_comment, read_mdf  # noqa: E402
from tests.pipeline.readers.generators import mdf_unfinalised, mf4_can_bus_log  # noqa: E402


def _values(exp):
    table = pa.Table.from_batches(list(exp.batches()))
    return {c.name: np.asarray(table.column(c.key).to_pylist()) for c in exp.columns}


def _write(path, groups, comment=None, version="4.10"):
    m = MDF(version=version)
    for name, sigs in groups:
        m.append(sigs, acq_name=name, comment=name or "")
    if comment is not None:
        m.header.comment = comment
    saved = m.save(path, overwrite=True)  # asammdf picks the suffix of the version it writes
    m.close()
    return saved


def _run(n=1000, fs=100.0):
    t = np.arange(n) / fs
    return t, [Signal(1.5 + 0.1 * np.sin(t), t, name="p_a", unit="bar"), Signal(np.arange(n) * 0.005, t, name="x", unit="mm")]


def test_round_trip_values_units_and_header_metadata(tmp_path):
    t, sigs = _run()
    comment = ('<HDcomment><TX>kind=timeseries; rig=plpa-2</TX><common_properties>'
               '<e name="operator">ana</e></common_properties></HDcomment>')
    exp = read_mdf(_write(tmp_path / "r.mf4", [("fast", sigs)], comment))
    assert exp.format == "mdf"
    assert [(c.name, c.unit) for c in exp.columns] == [("t", "s"), ("p_a", "bar"), ("x", "mm")]
    assert exp.metadata["kind"] == "timeseries" and exp.metadata["rig"] == "plpa-2"
    assert exp.metadata["operator"] == "ana" and "started_at" in exp.metadata
    v = _values(exp)
    np.testing.assert_array_equal(v["t"], t)
    np.testing.assert_array_equal(v["x"], np.arange(1000) * 0.005)


def test_batches_stream_in_slices(tmp_path, monkeypatch):
    import pipeline.readers.mdf as mdf_mod

    monkeypatch.setattr(mdf_mod, "BATCH_ROWS", 300)
    _, sigs = _run(1000)
    batches = list(read_mdf(_write(tmp_path / "r.mf4", [("g", sigs)])).batches())
    assert [b.num_rows for b in batches] == [300, 300, 300, 100]


def test_linear_conversion_applied(tmp_path):
    t = np.arange(10) / 10.0
    raw = np.arange(10, dtype=np.int16)
    conv = {"a": 0.5, "b": 1.0}  # phys = 0.5 * raw + 1
    sig = Signal(raw, t, name="p_a", unit="bar", conversion=conv)
    v = _values(read_mdf(_write(tmp_path / "c.mf4", [("g", [sig])])))
    np.testing.assert_allclose(v["p_a"], 0.5 * raw + 1.0)


def test_several_groups_need_the_group_key(tmp_path):
    _, fast = _run(1000, 100.0)
    t2 = np.arange(20) / 2.0
    slow = [Signal(20 + t2, t2, name="temp", unit="degC")]
    p = _write(tmp_path / "g.mf4", [("fast", fast), ("slow", slow)])
    with pytest.raises(ReaderError, match="2 channel groups with data .*'fast'.*'slow'"):
        read_mdf(p)
    assert [c.name for c in read_mdf(p, hints={"group": "slow"}).columns] == ["t", "temp"]
    assert [c.name for c in read_mdf(p, {"group": 0}).columns] == ["t", "p_a", "x"]
    with pytest.raises(ReaderError, match="no channel group 'nope'"):
        read_mdf(p, hints={"group": "nope"})


def test_mdf3_file(tmp_path):
    _, sigs = _run(50)
    p = _write(tmp_path / "old.mdf", [("", sigs)], version="3.30")
    upper = p.rename(p.with_name("OLD.MDF"))
    exp = read_export(upper)
    assert exp.format == "mdf" and [c.name for c in exp.columns] == ["t", "p_a", "x"]


def test_refused_can_bus_log_without_dbc(tmp_path):
    t = np.arange(5) / 10.0
    frames = [Signal(np.arange(5, dtype=np.uint32), t, name="CAN_DataFrame.ID"),
              Signal(np.arange(5, dtype=np.uint8), t, name="CAN_DataFrame.DLC")]
    with pytest.raises(ReaderError, match="bus log .*DBC"):
        read_mdf(_write(tmp_path / "can.mf4", [("CAN1", frames)]))


def test_can_logger_bus_log_is_refused_as_a_bus_log_not_as_damaged(tmp_path):
    # A CAN logger's MF4 (issue 25 item 7): CAN_DataFrame records, left unfinalised as loggers
    # leave them; it was refused as "not a readable MDF file ...: UnsupportedOperation: write".
    p = mf4_can_bus_log(tmp_path / "can.mf4")
    before = p.read_bytes()
    with pytest.raises(ReaderError) as err:
        read_mdf(p)
    msg = str(err.value)
    assert "an MDF bus log (CAN frames)" in msg and "DBC database" in msg and "export the decoded signals" in msg
    assert "UnsupportedOperation" not in msg and "\n" not in msg
    assert p.read_bytes() == before            # the logger's file is never finalised in place


def test_finalised_can_bus_log_is_refused_the_same_way(tmp_path):
    with pytest.raises(ReaderError, match=r"an MDF bus log \(CAN frames\)"):
        read_mdf(mf4_can_bus_log(tmp_path / "can.mf4", unfinalised=False))


def test_can_log_of_data_and_error_frames_is_a_bus_log_not_a_choice_of_groups(tmp_path):
    p = mf4_can_bus_log(tmp_path / "can.mf4", error_frames=3)
    with pytest.raises(ReaderError, match=r"an MDF bus log \(CAN frames\)"):
        read_mdf(p)
    with pytest.raises(ReaderError, match=r"channel group 1 is an MDF bus log \(CAN frames\)"):
        read_mdf(p, {"group": 1})


def test_unfinalised_mf4_of_signals_reads_like_the_finalised_one(tmp_path):
    t, sigs = _run(500)
    m = MDF(version="4.11")
    m.append(sigs, acq_name="fast")
    p = Path(m.save(tmp_path / "r.mf4", overwrite=True, compression=0))
    m.close()
    finalised = _values(read_mdf(p))
    before = mdf_unfinalised(p).read_bytes()
    assert before[:8] == b"UnFinMF "
    v = _values(read_mdf(p))
    np.testing.assert_array_equal(v["t"], t)
    np.testing.assert_array_equal(v["x"], finalised["x"])
    np.testing.assert_array_equal(v["p_a"], finalised["p_a"])
    assert p.read_bytes() == before


def test_refused_truncated_file(tmp_path):
    _, sigs = _run(5000)
    p = _write(tmp_path / "cut.mf4", [("g", sigs)])
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 3])
    with pytest.raises(ReaderError, match="MDF"):
        exp = read_mdf(p)
        list(exp.batches())


def test_refused_group_without_master_channel(tmp_path):
    _, sigs = _run(20)
    p = _write(tmp_path / "nomaster.mf4", [("g", sigs)])
    data = bytearray(p.read_bytes())
    # the master's CN block: cn_type 2 (master) -> 0 (a plain fixed-length channel)
    m = MDF(str(p))
    addr = m.groups[0].channels[m.masters_db[0]].address
    m.close()
    links = int.from_bytes(data[addr + 16:addr + 24], "little")
    type_at = addr + 24 + 8 * links
    assert data[type_at] == 2
    data[type_at] = 0
    p.write_bytes(bytes(data))
    with pytest.raises(ReaderError, match="no master"):
        read_mdf(p)


def test_refused_not_mdf(tmp_path):
    p = tmp_path / "junk.mf4"
    p.write_bytes(b"hello, this is not MDF" * 10)
    with pytest.raises(ReaderError, match="not a readable MDF file"):
        read_mdf(p)


def test_header_comment_plain_text():
    assert parse_header_comment("kind=step\nrig = r1") == {"kind": "step", "rig": "r1"}
    assert parse_header_comment("<HDcomment><TX>no pairs</TX></HDcomment>") == {}


def test_list_parts_names_groups_by_unique_acquisition_name_else_index(tmp_path):
    _, fast = _run(100, 100.0)
    t2 = np.arange(20) / 2.0
    slow = [Signal(20 + t2, t2, name="temp", unit="degC")]
    p = _write(tmp_path / "g.mf4", [("fast", fast), ("slow", slow)])
    assert list_parts(p) == ["fast", "slow"]
    # each name selects its own group (its own rate)
    assert [c.name for c in read_mdf(p, hints={"group": "slow"}).columns] == ["t", "temp"]
    # shared, numeric or missing acquisition names would be ambiguous: the 0-based index is used
    q = _write(tmp_path / "d.mf4", [("daq", fast), ("daq", slow), ("7", slow), ("", slow)])
    assert list_parts(q) == ["0", "1", "2", "3"]
    assert [c.name for c in read_mdf(q, hints={"group": "1"}).columns] == ["t", "temp"]


def test_list_parts_of_a_damaged_file_is_one_reader_error(tmp_path):
    p = tmp_path / "cut.mf4"
    p.write_bytes(b"MDF     4.10    " + bytes(100))
    with pytest.raises(ReaderError, match="MDF"):
        list_parts(p)


def test_header_run_id_is_the_prefix_of_each_group_in_groups_all_mode(tmp_path):
    _, fast = _run(10, 100.0)
    t2 = np.arange(4) / 2.0
    p = _write(tmp_path / "g.mf4", [("fast", fast), ("slow", [Signal(t2, t2, name="temp", unit="degC")])],
               comment="run_id=bench7/day3;kind=step")
    assert read_mdf(p, {"group": "slow"}).metadata["run_id"] == "bench7/day3"          # one group: as written
    assert read_mdf(p, {"groups": "all"}, {"group": "slow"}).metadata["run_id"] == "bench7/day3/slow"


def test_a_file_written_in_several_blocks_streams_in_order(tmp_path):
    """A logger appends blocks as it records (asammdf extend): every record comes back once, in order."""
    n = 400_000
    m = MDF(version="4.10")
    for k in range(3):
        t = (np.arange(n) + k * n) / 1000.0
        if k == 0:
            m.append([Signal(t * 2, t, name="x", unit="mm")], acq_name="daq")
        else:
            m.extend(0, [(t, None), (t * 2, None)])
    p = m.save(tmp_path / "blocks.mf4", overwrite=True)
    m.close()
    v = _values(read_mdf(p))
    t = np.arange(3 * n) / 1000.0
    np.testing.assert_array_equal(v["t"], t)
    np.testing.assert_array_equal(v["x"], t * 2)


def _first_channel(data: bytes) -> tuple[int, int]:
    """(address of the first data group's first channel group's first channel, its link count)
    in an MDF 4 file: HD links the first DG at 88, a DG its first CG at +32, a CG its first CN
    at +32; a block's link count is at +16."""
    import struct

    link = lambda at: struct.unpack_from("<Q", data, at)[0]  # noqa: E731
    cn = link(link(link(88) + 32) + 32)
    return cn, link(cn + 16)


def test_refused_channel_list_that_loops_back_on_itself(tmp_path):
    """A damaged link made asammdf walk a channel list forever (tests/fuzz): refused at once."""
    import struct

    t, sigs = _run(50)
    path = _write(tmp_path / "r.mf4", [("fast", sigs)])
    data = bytearray(path.read_bytes())
    cn, _ = _first_channel(bytes(data))
    struct.pack_into("<Q", data, cn + 24, cn)  # the channel's "next" is itself
    path.write_bytes(bytes(data))
    import threading

    got: list = []

    def read():
        try:
            read_mdf(path)
            got.append(None)
        except Exception as exc:  # noqa: BLE001 - checked below
            got.append(exc)

    reader = threading.Thread(target=read, daemon=True)  # a regression would spin forever: fail instead
    reader.start()
    reader.join(60)
    assert not reader.is_alive(), "the reader is still walking the looping list after 60 s"
    assert isinstance(got[0], ReaderError)
    assert "damaged MDF file: its channel block links loop back (block at 0x" in str(got[0])


def test_refused_channel_past_the_end_of_its_records(tmp_path):
    """A damaged byte offset made asammdf's C code read past the record and segfault (tests/fuzz)."""
    import struct

    t, sigs = _run(50)
    path = _write(tmp_path / "r.mf4", [("fast", sigs)])
    data = bytearray(path.read_bytes())
    cn, links = _first_channel(bytes(data))
    while cn:  # the last channel of the group: the one asammdf reads after the master
        nxt = struct.unpack_from("<Q", data, cn + 24)[0]
        if not nxt:
            break
        cn = nxt
        links = struct.unpack_from("<Q", data, cn + 16)[0]
    # CN data after the header (24 B) and the links: type, sync type, data type, bit offset (1 B
    # each), then the byte offset (4 B)
    struct.pack_into("<I", data, cn + 24 + 8 * links + 4, 4_194_312)
    path.write_bytes(bytes(data))
    with pytest.raises(ReaderError, match=r"damaged MDF file: channel `\w+` of channel group 0 lies past the end "
                                          r"of its \d+-byte records"):
        read_mdf(path)


def test_refused_list_longer_than_the_limit_and_read_within_it(tmp_path, monkeypatch):
    import pipeline.readers.mdf as mdf_reader

    t, sigs = _run(50)
    path = _write(tmp_path / "r.mf4", [("fast", sigs)])  # time + 2 channels in one group
    monkeypatch.setattr(mdf_reader, "MAX_CHAINED_BLOCKS", 3)
    assert {c.name for c in read_mdf(path).columns} >= {"p_a", "x"}
    monkeypatch.setattr(mdf_reader, "MAX_CHAINED_BLOCKS", 2)
    with pytest.raises(ReaderError, match="damaged MDF file: more than 2 channel blocks in one list"):
        read_mdf(path)


def test_can_logger_bus_log_is_one_quarantine_line_and_a_signal_log_beside_it_ingests(raw, warehouse):
    from pipeline.ingest.file import ingest_file
    from pipeline.raw.tree import RawTree

    raw.write("c/rig.toml", '[metadata]\nkind = "timeseries"\nrig = "can-1"\n')
    can = mf4_can_bus_log(raw.root / "c" / "can.mf4")
    t, sigs = _run(200)
    m = MDF(version="4.11")
    m.append(sigs, acq_name="fast")
    sig = mdf_unfinalised(Path(m.save(raw.root / "c" / "sig.mf4", overwrite=True, compression=0)))
    m.close()
    bad = ingest_file(RawTree(raw.root), can, warehouse)
    assert bad.run is None and bad.error.startswith("channel group 0 is an MDF bus log (CAN frames)")
    good = ingest_file(RawTree(raw.root), sig, warehouse)
    assert good.error is None and good.run["n_samples"] == 200
