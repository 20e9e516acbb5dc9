"""A vault value *transformed* on its way into a non-secret file (issue 18).

The leak check searches the output for a vault value's text; `{{ api_token|upper }}` or a slice
no longer contains it. These cases follow the value instead: an inventory var whose template
read a vault var is secret too, and a non-secret file or value that read one is refused, at
the fleet key that reads it. Each was written out before (render exit 0, the secret upper-cased
in compose.yml); each must be refused, with nothing written.
"""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

import test_hostile
from rosdeploy.vault import encrypt
from test_hostile import LAB_SECRET, cli, edit, set_env

lab = test_hostile.lab      # the fixture: the example fleet copied

SHOUTED = LAB_SECRET.upper()


def group_vars(lab: Path, **values: object) -> None:
    path = lab / "inventory" / "group_vars" / "all" / "vars.yml"
    data = yaml.safe_load(path.read_text())
    data.update(values)
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def written(lab: Path) -> str:
    return "".join(f.read_text() for f in (lab / "out").rglob("*") if f.is_file() and f.name != ".env")


def refused(capsys: pytest.CaptureFixture, lab: Path, *expect: str) -> str:
    for command in ("validate", "render"):
        code, text = cli(capsys, lab, command)
        assert code == 2, (command, text)
        for part in expect:
            assert part in text, (command, part, text)
        assert SHOUTED not in text
        assert not (lab / "out").exists(), f"{command} wrote files"
    return text


@pytest.mark.parametrize("value", ["{{ shout }}", "x-{{ vars.shout }}", "{{ vars['shout'] }}",
                                   "{{ host.vars.shout }}", "{{ shout[0:4] ~ '-' ~ shout[4:] }}"])
def test_a_var_computed_from_a_vault_var_is_refused_in_compose(capsys: pytest.CaptureFixture, lab: Path,
                                                               value: str) -> None:
    group_vars(lab, shout="{{ api_token | upper }}")
    edit(lab, set_env(value))
    refused(capsys, lab, "fleet.yml", "services.driver.environment.X", "var 'shout' (computed from vault var "
            "'api_token')", "secrets:")


def test_a_value_that_reads_every_var_reads_the_vault_ones(capsys: pytest.CaptureFixture, lab: Path) -> None:
    group_vars(lab, shout="{{ api_token | upper }}")
    edit(lab, set_env("{{ vars|dictsort }}"))
    refused(capsys, lab, "services.driver.environment.X", "vault var 'api_token'")


def test_a_chain_of_vars_keeps_the_vault_var_it_started_from(capsys: pytest.CaptureFixture, lab: Path) -> None:
    group_vars(lab, a="{{ api_token | reverse | join }}", b="{{ a | upper }}", c="Bearer {{ b }}")
    edit(lab, set_env("{{ c }}"))
    refused(capsys, lab, "var 'c' (computed from vault var 'api_token')")


def test_a_vault_var_transformed_in_the_fleet_value_itself(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, set_env("{{ api_token[0:3] ~ '-' ~ api_token[3:] }}"))
    refused(capsys, lab, "services.driver.environment.X", "vault var 'api_token'")


def test_another_robots_vault_var_through_hostvars(capsys: pytest.CaptureFixture, lab: Path) -> None:
    group_vars(lab, peer_token="{{ hostvars['r2'].api_token | upper }}")
    edit(lab, set_env("{{ peer_token }}"))
    refused(capsys, lab, "'peer_token'", "vault var 'api_token'")


def test_a_robot_file_from_a_derived_var_must_be_secret(capsys: pytest.CaptureFixture, lab: Path) -> None:
    group_vars(lab, shout="{{ api_token | upper }}")

    def add_file(secret: bool) -> None:
        def change(d: dict) -> None:
            d["files"] = {"token": {"var": "shout", "target": "/config/token", **({"secret": True} if secret else {})}}
            d["services"]["driver"]["files"] = ["token"]
        edit(lab, change)

    add_file(secret=False)
    refused(capsys, lab, "files.token.var", "'shout'", "secret: true")
    add_file(secret=True)
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    token = lab / "out" / "r1" / "files" / "token"
    assert token.read_text() == SHOUTED and token.stat().st_mode & 0o777 == 0o600


