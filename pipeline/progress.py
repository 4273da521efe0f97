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

    def _done(self, task: "_Task") -> None:
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
    """Concise log lines (cron, systemd): start, about every 10 % or 30 s, and the end."""

    def __init__(self, stream=None):
        self.stream = stream or sys.stderr
        self._last: dict[int, tuple[float, int]] = {}

    def message(self, text: str) -> None:
        print(text, file=self.stream, flush=True)

    @contextmanager
    def task(self, name: str, total: int):
        t = _Task(self, name, total)
        if total:
            self.message(f"{name}: {total} to do")
        self._last[id(t)] = (time.monotonic(), 0)
        try:
            yield t
        finally:
            self._last.pop(id(t), None)
            if total:
                self.message(f"{name}: {t.done}/{t.total} done in {time.monotonic() - t.started:.1f} s")

    def _update(self, t: _Task) -> None:
        last_time, last_done = self._last.get(id(t), (0.0, 0))
        now = time.monotonic()
        step = max(t.total // 10, 1)
        if t.done < t.total and (t.done - last_done >= step or now - last_time >= 30):
            self._last[id(t)] = (now, t.done)
            self.message(f"{name_pct(t)}")


def name_pct(t: _Task) -> str:
    pct = 100.0 * t.done / t.total if t.total else 100.0
    return f"{t.name}: {t.done}/{t.total} ({pct:.0f} %)"


class BarProgress(LogProgress):
    """A one-line bar redrawn in place on a terminal."""

    width = 30

    @contextmanager
    def task(self, name: str, total: int):
        t = _Task(self, name, total)
        try:
            yield t
        finally:
            if total:
                self._draw(t, final=True)

    def _update(self, t: _Task) -> None:
        self._draw(t)

    def _draw(self, t: _Task, final: bool = False) -> None:
        frac = t.done / t.total if t.total else 1.0
        filled = int(self.width * frac)
        elapsed = time.monotonic() - t.started
        eta = f" eta {elapsed / frac - elapsed:4.0f} s" if 0 < frac < 1 else f" {elapsed:5.1f} s"
        line = f"\r{t.name:<12} [{'#' * filled}{'.' * (self.width - filled)}] {t.done}/{t.total}{eta}"
        self.stream.write(line + ("\n" if final else ""))
        self.stream.flush()


def for_stream(stream=None, quiet: bool = False) -> Progress:
    """A bar when ``stream`` is a terminal, log lines when not, nothing when ``quiet``."""
    stream = stream or sys.stderr
    if quiet:
        return Progress()
    return BarProgress(stream) if getattr(stream, "isatty", lambda: False)() else LogProgress(stream)
