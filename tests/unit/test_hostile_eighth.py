"""Eighth hostile-input audit: connection vars that passed validate and stopped `status` with an
internal error, and Ansible vars rosdeploy ignores (or takes in clear text) without a word."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

import test_hostile
from test_hostile import cli
from test_vault_taint import group_vars

lab = test_hostile.lab


def host_vars(lab: Path, **values: object) -> None:
    """r1's own vars: an ansible_host there beats the one hosts.yml gives it."""
    path = lab / "inventory" / "host_vars" / "r1.yml"
    data = yaml.safe_load(path.read_text()) or {}
    path.write_text(yaml.safe_dump({**data, **values}, sort_keys=False))


@pytest.mark.parametrize("value", ["a..b", ".", "a" * 64 + ".example", "robot\u2028one", "robot\x85one",
                                   "robot\x1bone", "robot\u200bone"])
def test_an_address_the_resolver_cannot_take_is_refused_at_its_var(capsys: pytest.CaptureFixture, lab: Path,
                                                                   value: str) -> None:
    # each passed validate, check and render, then `status` died with UnicodeError (exit 1)
    host_vars(lab, ansible_host=value)
    for command in ("validate", "check", "render"):
        code, text = cli(capsys, lab, command)
        assert code == 2 and "r1.yml:" in text and "ansible_host" in text, (command, text)
        assert not (lab / "out").exists()


@pytest.mark.parametrize("value", ["fe80::1%eth0", "robot-1.example.com", "robot1.", "10.0.0.7", "bücher.example"])
def test_good_addresses_still_pass(capsys: pytest.CaptureFixture, lab: Path, value: str) -> None:
    host_vars(lab, ansible_host=value)
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


@pytest.mark.parametrize("value", ["a\u2028b", "a" * 5000, "a\x1bb"], ids=["separator", "long", "escape"])
def test_a_user_name_is_refused_at_its_var_not_in_a_template(capsys: pytest.CaptureFixture, lab: Path,
                                                             value: str) -> None:
    # "a\u2028b" was reported at rosdeploy's own logrotate.conf.j2, not at ansible_user
    group_vars(lab, ansible_user=value)
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "vars.yml:" in text and "ansible_user" in text and "logrotate" not in text, text


@pytest.mark.parametrize("var, value, says", [
    ("ansible_password", "hunter2-pass", "logs in with SSH keys only"),
    ("ansible_ssh_pass", "hunter2-pass", "logs in with SSH keys only"),
    ("ansible_host_key_checking", False, "always checks host keys"),
    ("ansible_become_exe", "doas", "sudo alone"),
    ("ansible_ssh_executable", "/usr/bin/ssh", "runs no ssh command"),
])
def test_an_ansible_var_rosdeploy_ignores_gets_a_warning_at_its_line(capsys: pytest.CaptureFixture, lab: Path,
                                                                    var: str, value: object, says: str) -> None:
    group_vars(lab, **{var: value})
    code, text = cli(capsys, lab, "validate")
    assert code == 0 and "vars.yml:" in text and var in text and says in text, text
    assert "hunter2-pass" not in text


def test_host_key_checking_left_on_says_nothing(capsys: pytest.CaptureFixture, lab: Path) -> None:
    group_vars(lab, ansible_host_key_checking=True)
    code, text = cli(capsys, lab, "validate")
    assert code == 0 and "ansible_host_key_checking" not in text, text


def test_a_plain_text_sudo_password_is_a_warning_and_never_shown(capsys: pytest.CaptureFixture, lab: Path) -> None:
    group_vars(lab, ansible_become=True, ansible_become_password="plain-sudo-pw")
    code, text = cli(capsys, lab, "check")
    assert code == 0 and "become-password-not-vaulted" in text and "vars.yml:" in text, text
    assert "plain-sudo-pw" not in text


def test_a_vaulted_sudo_password_is_not_warned_about(capsys: pytest.CaptureFixture, lab: Path) -> None:
    group_vars(lab, ansible_become=True, ansible_become_password="{{ api_token }}")
    code, text = cli(capsys, lab, "check")
    assert code == 0 and "become-password-not-vaulted" not in text, text


