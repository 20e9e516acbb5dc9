"""Probe L (eighth round): SSH-side inputs: jump hosts, known_hosts lines, key files, ssh config values.

Each test names the report's item; none needs the simulated fleet. The jump host tests run a
paramiko server (or a silent listener) in a thread on 127.0.0.1.
"""
from __future__ import annotations

import os
import socket
import subprocess
import threading
import time
from pathlib import Path
from typing import Any, Iterator

import paramiko
import pytest
import yaml

from rosdeploy import fleet, transport
from rosdeploy.errors import ConnectError, FleetSpecError, HostKeyError, InputError
from rosdeploy.model import Host
from rosdeploy.transport import SSHOptions, SSHTransport

K1 = "AAAAC3NzaC1lZDI1NTE5AAAAIF3PZyaHe/+IF0aoNVESTxMOYUUz/UjeBj/WAZRo1OOQ"


def robot(name: str = "robot1", address: str | None = None, port: int = 22, **vars: Any) -> Host:
    return Host(name, ("all",), vars, address or name, port=port, user="robot",
                key_file=vars.pop("key", None), key_file_var="ansible_ssh_private_key_file (inv.yml:7)")


def options(tmp_path: Path, config: str | None = None, known: str = "", timeout: float = 2.0) -> SSHOptions:
    (tmp_path / "known_hosts").write_text(known)
    if config is not None:
        (tmp_path / "ssh_config").write_text(config)
    return SSHOptions(known_hosts=str(tmp_path / "known_hosts"),
                      ssh_config=str(tmp_path / "ssh_config") if config is not None else None,
                      connect_timeout=timeout)


def closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def jump_server() -> Iterator[int]:
    """An sshd-like paramiko server on 127.0.0.1 whose host key is in no known_hosts file."""
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(4)
    key = paramiko.RSAKey.generate(1024)

    def serve() -> None:
        while True:
            try:
                sock, _ = listener.accept()
            except OSError:
                return
            server = paramiko.Transport(sock)
            server.add_server_key(key)
            try:
                server.start_server(server=paramiko.ServerInterface())
            except (paramiko.SSHException, EOFError, OSError):
                pass
    threading.Thread(target=serve, daemon=True).start()
    yield int(listener.getsockname()[1])
    listener.close()


def jumps(t: SSHTransport) -> list[Any]:
    """The jump host connections of a transport (ours, or fabric's gateway chain before the fix)."""
    if hasattr(t, "_hops"):
        return list(t._hops)
    out, gateway = [], t._conn.gateway
    while gateway and not isinstance(gateway, str):
        out.append(gateway)
        gateway = gateway.gateway
    return out


# ------------------------------------------------------------------ 1, 11

def test_1_a_jump_host_whose_key_is_unknown_stops_the_robot(tmp_path: Path, jump_server: int) -> None:
    # fabric's hop kept AutoAddPolicy: any jump host key was accepted, and it logged in
    config = f"Host robot1\n  HostName 127.0.0.1\n  Port 2201\n  ProxyJump robot@127.0.0.1:{jump_server}\n"
    opts = options(tmp_path, config, known=f"[127.0.0.1]:2201 ssh-ed25519 {K1}\n")
    t = SSHTransport(robot(), opts)
    hop = jumps(t)[0]
    assert isinstance(hop.client._policy, transport._RejectUnknown)
    with pytest.raises(HostKeyError) as raised:
        t.open()
    assert f"jump host [127.0.0.1]:{jump_server}" in raised.value.detail and "not in" in raised.value.detail


def test_11a_a_jump_host_that_never_answers_is_given_connect_timeout_not_15_s(tmp_path: Path) -> None:
    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(1)
    port = silent.getsockname()[1]
    opts = options(tmp_path, f"Host robot1\n  HostName 127.0.0.1\n  ProxyJump 127.0.0.1:{port}\n", timeout=1.0)
    started = time.monotonic()
    with pytest.raises(ConnectError) as raised:
        SSHTransport(robot(), opts).open()
    silent.close()
    assert time.monotonic() - started < 5, "paramiko's 15 s banner wait on the hop"
    assert "jump host" in raised.value.detail, raised.value.detail


@pytest.mark.parametrize("jump, hops", [("none", []), ("robot@127.0.0.1:2202", [("127.0.0.1", 2202)])])
def test_11b_proxyjump_none_is_no_hop_and_a_hop_at_the_robots_address_is_kept(tmp_path: Path, jump: str,
                                                                             hops: list) -> None:
    opts = options(tmp_path, f"Host robot1\n  HostName 127.0.0.1\n  Port 2201\n  ProxyJump {jump}\n")
    t = SSHTransport(robot(), opts)
    assert [(h.host, h.port) for h in jumps(t)] == hops
    assert all(isinstance(h.client._policy, transport._RejectUnknown) for h in jumps(t))


