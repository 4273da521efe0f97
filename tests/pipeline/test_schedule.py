"""`pneubench schedule`: a crontab line and systemd units that are ready to install."""
import configparser
import os
import re
import subprocess
import shlex

import pytest
from click.testing import CliRunner

from pipeline.cli import main
from pipeline.schedule import Schedule, crontab_line, parse_time, render, systemd_service, systemd_timer


@pytest.fixture
def sched(tmp_path):
    return Schedule(raw=tmp_path / "raw", warehouse=tmp_path / "wh", workdir=tmp_path, at="03:15",
                    executable="/opt/pb/bin/pneubench", user="lab")


def test_crontab_line_runs_the_rebuild_nightly_with_absolute_paths_and_a_log(sched, tmp_path):
    line = crontab_line(sched).splitlines()[-1]
    fields = line.split(None, 5)
    assert fields[:5] == ["15", "3", "*", "*", "*"]
    assert "%" not in line  # cron would turn it into a newline
    cmd = fields[5]
    assert cmd.startswith(f"cd {tmp_path} && ")
    words = shlex.split(cmd.split(" && ")[2].split(" >> ")[0])
    assert words == ["/opt/pb/bin/pneubench", "rebuild", "--raw", str(tmp_path / "raw"), "--warehouse",
                     str(tmp_path / "wh"), "--wait", "900"]
    assert f">> {tmp_path / 'wh' / 'logs' / 'rebuild.log'} 2>&1" in cmd
    assert "|| echo" in cmd  # cron mails a line only when the rebuild exits non-zero


def test_systemd_units_parse_and_say_what_runs_where_and_when(sched, tmp_path):
    svc = configparser.ConfigParser(strict=False, interpolation=None)
    svc.optionxform = str
    svc.read_string(systemd_service(sched))
    s = svc["Service"]
    assert s["Type"] == "oneshot" and s["User"] == "lab"
    assert s["WorkingDirectory"] == str(tmp_path)
    assert s["ExecStart"].startswith("/opt/pb/bin/pneubench rebuild --raw ")
    assert "--wait 900" in s["ExecStart"]
    assert s["StandardOutput"] == f"append:{tmp_path / 'wh' / 'logs' / 'rebuild.log'}"
    assert s["SuccessExitStatus"] == "1"
    timer = configparser.ConfigParser(strict=False, interpolation=None)
    timer.optionxform = str
    timer.read_string(systemd_timer(sched))
    assert timer["Timer"]["OnCalendar"] == "*-*-* 03:15:00"
    assert timer["Timer"]["Persistent"] == "true"
    assert timer["Timer"]["Unit"] == "pneubench-rebuild.service"
    assert timer["Install"]["WantedBy"] == "timers.target"


def test_bad_time_is_refused():
    with pytest.raises(ValueError):
        parse_time("25:00")
    with pytest.raises(ValueError):
        parse_time("noon")


def test_cli_prints_all_three(tmp_path):
    res = CliRunner().invoke(main, ["schedule", "--raw", str(tmp_path / "r"), "--warehouse", str(tmp_path / "w"),
                                    "--at", "01:05"])
    assert res.exit_code == 0, res.output
    assert "5 1 * * * cd " in res.output
    assert "[Service]" in res.output and "[Timer]" in res.output and "systemctl enable --now" in res.output
    res = CliRunner().invoke(main, ["schedule", "--at", "7pm"])
    assert res.exit_code == 2
    assert render(Schedule(raw="r", warehouse="w", workdir=".", executable="x"), "timer").startswith("# /etc/systemd")


