"""Hostile input sources (audit follow-up to issue 18): known_hosts files, dynamic inventory
scripts, YAML inventory keys and vars files. Every case is refused or skipped cleanly: the exit
code, the file (and key or line) named, no traceback or internal error, and a bounded time.

Cases that hung or filled memory before the fix run the CLI in a child process with a time
and memory limit, so a regression fails the test instead of hanging the suite.
"""
from __future__ import annotations

import json
import os
import random
import resource
import subprocess
import sys
import time
from pathlib import Path

import paramiko
import pytest

from rosdeploy.transport import MAX_KNOWN_HOSTS, parse_known_hosts
import test_hostile
from test_hostile import VAULT_CANARY, cli, edit

lab = test_hostile.lab      # fixtures: the example fleet copied, and real keys from ssh-keygen
keys = test_hostile.keys

RAW = "RAWBYTES-4f2a"      # inside a malformed known_hosts line: it must never be echoed back
LIMIT = 30.0               # seconds any of these cases may take


def unreachable(lab: Path, known_hosts: str) -> None:
    """ssh.known_hosts set, the keeper off, and every robot on port 1 (nothing listens: unreachable)."""
    edit(lab, lambda d: d.update(ssh={"known_hosts": known_hosts, "connect_timeout": "1s", "persist": 0}))
    inventory = lab / "inventory" / "group_vars" / "all" / "vars.yml"
    inventory.write_text(inventory.read_text() + "\nansible_port: 1\n")


def timed_cli(capsys: pytest.CaptureFixture, lab: Path, command: str, *argv: str) -> tuple[int, str]:
    started = time.monotonic()
    code, text = cli(capsys, lab, command, *argv)    # asserts: no traceback, internal error or secret
    assert time.monotonic() - started < LIMIT, text
    return code, text


def isolated(lab: Path, command: str, *argv: str) -> tuple[int, str]:
    """The CLI in a child process, stopped after LIMIT seconds and limited to 2 GB of memory."""
    def limit_memory() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))

    env = {k: v for k, v in os.environ.items() if not k.startswith("ROSDEPLOY_VAULT")}
    try:
        done = subprocess.run([sys.executable, "-m", "rosdeploy", command, str(lab / "fleet.yml"),
                               "--vault-password-file", str(lab / "inventory" / ".vault-password"), *argv],
                              cwd=lab, env=env, capture_output=True, text=True, errors="replace", timeout=LIMIT,
                              preexec_fn=limit_memory)
    except subprocess.TimeoutExpired:
        pytest.fail(f"`rosdeploy {command}` did not finish within {LIMIT:g} s")
    text = done.stdout + done.stderr
    assert "Traceback" not in text and "internal error" not in text, text
    return done.returncode, text


# ------------------------------------------------------------------ 1. known_hosts

NOISE = random.Random(18).randbytes(4096)   # random bytes: paramiko's error carried them all into the message


@pytest.mark.parametrize("bad", [f"127.0.0.1 ssh-ed25519 notbase64!!{RAW}".encode(),
                                 f"\x00\x01\xfe{RAW}\x1b[31m \x07 ssh-ed25519 ####".encode(),
                                 RAW.encode() + NOISE])
@pytest.mark.parametrize("json_out", [False, True])
def test_a_malformed_known_hosts_line_is_skipped_not_a_crash(capsys: pytest.CaptureFixture, lab: Path,
                                                             bad: bytes, json_out: bool) -> None:
    (lab / "kh").write_bytes(bad + b"\n")
    unreachable(lab, "./kh")
    code, text = timed_cli(capsys, lab, "status", *(["--json"] if json_out else []))
    assert code == 3, text            # unreachable robots, as with a clean known_hosts
    assert RAW not in text and "\x1b" not in text and "InvalidHostKey" not in text, text


def test_plain_keys_still_verify_beside_malformed_lines(keys: dict) -> None:
    lines = [f"127.0.0.1 ssh-ed25519 notbase64!!{RAW}", f"amr1 {' '.join(keys['host'])}",
             "\x00\xff garbage", f"[10.0.0.5]:2222 ssh-rsa AAAA{RAW}"]
    known = parse_known_hosts(lines, "kh")
    assert known.keys_for("amr1")
    assert any(w.startswith("kh:1: line(s) 1, 3, 4 skipped") for w in known.warnings), known.warnings
    assert not any(RAW in w for w in known.warnings)


