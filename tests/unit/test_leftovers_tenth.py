"""Leftovers of the probe rounds (tenth round, fixer E).

1. A writable bind of /sys's dangerous parts (/sys itself, kernel, fs/cgroup, firmware, power) is
   refused as /proc is; /sys/class, /sys/bus, /sys/devices and read-only binds stay allowed.
2. Every skipped known_hosts line is named with its line number and why, as status and apply
   show them (transport.known_hosts_problems); a line with runs of blanks is read, as OpenSSH reads it.
3. An inventory number Ansible reads as octal (`ros_domain_id: 017` is 15) is read so, with a warning.
5. The deploy user's home and a /home user's dot files are judged by one helper: same answers.
"""
from __future__ import annotations

from pathlib import Path

import pytest

from rosdeploy import checks, transport, yamlsrc
import test_hostile
from test_checks import fires, silent
from test_hostile import cli, edit
from test_ssh_eighth import K1, options, robot

lab = test_hostile.lab      # the fixture: the example fleet copied


# ------------------------------------------------------------------ 1. /sys

@pytest.mark.parametrize("volume", ["/sys/power:/p", "/sys/power/state:/s", "//sys/./power/:/p:rw",
                                    {"type": "bind", "source": "/sys/power", "target": "/p"}])
def test_a_writable_bind_of_sys_power_is_refused(volume: object) -> None:
    p = fires("mount-system-writable", volumes=[volume])
    assert "service 'driver'" in p.message and "/sys/power" in p.message and ":ro" in p.message, p.message
    assert p.severity == "error"


@pytest.mark.parametrize("volume, folder", [("/sys:/sys", "/sys/kernel"), ("/sys/:/host-sys", "/sys/kernel"),
                                            ("/sys/kernel/uevent_helper:/u", "/sys/kernel"),
                                            ("/sys/fs/cgroup:/sys/fs/cgroup", "/sys/fs"),
                                            ("/sys/firmware:/f", "/sys/firmware")])
def test_a_writable_bind_of_the_rest_of_dangerous_sys_is_refused(volume: str, folder: str) -> None:
    p = fires("mount-system-writable", volumes=[volume])
    assert volume.split(":")[0] in p.message and folder in p.message and "allow_privileged" in p.message, p.message


@pytest.mark.parametrize("volume", ["/sys:/sys:ro", "/sys/power:/p:ro", "/sys/class/gpio:/sys/class/gpio",
                                    "/sys/bus/iio/devices:/iio", "/sys/devices/platform:/d"])
def test_read_only_sys_and_its_hardware_folders_stay_allowed(volume: str) -> None:
    silent("mount-system-writable", volumes=[volume])


def test_a_writable_sys_power_is_refused_by_every_command(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(volumes=["/sys/power:/p"]))
    for command in ("validate", "check"):
        code, text = cli(capsys, lab, command)
        assert code == 2 and "mounts /sys/power writable" in text and ":ro" in text, (command, text)


# ------------------------------------------------------------------ 2. known_hosts

BAD_LINES = [f"@cert-authority *.fleet ssh-ed25519 {K1}",      # 1
             "garbage",                                          # 2
             f"@REVOKED x ssh-ed25519 {K1}",                     # 3
             "@revoked x ssh-ed25519 !!!",                       # 4
             "x ssh-ed448 AAAA",                                 # 5
             "x ssh-ed25519 !!!notbase64",                       # 6
             f"|1|!!!|xx= ssh-ed25519 {K1}",                     # 7
             f"x \x1b[31m {K1}"]                                 # 8


def test_every_skipped_known_hosts_line_is_named_with_why() -> None:
    known = transport.parse_known_hosts([*BAD_LINES, f"robot1 ssh-ed25519 {K1}"], "kh")
    why = {line: reason for line, _, reason in known.skipped}
    assert sorted(why) == list(range(1, 9)), known.skipped
    assert "@cert-authority" in why[1] and "certificates" in why[1]
    assert "not a host key line" in why[2]
    assert "unknown marker" in why[3] and "lower case" in why[3]
    assert "NOT revoked" in why[4]
    assert "ssh-ed448" in why[5] and "cannot use" in why[5]
    assert "base64" in why[6] and "ssh-ed25519" in why[6]
    assert "hashed host name" in why[7]
    assert "\x1b" not in why[8] and "its key type" in why[8]
    assert known.keys_for("robot1")           # the good line is still trusted
    assert all("!!!" not in w and "garbage" not in w for w in why.values())