def test_a_derived_secret_passed_with_secrets_goes_to_env_only(capsys: pytest.CaptureFixture, lab: Path) -> None:
    """The way out the message names: `secrets:` accepts a var computed from a vault var."""
    group_vars(lab, shout="{{ api_token | upper }}")
    edit(lab, lambda d: d["services"]["driver"].update(secrets={"SHOUT": "shout"}))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    assert f"SHOUT={SHOUTED}" in (lab / "out" / "r1" / ".env").read_text()
    assert SHOUTED not in written(lab)


def test_a_plain_var_with_the_same_text_is_still_plain(capsys: pytest.CaptureFixture, lab: Path) -> None:
    """Reading is what marks a var: a var that reads no vault var stays usable in compose.yml."""
    group_vars(lab, site="{{ 'north' | upper }}", unused="{{ api_token | upper }}")
    edit(lab, set_env("{{ site }}"))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    assert '"NORTH"' in (lab / "out" / "r1" / "compose.yml").read_text()


def test_a_derived_var_in_dds_peers_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    group_vars(lab, dds_peers=["{{ api_token | lower | replace('-', '') }}.example"])
    refused(capsys, lab, "dds_peers", "vault var 'api_token'")


def test_a_template_override_that_reads_a_derived_var_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    group_vars(lab, shout="{{ api_token | upper }}")
    (lab / "templates").mkdir()
    (lab / "templates" / "notes.txt.j2").write_text("token: {{ vars.shout }}\n")
    edit(lab, lambda d: d.update(templates="./templates"))
    refused(capsys, lab, "template notes.txt.j2", "notes.txt", "'shout'", "`secrets:`")


# ------------------------------------------------ what messages and the leak check see

def vault_file(lab: Path, name: str, text: str) -> None:
    password = (lab / "inventory" / ".vault-password").read_bytes().strip()
    (lab / "inventory" / "group_vars" / "all" / name).write_bytes(encrypt(text.encode(), password))


@pytest.mark.parametrize("var, value", [("ros_domain_id", "{{ api_token }}"), ("ansible_port", "{{ api_token }}"),
                                        ("ansible_user", "{{ api_token }};x")])
def test_a_message_about_a_bad_var_does_not_quote_the_vault_value(capsys: pytest.CaptureFixture, lab: Path,
                                                                  var: str, value: str) -> None:
    """The value is named as a var's (`got '********'`), whether copied or computed from the vault."""
    host_vars = lab / "inventory" / "host_vars" / "r1.yml"
    # `| list` was quoted one character at a time, which masking the secret's text could not catch
    for written in (value, value.replace("}}", "| upper }}"), value.replace("}}", "| list }}")):
        host_vars.write_text(yaml.safe_dump({var: written}))
        code, text = cli(capsys, lab, "validate")    # cli() asserts LAB_SECRET is not in the output
        assert code == 2 and var in text and "computed from vault var 'api_token'" in text, text
        assert "got '********' (a secret is never shown" in text, text
        assert SHOUTED not in text and "'u', 'n', 'i'" not in text and "'U', 'N', 'I'" not in text


def test_devices_computed_from_a_vault_var_are_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    group_vars(lab, devices={"motor": "/dev/{{ api_token | lower }}"})
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "devices comes from vault var 'api_token'" in text, text


@pytest.mark.parametrize("unused", ["ansible_become_password: robot", "door_pin: '1000'", "label: host"])
def test_a_vault_value_nothing_reads_is_not_searched_for(capsys: pytest.CaptureFixture, lab: Path,
                                                         unused: str) -> None:
    """A short vault value that no file reads ('1000', 'robot') used to be "written to compose.yml"
    wherever the same text stood (`user: "1000:1000"`, a comment naming the robot)."""
    vault_file(lab, "more_vault.yml", unused + "\n")
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    assert "secret value would be written" not in text


def test_a_vault_value_that_is_read_is_still_searched_for(capsys: pytest.CaptureFixture, lab: Path) -> None:
    """The text search stays for what is read: a vault var read when the inventory is loaded (the SSH
    user) and written as it is (the logs' home folder) is caught without following a template."""
    vault_file(lab, "more_vault.yml", "ansible_user: labsecretuser\n")    # logrotate.conf: /home/<user>/...
    code, text = cli(capsys, lab, "render")
    assert code == 2 and "secret value would be written to logrotate.conf" in text, text