def test_a_hashed_name_with_a_bad_salt_is_skipped_not_a_crash(keys: dict) -> None:
    # paramiko reads the salt only on lookup: every connection raised binascii.Error (internal error)
    good = paramiko.HostKeys.hash_host("amr2")
    lines = [f"|1|!!!notbase64|xx= {' '.join(keys['old'])}", f"{good} {' '.join(keys['host'])}",
             f"amr1 {' '.join(keys['host'])}"]
    known = parse_known_hosts(lines, "kh")
    assert known.keys_for("amr1") and known.keys_for("amr2")
    assert known.keys_for("amr3") == []
    assert any(w.startswith("kh:1: line(s) 1 skipped") for w in known.warnings), known.warnings


def test_a_big_known_hosts_is_not_copied_into_every_connection(keys: dict, monkeypatch: pytest.MonkeyPatch) -> None:
    # HostKeys.add scans every entry: adding a whole file was quadratic, and 20,000 lines took over 30 s
    # for each robot's connection. Now a connection gets the keys of its own name only.
    added: list[str] = []
    real_add = paramiko.HostKeys.add
    monkeypatch.setattr(paramiko.HostKeys, "add", lambda self, name, *rest: (added.append(name),
                                                                            real_add(self, name, *rest))[1])
    lines = [f"robot{i}.example {' '.join(keys['host'])}" for i in range(3000)]
    lines.append(f"{paramiko.HostKeys.hash_host('robot7.example')} {' '.join(keys['old'])}")
    known = parse_known_hosts(lines, "kh")
    assert added == []
    found = known.keys_for("robot7.example")
    assert added == []
    assert sorted(k.get_name() for k in found) == sorted([keys["host"][0], keys["old"][0]])


@pytest.mark.parametrize("kind", ["fifo", "dev-zero", "directory"])
def test_a_known_hosts_that_is_not_a_regular_file_is_refused(lab: Path, kind: str) -> None:
    path = lab / "kh"
    if kind == "fifo":
        os.mkfifo(path)                 # reading it waited for a writer, forever
    elif kind == "dev-zero":
        path.symlink_to("/dev/zero")    # read it all: 5 GB and a MemoryError after 37 s
    else:
        path.mkdir()
    unreachable(lab, "./kh")
    for command in ("validate", "status"):     # refused as the fleet file loads: no robot is asked
        code, text = isolated(lab, command, "--json")
        assert code == 2, text
        assert "ssh.known_hosts: " in text and f"{path} is not a regular file" in text, text


@pytest.mark.parametrize("command", ["validate", "status"])
def test_an_inventory_known_hosts_that_is_not_a_regular_file_is_an_input_error(lab: Path, command: str) -> None:
    os.mkfifo(lab / "kh-fifo")
    (lab / "kh").write_text("")
    unreachable(lab, "./kh")
    host_vars = lab / "inventory" / "host_vars" / "r2.yml"
    host_vars.write_text(f"rosdeploy_known_hosts: {lab / 'kh-fifo'}\n")
    code, text = isolated(lab, command)
    assert code == 2, text
    assert f"{host_vars}:1: rosdeploy_known_hosts: " in text and "not a regular file" in text, text


def test_a_known_hosts_past_the_size_bound_is_refused(lab: Path) -> None:
    path = lab / "kh"
    with path.open("wb") as handle:
        handle.truncate(MAX_KNOWN_HOSTS + 1)    # sparse: no disk used
    unreachable(lab, "./kh")
    code, text = isolated(lab, "status", "--json")
    assert code == 2, text
    assert "ssh.known_hosts: " in text and f"{path} is larger than 16 MB" in text, text


# ------------------------------------------------------------- 2. dynamic inventory

def script(lab: Path, body: str) -> str:
    path = lab / "dyn.sh"
    path.write_text(f"#!/bin/sh\n{body}\n")
    path.chmod(0o755)
    return str(path)


def printing(lab: Path, data: object) -> str:
    out = lab / "dyn.json"
    out.write_text(data if isinstance(data, str) else json.dumps(data))
    return script(lab, f"cat '{out}'")


def test_dynamic_inventory_nested_too_deeply(capsys: pytest.CaptureFixture, lab: Path) -> None:
    dyn = printing(lab, "[" * 100_000 + "]" * 100_000)
    code, text = timed_cli(capsys, lab, "validate", "-i", dyn)
    assert code == 2, text
    assert f"{dyn}: dynamic inventory script" in text and "nested too deeply" in text, text


def test_dynamic_inventory_nested_within_json_but_past_the_bound(capsys: pytest.CaptureFixture, lab: Path) -> None:
    deep: object = "x"
    for _ in range(500):           # json parses it; walking it later must not recurse 500 levels
        deep = {"a": deep}
    dyn = printing(lab, {"lab": {"hosts": ["r1"], "vars": {"deep": deep}}, "_meta": {"hostvars": {}}})
    code, text = timed_cli(capsys, lab, "validate", "-i", dyn)
    assert code == 2, text
    assert dyn in text and "nested too deeply" in text, text


