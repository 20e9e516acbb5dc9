"""Probe Q, items 1 and 7: a user template's host files (cron, udev, logrotate) and compose.yml read back.

The built-in outputs come from rendering the lab fixture (tests/unit/data/fleet) with `rosdeploy
render`; each must give no finding. Each hostile form of the probe's report must give one, at its line."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

from rosdeploy.cli import main
from rosdeploy.template_output import (Rotation, compose_schema_findings, cron_findings, logrotate_findings,
                                       rotation_for, udev_findings)
from rosdeploy.render import Renderer
from test_render import files, make_host, make_spec

DATA = Path(__file__).resolve().parent / "data" / "fleet"
LAB = Rotation("lab", "/root/rosdeploy/lab/logs")


@pytest.fixture(scope="module")
def built_in(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """r1's files as rosdeploy's own templates render them (udev entry, rotation every 5m)."""
    lab = tmp_path_factory.mktemp("lab") / "lab"
    shutil.copytree(DATA, lab)
    code = main(["render", str(lab / "fleet.yml"), "--vault-password-file", str(lab / "inventory" / ".vault-password"),
                 "--out", str(lab / "out")])
    assert code == 0
    return {p.name: p.read_text() for p in (lab / "out" / "r1").iterdir() if p.is_file()}


# ------------------------------------------------------------------ built-in outputs pass

def test_builtin_host_files_give_no_finding(built_in: dict[str, str]) -> None:
    assert "logrotate -s" in built_in["logrotate.cron"] and "SYMLINK+=" in built_in["99-rosdeploy.rules"]
    assert cron_findings(built_in["logrotate.cron"], LAB) == []
    assert udev_findings(built_in["99-rosdeploy.rules"]) == []
    assert logrotate_findings(built_in["logrotate.conf"], LAB) == []


def test_builtin_forms_not_in_the_lab_pass() -> None:
    off = "# Rendered by rosdeploy\n# (no schedule: logging.rotate_every is off)\n"
    assert cron_findings(off, LAB) == []
    serial = ('SUBSYSTEM=="tty", ATTRS{idVendor}=="0403", ATTRS{idProduct}=="6001", ATTRS{serial}=="A1", '
              'SYMLINK+="robot/motor", MODE="0660"\n')
    assert udev_findings(serial) == []
    continued = 'SUBSYSTEM=="tty", ATTRS{idVendor}=="0403", \\\n  ATTRS{idProduct}=="6001", SYMLINK+="robot/x"\n'
    assert udev_findings(continued) == []
    assert cron_findings("@hourly root /usr/sbin/logrotate -s /var/lib/logrotate/rosdeploy-lab.status "
                         "/etc/logrotate.d/rosdeploy-lab\nMAILTO=\"\"\n", LAB) == []
    spaced = ('"/root/rosdeploy/lab/logs/*/*.log"\n{\n  create 0640 root root\n'
              '  olddir /root/rosdeploy/lab/logs/old\n}\n')
    assert logrotate_findings(spaced, LAB) == []


def test_builtin_compose_is_valid_for_the_schema(built_in: dict[str, str]) -> None:
    assert compose_schema_findings(yaml.safe_load(built_in["compose.yml"])) == []


def test_rotation_for_reads_the_folders_as_render_does() -> None:
    spec = make_spec()
    assert rotation_for(spec, make_host("r1", user=None)).logs_dir == f"/root/rosdeploy/{spec.project}/logs"
    assert rotation_for(spec, make_host("r1", user="ros")).logs_dir == f"/home/ros/rosdeploy/{spec.project}/logs"
    other = make_host("r1", user="ros", vars={"rosdeploy_deploy_root": "/opt/rd/"})
    assert rotation_for(spec, other).logs_dir == f"/opt/rd/{spec.project}/logs"
    for host in (make_host("r1", user=None), make_host("r1", user="ros"), other):
        conf = files(Renderer(spec).render(host))["logrotate.conf"]
        assert logrotate_findings(conf, rotation_for(spec, host)) == [], conf


# ------------------------------------------------------------------ item 1: cron

def test_cron_k1_shell_command_refused() -> None:
    found = cron_findings('SHELL=/bin/sh\n* * * * * root /bin/sh -c "id > /tmp/pwned"\n', LAB)
    assert [f.line for f in found] == [2]
    assert "logrotate.cron line 2" in found[0].message and "/bin/sh -c" in found[0].message
    assert "as user 'root' on every robot" in found[0].message and "/etc/cron.d/rosdeploy-lab" in found[0].message


@pytest.mark.parametrize("line", [
    "@reboot root id > /tmp/pwned",
    "*/5 * * * * root logrotate -s /var/lib/logrotate/rosdeploy-lab.status /etc/logrotate.d/rosdeploy-lab; id",
    "*/5 * * * * root logrotate -s /var/lib/logrotate/rosdeploy-lab.status /etc/logrotate.conf",
    "*/5 * * * * ros logrotate -s /var/lib/logrotate/rosdeploy-lab.status /etc/logrotate.d/rosdeploy-lab",
    "*/5 * * * * root logrotate -s /tmp/s /etc/logrotate.d/rosdeploy-lab%id",
    "not a cron line",
    "SHELL=/tmp/evil",
    "PATH=/tmp:/usr/bin",
    "LD_PRELOAD=/tmp/x.so",
])
def test_cron_other_lines_refused(line: str) -> None:
    found = cron_findings(f"# c\n{line}\n", LAB)
    assert [f.line for f in found] == [2], found


# ------------------------------------------------------------------ item 1: udev

def test_udev_k2_run_refused() -> None:
    found = udev_findings("# x\nACTION==\"add\", RUN+=\"/bin/sh -c 'id > /tmp/pwned'\"\n")
    assert [f.line for f in found] == [2]
    assert "RUN+=" in found[0].message and "/bin/sh -c" in found[0].message and "as root" in found[0].message


@pytest.mark.parametrize("rule", [
    'SUBSYSTEM=="tty", ATTRS{idVendor}=="0403", ATTRS{idProduct}=="6001", PROGRAM="/bin/id"',
    'SUBSYSTEM=="tty", ATTRS{idVendor}=="0403", ATTRS{idProduct}=="6001", IMPORT{program}="/bin/id"',
    'SUBSYSTEM=="tty", ATTRS{idVendor}=="0403", ATTRS{idProduct}=="6001", IMPORT{file}="/etc/x"',
    'SUBSYSTEM=="tty", ATTRS{idVendor}=="0403", ATTRS{idProduct}=="6001", ENV{SYSTEMD_WANTS}="evil.service"',
    'SUBSYSTEM=="tty", ATTRS{idVendor}=="0403", ATTRS{idProduct}=="6001", ATTR{power/control}="on"',
    'SUBSYSTEM=="tty", ATTRS{idVendor}=="0403", ATTRS{idProduct}=="6001", OWNER="ros"',
    'KERNEL=="sda", MODE="0666"',
    'SUBSYSTEM=="block", SYMLINK+="robot/motor"',
    'SUBSYSTEM=="tty", ATTRS{idVendor}=="0403", \\\n ATTRS{idProduct}=="6001", RUN+="/bin/id"',
    'SUBSYSTEM=="tty" garbage',
])
def test_udev_more_than_builtin_refused(rule: str) -> None:
    found = udev_findings(f"# x\n{rule}\n")
    assert found and {f.line for f in found} == {2}, found


# ------------------------------------------------------------------ item 1: logrotate

SCRIPTS = ("prerotate", "firstaction", "lastaction", "preremove")
BUILTIN_BLOCK = "/root/rosdeploy/lab/logs/*/*.log {\n    su root root\n    size 50M\n    copytruncate\n"


def test_logrotate_k3_postrotate_refused() -> None:
    text = BUILTIN_BLOCK + "    postrotate\n        id > /tmp/pwned\n    endscript\n}\n"
    found = logrotate_findings(text, LAB)
    assert [f.line for f in found] == [5]
    assert "postrotate" in found[0].message and "/etc/logrotate.d/rosdeploy-lab" in found[0].message


def test_logrotate_k4_shadow_refused() -> None:
    text = "/etc/shadow {\n  su root root\n  create 0666 root root\n  rotate 1\n  size 0\n}\n"
    found = logrotate_findings(text, LAB)
    assert [f.line for f in found] == [1, 3]
    assert "/etc/shadow" in found[0].message and "0666" in found[1].message


@pytest.mark.parametrize("line", [
    "    prerotate", "    firstaction", "    lastaction", "    preremove", "    mail root@example.com",
    "    compresscmd /tmp/x", "    include /tmp/other", "    allowhardlink", "    olddir /etc",
    "    createolddir 0777 root root", "    somethingnew yes",
])
def test_logrotate_directives_refused(line: str) -> None:
    end = "endscript\n" if line.strip() in SCRIPTS else ""
    found = logrotate_findings(BUILTIN_BLOCK + line + "\n" + end + "}\n", LAB)
    assert [f.line for f in found] == [5], found


@pytest.mark.parametrize("path", ["/root/rosdeploy/lab/logs/../../../etc/*", "/root/rosdeploy/lab/logs",
                                  "/root/rosdeploy/other/logs/*/*.log", "relative/*.log", '"/etc/pass wd"'])
def test_logrotate_paths_outside_logs_refused(path: str) -> None:
    found = logrotate_findings(f"{path} {{\n  size 1M\n}}\n", LAB)
    assert [f.line for f in found] == [1], found


def test_logrotate_second_path_on_a_line_refused() -> None:
    found = logrotate_findings("/root/rosdeploy/lab/logs/a/*.log /var/log/syslog {\n}\n", LAB)
    assert len(found) == 1 and "/var/log/syslog" in found[0].message


# ------------------------------------------------------------------ item 7: compose schema

def _compose(extra: dict) -> dict:
    return {"services": {"driver": {"image": "r/d:1", **extra}}}


@pytest.mark.parametrize("extra, key", [({"Privileged": True}, ("services", "driver", "Privileged")),
                                        ({"privileged": "1"}, ("services", "driver", "privileged")),
                                        ({"read_only": "maybe"}, ("services", "driver", "read_only")),
                                        ({"use_api_socket": True}, ("services", "driver", "use_api_socket"))])
def test_compose_refused_forms(extra: dict, key: tuple) -> None:
    found = compose_schema_findings(_compose(extra))
    assert [f.path for f in found] == [key] and not found[0].v2_accepts, found
    assert "Compose" in found[0].message


def test_compose_privileged_case_named() -> None:
    (found,) = compose_schema_findings(_compose({"Privileged": True}))
    assert "'Privileged'" in found.message and "did you mean 'privileged'?" in found.message


@pytest.mark.parametrize("extra", [{"privileged": "yes"}, {"x-note": 1}, {"pids_limit": "12"}, {"cpus": "1.5"},
                                   {"volumes": [{"type": "bind", "source": "/a", "target": "/b",
                                                 "read_only": "false"}]}])
def test_compose_forms_compose_accepts_pass(extra: dict) -> None:
    assert compose_schema_findings({"x-top": {"a": 1}, **_compose(extra)}) == []


def test_compose_v2_only_keys_marked() -> None:
    found = compose_schema_findings({"name": "t", **_compose({"gpus": "all", "Gpus": "all"})})
    assert {(f.path, f.v2_accepts) for f in found} == {(("name",), True), (("services", "driver", "Gpus"), False),
                                                       (("services", "driver", "gpus"), True)}, found


# ------------------------------------------------------------------ wired into check (checks.py)

def _wired(rule_id: str) -> bool:
    from rosdeploy import checks
    return rule_id in checks.RULES


HOSTILE = {
    "logrotate.cron.j2": 'SHELL=/bin/sh\n* * * * * root /bin/sh -c "id > /tmp/pwned"\n',
    "udev.rules.j2": "ACTION==\"add\", RUN+=\"/bin/sh -c 'id > /tmp/pwned'\"\n",
    "logrotate.conf.j2": "/etc/shadow {\n  su root root\n  create 0666 root root\n  rotate 1\n  size 0\n}\n",
}


@pytest.mark.skipif(not _wired("host-template-root"), reason="host-template-root is not in checks.py yet")
@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_check_refuses_a_hostile_host_template(tmp_path: Path, name: str, capsys: pytest.CaptureFixture) -> None:
    lab = tmp_path / "lab"
    shutil.copytree(DATA, lab)
    (lab / "templates").mkdir()
    (lab / "templates" / name).write_text(HOSTILE[name])
    with (lab / "fleet.yml").open("a") as fleet:
        fleet.write("templates: templates\n")
    code = main(["check", str(lab / "fleet.yml"), "--vault-password-file", str(lab / "inventory" / ".vault-password")])
    text = capsys.readouterr().out
    assert code == 2 and "host-template-root" in text and name in text, text
