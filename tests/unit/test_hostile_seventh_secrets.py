"""Seventh hostile-input audit, secrets: each case read a vault value past the tracking, quoted
one (or one computed from it) in a message, copied the vault password into a release, or
crashed (exit 1) on an odd value or file.

1. `host.vars.raw[...]`, `secret_texts()`, `origin(..)`, `hostvars[x].raw` read vault values untracked.
2. `hostvars[other].override(..)` from an inventory value rewrote another robot's vars.
3. `{{ host|string }}` wrote the robot's vault values (Host's repr).
4. Error messages quoted values computed from a vault var (fleet values, inventory vars, user
   templates, tunables, dds_peers): masking the output finds only a secret's exact text.
5. A `files:` path computed from a vault var was quoted in "does not exist".
6. A vault value holding `{{` that failed to template was quoted (cut short, or repr-escaped).
7. `files: {copy: <the vault password file>}` put the password in a world-readable release file.
11. `files: {var: ..}` whose value is not plain data (`{{ range(3) }}`): internal error.
12. An `ssh.config` line paramiko cannot parse: internal error quoting the line.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import pytest
import yaml

import test_hostile
from rosdeploy.errors import InputError
from rosdeploy.transport import SSHOptions, parsed_ssh_config
from test_hostile import LAB_SECRET, cli, edit, set_env
from test_vault_taint import group_vars, vault_file

lab = test_hostile.lab      # the fixture: the example fleet copied, its vault password in place

REVERSED = LAB_SECRET[::-1]


def no_secret_anywhere(lab: Path, text: str, *secrets: str) -> None:
    """Neither the vault value nor its reverse in the output, nor in any file written but .env."""
    written = "".join(f.read_text() for f in (lab / "out").rglob("*") if f.is_file() and f.name != ".env") \
        if (lab / "out").exists() else ""
    for secret in (LAB_SECRET, REVERSED, *secrets):
        assert secret not in text, (secret, text)
        assert secret not in written, secret


def refused(capsys: pytest.CaptureFixture, lab: Path, *expect: str, secrets: tuple[str, ...] = (),
            commands: tuple[str, ...] = ("validate", "render")) -> None:
    for command in commands:
        code, text = cli(capsys, lab, command)      # cli(): no traceback, no internal error
        assert code == 2, (command, text)
        for part in expect:
            assert part in text, (command, part, text)
        no_secret_anywhere(lab, text, *secrets)
        assert not (lab / "out").exists(), f"{command} wrote files"


def add_file(name: str, entry: dict) -> Callable[[dict], None]:
    def change(d: dict) -> None:
        d["files"] = {name: entry}
        d["services"]["driver"]["files"] = [name]
    return change


# ------------------------------------------------ 1. HostVars members that read untracked

@pytest.mark.parametrize("value", [
    "{{ host.vars.raw['api_token']|reverse|join }}",
    "{{ host.vars.secret_texts()|list|first|reverse|join }}",
    "{{ host.vars.secret_texts_read()|list|first|reverse|join }}",
    "{{ host.vars.origin('api_token').inline_secrets|list|first|reverse|join }}",
    "{{ host.vars.value('api_token')|reverse|join }}",
])
def test_a_fleet_value_cannot_read_vault_values_through_hostvars_members(capsys: pytest.CaptureFixture, lab: Path,
                                                                        value: str) -> None:
    edit(lab, set_env(value))
    refused(capsys, lab, "services.driver.environment.X")


def test_an_inventory_value_cannot_read_raw_vars_through_hostvars(capsys: pytest.CaptureFixture, lab: Path) -> None:
    group_vars(lab, tag="{{ hostvars[inventory_hostname].raw['api_token'] | reverse | join }}")
    edit(lab, set_env("{{ tag }}"))
    refused(capsys, lab, "services.driver.environment.X", "tag")


# ------------------------------------------------ 2. override from a template

def test_an_inventory_value_cannot_override_another_robots_var(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "inventory" / "host_vars" / "r1.yml").write_text(
        (lab / "inventory" / "host_vars" / "r1.yml").read_text()
        + "site: \"{{ hostvars['r2'].override('ansible_host', '10.6.6.6') }}north\"\n")
    edit(lab, set_env("{{ site }}"))
    refused(capsys, lab, "r1.yml", "site", "not safely callable")


# ------------------------------------------------ 3. objects a template can print

@pytest.mark.parametrize("value", ["{{ host|string|reverse|join }}", "{{ host.vars|string|reverse|join }}",
                                   "{{ vars|string|reverse|join }}"])
def test_printing_what_a_template_sees_prints_no_secret(capsys: pytest.CaptureFixture, lab: Path, value: str) -> None:
    edit(lab, set_env(value))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    no_secret_anywhere(lab, text)


def test_printing_a_template_files_context_prints_no_secret(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "templates").mkdir()
    (lab / "templates" / "notes.txt.j2").write_text(
        "{{ host|string|reverse|join }}\n{{ spec|string|reverse|join }}\n{{ services|string|reverse|join }}\n")
    edit(lab, lambda d: d.update(templates="./templates"))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    assert "r1" in (lab / "out" / "r1" / "notes.txt").read_text()[::-1]
    no_secret_anywhere(lab, text)


# ------------------------------------------------ 4. messages about values computed from a vault var

def test_a_failing_fleet_value_that_read_a_vault_var_is_not_quoted(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, set_env("{{ {}[api_token|reverse|join] }}"))
    refused(capsys, lab, "services.driver.environment.X", "vault var 'api_token'", "not shown")


def test_a_failing_inventory_var_that_read_a_vault_var_is_not_quoted(capsys: pytest.CaptureFixture,
                                                                     lab: Path) -> None:
    group_vars(lab, leaky="{{ {}[api_token|reverse|join] }}")
    edit(lab, set_env("{{ leaky }}"))
    refused(capsys, lab, "leaky", "vault var 'api_token'", "not shown")


def test_a_failing_user_template_that_read_a_vault_var_is_not_quoted(capsys: pytest.CaptureFixture,
                                                                     lab: Path) -> None:
    (lab / "templates").mkdir()
    (lab / "templates" / "notes.txt.j2").write_text("{{ {}[vars.api_token|reverse|join] }}\n")
    edit(lab, lambda d: d.update(templates="./templates"))
    refused(capsys, lab, "notes.txt.j2:1", "vault var 'api_token'", "not shown")


@pytest.mark.parametrize("var, value", [("logrotate_keep", "{{ api_token[:10] }}"),
                                        ("dds_socket_buffer", "{{ api_token|reverse|join }}")])
def test_a_bad_tunable_computed_from_a_vault_var_is_not_quoted(capsys: pytest.CaptureFixture, lab: Path, var: str,
                                                               value: str) -> None:
    group_vars(lab, **{var: value})
    refused(capsys, lab, var, "'********'", "vault var 'api_token'", secrets=(LAB_SECRET[:10],))


def test_bad_dds_peers_computed_from_a_vault_var_are_not_quoted(capsys: pytest.CaptureFixture, lab: Path) -> None:
    group_vars(lab, dds_peers=["{{ api_token|reverse|join }}_"])
    refused(capsys, lab, "dds_peers", "vault var 'api_token'")


# ------------------------------------------------ 5. a files: path computed from a vault var

@pytest.mark.parametrize("kind", ["template", "copy"])
def test_a_file_path_computed_from_a_vault_var_is_refused(capsys: pytest.CaptureFixture, lab: Path,
                                                          kind: str) -> None:
    edit(lab, add_file("params", {kind: "p/{{ vars.api_token|reverse|join }}.yaml", "target": "/config/p.yaml"}))
    refused(capsys, lab, f"files.params.{kind}", "vault var 'api_token'", "a path is not secret")


# ------------------------------------------------ 6. a vault value that fails to template

@pytest.mark.parametrize("secret", ["Pa\\ss-w0rd-{{ zq_hidden_name }}",
                                    "tok-" + "A" * 60 + "{{ zq_hidden_name }}SECRETTAIL" * 4])
def test_a_vault_value_that_fails_to_template_is_never_quoted(capsys: pytest.CaptureFixture, lab: Path,
                                                              secret: str) -> None:
    vault_file(lab, "vault.yml", yaml.safe_dump({"api_token": secret}))
    parts = ("zq_hidden_name", "SECRETTAIL", "w0rd", "Pa\\\\ss", "tok-AAAA")
    refused(capsys, lab, "vault.yml", "api_token", "not shown", secrets=parts)


# ------------------------------------------------ 7. the vault password file as a release file

@pytest.mark.parametrize("kind, source", [("copy", "inventory/.vault-password"),
                                          ("template", "inventory/.vault-password"), ("copy", "pw-link")])
def test_the_vault_password_file_never_goes_into_a_release(capsys: pytest.CaptureFixture, lab: Path, kind: str,
                                                           source: str) -> None:
    (lab / "pw-link").symlink_to(lab / "inventory" / ".vault-password")
    password = (lab / "inventory" / ".vault-password").read_text().strip()
    edit(lab, add_file("pw", {kind: source, "target": "/config/pw.txt"}))
    refused(capsys, lab, f"files.pw.{kind}", "vault password file", secrets=(password,))


# ------------------------------------------------ 11. a files: var that is not plain data

@pytest.mark.parametrize("value", ["{{ range(3) }}", "{{ [api_token|reverse|join, range(1)] }}"])
def test_a_file_var_that_is_not_plain_data_is_a_clean_error(capsys: pytest.CaptureFixture, lab: Path,
                                                            value: str) -> None:
    group_vars(lab, calib=value)
    edit(lab, add_file("cal", {"var": "calib", "target": "/config/cal.yaml"}))
    refused(capsys, lab, "files.cal.var", "robot 'r1'", "'calib'", "range object")


# ------------------------------------------------ 12. an ssh config paramiko cannot parse

def test_an_unparsable_ssh_config_line_is_named_by_number_not_quoted(tmp_path: Path) -> None:
    config = tmp_path / "ssh_config"
    config.write_text("Host r1\n  Port 2222\nTopSecretPassw0rd-Not-Vault\n")
    with pytest.raises(InputError) as raised:
        parsed_ssh_config(SSHOptions(ssh_config=str(config)))
    problem = raised.value.problems[0]
    assert (problem.file, problem.line) == (str(config), 3), problem
    assert "TopSecret" not in problem.message and "not shown" in problem.message, problem


def test_an_ssh_config_that_is_a_vault_password_file_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    password = lab / "inventory" / ".vault-password"
    cli(capsys, lab, "validate")       # a Vault of this run now knows the password file
    with pytest.raises(InputError) as raised:
        parsed_ssh_config(SSHOptions(ssh_config=str(password)))
    assert "vault password file" in raised.value.problems[0].message
    assert password.read_text().strip() not in str(raised.value.problems)


def test_an_unparsable_ssh_config_is_exit_2_on_status(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "ssh_config").write_text("Host r1\nTopSecretPassw0rd-Not-Vault\n")
    (lab / "known_hosts").write_text("")
    edit(lab, lambda d: d.update(ssh={"config": "ssh_config", "known_hosts": "known_hosts", "persist": 0,
                                      "connect_timeout": "2s"}))
    code, text = cli(capsys, lab, "status")
    assert code == 2, text
    assert "ssh_config:2" in text and "TopSecret" not in text, text