def test_paths_with_spaces_and_percent_stay_one_argument(tmp_path):
    base = tmp_path / "lab data 100% $HOME"
    s = Schedule(raw=base / "raw", warehouse=base / "wh", workdir=base, at="02:30",
                 executable="/opt/pb/bin/pneubench", user=None)
    svc = configparser.ConfigParser(strict=False, interpolation=None)
    svc.optionxform = str
    svc.read_string(systemd_service(s))
    sv = svc["Service"]

    def words(value, exec_line=True):  # split like a shell with double quotes; %% is %, and $$ is $ in Exec
        return [w.replace("%%", "%").replace("$$", "$") if exec_line else w.replace("%%", "%")
                for w in shlex.split(value, posix=True)]

    envs = [words(v, exec_line=False) for k, v in svc.items("Service") if k == "Environment"] or [
        words(sv["Environment"], exec_line=False)]
    assert [f"PNEUBENCH_WAREHOUSE={base / 'wh'}"] in envs
    assert words(sv["ExecStartPre"]) == ["/bin/mkdir", "-p", str(base / "wh" / "logs")]
    assert words(sv["ExecStart"])[:4] == ["/opt/pb/bin/pneubench", "rebuild", "--raw", str(base / "raw")]
    assert sv["WorkingDirectory"] == str(base).replace("%", "%%")
    cron = crontab_line(s).splitlines()[-1]
    assert "%" not in cron.replace("\\%", "")  # cron turns a bare % into a newline


# -- hostile paths and names ---------------------------------------------------------------------
def _cron_command(line: str) -> str:
    """The shell command cron runs for a crontab line: after the five time fields, up to the
    first bare ``%`` (cron's newline), with ``\\%`` turned back into ``%`` (cronie do_command.c)."""
    cmd = line.split(None, 5)[5]
    out, i = [], 0
    while i < len(cmd):
        c = cmd[i]
        if c == "\\" and i + 1 < len(cmd) and cmd[i + 1] == "%":
            out.append("%")
            i += 2
            continue
        if c == "%":
            break
        out.append(c)
        i += 1
    return "".join(out)


def _systemd_words(value: str, exec_line: bool = True) -> list[str]:
    """Split a unit-file value into words like systemd does for ``Exec*=``/``Environment=``
    (double and single quotes, C escapes), then undo ``%%`` (and ``$$`` in Exec lines)."""
    words, cur, i, quote, have = [], [], 0, None, False
    escapes = {"n": "\n", "t": "\t", "\\": "\\", '"': '"', "'": "'", " ": " ", ";": ";"}
    while i < len(value):
        c = value[i]
        if c == "\\":
            nxt = value[i + 1]
            assert nxt in escapes, f"unexpected escape \\{nxt} in {value!r}"
            cur.append(escapes[nxt])
            i, have = i + 2, True
            continue
        if quote:
            if c == quote:
                quote = None
            else:
                cur.append(c)
        elif c in "\"'":
            quote, have = c, True
        elif c.isspace():
            if have:
                words.append("".join(cur))
            cur, have = [], False
        else:
            cur.append(c)
            have = True
        i += 1
    assert quote is None, f"unclosed quote in {value!r}"
    if have:
        words.append("".join(cur))

    def unspec(w):  # %% -> %, and a lone % would be a specifier: refuse it
        assert re.fullmatch(r"(?:[^%]|%%)*", w), f"bare % specifier in {w!r}"
        w = w.replace("%%", "%")
        if exec_line:
            assert re.fullmatch(r"(?:[^$]|\$\$)*", w), f"bare $ variable in {w!r}"
            w = w.replace("$$", "$")
        return w

    return [unspec(w) for w in words]


HOSTILE = ["$(touch {x}/PWNED)", "`touch {x}/PWNED2`", "a'b\"c", "100% $HOME ; x", "back\\slash", "é ü"]


@pytest.mark.parametrize("name", HOSTILE)
def test_cron_line_run_by_sh_executes_nothing_from_a_path(tmp_path, name):
    x = tmp_path / "x"
    x.mkdir()
    bad = name.replace("{x}", str(x))
    base = x / bad
    # the "executable" is a script that prints its arguments, one per line, and fails (exit 3)
    exe = tmp_path / "fake-pneubench"
    exe.write_text('#!/bin/sh\nfor a in "$@"; do printf "%s\\n" "$a"; done\nexit 3\n')
    exe.chmod(0o755)
    s = Schedule(raw=base / "raw", warehouse=base / "wh", workdir=x, log=base / "logs" / "r.log",
                 executable=str(exe))
    line = crontab_line(s).splitlines()[-1]
    res = subprocess.run(["/bin/sh", "-c", _cron_command(line)], capture_output=True, text=True, cwd=tmp_path)
    assert not any(p.name.startswith("PWNED") for p in x.iterdir())
    assert not (tmp_path / "PWNED").exists()
    # the arguments arrived exactly, and the failure line names the log exactly
    logged = (base / "logs" / "r.log").read_text().splitlines()
    assert logged == ["rebuild", "--raw", str(base / "raw"), "--warehouse", str(base / "wh"), "--wait", "900"]
    assert res.stdout == f"pneubench-rebuild failed with exit code 3 (see {base / 'logs' / 'r.log'})\n"


