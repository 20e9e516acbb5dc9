"""Inventory values refused where they are written (probe S, round 11): a vars folder that is not a
folder, control characters written as escapes, strings past the renderer's bound, integers Python
will not read, and a known_hosts file that is not UTF-8."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import yaml

from rosdeploy import sandbox, transport, yamlsrc
from rosdeploy.errors import InputError
from rosdeploy.inventory import load_inventory
from test_hostile import cli, lab  # noqa: F401 - the fixture and its helper

HOSTS = "[lab]\nr1 ansible_host=127.0.0.1 ros_domain_id=1{extra}\nr2 ansible_host=127.0.0.2 ros_domain_id=2\n"


def problems(path: Path) -> list[str]:
    with pytest.raises(InputError) as raised:
        load_inventory(str(path))
    return [str(p) for p in raised.value.problems]


# ------------------------------------------------- 1. host_vars / group_vars that are not folders


def _make(kind: str, path: Path, saved: Path) -> None:
    if kind == "dangling":
        path.symlink_to(path.parent / "elsewhere_typo")
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "file":
        path.write_text(saved.read_text())
    else:   # a link to a regular file
        path.symlink_to(saved)


@pytest.mark.parametrize("folder", ["host_vars", "group_vars"])
@pytest.mark.parametrize("kind, said", [("dangling", "a symlink to"), ("fifo", "a FIFO"),
                                        ("file", "a regular file where"), ("link_to_file", "a regular file, where")])
def test_a_vars_folder_that_is_not_a_folder_is_refused(capsys: pytest.CaptureFixture, lab: Path,  # noqa: F811
                                                       folder: str, kind: str, said: str) -> None:
    """Skipped, the robots deployed without its vars (exit 0); now exit 2 naming the folder and what it is."""
    path = lab / "inventory" / folder
    saved = lab / "saved.yml"
    saved.write_text(yaml.safe_dump({"gpu": True}))
    os.rename(path, lab / f"{folder}.away")
    _make(kind, path, saved)
    code, text = cli(capsys, lab, "validate")
    assert code == 2, text
    line = next(line for line in text.splitlines() if f"inventory/{folder}:" in line)
    assert said in line and "vars would be lost" in line, line


def test_an_absent_vars_folder_is_still_fine(tmp_path: Path) -> None:
    (tmp_path / "hosts").write_text(HOSTS.format(extra=""))
    assert sorted(load_inventory(str(tmp_path / "hosts")).hosts) == ["r1", "r2"]


# ------------------------------------------------- 4. control characters written as escapes


@pytest.mark.parametrize("name, text, line, key", [
    ("hosts", HOSTS.format(extra=" zz=a\0b"), 2, "zz"),                           # a raw NUL in INI
    ("hosts", HOSTS.format(extra=""" zz='"a\\x00b"'"""), 2, "zz"),                  # a literal's escape
    ("hosts", HOSTS.format(extra="") + "[lab:vars]\nqq=x\0q\n", 5, "qq"),         # NUL in a [g:vars]
    ("hosts.json", '{"all": {"hosts": {\n"r1": {"ansible_host": "127.0.0.1",\n "zz": "a\\u0000b"}}}}', 3,
     "all.hosts.r1.zz"),
    ("hosts.yml", 'all:\n  hosts:\n    r1:\n      zz: "a\\0b"\n', 4, "all.hosts.r1.zz"),
], ids=["ini-raw-nul", "ini-literal", "ini-vars-nul", "json", "yaml-nul"])
def test_a_control_character_is_refused_where_it_is_written(tmp_path: Path, name: str, text: str, line: int,
                                                           key: str) -> None:
    (tmp_path / name).write_text(text)
    found = problems(tmp_path / name)
    assert any(f"{name}:{line}: {key}: holds a NUL byte (U+0000)" in p for p in found), found


def test_other_control_characters_in_a_var_load_as_in_ansible(tmp_path: Path) -> None:
    """`"\\e[1;32m"` in a motd, `"D:\\build"` (a backspace): Ansible takes them, and a var rosdeploy never
    reads must not fail the inventory; where one lands (an environment value) it is refused there."""
    (tmp_path / "hosts.yml").write_text('all:\n  hosts:\n    r1:\n      motd: "\\e[1;32m"\n      win: "D:\\build"\n')
    (host,) = load_inventory(str(tmp_path / "hosts.yml")).hosts.values()
    assert host.vars["motd"] == "\x1b[1;32m" and host.vars["win"] == "D:\build"


def test_a_control_character_in_a_vars_file_is_refused_at_its_line(tmp_path: Path) -> None:
    (tmp_path / "hosts").write_text(HOSTS.format(extra=""))
    (tmp_path / "host_vars").mkdir()
    (tmp_path / "host_vars" / "r1.yml").write_text('a: 1\nzz: "a\\0b"\n')
    found = problems(tmp_path / "hosts")
    assert any("r1.yml:2: zz: holds a NUL byte (U+0000)" in p for p in found), found


def test_the_fleet_file_keeps_its_own_control_character_check() -> None:
    """fleet.Reader.scan_control_chars names each fleet key once, in its own words."""
    assert yamlsrc.load("fleet.yml", 'x: "a\\0b"\n', warnings=[]).data == {"x": "a\0b"}


def test_tabs_and_line_breaks_written_as_escapes_stay_allowed(tmp_path: Path) -> None:
    (tmp_path / "hosts.yml").write_text('all:\n  hosts:\n    r1:\n      zz: "a\\tb\\nc\\r"\n      yy: "\\u00e9"\n')
    (host,) = load_inventory(str(tmp_path / "hosts.yml")).hosts.values()
    assert host.vars["zz"] == "a\tb\nc\r" and host.vars["yy"] == "é"


# ------------------------------------------------- 5. strings past the renderer's bound


def test_the_string_bound_is_the_renderers() -> None:
    assert yamlsrc.MAX_STRING == sandbox.MAX_LENGTH


@pytest.mark.parametrize("text, line, key", [
    ("a: 1\nzz: " + "x" * 1_000_001 + "\n", 2, "zz"),
    ("a: 1\nzz: '" + "x" * 1_000_001 + "'\r\n", 2, "zz"),
    ('{\n "a": 1,\n "zz": "' + "x" * 1_000_001 + '"\n}\n', 3, "zz"),
], ids=["plain", "quoted", "json"])
def test_a_huge_string_is_refused_at_its_line_before_it_is_parsed(monkeypatch: pytest.MonkeyPatch, text: str,
                                                                  line: int, key: str) -> None:
    """Found on its line: libyaml never holds it (a 64 MiB one cost near 300 MB)."""
    monkeypatch.setattr(yamlsrc.yaml, "parse", lambda *a, **k: pytest.fail("parsed"))
    with pytest.raises(InputError) as raised:
        yamlsrc.load("vars.json" if text.startswith("{") else "vars.yml", text)
    (problem,) = raised.value.problems
    assert (problem.line, problem.key) == (line, key)
    assert "a string of 1,000,001 characters, more than the 1,000,000" in problem.message


@pytest.mark.parametrize("head, line", [("a: 1\nzz: |\n", 2), ("all:\n  hosts:\n    r1:\n      zz: >-  # notes\n", 4)],
                         ids=["top", "nested"])
def test_a_huge_block_scalar_is_refused_at_its_key(head: str, line: int) -> None:
    indent = " " * (len(head.splitlines()[-1]) - len(head.splitlines()[-1].lstrip()) + 2)
    text = head + (indent + "x" * 98 + "\n") * 10_300 + "b: 2\n"
    with pytest.raises(InputError) as raised:
        yamlsrc.load("vars.yml", text)
    (problem,) = raised.value.problems
    assert problem.line == line and "more than the 1,000,000" in problem.message


def test_a_block_scalar_just_under_the_bound_with_crlf_is_read() -> None:
    """The parse counts the value itself: a CRLF file's line ends are no part of it."""
    text = "a: 1\r\nzz: |\r\n" + ("  " + "x" * 98 + "\r\n") * 10_000 + "b: 2\r\n"
    assert len(yamlsrc.load("vars.yml", text).data["zz"]) == 990_000


