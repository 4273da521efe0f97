"""The nightly job as a crontab line or a systemd service + timer (``pneubench schedule``).

Everything is rendered with absolute paths: the working directory, the raw tree, the warehouse,
the log file and the ``pneubench`` executable, so the text can be pasted as it is. Overlapping
runs are handled by the rebuild's own lock (``warehouse/.rebuild.lock``): a run that finds the
previous one still going waits ``--wait`` seconds, then exits with code 4 and a clear message.

Everything given to it is untrusted text pasted into a shell (cron) and a unit file (systemd):

* every path must be absolute after resolving, valid UTF-8, and free of control characters
  (a newline would add a crontab entry or a unit directive); anything else is a ``ValueError``
  (the CLI's usage error, exit 2);
* the user name must be a conservative POSIX name (``[A-Za-z_][A-Za-z0-9_.-]{0,31}``), the unit
  name ``[A-Za-z0-9_.-]+`` (``@``-free: no template instances);
* cron: every word is ``shlex.quote``-d (single quotes: no ``$(...)``, backtick or variable is
  expanded), the failure message too, and every ``%`` becomes ``\\%`` (cron turns a bare ``%``
  into a newline and removes the backslash before a ``%``);
* systemd: words of ``Exec*=`` and ``Environment=`` lines are double-quoted with C escapes
  (``\\``, ``\"``), ``%`` is doubled everywhere a specifier is expanded (also ``Description=``,
  ``WorkingDirectory=``, ``StandardOutput=``), and ``$`` is doubled in ``Exec*=`` lines.
"""
from __future__ import annotations

import re
import shlex
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path

FORMATS = ("all", "cron", "service", "timer")

#: A user name we paste into ``User=`` and the crontab comment: conservative POSIX.
USER_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_.-]{0,31}")
#: The unit's name (file name of the service and timer, and the cron comment).
UNIT_NAME = re.compile(r"[A-Za-z0-9_.-]{1,200}")
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def check_text(what: str, text: str) -> str:
    """``text`` if it can be pasted into a crontab or unit file: valid UTF-8 and no control
    character (newline, tab, NUL, ESC...); else ``ValueError`` naming ``what``."""
    text = str(text)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise ValueError(f"{what} is not valid UTF-8: {text.encode('utf-8', 'surrogateescape')!r}") from None
    m = _CONTROL.search(text)
    if m:
        raise ValueError(f"{what} contains a control character {m.group()!r} (newline, tab, ...): {text!r}")
    return text


@dataclass
class Schedule:
    """What the nightly job runs and when."""

    raw: Path
    warehouse: Path
    workdir: Path
    at: str = "02:30"                      # HH:MM, local time of the machine
    log: Path | None = None                # default: <warehouse>/logs/rebuild.log
    user: str | None = None                # systemd User= (cron: install in that user's crontab)
    name: str = "pneubench-rebuild"
    wait_s: int = 900                      # how long to wait for a rebuild still running
    extra_args: list[str] = field(default_factory=list)
    executable: str | None = None

    def __post_init__(self):
        for what, value in (("--raw", self.raw), ("--warehouse", self.warehouse), ("--workdir", self.workdir),
                            ("--log", self.log or ""), ("the executable", self.executable or "")):
            check_text(f"{what} path", value)
        for arg in self.extra_args:
            check_text("an extra argument", arg)
        if self.user is not None and not USER_NAME.fullmatch(str(self.user)):
            raise ValueError(f"--user {str(self.user)!r} is not a plain user name "
                             "(letters, digits, _ . -, starting with a letter or _, at most 32)")
        if not UNIT_NAME.fullmatch(str(self.name)):
            raise ValueError(f"unit name {self.name!r} is not a plain name (letters, digits, _ . -)")
        self.raw, self.warehouse, self.workdir = (Path(p).expanduser().resolve() for p in
                                                  (self.raw, self.warehouse, self.workdir))
        self.log = Path(self.log).expanduser().resolve() if self.log else self.warehouse / "logs" / "rebuild.log"
        hh, mm = parse_time(self.at)
        self.hour, self.minute = hh, mm
        self.executable = check_text("the executable path", self.executable or find_executable())
        for what, value in (("--raw", self.raw), ("--warehouse", self.warehouse), ("--workdir", self.workdir),
                            ("--log", self.log)):  # resolving may have followed a symlink to a worse name
            check_text(f"{what} path", value)

    def command(self) -> list[str]:
        return [self.executable, "rebuild", "--raw", str(self.raw), "--warehouse", str(self.warehouse),
                "--wait", str(self.wait_s), *self.extra_args]


def parse_time(text: str) -> tuple[int, int]:
    """``"HH:MM"`` -> (hour, minute); ValueError when it is not a time of day."""
    try:
        hh, mm = (int(x) for x in str(text).split(":"))
    except ValueError:
        raise ValueError(f"--at wants HH:MM, got {text!r}") from None
    if not (0 <= hh < 24 and 0 <= mm < 60):
        raise ValueError(f"--at wants HH:MM, got {text!r}")
    return hh, mm


