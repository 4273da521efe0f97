"""Measure what a user runs: a whole command as a process, its wall time and the peak memory of
its whole process tree (the command and every worker it starts).

``ru_maxrss`` of a child is the largest single process, not the tree: two workers of 400 MB each
use 800 MB of the machine. So the tree is sampled from ``/proc`` every ``interval_s`` (the RSS
of the process and all its descendants, summed) and the peak of those sums is reported, beside
the largest single-process peak from ``os.wait4``, and the peak of the tree's summed PSS
(``smaps_rollup``): forked workers share their parent's pages, which the RSS sum counts once per
process and the PSS sum once.
"""
from __future__ import annotations

import os
import statistics
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

_PAGE = os.sysconf("SC_PAGE_SIZE")


def pneubench_cmd() -> list[str]:
    """The console script as a user runs it (this interpreter, the installed entry point)."""
    return [sys.executable, "-c", "from pipeline.cli import main; main()"]


def _children() -> dict[int, list[int]]:
    kids: dict[int, list[int]] = {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat", "rb") as fh:
                stat = fh.read()
        except OSError:
            continue
        # the command name is in parentheses and may hold spaces: parse after the last ')'
        ppid = int(stat[stat.rfind(b")") + 2:].split()[1])
        kids.setdefault(ppid, []).append(int(d))
    return kids


def _tree(pid: int) -> list[int]:
    kids = _children()
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(kids.get(p, ()))
    return out


def _rss(p: int) -> int:
    try:
        with open(f"/proc/{p}/statm", "rb") as fh:
            return int(fh.read().split()[1]) * _PAGE
    except OSError:
        return 0


def _pss(p: int) -> int:
    """Proportional set size of ``p``: its private pages plus its share of the pages it shares
    (a page three forked workers share counts a third to each). [bytes]"""
    try:
        with open(f"/proc/{p}/smaps_rollup", "rb") as fh:
            for line in fh:
                if line.startswith(b"Pss:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return 0


def tree_rss_bytes(pid: int) -> int:
    """Resident memory of ``pid`` and all its descendants, summed. [bytes]"""
    return sum(_rss(p) for p in _tree(pid))


def tree_pss_by_process(pid: int) -> dict[int, int]:
    """PSS of ``pid`` and of each of its descendants, by process id [bytes]."""
    return {p: _pss(p) for p in _tree(pid)}


def tree_memory_bytes(pid: int) -> tuple[int, int]:
    """(RSS, PSS) of ``pid`` and all its descendants, summed [bytes]. The RSS sum counts a page
    that forked workers share once per process (it over-states a forked pool); the PSS sum counts
    every page once: the memory the tree takes from the machine."""
    procs = _tree(pid)
    return sum(_rss(p) for p in procs), sum(_pss(p) for p in procs)


@dataclass
class Measured:
    """One run of a command."""

    cmd: list[str]
    wall_s: float
    exit_code: int
    tree_peak_mb: float
    max_process_mb: float
    cpu_s: float
    stdout: str = ""
    stderr: str = ""
    #: peak of the tree's summed PSS (shared pages counted once) [MB]
    tree_peak_pss_mb: float = 0.0


def measure(cmd: list[str], cwd: Path | None = None, env: dict | None = None, interval_s: float = 0.02,
            check: bool = True) -> Measured:
    """Run ``cmd`` to completion; wall time, peak tree RSS, CPU of the tree.

    Without ``env``, this process's environment less ``PYTHONDONTWRITEBYTECODE``: the command
    runs as an installed one does, its bytecode cached (with it, every ``pneubench`` process
    compiled every project module again, ~0.7 s, while a baseline loaded its libraries' cache)."""
    if env is None:
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    out_path = f"/tmp/pneubench-bench-{os.getpid()}.out"
    err_path = f"/tmp/pneubench-bench-{os.getpid()}.err"
    peak = [0, 0]  # tree RSS, tree PSS
    with open(out_path, "wb") as fo, open(err_path, "wb") as fe:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=fo, stderr=fe, stdin=subprocess.DEVNULL)
        done = threading.Event()

        def sample():
            while not done.is_set():
                rss, pss = tree_memory_bytes(proc.pid)
                peak[0], peak[1] = max(peak[0], rss), max(peak[1], pss)
                done.wait(interval_s)

        th = threading.Thread(target=sample, daemon=True)
        th.start()
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        done.set()
        th.join()
    proc.returncode = code = os.waitstatus_to_exitcode(status)
    out, err = Path(out_path).read_text(errors="replace"), Path(err_path).read_text(errors="replace")
    Path(out_path).unlink(missing_ok=True)
    Path(err_path).unlink(missing_ok=True)
    if check and code not in (0, 1):
        raise SystemExit(f"{' '.join(map(str, cmd))} failed ({code}):\n{err[-2000:]}")
    return Measured(cmd=[str(c) for c in cmd], wall_s=wall, exit_code=code, tree_peak_mb=peak[0] / 1e6,
                    max_process_mb=usage.ru_maxrss * 1024 / 1e6, cpu_s=usage.ru_utime + usage.ru_stime,
                    stdout=out, stderr=err, tree_peak_pss_mb=peak[1] / 1e6)


@dataclass
class Series:
    """Repeated measurements of one command; medians."""

    name: str
    runs: list[Measured] = field(default_factory=list)

    @property
    def wall_s(self) -> float:
        return statistics.median(r.wall_s for r in self.runs)

    @property
    def tree_peak_mb(self) -> float:
        return max(r.tree_peak_mb for r in self.runs)

    @property
    def tree_peak_pss_mb(self) -> float:
        return max(r.tree_peak_pss_mb for r in self.runs)

    @property
    def cpu_s(self) -> float:
        return statistics.median(r.cpu_s for r in self.runs)


def verdict(ok: bool) -> str:
    return "PASS" if ok else "MISS"
