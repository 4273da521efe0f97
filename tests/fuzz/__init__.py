"""Reader fuzz harness: seeded mutants of small valid exports, ingested in child processes.

Seeds are small valid runs in every format the readers take (CSV, LVM, TDMS, MAT v5
uncompressed and compressed, MAT v7.3, XLSX, MF4), written by the simulator writers
(:mod:`pipeline.simulator.writers`) and the reader-test generators
(:mod:`tests.pipeline.readers.generators`). Mutant ``i`` of a run with seed ``s`` is derived
from ``random.Random(f"{s}:{i}")`` only, so it is the same whatever the batch it runs in:
1 to 3 stacked mutations among bit flips, random bytes, byte insertions and deletions,
truncation, chunk duplication, header-field tweaks, huge numbers written over (size) fields
and long runs of delimiters / line breaks.

Each mutant is ingested as the nightly rebuild does it (:func:`pipeline.ingest.file.ingest_file`
on a raw tree ``raw/fuzz/<name>``) in a child process with an address-space limit
(``RLIMIT_AS``, :data:`MEMORY_LIMIT`) and a per-mutant timeout (:data:`TIMEOUT_S`). Outcomes:

``run``          ingested.
``quarantined``  a one-line reason that says what is wrong.
``unexplained``  the reason is the ingest's fallback ``cannot read file: <Exception>: ...``:
                 a reader let an exception other than ReaderError escape (a finding).
``bad-reason``   empty or multi-line reason (a finding).
``memory``       MemoryError (the limit was hit: an unbounded allocation; a finding).
``crash``        the child died (a signal, a non-zero exit): a finding.
``hang``         no answer within the timeout: a finding.

Failing mutants are saved under ``/tmp/pneubench-fuzz/`` with a ``.txt`` saying how they were
made, for reproduction (``python -m tests.fuzz --replay FILE``).
"""
from __future__ import annotations

import json
import os
import random
import re
import resource
import select
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

#: Address-space limit of a child process [B]. About 0.65 GiB of it is the interpreter with
#: numpy, pyarrow, pandas, scipy, h5py and npTDMS mapped (with ``MALLOC_ARENA_MAX=2`` and
#: pyarrow's system allocator, set for the child; glibc's default arenas alone reserve 64 MiB
#: per thread), so one mutant may allocate about 0.85 GiB.
MEMORY_LIMIT = 3 << 29
#: Seconds one mutant may take before it counts as a hang [s].
TIMEOUT_S = 20.0
#: Where failing mutants are saved.
SAVE_DIR = Path("/tmp/pneubench-fuzz")
#: Outcomes that are findings.
FINDINGS = ("unexplained", "bad-reason", "memory", "crash", "hang")

_ROOT = Path(__file__).resolve().parents[2]


# -- seeds ---------------------------------------------------------------------------------
# The seeds' writers (numpy, pandas, scipy, the simulator) are imported by the functions that
# write seeds, not at the top: the fuzz child imports this package too, and everything it maps
# counts against its address-space limit (MEMORY_LIMIT).
def _frame(n: int = 24):
    import numpy as np
    import pandas as pd

    t = np.arange(n) * 1e-3
    return pd.DataFrame({"t_s": t, "x_m": np.linspace(0.0, 0.02, n), "x_ref_m": np.where(t > 0.01, 0.02, 0.0),
                         "p_a_pa": np.linspace(1e5, 3e5, n)})