def find_executable() -> str:
    """Absolute path of the ``pneubench`` console script (the one running, else on PATH)."""
    here = Path(sys.argv[0]).resolve() if sys.argv and sys.argv[0] else None
    if here is not None and here.name == "pneubench" and here.is_file():
        return str(here)
    found = shutil.which("pneubench")
    if found:
        return str(Path(found).resolve())
    bindir = Path(sys.executable).parent / "pneubench"
    return str(bindir)


def crontab_line(s: Schedule) -> str:
    """A crontab entry: the rebuild at ``s.at`` every night, output appended to the log.

    cron mails whatever the line prints: nothing on success, one line when the rebuild exits
    non-zero (1: inputs quarantined, 2: usage, 3+: failed and the previous warehouse kept).
    """
    cmd = " ".join(shlex.quote(c) for c in s.command())
    log = shlex.quote(str(s.log))
    # The failure message: the exit code is the only expansion ("$?"); the rest is single-quoted.
    fail = f"echo {shlex.quote(s.name + ' failed with exit code')} \"$?\" {shlex.quote(f'(see {s.log})')}"
    line = (f"{s.minute} {s.hour} * * * cd {shlex.quote(str(s.workdir))} && mkdir -p {shlex.quote(str(s.log.parent))}"
            f" && {cmd} >> {log} 2>&1 || {fail}")
    return (f"# {s.name}: nightly pneubench rebuild at {s.hour:02d}:{s.minute:02d} (install: crontab -e"
            f"{' as ' + s.user if s.user else ''})\n"
            "# exit 2: refused, nothing written (raw/ empty or not mounted: every run, or more than half, would be\n"
            "# deleted); to delete them on purpose put PNEUBENCH_ALLOW_MASS_DELETE=1 before pneubench, once\n"
            + line.replace("%", "\\%"))  # cron: bare % = newline


def _sd_quote(value, exec_line: bool = True) -> str:
    """One systemd unit-file word: ``%`` doubled (a specifier otherwise), and ``$`` in ``Exec*=``
    lines (a variable there; ``Environment=`` does not expand it); double-quoted with ``\\`` and
    ``"`` escaped when it has blanks, quotes or ``;``, so a path with spaces stays one argument."""
    text = str(value).replace("%", "%%")
    if exec_line:
        text = text.replace("$", "$$")
    if text and not any(c.isspace() or c in "\"'\\;" for c in text):
        return text
    text = text.replace("\\", "\\\\").replace('"', '\\"')
    return f'"{text}"'


def systemd_service(s: Schedule) -> str:
    cmd = " ".join(_sd_quote(c) for c in s.command())
    user = f"User={s.user}\n" if s.user else ""
    return f"""# /etc/systemd/system/{s.name}.service
[Unit]
Description=pneubench nightly rebuild of {str(s.warehouse).replace("%", "%%")}
After=local-fs.target network-online.target
Wants=network-online.target

[Service]
Type=oneshot
{user}WorkingDirectory={str(s.workdir).replace("%", "%%")}
Environment={_sd_quote(f"PNEUBENCH_RAW={s.raw}", exec_line=False)}
Environment={_sd_quote(f"PNEUBENCH_WAREHOUSE={s.warehouse}", exec_line=False)}
ExecStartPre=/bin/mkdir -p {_sd_quote(s.log.parent)}
ExecStart={cmd}
# exit 1 = warehouse built, some inputs quarantined (see the morning report): not a failure.
# Remove the next line to be alerted (OnFailure=, systemctl --failed) on quarantined inputs too.
SuccessExitStatus=1
# exit 2 = refused before anything was written: raw/ empty or not mounted (the rebuild would delete
# every run, or more than half), or a usage error. To delete that many runs on purpose, uncomment:
#Environment=PNEUBENCH_ALLOW_MASS_DELETE=1
# exit 130/143 = interrupted (SIGINT, SIGTERM: systemctl stop): a failure; the previous warehouse kept.
StandardOutput=append:{str(s.log).replace("%", "%%")}
StandardError=append:{str(s.log).replace("%", "%%")}
Nice=10
IOSchedulingClass=best-effort
IOSchedulingPriority=7
TimeoutStartSec=6h
"""


def systemd_timer(s: Schedule) -> str:
    return f"""# /etc/systemd/system/{s.name}.timer
[Unit]
Description=Run {s.name}.service every night at {s.hour:02d}:{s.minute:02d}

[Timer]
OnCalendar=*-*-* {s.hour:02d}:{s.minute:02d}:00
Persistent=true
Unit={s.name}.service

[Install]
WantedBy=timers.target
"""


def render(s: Schedule, fmt: str = "all") -> str:
    """The crontab line, the service, the timer, or all three with install instructions."""
    if fmt == "cron":
        return crontab_line(s)
    if fmt == "service":
        return systemd_service(s)
    if fmt == "timer":
        return systemd_timer(s)
    if fmt != "all":
        raise ValueError(f"unknown format {fmt!r} (one of {', '.join(FORMATS)})")
    return "\n".join([
        "# ---- cron: add this line with `crontab -e` ----",
        crontab_line(s),
        "",
        "# ---- or systemd: save the two units below, then",
        f"#   sudo systemctl daemon-reload && sudo systemctl enable --now {s.name}.timer",
        f"#   systemctl list-timers {s.name}.timer; journalctl -u {s.name}.service; tail {s.log}",
        "",
        systemd_service(s),
        systemd_timer(s),
    ])
