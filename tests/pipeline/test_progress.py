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


def test_log_lines_every_tenth_and_at_the_end():
    out = io.StringIO()
    p = LogProgress(out)
    with p.task("ingest", 20) as t:
        for _ in range(20):
            t.advance()
    lines = out.getvalue().splitlines()
    assert lines[0] == "ingest: 20 to do"
    assert lines[1:-1] == [f"ingest: {k}/20 ({5 * k} %)" for k in range(2, 20, 2)]
    assert lines[-1].startswith("ingest: 20/20 done in ")