def make_seeds(folder: Path) -> dict[str, bytes]:
    """Small valid exports: name (with its extension) -> bytes. Deterministic."""
    import numpy as np

    from pipeline.simulator.writers import (default_columns, write_csv, write_lvm, write_mat, write_mf4, write_tdms,
                                            write_xlsx)
    from tests.pipeline.readers.generators import LvmSegment, lvm_bytes, mat_v5, mat_v73

    folder.mkdir(parents=True, exist_ok=True)
    meta = {"kind": "step", "started_at": "2026-01-02T03:04:05", "rig": "plpa-1"}
    frame = _frame()
    cols = default_columns(["x_m", "x_ref_m", "p_a_pa"], units={"x": "mm", "x_ref": "mm", "p_a": "bar(a)"})
    with_t = default_columns(["t_s"], units={"t": "ms"}) + cols
    write_csv(folder / "seed.csv", frame, with_t, meta)
    write_csv(folder / "seed_semicolon.txt", frame, with_t, meta, delimiter=";", decimal=",")
    write_lvm(folder / "seed.lvm", frame, cols, meta, segments=2)
    (folder / "seed_no_x.lvm").write_bytes(lvm_bytes(
        [LvmSegment({"x": [0.0, 1.0, 2.0, 3.0], "x_ref": [0.0, 0.0, 1.0, 1.0]}, units={"x": "mm", "x_ref": "mm"})],
        x_columns="No", description="kind=step; rig=plpa-1; started_at=2026-01-02T03:04:05"))
    write_tdms(folder / "seed.tdms", [frame.iloc[:12], frame.iloc[12:]], cols, meta)
    write_tdms(folder / "seed_waveform.tdms", frame, cols, meta, waveform=True, fs_hz=1000.0)
    write_mat(folder / "seed_v7.mat", frame, cols, meta)
    variables = {"t": frame["t_s"].to_numpy(), "x": frame["x_m"].to_numpy() * 1e3,
                 "x_ref": frame["x_ref_m"].to_numpy() * 1e3, "meta": meta,
                 "units": {"t": "s", "x": "mm", "x_ref": "mm"}}
    mat_v5(folder / "seed_v5.mat", variables)
    data = bytearray((folder / "seed_v5.mat").read_bytes())
    data[:116] = b"MATLAB 5.0 MAT-file, fuzz seed".ljust(116, b" ")     # no creation time
    (folder / "seed_v5.mat").write_bytes(bytes(data))
    mat_v73(folder / "seed_v73.mat", {**variables, "t": np.asarray(variables["t"])})
    write_xlsx(folder / "seed.xlsx", frame, with_t, meta)        # a zip of XML parts: calamine reads it
    write_mf4(folder / "seed.mf4", frame, cols, meta)            # ASAM MDF 4.10: asammdf reads it
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


# -- mutations -----------------------------------------------------------------------------
_HUGE = [0xFFFFFFFF, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFE, 1 << 30, 1 << 24, 0xFFFF, 0x7FFF]
_HUGE64 = [(1 << 64) - 1, (1 << 63) - 1, 1 << 62, 1 << 40, 1 << 33]


def _bitflip(d: bytearray, r: random.Random) -> str:
    k = r.randint(1, 8)
    for _ in range(k):
        i = r.randrange(len(d))
        d[i] ^= 1 << r.randrange(8)
    return f"bitflip x{k}"


def _bytes(d: bytearray, r: random.Random) -> str:
    i = r.randrange(len(d))
    n = r.randint(1, 8)
    d[i:i + n] = bytes(r.randrange(256) for _ in range(min(n, len(d) - i)))
    return f"random bytes at {i}"


def _insert(d: bytearray, r: random.Random) -> str:
    i = r.randrange(len(d) + 1)
    n = r.randint(1, 64)
    d[i:i] = bytes(r.randrange(256) for _ in range(n))
    return f"insert {n} at {i}"


def _delete(d: bytearray, r: random.Random) -> str:
    i = r.randrange(len(d))
    n = r.randint(1, min(256, len(d) - i))
    del d[i:i + n]
    return f"delete {n} at {i}"


def _truncate(d: bytearray, r: random.Random) -> str:
    i = r.randrange(len(d))
    del d[i:]
    return f"truncate at {i}"


def _duplicate(d: bytearray, r: random.Random) -> str:
    i = r.randrange(len(d))
    n = r.randint(1, min(4096, len(d) - i))
    j = r.randrange(len(d) + 1)
    times = r.choice([1, 1, 2, 16])
    d[j:j] = d[i:i + n] * times
    return f"duplicate {n}x{times} from {i} to {j}"


def _header(d: bytearray, r: random.Random) -> str:
    i = r.randrange(min(len(d), 256))
    d[i] = r.choice([0, 0xFF, 0x7F, 0x80, 0x01, 0x20, 0x0A, 0x2C, 0x09])
    return f"header byte {i}"


def _huge(d: bytearray, r: random.Random) -> str:
    wide = r.random() < 0.3
    v = r.choice(_HUGE64 if wide else _HUGE)
    n = 8 if wide else 4
    i = r.randrange(max(1, len(d) - n + 1)) & ~3
    d[i:i + n] = v.to_bytes(n, r.choice(["little", "big"]))
    return f"huge {v:#x} at {i}"


