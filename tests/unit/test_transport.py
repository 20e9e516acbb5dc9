"""SSHTransport setup without a network: what each robot's connection is built from."""
from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from rosdeploy.model import Host
from rosdeploy.transport import SSHOptions, SSHTransport, parsed_ssh_config


def test_robot_threads_share_the_parsed_ssh_config_but_never_one_fabric_config(tmp_path: Path) -> None:
    known = tmp_path / "known_hosts"
    known.write_text("")
    options = SSHOptions(known_hosts=str(known))
    parsed = parsed_ssh_config(options)
    hosts = [Host(f"r{i}", ("all",), {}, "127.0.0.1", port=2200 + i, user="robot") for i in range(50)]
    with ThreadPoolExecutor(max_workers=16) as pool:
        transports = list(pool.map(lambda h: SSHTransport(h, options), hosts))
    configs = {id(t._conn.config) for t in transports}
    assert len(configs) == len(hosts)
    assert all(t._conn.config.base_ssh_config is parsed for t in transports)   # parsed once
    assert [t._conn.port for t in transports] == [h.port for h in hosts]


def test_ssh_configs_port_is_used_unless_the_inventory_gives_one(tmp_path: Path) -> None:
    # a robot without ansible_port went to 22 whatever its `Port` in the ssh config said
    known, config = tmp_path / "known_hosts", tmp_path / "ssh_config"
    known.write_text("")
    config.write_text("Host amr1\n  HostName 127.0.0.1\n  Port 2311\n")
    options = SSHOptions(known_hosts=str(known), ssh_config=str(config))
    plain = SSHTransport(Host("amr1", ("all",), {}, "amr1"), options)
    given = SSHTransport(Host("amr1", ("all",), {}, "amr1", port=2200), options)
    other = SSHTransport(Host("amr2", ("all",), {}, "amr2"), options)
    assert (plain._conn.host, plain._conn.port, given._conn.port, other._conn.port) == ("127.0.0.1", 2311, 2200, 22)


def test_an_unknown_key_is_named_with_its_fingerprint_and_the_file_to_add_it_to(tmp_path: Path) -> None:
    # the message showed no fingerprint, and told to append to ~/.ssh/known_hosts whatever file was read
    import paramiko

    from rosdeploy.transport import UnknownHostKey, _RejectUnknown
    known = tmp_path / "fleet known_hosts"
    known.write_text("")
    offered = paramiko.Ed25519Key.from_private_key_file(_ed25519_key(tmp_path))
    with pytest.raises(UnknownHostKey) as caught:
        _RejectUnknown([]).missing_host_key(paramiko.SSHClient(), "[127.0.0.1]:2201", offered)
    assert caught.value.key is offered
    robot = SSHTransport(Host("r1", ("all",), {}, "127.0.0.1", port=2201), SSHOptions(known_hosts=str(known)))
    text = robot._unknown_key_message(caught.value.key)
    assert f"host key of [127.0.0.1]:2201 (it offered ssh-ed25519 {offered.fingerprint}) is not in {known}" in text
    assert f"`ssh-keyscan -p 2201 127.0.0.1 >> '{known}'`" in text, text


def _ed25519_key(folder: Path) -> str:
    import subprocess
    path = folder / "key"
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(path)], check=True)
    return str(path)


class _Flood:
    """A channel whose command prints without end (or an sshd that floods): always ready."""

    def __init__(self) -> None:
        self.closed = False
        self.received = 0

    def recv_ready(self) -> bool:
        return not self.closed

    def recv(self, n: int) -> bytes:
        self.received += n
        return b"y" * n

    def recv_stderr_ready(self) -> bool:
        return False

    def recv_stderr(self, n: int) -> bytes:
        return b""

    def close(self) -> None:
        self.closed = True


def test_a_command_without_end_is_stopped_past_the_output_cap(monkeypatch) -> None:
    # its output was kept whole: 1.8 GB in 8 s, then a MemoryError (an internal error)
    from rosdeploy import transport
    monkeypatch.setattr(transport, "MAX_OUTPUT", 1 << 20)
    chan = _Flood()
    with pytest.raises(transport.OutputTooLarge):
        transport._drain(chan, time.monotonic() + 30)   # type: ignore[arg-type]
    assert chan.closed and (1 << 20) < chan.received <= (1 << 20) + 65536


def test_ssh_failures_say_what_to_check(tmp_path: Path) -> None:
    # paramiko's own words ("No existing session", "Authentication failed.") named neither the
    # user nor the key, nor the timeout
    import paramiko
    robot = SSHTransport(Host("r1", ("all",), {}, "127.0.0.1", user="robot", key_file="/keys/r1"),
                         SSHOptions(known_hosts=str(tmp_path / "kh")))
    login = robot._why(paramiko.AuthenticationException("Authentication failed."))
    assert "login as 'robot' with /keys/r1): check ansible_user and ansible_ssh_private_key_file" in login
    assert "login as 'robot'" in robot._why(paramiko.SSHException("No authentication methods available"))
    assert "the SSH handshake did not finish within ssh.connect_timeout" in \
        robot._why(paramiko.SSHException("No existing session"))


def test_an_edited_ssh_config_is_read_again_by_a_process_that_lives_on(tmp_path: Path) -> None:
    # the connection keeper made a new connection for an edited config, but with the config as
    # it first parsed it: the robot's new HostName or Port was never used
    import os
    config = tmp_path / "ssh_config"
    config.write_text("Host amr1\n  HostName 127.0.0.1\n  Port 2311\n")
    options = SSHOptions(known_hosts=str(tmp_path / "known_hosts"), ssh_config=str(config))
    first = SSHTransport(Host("amr1", ("all",), {}, "amr1"), options)
    config.write_text("Host amr1\n  HostName 127.0.0.2\n  Port 2312\n")
    os.utime(config, ns=(0, os.stat(config).st_mtime_ns + 1_000_000))
    again = SSHTransport(Host("amr1", ("all",), {}, "amr1"), options)
    assert (first._conn.host, first._conn.port) == ("127.0.0.1", 2311)
    assert (again._conn.host, again._conn.port) == ("127.0.0.2", 2312)


def test_the_keepers_connection_changes_with_the_users_own_ssh_config(tmp_path: Path, monkeypatch) -> None:
    # without `ssh.config` in the fleet file, ~/.ssh/config is read, but editing it kept the old connection
    import os

    from rosdeploy import keeper
    monkeypatch.setenv("HOME", str(tmp_path))
    (tmp_path / ".ssh").mkdir()
    user_config = tmp_path / ".ssh" / "config"
    user_config.write_text("Host amr1\n  Port 2311\n")
    options = SSHOptions(known_hosts=str(tmp_path / "known_hosts"))
    host = Host("amr1", ("all",), {}, "amr1")
    before = keeper.connection_key(host, options)
    user_config.write_text("Host amr1\n  Port 2312\n")
    os.utime(user_config, ns=(0, os.stat(user_config).st_mtime_ns + 1_000_000))
    assert keeper.connection_key(host, options) != before
    assert SSHTransport(host, options)._conn.port == 2312