def test_a_vault_value_is_not_held_to_the_bound_by_its_ciphertext() -> None:
    text = "a: 1\nzz: !vault |\n" + ("  " + "3" * 80 + "\n") * 13_000
    assert yamlsrc.load("vars.yml", text).data["zz"].startswith("3" * 80)


def test_a_huge_string_the_line_check_cannot_judge_is_refused_as_it_is_parsed() -> None:
    with pytest.raises(InputError) as raised:
        yamlsrc.load("vars.yml", "a: 1\nzz: [" + "x" * 1_000_001 + ", b]\n")
    (problem,) = raised.value.problems
    assert (problem.line, problem.key) == (2, "zz") and "a string of 1,000,001 characters" in problem.message


def test_many_short_block_scalars_are_read() -> None:
    text = "".join(f"k{i}: |\n  {'x' * 60}\n" for i in range(16_000))    # 1.1 M characters
    assert len(yamlsrc.load("vars.yml", text).data) == 16_000


@pytest.mark.parametrize("text", [
    "zz: a #" + "x" * 1_100_000 + "\n",                  # a long comment
    'zz: "' + "\\x41" * 300_000 + '"\n',                 # 1.2 M characters written, 300,000 read
    "zz: [" + "abcdef," * 200_000 + "]\n",               # a long line of short values
], ids=["comment", "escapes", "flow"])
def test_a_long_line_of_short_values_is_read(text: str) -> None:
    assert yamlsrc.load("vars.yml", text).data["zz"]