GOOD_HOST = {"ansible_host": "127.0.0.1", "ros_domain_id": 1}


@pytest.mark.parametrize("data, key, words", [
    ({"lab": {"hosts": ["r1"]}, "_meta": {"hostvars": [1]}}, "_meta.hostvars", "mapping of host name"),
    ({"lab": {"hosts": ["r1"]}, "_meta": {"hostvars": {"r1": [1]}}}, "_meta.hostvars.r1", "must be a mapping"),
    ({"lab": {"hosts": ["r1"]}, "_meta": {"hostvars": {"r1": "x"}}}, "_meta.hostvars.r1", "must be a mapping"),
    ({"lab": {"hosts": ["r1"]}, "_meta": 5}, "_meta", "hostvars"),
    ({"lab": {"hosts": "r1"}, "_meta": {"hostvars": {"r1": GOOD_HOST}}}, "lab.hosts", "a list of host names"),
    ({"lab": {"hosts": {"r1": {}}}, "_meta": {"hostvars": {"r1": GOOD_HOST}}}, "lab.hosts", "a list of host names"),
    ({"lab": {"hosts": ["r1"], "children": "x"}, "_meta": {"hostvars": {"r1": GOOD_HOST}}}, "lab.children",
     "a list of group names"),
    ({"lab": {"hosts": ["r1"], "vars": [1]}, "_meta": {"hostvars": {"r1": GOOD_HOST}}}, "lab.vars",
     "a mapping of name: value"),
    ({"lab": ["r1", None], "_meta": {"hostvars": {"r1": GOOD_HOST}}}, "lab.hosts[1]", "host name null"),
    ({"lab": {"hosts": ["r1", 7]}, "_meta": {"hostvars": {"r1": GOOD_HOST}}}, "lab.hosts[1]", "host name 7"),
    ({"lab": {"hosts": ["r1", ["r2"]]}, "_meta": {"hostvars": {"r1": GOOD_HOST}}}, "lab.hosts[1]",
     "host name a list"),
    ({"lab": {"hosts": ["r1"], "children": [True]}, "_meta": {"hostvars": {"r1": GOOD_HOST}}}, "lab.children[0]",
     "group name true"),
])
def test_dynamic_inventory_output_of_the_wrong_shape(capsys: pytest.CaptureFixture, lab: Path, data: dict,
                                                     key: str, words: str) -> None:
    dyn = printing(lab, data)
    code, text = timed_cli(capsys, lab, "validate", "-i", dyn)
    assert code == 2, text
    assert f"{dyn}:1: {key}: " in text and words in text, text
    assert "robot 'None'" not in text and "'7'" not in text


