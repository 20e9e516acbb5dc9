"""Loading, eighth round: values no file can hold, non-finite numbers, connection vars computed
from a vault, JSON surrogate pairs, `<<` overrides, and inventory files read as Ansible reads them.

Each refusal is an input error (exit 2) at the file:line or key where the value is set, never an
internal error, and never quoting a vault value (cli() asserts both)."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import yaml

import test_hostile
from rosdeploy import yamlsrc
from rosdeploy.errors import InputError
from rosdeploy.inventory import load_inventory
from rosdeploy.vault import Vault, encrypt, encrypt_string
from test_hostile import cli, edit, set_env
from test_vault_taint import group_vars, vault_file

lab = test_hostile.lab      # the fixture: the example fleet copied

SECRET = "TOPSECRET-x-TOKEN"


def refused(capsys: pytest.CaptureFixture, lab: Path, *expect: str,
            commands: tuple[str, ...] = ("validate", "render")) -> str:
    text = ""
    for command in commands:
        code, text = cli(capsys, lab, command)
        assert code == 2, (command, text)
        for part in expect:
            assert part in text, (command, part, text)
        assert "TOPSECRET" not in text and "Traceback" not in text, text
        assert not (lab / "out").exists()
    return text


def encrypted(lab: Path, text: str) -> bytes:
    return encrypt(text.encode(), (lab / "inventory" / ".vault-password").read_bytes().strip())


# ------------------------------------------------------------- I1/I2: values no file can hold

def test_a_lone_surrogate_in_a_vault_ini_file_is_an_input_error_that_quotes_no_secret(
        capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "inventory" / "extra").write_bytes(encrypted(lab, '[lab:vars]\nextra_token="TOPSECRET-\\ud800-TOKEN"\n'))
    edit(lab, lambda d: d["services"]["bridge"]["secrets"].update(EXTRA=("extra_token")))
    refused(capsys, lab, "extra:2", "extra_token", "lone surrogate (U+D800", commands=("check",))
    code, text = cli(capsys, lab, "render", "--json")     # the JSON document quotes no secret either
    assert code == 2 and "U+D800" in text and "TOPSECRET" not in text, text


def test_a_jinja_escape_to_a_lone_surrogate_in_an_inventory_var_is_refused_at_the_var(
        capsys: pytest.CaptureFixture, lab: Path) -> None:
    group_vars(lab, cal='{{ "\\ud800" }}')
    edit(lab, set_env("{{ cal }}"))
    refused(capsys, lab, "vars.yml:", "lone surrogate (U+D800")


def test_a_jinja_escape_to_a_lone_surrogate_in_a_fleet_value_is_refused_at_its_key(
        capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, set_env('{{ "a\\udc80" }}'))
    refused(capsys, lab, "services.driver.environment.X", "lone surrogate (U+DC80")


def test_a_template_file_rendering_a_lone_surrogate_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "tpl").mkdir()
    (lab / "tpl" / "note.txt.j2").write_text('x: {{ "\\udc80" }}\n')
    edit(lab, lambda d: d.update(templates="./tpl"))
    refused(capsys, lab, "note.txt.j2", "lone surrogate")


@pytest.mark.parametrize("char", ["\ufffe", "\uffff", "\ufdd0", "\U0001fffe"])
def test_a_noncharacter_escape_in_the_fleet_file_is_refused_at_its_line(capsys: pytest.CaptureFixture, lab: Path,
                                                                         char: str) -> None:
    edit(lab, set_env(f"a{char}b"))     # safe_dump writes it as a "\uXXXX" escape, which libyaml reads
    refused(capsys, lab, "fleet.yml:", "services.driver.environment.X", f"noncharacter U+{ord(char):04X}",
            commands=("validate",))


def test_a_noncharacter_in_an_ini_value_or_a_jinja_escape_is_refused(capsys: pytest.CaptureFixture,
                                                                      lab: Path) -> None:
    (lab / "inventory" / "extra").write_text('[lab:vars]\nsite="a\\uffffb"\n')
    edit(lab, set_env("{{ site }}"))
    refused(capsys, lab, "extra:2", "site", "noncharacter U+FFFF", commands=("validate",))
    (lab / "inventory" / "extra").unlink()
    group_vars(lab, site="{{ 'x' ~ '\\ufffe' }}")
    refused(capsys, lab, "vars.yml:", "noncharacter U+FFFE", commands=("validate",))


def test_a_dynamic_inventory_printing_a_lone_surrogate_is_refused(capsys: pytest.CaptureFixture,
                                                                    lab: Path) -> None:
    script = lab / "inventory" / "dyn.py"
    output = '{"lab": {"hosts": ["r3"]}, "_meta": {"hostvars": {"r3": {"ansible_host": "127.0.0.3", ' \
             '"ros_domain_id": 3, "cal": "a\\ud800b"}}}}'
    script.write_text(f"#!/bin/sh\ncat <<'EOF'\n{output}\nEOF\n")
    script.chmod(0o755)
    refused(capsys, lab, "dyn.py", "_meta.hostvars.r3.cal", "lone surrogate", commands=("validate",))


def test_a_vault_inline_value_with_a_noncharacter_is_refused_at_its_line(lab: Path) -> None:
    vault = Vault(password_file=str(lab / "inventory" / ".vault-password"))
    (lab / "inventory" / "host_vars" / "r2.yml").write_text(encrypt_string("a\ufffeb", vault, "k"))
    with pytest.raises(InputError) as info:
        load_inventory(str(lab / "inventory"), vault)
    text = str(info.value)
    assert "r2.yml:1" in text and "U+FFFE" in text, text


# ------------------------------------------------------------- I3: non-finite numbers

@pytest.mark.parametrize("var", ["ansible_port", "ros_domain_id", "rosdeploy_deploy_root", "gpu"])
def test_an_infinite_literal_in_an_inventory_var_is_an_input_error_at_the_var(capsys: pytest.CaptureFixture,
                                                                              lab: Path, var: str) -> None:
    (lab / "inventory" / "host_vars" / "r1.yml").write_text(f'{var}: "{{{{ 1e400 }}}}"\n')
    text = refused(capsys, lab, "r1.yml:1", "not a finite number", commands=("validate",))
    assert "NameError" not in text


@pytest.mark.parametrize("value", ["{{ 1e400 }}", "{{ 1e400 * 0 }}", "{{ [1e400] | first }}"])
def test_an_infinite_literal_in_a_fleet_value_is_an_input_error(capsys: pytest.CaptureFixture, lab: Path,
                                                                 value: str) -> None:
    edit(lab, set_env(value))
    text = refused(capsys, lab, "services.driver.environment.X", "not a finite number", commands=("validate",))
    assert "NameError" not in text


def test_an_inventory_var_read_by_the_fleet_that_is_infinite_names_the_var(capsys: pytest.CaptureFixture,
                                                                            lab: Path) -> None:
    group_vars(lab, x="{{ 1e400 }}", y="{{ (10 ** 300) * 1.0e10 }}")
    edit(lab, set_env("{{ x }}"))
    refused(capsys, lab, "vars.yml:", "not a finite number", commands=("validate",))
    edit(lab, set_env("{{ y }}"))
    refused(capsys, lab, "vars.yml:", "not a finite number", commands=("validate",))


# ------------------------------------------------------------- K4: connection vars from a vault

@pytest.mark.parametrize("var, value", [
    ("ansible_host", "{{ api_token | upper }}.example"),
    ("ansible_port", "{{ api_token | length + 1000 }}"),
    ("ansible_ssh_private_key_file", "/nonexistent/{{ api_token | reverse | join }}"),
])
def test_a_connection_var_computed_from_a_vault_var_is_refused_at_load(capsys: pytest.CaptureFixture, lab: Path,
                                                                        var: str, value: str) -> None:
    (lab / "inventory" / "host_vars" / "r1.yml").write_text(yaml.safe_dump({var: value}))
    text = refused(capsys, lab, "r1.yml:1", var, "computed from vault var 'api_token'", commands=("validate",))
    assert "unit-test-token" not in text.lower() and "KOT-TSET" not in text


def test_a_connection_var_that_is_a_vault_value_as_it_is_stays_allowed(capsys: pytest.CaptureFixture,
                                                                        lab: Path) -> None:
    vault_file(lab, "conn.yml", "vault_host: 127.0.0.9\nansible_port: 2222\n")
    (lab / "inventory" / "host_vars" / "r1.yml").write_text('ansible_host: "{{ vault_host }}"\n')
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


# ------------------------------------------------------------- I6: JSON surrogate pairs

def test_a_json_file_with_escaped_surrogate_pairs_reads_as_json_does(tmp_path: Path) -> None:
    path = tmp_path / "all.json"
    path.write_text(json.dumps({"site": "Lab \U0001f600 \U0001d538", "raw": "\\ud83d\\ude00"}))
    assert "\\ud83d" in path.read_text()
    assert yamlsrc.load(path).data == {"site": "Lab \U0001f600 \U0001d538", "raw": "\\ud83d\\ude00"}
    path.write_text('{\n "site": "a \\ud83d b"\n}\n')       # a lone one stays refused, at its line
    with pytest.raises(InputError) as info:
        yamlsrc.load(path)
    assert info.value.problems[0].line == 2


def test_a_json_vars_file_with_an_emoji_loads(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "inventory" / "host_vars" / "r2.json").write_text(json.dumps({"site": "Lab \U0001f600"}))
    edit(lab, set_env("{{ site | default('none') }}"))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    assert "Lab \U0001f600" in (lab / "out" / "r2" / "compose.yml").read_text(encoding="utf-8")


# ------------------------------------------------------------- I12: `<<` overrides

def test_a_key_over_a_merged_one_overrides_it_and_a_real_duplicate_stays_an_error(tmp_path: Path) -> None:
    path = tmp_path / "f.yml"
    path.write_text("base: &b {restart: always, user: '1000:1000'}\n"
                    "svc:\n  <<: *b\n  image: x\n  restart: unless-stopped\n")
    doc = yamlsrc.load(path)
    assert doc.data["svc"] == {"restart": "unless-stopped", "user": "1000:1000", "image": "x"}
    assert doc.line(("svc", "restart")) == 5
    path.write_text("svc:\n  <<: {a: 1}\n  b: 2\n  b: 3\n")
    with pytest.raises(InputError) as info:
        yamlsrc.load(path)
    assert info.value.problems[0].line == 4 and "duplicate key" in str(info.value)


def test_a_fleet_file_overriding_a_merged_key_validates(capsys: pytest.CaptureFixture, lab: Path) -> None:
    path = lab / "fleet.yml"
    text = path.read_text().replace("    restart: always\n", "    restart: always\n    <<: &base {restart: always}\n")
    path.write_text(text.replace("  driver:\n", "  driver:\n"))
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


# ------------------------------------------------------------- I10: non-UTF-8 files

def test_a_non_utf8_vars_file_is_named_at_its_line(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "inventory" / "host_vars" / "r1.yml").write_bytes(b"gpu: true\nb: 2\nsite: caf\xe9\n")
    text = refused(capsys, lab, "r1.yml:3", "0xe9", commands=("validate",))
    assert "at byte" not in text


def test_a_utf16_inventory_file_says_so(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "inventory" / "extra").write_bytes("[lab]\nr3\n".encode("utf-16"))
    refused(capsys, lab, "extra:1", "UTF-16", commands=("validate",))


# ------------------------------------------------------------- I8: a NAME.yml/ folder

def test_a_group_vars_folder_named_like_a_file_is_read_as_ansible_reads_it(tmp_path: Path) -> None:
    (tmp_path / "hosts").write_text("[g]\nr1\n")
    (tmp_path / "group_vars" / "all.yml").mkdir(parents=True)
    (tmp_path / "group_vars" / "all.yml" / "a.yml").write_text("site: fromdir\n")
    (tmp_path / "host_vars" / "r1.yaml").mkdir(parents=True)
    (tmp_path / "host_vars" / "r1.yaml" / "c.yml").write_text("top: 1\n")
    inventory = load_inventory(str(tmp_path / "hosts"))
    host = inventory.hosts["r1"]
    assert host.vars["site"] == "fromdir" and host.vars["top"] == 1
    assert not inventory.warnings


# ------------------------------------------------------------- I9: IPv6 host names, ASCII ports

@pytest.mark.parametrize("line, hosts", [
    ("[::1]:2222", {"::1": 2222}),
    ("::1", {"::1": None}),
    ("fe80::1 ansible_port=22", {"fe80::1": 22}),
    ("[fe80::1]:2222", {"fe80::1": 2222}),
    ("fe80::1:22", {"fe80::1:22": None}),            # all address, as in Ansible
    ("fe80::[1:2]", {"fe80::1": None, "fe80::2": None}),
    ("r[01:02]:22", {"r01": 22, "r02": 22}),
])
def test_ini_ipv6_hosts_read_as_ansible_reads_them(tmp_path: Path, line: str, hosts: dict[str, int | None]) -> None:
    (tmp_path / "hosts").write_text(f"[a]\n{line}\n")
    inventory = load_inventory(str(tmp_path / "hosts"))
    assert {name: h.vars.get("ansible_port") for name, h in inventory.hosts.items()} == hosts


@pytest.mark.parametrize("line, expect", [
    ("robot1:\uff12\uff12", "invalid host name 'robot1:"),     # Ansible: a host name, not port 22
    ("-rf", "may not start with '-'"),
    ("[::1]", "invalid section header"),
])
def test_ini_host_names_ansible_reads_otherwise_are_refused_with_the_reason(tmp_path: Path, line: str,
                                                                             expect: str) -> None:
    (tmp_path / "hosts").write_text(f"[a]\nok1\n{line}\n")
    with pytest.raises(InputError) as info:
        load_inventory(str(tmp_path / "hosts"))
    assert expect in str(info.value) and "hosts:3" in str(info.value), str(info.value)


# ------------------------------------------------------------- I13: minor load differences

def test_unsafe_and_set_tags_on_collections_read_as_ansible_reads_them(tmp_path: Path) -> None:
    path = tmp_path / "hosts.yml"
    path.write_text('x:\n  a: !unsafe {k: "{{ y }}", z: [1, "{{ q }}"]}\n  s: !!set {p, q}\n')
    data = yamlsrc.load(path).data["x"]
    assert data == {"a": {"k": "{{ y }}", "z": [1, "{{ q }}"]}, "s": ["p", "q"]}
    assert isinstance(data["a"]["k"], yamlsrc.Unsafe) and isinstance(data["a"]["z"][1], yamlsrc.Unsafe)


def test_a_binary_value_is_refused_at_its_line_not_written_as_a_python_repr(tmp_path: Path) -> None:
    path = tmp_path / "v.yml"
    path.write_text("a: 1\nb: !!binary aGVsbG8=\n")
    with pytest.raises(InputError) as info:
        yamlsrc.load(path)
    assert info.value.problems[0].line == 2 and "!!binary" in str(info.value)


def test_a_json_file_with_a_syntax_error_is_called_invalid_json(tmp_path: Path) -> None:
    path = tmp_path / "v.json"
    path.write_text('{"a": [1, }\n')
    with pytest.raises(InputError) as info:
        yamlsrc.load(path)
    assert "invalid JSON" in str(info.value)


def test_a_vars_file_that_is_a_symlink_loop_is_called_a_loop(tmp_path: Path) -> None:
    (tmp_path / "hosts").write_text("[g]\nr1\n")
    (tmp_path / "host_vars").mkdir()
    (tmp_path / "host_vars" / "r1.yml").symlink_to("r1.yml")
    with pytest.raises(InputError) as info:
        load_inventory(str(tmp_path / "hosts"))
    assert "symlink loop" in str(info.value) and "does not exist" not in str(info.value)


def test_a_fifo_in_an_inventory_folder_is_not_called_a_yaml_file(tmp_path: Path) -> None:
    (tmp_path / "hosts").write_text("[g]\nr1\n")
    os.mkfifo(tmp_path / "extra")
    with pytest.raises(InputError) as info:
        load_inventory(str(tmp_path))
    assert "not a regular file" in str(info.value) and "a YAML file" not in str(info.value)