# ------------------------------------------------------------------ 2, 12, 14

def keys(tmp_path: Path, text: str, name: str = "[127.0.0.1]:2201") -> list:
    path = tmp_path / "kh"
    path.write_text(text)
    return transport._parsed_host_keys(str(path)).keys_for(name)


def test_2_a_commented_out_key_and_a_negated_pattern_are_not_trusted(tmp_path: Path) -> None:
    assert keys(tmp_path, f"# old key, removed\x0c[127.0.0.1]:2201 ssh-ed25519 {K1}\n") == []
    assert keys(tmp_path, f"# a\u2028[127.0.0.1]:2201 ssh-ed25519 {K1}\n") == []
    assert keys(tmp_path, f"[127.0.0.1]:2201,![127.0.0.1]:2201 ssh-ed25519 {K1}\n") == []
    assert keys(tmp_path, f"other,![127.0.0.2]:2201 ssh-ed25519 {K1}\n") == []
    notes = transport.known_hosts_warnings(str(tmp_path / "kh"))
    (tmp_path / "kh2").write_text("# a\x0cb\u2028c\nbroken line\n")
    assert transport.known_hosts_warnings(str(tmp_path / "kh2"))[0].startswith(f"{tmp_path / 'kh2'}:2: line(s) 2 ")
    assert notes == ()


def test_12_wildcards_in_known_hosts_match_as_in_openssh(tmp_path: Path) -> None:
    assert len(keys(tmp_path, f"[127.0.0.*]:2201 ssh-ed25519 {K1}\n")) == 1
    assert len(keys(tmp_path, f"[127.0.0.?]:2201 ssh-ed25519 {K1}\n")) == 1
    assert len(keys(tmp_path, f"[127.0.0.?]:2201 ssh-ed25519 {K1}\n", "[127.0.0.10]:2201")) == 0
    assert len(keys(tmp_path, f"ROBOT1 ssh-ed25519 {K1}\n", "robot1")) == 1


def test_14_skipped_lines_are_warned_when_the_key_is_found_and_a_symlink_loop_is_refused(tmp_path: Path) -> None:
    opts = options(tmp_path, known=f"[127.0.0.1]:2201 ssh-ed25519 {K1}\n@REVOKED x ssh-ed25519 {K1}\n"
                                   "@revoked x ssh-ed25519 !!!\nx ssh-ed448 AAAA\n")
    found = transport.known_hosts_problems([robot(address="127.0.0.1", port=2201)], opts)
    assert [(p.line, p.severity) for p in found] == [(2, "warning"), (3, "warning"), (4, "warning")], found
    assert "unknown marker" in found[0].message and "NOT revoked" in found[1].message
    assert "key type ssh-ed448" in found[2].message
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    assert "cannot be read" in (fleet.known_hosts_problem(str(loop)) or "")
    with pytest.raises(HostKeyError) as raised:
        SSHTransport(robot(), SSHOptions(known_hosts=str(loop)))
    assert "cannot be read" in raised.value.detail


# ------------------------------------------------------------------ 3, 8, 16

def key_error(tmp_path: Path, key: Path) -> str:
    opts = options(tmp_path, timeout=3.0)
    started = time.monotonic()
    with pytest.raises(ConnectError) as raised:
        transport.connect(robot(address="127.0.0.1", port=closed_port(), key=str(key)), opts)
    assert time.monotonic() - started < 2, "no retries, no hang"
    assert "tries within" not in raised.value.detail and str(key) in raised.value.detail
    return raised.value.detail


def test_3_a_fifo_or_device_as_key_file_is_refused_unread(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "fifo")
    assert "named pipe" in key_error(tmp_path, tmp_path / "fifo")
    assert "a device" in key_error(tmp_path, Path("/dev/zero"))
    config = f"Host robot1\n  HostName 127.0.0.1\n  Port {closed_port()}\n  IdentityFile {tmp_path / 'fifo'}\n"
    with pytest.raises(ConnectError) as raised:
        transport.connect(robot(), options(tmp_path, config))
    assert "IdentityFile" in raised.value.detail and "named pipe" in raised.value.detail


def test_8_a_directory_or_public_key_names_the_file_and_its_var(tmp_path: Path) -> None:
    (tmp_path / "keydir").mkdir()
    text = key_error(tmp_path, tmp_path / "keydir")
    assert "is a directory" in text and "ansible_ssh_private_key_file (inv.yml:7)" in text, text
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(tmp_path / "id")], check=True)
    assert "public key" in key_error(tmp_path, tmp_path / "id.pub")


def test_16_a_key_others_can_read_is_refused_as_openssh_does(tmp_path: Path) -> None:
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(tmp_path / "id")], check=True)
    (tmp_path / "id").chmod(0o644)
    text = key_error(tmp_path, tmp_path / "id")
    assert "UNPROTECTED PRIVATE KEY FILE" in text and "chmod 600" in text, text


