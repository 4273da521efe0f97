"""Measure what a user runs: a whole command as a process, its wall time and the peak memory of
its whole process tree (the command and every worker it starts).

``ru_maxrss`` of a child is the largest single process, not the tree: two workers of 400 MB each
use 800 MB of the machine. So the tree is sampled from ``/proc`` every ``interval_s`` (the RSS
of the process and all its descendants, summed) and the peak of those sums is reported, beside
the largest single-process peak from ``os.wait4``.
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


def tree_rss_bytes(pid: int) -> int:
    """Resident memory of ``pid`` and all its descendants, summed. [bytes]"""
    kids = _children()
    total, todo = 0, [pid]
    while todo:
        p = todo.pop()
        try:
            with open(f"/proc/{p}/statm", "rb") as fh:
                total += int(fh.read().split()[1]) * _PAGE
        except OSError:
            pass
        todo.extend(kids.get(p, ()))
    return total


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


def measure(cmd: list[str], cwd: Path | None = None, env: dict | None = None, interval_s: float = 0.02,
            check: bool = True) -> Measured:
    """Run ``cmd`` to completion; wall time, peak tree RSS, CPU of the tree."""
    out_path = f"/tmp/pneubench-bench-{os.getpid()}.out"
    err_path = f"/tmp/pneubench-bench-{os.getpid()}.err"
    peak = [0]
    with open(out_path, "wb") as fo, open(err_path, "wb") as fe:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=fo, stderr=fe, stdin=subprocess.DEVNULL)
        done = threading.Event()

        def sample():
            while not done.is_set():
                peak[0] = max(peak[0], tree_rss_bytes(proc.pid))
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
                    stdout=out, stderr=err)


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
    def cpu_s(self) -> float:
        return statistics.median(r.cpu_s for r in self.runs)


def verdict(ok: bool) -> str:
    return "PASS" if ok else "MISS"