# ------------------------------------------------- 6. integers of more than 4,300 digits


@pytest.mark.parametrize("path, text", [
    ("hosts.yml", "all:\n  hosts:\n    r1:\n      ros_domain_id: " + "7" * 5000 + "\n"),
    ("hosts.json", '{"all": {"hosts": {"r1": {\n"ros_domain_id": ' + "7" * 5000 + "}}}}"),
    ("fleet.yml", "project: lab\nx: -1_" + "7" * 5000 + "\n"),
], ids=["yaml", "json", "fleet"])
def test_a_huge_integer_is_said_in_our_words(path: str, text: str) -> None:
    with pytest.raises(InputError) as raised:
        yamlsrc.load(path, text)
    (problem,) = raised.value.problems
    assert problem.line is not None and problem.line > 1
    assert "an integer of 5,00" in problem.message and "more than Python reads (4,300)" in problem.message
    assert "sys." not in problem.message and "set_int_max_str_digits" not in problem.message


def test_a_huge_integer_in_an_ini_inventory_names_no_python_function(tmp_path: Path) -> None:
    (tmp_path / "hosts").write_text(HOSTS.format(extra="").replace("ros_domain_id=1", "ros_domain_id=" + "7" * 5000))
    found = problems(tmp_path / "hosts")
    assert any("hosts:2: ros_domain_id" in p and "5000 digits" in p for p in found), found
    assert not any("set_int_max_str_digits" in p for p in found)


# ------------------------------------------------- 9. a known_hosts file that is not UTF-8

KEY = "AAAAC3NzaC1lZDI1NTE5AAAAIOMqqnkVzrm0SdG6UOoqKLsabgH5C9okWi0dh2l9GKJl"


@pytest.mark.parametrize("encoding", ["utf-16", "utf-16-le", "utf-16-be"])
def test_a_utf16_known_hosts_is_refused_as_such(tmp_path: Path, encoding: str) -> None:
    path = tmp_path / "kh2"
    path.write_bytes(f"r1 ssh-ed25519 {KEY}\nr2 ssh-ed25519 {KEY}\n".encode(encoding))
    with pytest.raises(transport.UnusableKnownHosts) as raised:
        transport._parsed_host_keys(str(path))
    assert "not UTF-8 (it looks like UTF-16)" in str(raised.value) and str(path) in str(raised.value)
    assert "key type" not in str(raised.value)


def test_a_stray_byte_in_known_hosts_is_named_on_its_line(tmp_path: Path) -> None:
    path = tmp_path / "kh"
    path.write_bytes(f"r1 ssh-ed25519 {KEY}\nr\xe92 ssh-\xff {KEY}\n".encode("latin-1"))
    known = transport._parsed_host_keys(str(path))
    assert len(known.entries) == 1
    assert [(line, why) for line, _, why in known.skipped] == [
        (2, "holds a byte that is not UTF-8, skipped; save the file as UTF-8")]
    assert json.dumps(known.warnings)   # printable