def test_status_gets_one_warning_per_skipped_line(tmp_path: Path) -> None:
    opts = options(tmp_path, known="\n".join([*BAD_LINES, f"robot1 ssh-ed25519 {K1}"]) + "\n")
    found = transport.known_hosts_problems([robot(), robot("robot2")], opts)     # the file once, not per robot
    assert [(p.line, p.severity) for p in found] == [(n, "warning") for n in range(1, 9)], found
    assert all(p.file == opts.known_hosts for p in found)
    assert str(found[0]).startswith(f"{opts.known_hosts}:1: ")


def test_many_skipped_lines_are_named_up_to_a_bound(tmp_path: Path) -> None:
    opts = options(tmp_path, known="bad\n" * 50)
    found = transport.known_hosts_problems([robot()], opts)
    assert len(found) == transport.MAX_SKIPPED_SHOWN + 1
    assert found[-1].line == transport.MAX_SKIPPED_SHOWN + 1 and "30 more" in found[-1].message


def test_an_unusable_known_hosts_is_an_error_not_a_crash(tmp_path: Path) -> None:
    (tmp_path / "dir").mkdir()
    found = transport.known_hosts_problems([robot()], transport.SSHOptions(known_hosts=str(tmp_path / "dir")))
    assert [p.severity for p in found] == ["error"] and "not a regular file" in found[0].message


def test_a_line_with_runs_of_blanks_is_read_as_openssh_reads_it() -> None:
    known = transport.parse_known_hosts([f"robot1  ssh-ed25519 \t {K1}"], "kh")
    assert len(known.keys_for("robot1")) == 1 and known.skipped == ()


# ------------------------------------------------------------------ 3. octal-looking numbers

def test_an_octal_looking_number_is_read_as_ansible_reads_it_with_a_warning() -> None:
    warnings: list = []
    text = ("all:\n  vars:\n    ros_domain_id: 017\n    ansible_port: 0022\n    mode: 0644\n  hosts:\n"
            "    r1: {ansible_port: '0022', ros_domain_id: 07}\n    r2: {ansible_ssh_port: 0_22}\n")
    doc = yamlsrc.load("hosts.yml", text, duplicates=warnings)
    assert doc.data["all"]["vars"] == {"ros_domain_id": 15, "ansible_port": 18, "mode": 420}
    assert [(w.line, w.key, w.severity) for w in warnings] == [
        (3, "all.vars.ros_domain_id", "warning"), (4, "all.vars.ansible_port", "warning"),
        (8, "all.hosts.r2.ansible_ssh_port", "warning")], warnings
    assert warnings[0].message == "`017` is read as octal (15), as Ansible reads it; write 15, or quote it"


def test_the_fleet_file_load_without_a_sink_stays_quiet() -> None:
    assert yamlsrc.load("f.yml", "ros_domain_id: 017\n").data == {"ros_domain_id": 15}


@pytest.mark.parametrize("command", ["validate", "check"])
def test_validate_and_check_warn_of_an_octal_domain_id(capsys: pytest.CaptureFixture, lab: Path,
                                                       command: str) -> None:
    path = lab / "inventory" / "host_vars" / "r1.yml"
    path.write_text(path.read_text() + "ros_domain_id: 017\n")
    line = path.read_text().count("\n")
    code, text = cli(capsys, lab, command)
    assert code == 0, text
    assert f"r1.yml:{line}:" in text and "`017` is read as octal (15)" in text, text


# ------------------------------------------------------------------ 5. one home helper

@pytest.mark.parametrize("path, home, root, expect", [
    ("/home/ros/.ssh/authorized_keys", "/home/ros", "/srv/ros", "/home/ros/.ssh"),
    ("/home/ros/maps", "/home/ros", "/srv/ros", ""), ("/home", "/home/ros", "/srv/ros", "/home/ros"),
    ("/srv/ros/p/releases", "/home/ros", "/srv/ros", "/srv/ros"), ("/srv", "/home/ros", "/srv/ros", "/srv/ros")])
def test_the_deploy_user_folders(path: str, home: str, root: str, expect: str) -> None:
    assert checks._deploy_folder(path, home, root) == expect


@pytest.mark.parametrize("path, expect", [("/home/ana/.bashrc", "/home/ana/.bashrc"), ("/home/ana", "/home/ana"),
                                          ("/home/ana/", "/home/ana"), ("/home/ana/maps/x", ""),
                                          ("/home", "/home"), ("/home/ana/.ssh/k", "/home/ana/.ssh")])
def test_a_home_under_home_and_its_dot_files(path: str, expect: str) -> None:
    assert checks._system_folder(path) == expect
