"""Progress: a bar on a terminal (messages above it, nested tasks), log lines off a terminal."""
import io

from pipeline.progress import BarProgress, LogProgress, Progress, for_stream


class Terminal(io.StringIO):
    def isatty(self):
        return True


def screen(text: str) -> list[str]:
    """What a terminal shows: ``\\r`` returns to column 0, ``ESC[K`` clears to the line's end."""
    lines, cur, col = [], [], 0
    i = 0
    while i < len(text):
        if text.startswith("\x1b[K", i):
            del cur[col:]
            i += 3
            continue
        ch = text[i]
        if ch == "\r":
            col = 0
        elif ch == "\n":
            lines.append("".join(cur))
            cur, col = [], 0
        else:
            if col < len(cur):
                cur[col] = ch
            else:
                cur.append(ch)
            col += 1
        i += 1
    if cur:
        lines.append("".join(cur))
    return lines


def test_for_stream_picks_bar_on_a_terminal_log_lines_otherwise_and_silence():
    assert type(for_stream(Terminal())) is BarProgress
    assert type(for_stream(io.StringIO())) is LogProgress
    assert type(for_stream(Terminal(), quiet=True)) is Progress


def test_bar_messages_print_above_the_bar_never_into_it():
    out = Terminal()
    p = BarProgress(out)
    with p.task("stages", 2) as outer:
        outer.advance()
        with p.task("fits", 4) as inner:
            inner.advance()
            inner.advance()
            p.message("stage models ran: 3 rows")
            inner.advance(2)
        p.message("stage durability ran")
        outer.advance()
    lines = screen(out.getvalue())
    assert "stage models ran: 3 rows" in lines
    assert "stage durability ran" in lines
    fits = [ln for ln in lines if ln.startswith("fits")]
    assert len(fits) == 1 and "[" + "#" * 30 + "] 4/4" in fits[0]  # a finished task leaves one line
    assert lines[-1].startswith("stages") and "2/2" in lines[-1]
    assert not any("ran" in ln and "[" in ln for ln in lines)  # no message glued to a bar


def test_bar_of_a_nested_task_names_the_outer_task():
    out = Terminal()
    p = BarProgress(out)
    with p.task("stages", 4) as outer:
        outer.advance()
        with p.task("fits", 10) as inner:
            inner.advance(5)
            assert screen(out.getvalue())[-1].startswith("stages 1/4 > fits")


def test_log_lines_one_per_outer_task_and_per_stage_message():
    out = io.StringIO()
    p = LogProgress(out)
    with p.task("ingest", 20) as t:
        for _ in range(20):
            t.advance()
    with p.task("stages", 2) as stages:
        for name in ("models", "durability"):
            with p.task(f"{name} runs", 50) as inner:
                for _ in range(50):
                    inner.advance()
            p.message(f"stage {name} ran: 3 rows")
            stages.advance()
    lines = out.getvalue().splitlines()
    assert len(lines) == 4, lines
    assert lines[0].startswith("ingest: 20/20 done in ")
    assert lines[1:3] == ["stage models ran: 3 rows", "stage durability ran: 3 rows"]
    assert lines[3].startswith("stages: 2/2 done in ")


def test_log_heartbeat_on_a_long_task(monkeypatch):
    import pipeline.progress as pg

    clock = [1000.0]
    monkeypatch.setattr(pg.time, "monotonic", lambda: clock[0])
    out = io.StringIO()
    p = LogProgress(out)
    with p.task("stages", 1):
        with p.task("durability runs", 10) as t:
            for _ in range(10):
                clock[0] += 25.0  # 250 s in all: a heartbeat about every minute, none at the end
                t.advance()
    lines = out.getvalue().splitlines()
    assert lines[:-1] == ["durability runs: 3/10 (30 %)", "durability runs: 6/10 (60 %)",
                          "durability runs: 9/10 (90 %)"]
    assert lines[-1] == "stages: 0/1 done in 250.0 s"