def test_dynamic_inventory_never_sees_the_vault_password(capsys: pytest.CaptureFixture, lab: Path,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    password_file = lab / "pwfile-canary-31b7"
    password_file.write_text((lab / "inventory" / ".vault-password").read_text())
    monkeypatch.setenv("ROSDEPLOY_VAULT_PASSWORD_FILE", str(password_file))   # VAULT_CANARY: set by `lab`
    monkeypatch.setenv("CLOUD_API_TOKEN", "for-the-script")   # the rest of the environment is the script's
    dyn = script(lab, 'echo "pw=[$ROSDEPLOY_VAULT_PASSWORD] file=[$ROSDEPLOY_VAULT_PASSWORD_FILE] '
                      'api=[$CLOUD_API_TOKEN]" >&2; exit 1')
    code, text = timed_cli(capsys, lab, "validate", "-i", dyn)   # cli() asserts VAULT_CANARY is not shown
    assert code == 2, text
    assert f"{dyn}: dynamic inventory script: `dyn.sh --list` exited 1: pw=[] file=[] api=[for-the-script]" \
        in text, text
    assert VAULT_CANARY not in text and "pwfile-canary" not in text


def test_dynamic_inventory_stderr_is_quoted_short_and_on_one_line(capsys: pytest.CaptureFixture, lab: Path) -> None:
    dyn = script(lab, "i=0; while [ $i -lt 3000 ]; do echo \"line $i of noise\" >&2; i=$((i+1)); done; "
                      "printf 'last words\\033[2J\\n' >&2; exit 4")
    code, text = timed_cli(capsys, lab, "validate", "-i", dyn)
    assert code == 2, text
    line = next(x for x in text.splitlines() if "exited 4" in x)
    assert line.endswith("last words\\x1b[2J") and len(line) < 2500 and "line 0 of noise" not in text, line
    assert "\x1b" not in text


def test_dynamic_inventory_output_past_64_mb_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    dyn = script(lab, "printf '{\"lab\": {\"hosts\": [\"r1\"], \"vars\": {\"x\": \"'; "
                      "head -c 70000000 /dev/zero | tr '\\0' a; printf '\"}}}'")
    code, text = timed_cli(capsys, lab, "validate", "-i", dyn)
    assert code == 2, text
    assert f"{dyn}: dynamic inventory script: `dyn.sh --list` printed more than 64 MB" in text, text


# ---------------------------------------------------------------- 3. YAML inventory keys

HOSTS = "all:\n  children:\n    lab:\n      hosts:\n        r1: {ansible_host: 127.0.0.1, ros_domain_id: 1}\n"


@pytest.mark.parametrize("key, shown", [("~", "null"), ("1", "the number 1"), ("0x10", "the number 16"),
                                        ("1.5", "the number 1.5"), ("true", "the boolean true"),
                                        ("yes", "the boolean true"), ("2024-01-01", "a date")])
@pytest.mark.parametrize("what", ["host", "group"])
def test_yaml_host_and_group_names_must_be_strings(capsys: pytest.CaptureFixture, lab: Path, key: str, shown: str,
                                                    what: str) -> None:
    # Ansible 2.19's yaml plugin refuses them all: "Host pattern 1 must be a string. Enclose
    # integers/floats in quotation marks"; "Invalid group name supplied, expected a string".
    entry = (f"        {key}: {{ansible_host: 127.0.0.2, ros_domain_id: 2}}\n" if what == "host" else
             f"    {key}:\n      hosts: {{r2: {{ansible_host: 127.0.0.2, ros_domain_id: 2}}}}\n")
    (lab / "inventory" / "hosts.yml").write_text(HOSTS + entry)
    code, text = timed_cli(capsys, lab, "validate")
    assert code == 2, text
    assert "hosts.yml:6: " in text, text
    assert f"{what} name is {shown}" in text and "must be a string" in text and "quote it" in text, text
    assert "'None'" not in text and "'True'" not in text
    if key != "~":   # quoted, as the message says: a name like any other
        (lab / "inventory" / "hosts.yml").write_text(HOSTS + entry.replace(f"{key}:", f"'{key}':", 1))
        code, text = timed_cli(capsys, lab, "validate")
        assert code == 0, text


# ------------------------------------------------------------------- 4. vars files

@pytest.mark.parametrize("name", ["host_vars/r2.yml", "group_vars/all/zz.yml", "group_vars/lab.yaml"])
@pytest.mark.parametrize("kind, words", [("fifo", "not a regular file"), ("dev-zero", "not a regular file"),
                                         ("dev-urandom", "not a regular file"),
                                         ("dangling", "which does not exist")])
def test_vars_files_that_are_not_regular_files_are_refused(lab: Path, name: str, kind: str, words: str) -> None:
    path = lab / "inventory" / name
    path.parent.mkdir(parents=True, exist_ok=True)
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "dangling":
        path.symlink_to(lab / "nowhere.yml")
    else:
        path.symlink_to(f"/dev/{kind[4:]}")
    code, text = isolated(lab, "validate")
    assert code == 2, text
    assert f"{path}: " in text and words in text, text


# ------------------------------------------------------------- 5. host names that name folders

@pytest.mark.parametrize("form", ["yaml", "ini"])
def test_a_host_name_too_long_for_a_folder_is_refused_at_load(capsys: pytest.CaptureFixture, lab: Path,
                                                              form: str) -> None:
    name = "r" * 300        # passed validate and check, then render failed on "File name too long"
    if form == "yaml":
        hosts = lab / "inventory" / "hosts.yml"
        hosts.write_text(hosts.read_text().replace(
            "        r2:\n", f"        {name}:\n          ansible_host: 127.0.0.3\n          ros_domain_id: 3\n"
                             "        r2:\n"))
        argv: tuple[str, ...] = ()
    else:
        ini = lab / "robots.ini"
        ini.write_text(f"[lab]\nr1 ansible_host=127.0.0.1 ros_domain_id=1\n{name} ansible_host=1.2.3.4 "
                       "ros_domain_id=5\n")
        argv = ("-i", str(ini))
    for command in ("validate", "render"):
        code, text = cli(capsys, lab, command, *argv)
        assert code == 2 and "is 300 bytes long: at most 253" in text, text
    assert not (lab / "out").exists()
