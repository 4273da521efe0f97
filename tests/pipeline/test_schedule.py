"""`pneubench schedule`: a crontab line and systemd units that are ready to install."""
import configparser
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
