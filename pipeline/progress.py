"""Progress on long work: a bar on a terminal, concise log lines otherwise, nothing when silent.

The library reports through a :class:`Progress`; the CLI picks the flavour
(:func:`for_stream`). Nothing here imports click.
"""
from __future__ import annotations

import logging
import sys
import time
from contextlib import contextmanager

log = logging.getLogger("pneubench")


class Progress:
    """Silent progress (the default for library calls and tests)."""

    def message(self, text: str) -> None:
        log.info(text)

    @contextmanager
    def task(self, name: str, total: int):
        yield _Task(self, name, total)

    def _update(self, task: "_Task") -> None:
        pass


class _Task:
    def __init__(self, owner: Progress, name: str, total: int):
        self.owner, self.name, self.total, self.done = owner, name, max(int(total), 0), 0
        self.started = time.monotonic()

    def advance(self, n: int = 1, note: str = "") -> None:
        self.done += n
        self.note = note
        self.owner._update(self)


class LogProgress(Progress):
    """Concise log lines (cron, systemd): one line per finished outer task, a heartbeat on long ones.

    A task prints nothing when it starts; a task inside another (a stage's per-run work) prints
    nothing when it ends either, since the outer task and the stage's own message say enough:
    a rebuild logs one line per stage. Any task running longer than :attr:`heartbeat_s` prints
    its progress about that often, so a long night is visibly alive.
    """

    heartbeat_s = 60.0

    def __init__(self, stream=None):
        self.stream = stream or sys.stderr
        self._last: dict[int, float] = {}
        self._depth = 0

    def message(self, text: str) -> None:
        print(text, file=self.stream, flush=True)

    @contextmanager
    def task(self, name: str, total: int):
        t = _Task(self, name, total)
        outer = self._depth == 0
        self._depth += 1
        self._last[id(t)] = time.monotonic()
        try:
            yield t
        finally:
            self._depth -= 1
            self._last.pop(id(t), None)
            if total and outer:
                self.message(f"{name}: {t.done}/{t.total} done in {time.monotonic() - t.started:.1f} s")

    def _update(self, t: _Task) -> None:
        now = time.monotonic()
        if t.done < t.total and now - self._last.get(id(t), now) >= self.heartbeat_s:
            self._last[id(t)] = now
            self.message(name_pct(t))


def name_pct(t: _Task) -> str:
    pct = 100.0 * t.done / t.total if t.total else 100.0
    return f"{t.name}: {t.done}/{t.total} ({pct:.0f} %)"


class BarProgress(LogProgress):
    """A one-line bar redrawn in place on a terminal.

    Messages are printed above the bar (the bar line is cleared first and drawn again after);
    a task started inside another shows as ``outer 2/4 > inner [###...]``, and a finished task
    leaves one line behind.
    """

    width = 30
    _CLEAR = "\r\x1b[K"

    def __init__(self, stream=None):
        super().__init__(stream)
        self._active: list[_Task] = []

    def message(self, text: str) -> None:
        self.stream.write(f"{self._CLEAR}{text}\n")
        self._redraw()

    @contextmanager
    def task(self, name: str, total: int):
        t = _Task(self, name, total)
        self._active.append(t)
        try:
            yield t
        finally:
            self._active.remove(t)
            if total:
                self.stream.write(f"{self._CLEAR}{self._line(t, final=True)}\n")
            self._redraw()

    def _update(self, t: _Task) -> None:
        self._redraw()

    def _redraw(self) -> None:
        if self._active:
            self.stream.write(f"{self._CLEAR}{self._line(self._active[-1])}")
        self.stream.flush()

    def _line(self, t: _Task, final: bool = False) -> str:
        frac = t.done / t.total if t.total else 1.0
        filled = int(self.width * frac)
        elapsed = time.monotonic() - t.started
        eta = f" eta {elapsed / frac - elapsed:4.0f} s" if 0 < frac < 1 and not final else f" {elapsed:5.1f} s"
        outer = "".join(f"{o.name} {o.done}/{o.total} > " for o in self._active if o is not t and not final)
        return f"{outer}{t.name:<12} [{'#' * filled}{'.' * (self.width - filled)}] {t.done}/{t.total}{eta}"


def for_stream(stream=None, quiet: bool = False) -> Progress:
    """A bar when ``stream`` is a terminal, log lines when not, nothing when ``quiet``."""
    stream = stream or sys.stderr
    if quiet:
        return Progress()
    return BarProgress(stream) if getattr(stream, "isatty", lambda: False)() else LogProgress(stream)