# ------------------------------------------------------------------ 4, 9, 6, 7

@pytest.mark.parametrize("line", ["Port abc", "CanonicalizeHostname yes\n  CanonicalizeMaxDots x",
                                  "ProxyJump robot@127.0.0.1:abc"])
def test_4_ssh_config_values_fabric_crashed_on_are_input_errors_with_file_line(tmp_path: Path, line: str) -> None:
    opts = options(tmp_path, f"Host robot1\n  HostName 127.0.0.1\n  {line}\n")
    with pytest.raises(InputError) as raised:
        SSHTransport(robot(), opts)
    problem = raised.value.problems[0]
    assert problem.file == opts.ssh_config and problem.line in (3, 4), problem


@pytest.mark.parametrize("value", ["Yes", "/tmp/agent.sock"])
def test_4_forwardagent_as_openssh_takes_it_is_no_crash(tmp_path: Path, value: str) -> None:
    t = SSHTransport(robot(), options(tmp_path, f"Host robot1\n  HostName 127.0.0.1\n  ForwardAgent {value}\n"))
    assert t._conn.host == "127.0.0.1"


@pytest.mark.parametrize("port", ["99999", "0", "-1", "67737"])
def test_9_an_ssh_config_port_outside_1_to_65535_is_refused(tmp_path: Path, port: str) -> None:
    opts = options(tmp_path, f"Host robot1\n  HostName 127.0.0.1\n  Port {port}\n")
    with pytest.raises(InputError) as raised:
        SSHTransport(robot(), opts)
    assert (raised.value.problems[0].line, "Port") == (3, raised.value.problems[0].message[:4])


def test_6_include_is_followed_and_a_loop_is_an_error(tmp_path: Path) -> None:
    (tmp_path / "other.conf").write_text("Host robot1\n  HostName 127.0.0.1\n  Port 2201\n  User robot\n")
    opts = options(tmp_path, f"Include {tmp_path}/oth*.conf\nHost robot2\n  HostName 10.0.0.2\n")
    t = SSHTransport(robot(), opts)
    assert (t._conn.host, t._conn.port) == ("127.0.0.1", 2201)
    assert SSHTransport(robot("robot2"), opts)._conn.host == "10.0.0.2"     # back at the top level after it
    (tmp_path / "other.conf").write_text(f"Include {tmp_path}/ssh_config\n")
    with pytest.raises(InputError) as raised:
        SSHTransport(robot(), opts)
    assert "Include loop" in raised.value.problems[0].message, raised.value.problems


def test_7_an_explicit_ansible_port_22_wins_over_the_ssh_configs_port(tmp_path: Path) -> None:
    opts = options(tmp_path, "Host robot1\n  HostName 127.0.0.1\n  Port 2201\n")
    assert SSHTransport(robot(ansible_port=22), opts)._conn.port == 22
    assert SSHTransport(robot(), opts)._conn.port == 2201


# ------------------------------------------------------------------ 10

@pytest.mark.parametrize("text, line", [("$ANSIBLE_VAULT;1.1;AES256\n6133383335\n", 1),
                                        ("Host robot1\n  ProxyCommand\n", 2), ("Host robot1\n  Port abc\n", 2)])
def test_10_validate_refuses_the_ssh_config_status_refuses(tmp_path: Path, text: str, line: int) -> None:
    (tmp_path / "inv.yml").write_text("all: {hosts: {robot1: {ros_domain_id: 11}}}\n")
    (tmp_path / "ssh_config").write_text(text)
    doc = {"project": "probe", "inventory": "inv.yml", "registry": "registry.local:5000", "version": "1.0.0",
           "ssh": {"config": "ssh_config"}, "services": {"driver": {"image": "demo/driver"}}}
    (tmp_path / "fleet.yml").write_text(yaml.safe_dump(doc))
    with pytest.raises(FleetSpecError) as raised:
        fleet.load_fleet(tmp_path / "fleet.yml")
    assert f"ssh_config:{line}:" in str(raised.value.problems[0]), raised.value.problems


def test_a_user_config_that_is_a_symlink_loop_is_read_and_refused_not_skipped(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # os.path.exists() called the loop absent: rosdeploy went on without the user's config, silently
    monkeypatch.setenv("HOME", str(tmp_path))
    (tmp_path / ".ssh").mkdir()
    (tmp_path / ".ssh" / "config").symlink_to(tmp_path / ".ssh" / "config")
    assert str(tmp_path / ".ssh" / "config") in transport.ssh_config_paths(SSHOptions())
    (tmp_path / ".ssh" / "config").unlink()
    (tmp_path / ".ssh" / "config").symlink_to(tmp_path / "nowhere")      # dangling: none, as in OpenSSH
    assert str(tmp_path / ".ssh" / "config") not in transport.ssh_config_paths(SSHOptions())