def _text(d: bytearray, r: random.Random) -> str:
    i = r.randrange(len(d) + 1)
    piece = r.choice([b",", b"\t", b";", b"\n", b"\r", b"9", b'"', b"[", b"#", b"\x00", b"nan\t"])
    n = r.choice([1, 10, 1000, 20000])
    d[i:i] = piece * n
    return f"insert {piece!r}x{n} at {i}"


MUTATIONS = [_bitflip, _bytes, _insert, _delete, _truncate, _duplicate, _header, _huge, _text]


@dataclass
class Mutant:
    index: int
    seed_name: str
    how: list[str] = field(default_factory=list)
    data: bytes = b""

    @property
    def name(self) -> str:
        stem, ext = self.seed_name.rsplit(".", 1)
        return f"m{self.index:06d}_{stem}.{ext}"


def mutant(seeds: dict[str, bytes], seed: int, index: int) -> Mutant:
    """Mutant ``index`` of run ``seed``: depends on these two numbers (and the seeds) only."""
    r = random.Random(f"{seed}:{index}:{','.join(sorted(seeds))}")
    names = sorted(seeds)
    name = names[r.randrange(len(names))]
    d = bytearray(seeds[name])
    how = []
    for _ in range(r.choice([1, 1, 2, 3])):
        if not d:
            break
        how.append(r.choice(MUTATIONS)(d, r))
    return Mutant(index, name, how, bytes(d))


# -- outcomes ------------------------------------------------------------------------------
def classify(run: bool, error: str | None) -> str:
    """Outcome of one ingest result (see the module docstring)."""
    if run:
        return "run"
    if not error or "\n" in error or not error.strip():
        return "bad-reason"
    if "MemoryError" in error:
        return "memory"
    if error.startswith("cannot read file:"):
        return "unexplained"
    return "quarantined"


# -- child ---------------------------------------------------------------------------------
def child_main() -> None:
    """Read mutant paths (one per stdin line), ingest each, answer one JSON line per mutant."""
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
    # imported after the limit is set: what the ingest maps counts against it
    from pipeline.ingest.file import ingest_file
    from pipeline.raw.tree import RawTree

    raw, warehouse = Path(sys.argv[-2]), Path(sys.argv[-1])
    tree = RawTree(raw)
    # the answers go through a descriptor of their own: a library that prints while reading a
    # mutant (Python or C code writing to fd 1) writes to stderr, never into the answers
    answers = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)
    print(json.dumps({"ready": True}), file=answers, flush=True)
    for line in sys.stdin:
        path = Path(line.strip())
        try:
            res = ingest_file(tree, path, warehouse, reuse=False)
            out = {"run": res.run is not None, "error": res.error}
        except MemoryError:
            out = {"run": False, "error": "MemoryError escaped ingest_file"}
        except BaseException as exc:  # noqa: BLE001 - reported as a finding
            out = {"run": False, "error": f"cannot read file: {type(exc).__name__} escaped ingest_file: {exc}"}
        shutil.rmtree(warehouse, ignore_errors=True)
        print(json.dumps(out), file=answers, flush=True)


class _Child:
    def __init__(self, raw: Path, warehouse: Path, argv: list[str] | None = None):
        env = {**os.environ, "PYTHONPATH": str(_ROOT), "MALLOC_ARENA_MAX": "2", "ARROW_DEFAULT_MEMORY_POOL": "system"}
        argv = argv or [sys.executable, "-m", "tests.fuzz", "--child", str(raw), str(warehouse)]
        self.proc = subprocess.Popen(argv,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                     cwd=_ROOT, env=env, text=True, bufsize=1)
        if not self._line(60.0):
            raise RuntimeError("fuzz child did not start")

    def _line(self, timeout: float) -> str | None:
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        if not ready:
            return None                          # timeout
        return self.proc.stdout.readline()       # "" at EOF: the child is gone

    def ask(self, path: Path, timeout: float) -> tuple[str, str | None]:
        """(outcome, reason) of one mutant."""
        try:
            self.proc.stdin.write(f"{path}\n")
            self.proc.stdin.flush()
        except BrokenPipeError:
            return self.died()
        line = self._line(timeout)
        if line == "" or (line is None and self.proc.poll() is not None):
            return self.died()
        if line is None:
            self.kill()
            return "hang", f"no answer within {timeout:g} s"
        out = json.loads(line)
        return classify(out["run"], out["error"]), out["error"]

    def died(self) -> tuple[str, str]:
        code = self.proc.wait()
        if code < 0:
            return "crash", f"child killed by signal {-code}"
        return "crash", f"child exited with code {code}"

    def alive(self) -> bool:
        return self.proc.poll() is None

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.stdin.close()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.kill()