@pytest.mark.parametrize("name", HOSTILE)
def test_systemd_unit_gives_back_the_paths_exactly(tmp_path, name):
    base = tmp_path / name.replace("{x}", "x")
    s = Schedule(raw=base / "raw", warehouse=base / "wh", workdir=base, executable="/opt/pb/bin/pneubench",
                 user="lab-1")
    text = systemd_service(s)
    lines = dict(ln.split("=", 1) for ln in text.splitlines() if "=" in ln and not ln.startswith("#"))
    envs = [_systemd_words(ln.split("=", 1)[1], exec_line=False) for ln in text.splitlines()
            if ln.startswith("Environment=")]
    assert envs == [[f"PNEUBENCH_RAW={base / 'raw'}"], [f"PNEUBENCH_WAREHOUSE={base / 'wh'}"]]
    assert _systemd_words(lines["ExecStart"]) == ["/opt/pb/bin/pneubench", "rebuild", "--raw", str(base / "raw"),
                                                  "--warehouse", str(base / "wh"), "--wait", "900"]
    assert _systemd_words(lines["ExecStartPre"]) == ["/bin/mkdir", "-p", str(base / "wh" / "logs")]
    for key in ("WorkingDirectory", "StandardOutput", "Description"):  # specifiers only, no word splitting
        assert re.fullmatch(r"(?:[^%]|%%)*", lines[key]), key
    assert lines["WorkingDirectory"].replace("%%", "%") == str(base)
    assert lines["StandardOutput"].replace("%%", "%") == f"append:{base / 'wh' / 'logs' / 'rebuild.log'}"
    assert lines["User"] == "lab-1"


@pytest.mark.parametrize("option,value", [
    ("--warehouse", "wh\n0 * * * * touch /tmp/evil"), ("--raw", "raw\rx"), ("--workdir", "a\tb"),
    ("--log", "log\x1b[2J"), ("--user", "lab\nExecStartPre=/bin/rm -rf /"), ("--user", "lab x"),
    ("--user", "$(id)"), ("--user", "-root"), ("--user", "a" * 33)])
def test_control_characters_and_bad_user_names_are_a_usage_error(tmp_path, option, value):
    args = {"--raw": str(tmp_path / "r"), "--warehouse": str(tmp_path / "w")}
    args[option] = value if option == "--user" else str(tmp_path / value)
    res = CliRunner().invoke(main, ["schedule", *[x for kv in args.items() for x in kv]])
    assert res.exit_code == 2, res.output
    assert "Usage" in res.output or "Error" in res.output
    assert "[Service]" not in res.output


def test_a_path_that_is_not_utf8_is_refused(tmp_path):
    with pytest.raises(ValueError, match="UTF-8"):
        Schedule(raw=os.fsdecode(bytes(tmp_path) + b"/m\xe9sure"), warehouse=tmp_path, workdir=tmp_path,
                 executable="/x")


def test_the_units_count_only_1_as_success_and_say_how_to_allow_a_mass_delete(sched):
    svc = configparser.ConfigParser(strict=False, interpolation=None)
    svc.optionxform = str
    text = systemd_service(sched)
    svc.read_string(text)
    assert svc["Service"]["SuccessExitStatus"] == "1"  # 2 (refused), 3, 4, 130, 143 (interrupted) fail
    assert "#Environment=PNEUBENCH_ALLOW_MASS_DELETE=1" in text.splitlines()
    assert "Environment" not in [k for k in svc["Service"] if "MASS" in svc["Service"][k]]  # off by default
    cron = crontab_line(sched).splitlines()
    assert all(ln.startswith("#") for ln in cron[:-1]) and "PNEUBENCH_ALLOW_MASS_DELETE=1" in " ".join(cron[:-1])
    assert "PNEUBENCH_ALLOW_MASS_DELETE" not in cron[-1]