def test_status_warns_of_a_skipped_known_hosts_line_even_when_no_key_is_needed(
        capsys: pytest.CaptureFixture, lab: Path) -> None:
    # a broken @revoked line left its key trusted without a word once the robot's own key was found
    known = lab / "known_hosts"
    known.write_text("@revoked [127.0.0.1]:1 ssh-ed25519 !!not-base64!!\n")
    fleet = lab / "fleet.yml"
    data = yaml.safe_load(fleet.read_text())
    data["ssh"] = {"known_hosts": str(known), "connect_timeout": "1s", "persist": 0}
    fleet.write_text(yaml.safe_dump(data, sort_keys=False))
    host_vars(lab, ansible_port=1)
    code, text = cli(capsys, lab, "status", "--limit", "r1")
    assert code == 3 and f"{known}:1:" in text and "warning" in text, text


@pytest.mark.parametrize("value, good", [("10k", False), ("10M", False), ("10KB", False), ("10kiB", False),
                                         ("10MB", True), ("8MiB", True), ("1kB", True), ("10485760", True)])
def test_a_socket_buffer_is_written_only_in_units_cyclonedds_reads(capsys: pytest.CaptureFixture, lab: Path,
                                                                    value: str, good: bool) -> None:
    # CycloneDDS refuses `10k` or `10M` at start: the robot's DDS would not come up
    group_vars(lab, dds_socket_buffer=value)
    code, text = cli(capsys, lab, "validate")
    assert (code == 0) == good and (good or "dds_socket_buffer" in text and "vars.yml:" in text), text


def test_a_user_compose_template_that_writes_a_key_twice_is_invalid(capsys: pytest.CaptureFixture, lab: Path) -> None:
    # check passed it; Compose v2 refuses a mapping with a key twice ("mapping key already defined")
    from test_hostile import edit
    builtin = Path(__file__).resolve().parents[2] / "rosdeploy" / "templates" / "compose.yml.j2"
    (lab / "templates").mkdir()
    (lab / "templates" / "compose.yml.j2").write_text(builtin.read_text() + "x-note: 1\nx-note: 2\n")
    edit(lab, lambda d: d.update(templates="./templates"))
    code, text = cli(capsys, lab, "check")
    assert code == 2 and "compose-invalid" in text and "duplicate key" in text, text


def test_a_home_from_a_vault_var_says_got_once(capsys: pytest.CaptureFixture, lab: Path) -> None:
    group_vars(lab, rosdeploy_home="{{ api_token }}")
    code, text = cli(capsys, lab, "validate")
    line = next(each for each in text.splitlines() if "rosdeploy_home" in each)
    assert code == 2 and line.count("got ") == 1 and "'********'" in line, text


@pytest.mark.parametrize("separator", ["\u2028", "\u2029", "\x85"])
def test_a_line_separator_in_a_compose_pass_through_value_reaches_compose_as_written(
        capsys: pytest.CaptureFixture, lab: Path, separator: str) -> None:
    # PyYAML wrote it raw in a quoted scalar, and YAML folded it into a space: two extra_hosts became one
    from test_hostile import edit
    hosts = [f"a{separator}b:1.2.3.4", "c:9.9.9.9"]
    edit(lab, lambda d: d["services"]["driver"].update(compose={"extra_hosts": hosts, "domainname": f"x{separator}y"}))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    driver = yaml.safe_load((lab / "out" / "r1" / "compose.yml").read_text())["services"]["driver"]
    assert driver["extra_hosts"] == hosts and driver["domainname"] == f"x{separator}y"


@pytest.mark.parametrize("kind", ["folder", "fifo"])
def test_a_key_file_that_is_no_regular_file_is_refused_by_validate(capsys: pytest.CaptureFixture, lab: Path,
                                                                   kind: str) -> None:
    # validate passed it; status hung on a fifo, or called a folder an unreachable robot
    import os
    key = lab / "key"
    key.mkdir() if kind == "folder" else os.mkfifo(key)
    host_vars(lab, ansible_ssh_private_key_file=str(key))
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "r1.yml:" in text and "ansible_ssh_private_key_file" in text and "not" in text, text