@dataclass
class Report:
    counts: Counter = field(default_factory=Counter)
    findings: list[tuple[Mutant, str, str | None, Path | None]] = field(default_factory=list)
    reasons: Counter = field(default_factory=Counter)
    seconds: float = 0.0

    def summary(self) -> str:
        total = sum(self.counts.values())
        lines = [f"{total} mutants in {self.seconds:.1f} s: "
                 + ", ".join(f"{k} {v}" for k, v in sorted(self.counts.items()))]
        for m, outcome, reason, saved in self.findings[:50]:
            lines.append(f"  {outcome}: {m.name} ({'; '.join(m.how)}): {reason} -> {saved}")
        return "\n".join(lines)


def run(n: int, seed: int, save: bool = True, timeout: float = TIMEOUT_S, log=None, only: str | None = None) -> Report:
    """Run ``n`` mutants of run ``seed`` (one child process, restarted after a crash or hang);
    ``only``: mutate only the seeds whose file name contains this text (e.g. ``"v5"``)."""
    start = time.monotonic()
    report = Report()
    with tempfile.TemporaryDirectory(prefix="pneubench-fuzz-") as tmp:
        tmp = Path(tmp)
        seeds = make_seeds(tmp / "seeds")
        if only:
            seeds = {k: v for k, v in seeds.items() if only in k}
            if not seeds:
                raise ValueError(f"no seed file name contains {only!r}")
        raw, warehouse = tmp / "raw", tmp / "warehouse"
        (raw / "fuzz").mkdir(parents=True)
        child = None
        try:
            for i in range(n):
                m = mutant(seeds, seed, i)
                path = raw / "fuzz" / m.name
                path.write_bytes(m.data)
                if child is None or not child.alive():
                    child = _Child(raw, warehouse)
                outcome, reason = child.ask(path, timeout)
                path.unlink()
                report.counts[outcome] += 1
                if outcome == "quarantined":
                    report.reasons[_shape(reason)] += 1
                if outcome in FINDINGS:
                    saved = _save(m, outcome, reason, seed) if save else None
                    report.findings.append((m, outcome, reason, saved))
                if log is not None and (i + 1) % 500 == 0:
                    log(f"{i + 1}/{n}: " + ", ".join(f"{k} {v}" for k, v in sorted(report.counts.items())))
        finally:
            if child is not None:
                child.close()
    report.seconds = time.monotonic() - start
    return report


def _shape(reason: str | None) -> str:
    """A reason with its numbers and quoted values blanked, to count kinds of reasons."""
    text = re.sub(r"`[^`]*`|'[^']*'|\"[^\"]*\"", "_", reason or "")
    return re.sub(r"\d+(\.\d+)?", "N", text)[:90]


def _save(m: Mutant, outcome: str, reason: str | None, seed: int) -> Path:
    SAVE_DIR.mkdir(parents=True, exist_ok=True)
    path = SAVE_DIR / f"{outcome}-seed{seed}-{m.name}"
    path.write_bytes(m.data)
    path.with_name(path.name + ".txt").write_text(
        f"seed {seed} mutant {m.index} of {m.seed_name}: {'; '.join(m.how)}\noutcome {outcome}: {reason}\n"
        f"reproduce: python -m tests.fuzz --replay {path}\n")
    return path


def replay(path: Path, timeout: float = TIMEOUT_S) -> tuple[str, str | None]:
    """Ingest one saved mutant in a child (as the run did): (outcome, reason)."""
    with tempfile.TemporaryDirectory(prefix="pneubench-fuzz-") as tmp:
        raw = Path(tmp) / "raw"
        (raw / "fuzz").mkdir(parents=True)
        target = raw / "fuzz" / Path(path).name.split("-", 2)[-1]
        shutil.copyfile(path, target)
        child = _Child(raw, Path(tmp) / "warehouse")
        try:
            return child.ask(target, timeout)
        finally:
            child.close()
