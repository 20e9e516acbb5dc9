"""Getting commands and bytes to a robot: a narrow protocol and its SSH implementation.

`Transport` is all the deploy logic sees: run a Command, get a Result. The SSH
implementation uses fabric for what it is good at (ssh_config, ProxyJump
gateways, agent and key handling) and drives the paramiko channel itself for
exec, because a deploy is dozens of short commands per robot and hundreds of
robots at once: one connection per robot, no reader threads per command.

Host keys are always verified: fabric's default policy would add unknown keys;
we replace it with RejectPolicy before connecting.
"""
from __future__ import annotations

import base64
import binascii
import functools
import hmac
import getpass
import logging
import os
import random
import re
import select
import shlex
import socket
import stat
import threading
import time
from concurrent.futures import Future
from dataclasses import dataclass, replace
from typing import Callable, Iterable, Iterator, Mapping, Protocol, Sequence

import paramiko
from fabric import Config, Connection
from paramiko.pkey import UnknownKeyType

from rosdeploy import execwait
from rosdeploy.commands import Command
from rosdeploy.errors import ChannelRefused, CommandFailed, ConnectError, HostKeyError, InputError, Problem
from rosdeploy.fleet import MAX_KNOWN_HOSTS, BadSSHConfig, proxy_jump_hops, read_ssh_config
from rosdeploy.model import Host


# paramiko reports a dropped connection from its own threads through its loggers (with
# tracebacks); with no handler, Python's last-resort handler would print them into the
# progress output. The failed command reports the loss itself (ConnectError).
logging.getLogger("paramiko").addHandler(logging.NullHandler())

KEEPALIVE = 2.0       # s: an SSH keepalive after this long without traffic...
LINK_TIMEOUT = 6.0    # s: ...and the link counts as lost when nothing sent is acknowledged for this long
LINK_QUIET = 4.0      # s without a byte on a command's channel before asking whether the robot answers
EXEC_REPLY = LINK_QUIET + LINK_TIMEOUT   # s for sshd's reply to an exec request (execwait)


@dataclass(frozen=True)
class Result:
    command: str        # as shown to people: secrets masked by the caller's Output
    stdout: str
    stderr: str
    exited: int
    duration: float

    @property
    def ok(self) -> bool:
        return self.exited == 0


class Transport(Protocol):
    host: Host

    def run(self, command: Command) -> Result: ...

    def check(self, command: Command, what: str = "") -> Result:
        """run, raising CommandFailed on a non-zero exit."""
        ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class SSHOptions:
    known_hosts: str | None = None       # None: ~/.ssh/known_hosts
    ssh_config: str | None = None        # None: ~/.ssh/config when present
    connect_timeout: float = 10.0
    command_timeout: float = 600.0


def known_hosts_for(host: Host, options: SSHOptions) -> list[str]:
    """Known-hosts files to trust for a robot: the inventory's, else the fleet's, else the user's."""
    chosen = host.vars.get("rosdeploy_known_hosts") or options.known_hosts or "~/.ssh/known_hosts"
    files = [os.path.expanduser(str(chosen))]
    if os.path.exists("/etc/ssh/ssh_known_hosts"):
        files.append("/etc/ssh/ssh_known_hosts")
    return files


FABRIC_OVERRIDES = {"load_ssh_configs": True}


def ssh_config_paths(options: SSHOptions) -> list[str]:
    """The ssh configs read, as fabric reads them: the fleet's file, else the system's then the user's."""
    if options.ssh_config:
        return [os.path.expanduser(options.ssh_config)]
    return [p for p in ("/etc/ssh/ssh_config", os.path.expanduser("~/.ssh/config")) if _present(p)]


def _present(path: str) -> bool:
    """A default config to read: absent (or a dangling link) is none, as in OpenSSH; one that
    exists but cannot be read (a symlink loop, no permission) is read, and its error said, as
    OpenSSH refuses to run then. os.path.exists() called a loop absent, and it was skipped silently."""
    try:
        os.stat(path)
    except FileNotFoundError:
        return False
    except OSError:
        return True
    return True


def parsed_ssh_config(options: SSHOptions) -> paramiko.SSHConfig:
    """ssh_config parsed once per run, not once per robot; SSHConfig lookups only read it, so
    robot threads share it. The files' mtimes key the cache with the options: the connection
    keeper lives on, and an edited config (or a file it Includes) must be read again."""
    return _ssh_config(options)[0]


def ssh_config_files(options: SSHOptions) -> list[str]:
    """Every ssh config file read for these options, Included ones too (the keeper keys on their mtimes)."""
    try:
        return list(_ssh_config(options)[1])
    except (InputError, ConnectError):      # each robot's connection reports it
        return ssh_config_paths(options)


def _ssh_config(options: SSHOptions) -> tuple[paramiko.SSHConfig, tuple[str, ...]]:
    paths = ssh_config_paths(options)
    if options.ssh_config and not os.path.exists(paths[0]):
        raise ConnectError("ssh", f"ssh config {paths[0]} does not exist: fix `ssh.config` in the fleet file")
    stamps = tuple((p, mtime_ns(p)) for p in paths)
    config, read = _parsed_ssh_config(options, stamps)
    if any(mtime_ns(path) != stamp for path, stamp in read):     # an Included file was edited
        _parsed_ssh_config.cache_clear()
        config, read = _parsed_ssh_config(options, stamps)
    return config, tuple(path for path, _ in read)


def mtime_ns(path: str) -> int:
    try:
        return os.stat(path).st_mtime_ns
    except OSError:
        return 0


@functools.lru_cache(maxsize=8)
def _parsed_ssh_config(options: SSHOptions, stamps: tuple[tuple[str, int], ...],
                       ) -> tuple[paramiko.SSHConfig, tuple[tuple[str, int], ...]]:
    # each read bounded (fleet.read_ssh_config): a fifo, /dev/zero or a binary file must not hang,
    # fill memory or crash the run; the values fabric would crash on are refused there by file:line
    config = paramiko.SSHConfig()
    read: list[tuple[str, int]] = []
    for each, _ in stamps:
        try:
            text = read_ssh_config(each)
        except BadSSHConfig as exc:
            if exc.unreadable:
                raise ConnectError("ssh", f"ssh config {exc}") from None
            # an input error (exit 2), not an unreachable robot: no robot can be reached with this config
            raise InputError([Problem(exc.file, exc.line, "", exc.message)]) from None
        read += [(path, mtime_ns(path)) for path in text.files]
        lines = _Numbered(text.lines)
        try:
            config.parse(lines)
        except (paramiko.ssh_exception.ConfigParseError, ValueError):
            # paramiko's error quotes the line, which may be anything (a secret in a file named by mistake)
            why = "not an OpenSSH client config line (the line is not shown): fix it, or `ssh.config` in the fleet file"
            raise InputError([Problem(*text.origins[max(lines.number - 1, 0)], "", why)]) from None
    return config, tuple(read)


class _Numbered:
    """A config's lines, counted as paramiko reads them, so an error can name the line (and its file)."""

    def __init__(self, lines: Sequence[str]) -> None:
        self._lines = lines
        self.number = 0

    def __iter__(self) -> Iterator[str]:
        for line in self._lines:
            self.number += 1
            yield line


def fabric_config(options: SSHOptions) -> Config:
    """A Config of its own for each connection: fabric merges a Config in place while it
    connects, and robot threads sharing one saw it empty ("no config key found for
    'authentication'", at 100 robots)."""
    return Config(overrides=dict(FABRIC_OVERRIDES), ssh_config=parsed_ssh_config(options))


class KeyFileError(ConnectError):
    """A private key file that cannot be one: reported at once, never retried (it would not change)."""


MAX_KEY_FILE = 64 << 10     # bytes: an OpenSSH private key is a few KB (RSA 16384 bits: ~12 KB)
_PUBLIC_KEY = (b"ssh-", b"ecdsa-", b"sk-ssh-", b"sk-ecdsa-")


def key_file_problem(path: str) -> str | None:
    """Why `path` cannot be a private key file, or None (a missing one too: the caller decides).
    Opened without blocking (a fifo) and checked on the descriptor; at most 64 bytes are read."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0))
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as exc:
        return f"cannot be read ({exc.strerror}): check its permissions"
    try:
        info = os.fstat(fd)
        head = os.read(fd, 64) if stat.S_ISREG(info.st_mode) else b""
    finally:
        os.close(fd)
    if not stat.S_ISREG(info.st_mode):
        return f"is {_file_kind(info.st_mode)}, not a private key file"
    if info.st_size > MAX_KEY_FILE:
        return f"is larger than {MAX_KEY_FILE >> 10} KB: that is no private key"
    if path.endswith(".pub") or head.lstrip().startswith(_PUBLIC_KEY):
        return "is a public key: give the private key (the file without .pub)"
    if info.st_uid == os.getuid() and info.st_mode & 0o077:
        # as OpenSSH (and so Ansible) refuses it: others on this machine can read the key
        return (f"is an UNPROTECTED PRIVATE KEY FILE (mode {stat.S_IMODE(info.st_mode):04o}: others can read it); "
                f"OpenSSH refuses it too: run `chmod 600 {shlex.quote(path)}`")
    return None


def port_given(host: Host) -> bool:
    """Whether the inventory set the robot's port (ansible_port or ansible_ssh_port, not null), so
    that it wins over the ssh config's Port; a Host built without vars (the keeper's) by its value."""
    given = getattr(host, "port_given", None)
    if given is not None:
        return bool(given)
    return any(host.vars.get(var) is not None for var in ("ansible_port", "ansible_ssh_port")) or host.port != 22


def _endpoint(host: str, port: int) -> str:
    """The name paramiko looks a host key up by (SSHClient.connect), as in known_hosts."""
    return host if port == 22 else f"[{host}]:{port}"


def _trust(conn: Connection, files: list[KnownHosts]) -> None:
    """Make conn's client accept only the keys `files` list for it (never an unknown or @revoked one)."""
    name = _endpoint(conn.host, conn.port)      # after ssh_config's HostName and Port
    keys = _distinct(key for known in files for key in known.keys_for(name))
    policy = _RejectUnknown(files)
    if len({key.get_name() for key in keys}) == len(keys):
        for key in keys:
            conn.client.get_host_keys().add(name, key.get_name(), key)
    else:
        # paramiko keeps one key per type and name, so it would call a robot whose second
        # key of a type is listed "changed"; OpenSSH accepts any listed key: the policy does
        policy.listed[name] = keys
    conn.client.set_missing_host_key_policy(policy)


class SSHTransport:
    """One SSH connection to one robot, reused for every command of a run."""

    def __init__(self, host: Host, options: SSHOptions, config: Config | None = None) -> None:
        self.host = host
        self.options = options
        self._conn = self._connection(config or fabric_config(options))
        self._dialling = self._conn       # the connection being opened: the robot's or a jump host's
        # False: a dropped connection is not opened again by the next command (a deploy
        # that lost its robot mid-step must not carry on over a new one)
        self.reconnect = True

    def _connection(self, config: Config) -> Connection:
        kwargs: dict = {}
        if self.host.key_file:
            kwargs["key_filename"] = [os.path.expanduser(self.host.key_file)]
        # an explicit ansible_port, 22 included, wins over the ssh config's Port (Ansible passes -o Port=)
        conn = self._client(self.host.address, self.host.user, self.host.port if port_given(self.host) else None,
                            config, kwargs)
        self._hops = self._jump_hosts(conn, config)
        if "proxyjump" not in conn.ssh_config and conn.ssh_config.get("proxycommand"):
            conn.gateway = conn.ssh_config["proxycommand"]      # fabric runs it, as it did
        try:
            files = [_parsed_host_keys(path) for path in known_hosts_for(self.host, self.options)]
        except UnusableKnownHosts as exc:
            raise HostKeyError(self.host.name, f"{exc}: {self._known_hosts_setting(exc.path)}") from exc
        for each in (*self._hops, conn):     # a jump host is verified exactly as the robot is
            _trust(each, files)
        return conn

    def _client(self, address: str, user: str | None, port: int | None, config: Config, kwargs: dict) -> Connection:
        """A fabric Connection without fabric's gateway (see _jump_hosts) nor agent forwarding
        (rosdeploy opens its channels itself, so ForwardAgent never applied; `ForwardAgent Yes`
        was a KeyError in fabric). The banner wait is bounded by connect_timeout too: through a
        jump host, paramiko's own 15 s applied."""
        timeout = int(self.options.connect_timeout) or None
        return Connection(address, user=user, port=port, config=config, gateway=False, forward_agent=False,
                          connect_timeout=timeout, connect_kwargs={**kwargs, "banner_timeout": timeout})

    def _jump_hosts(self, conn: Connection, config: Config) -> list[Connection]:
        """ProxyJump's hosts, first hop first, built here: fabric's hops kept fabric's auto-add policy (any
        jump host key was accepted), had no connect timeout, were dropped when a hop had the robot's
        address and made `ProxyJump none` a host called "none". A hop's own ProxyJump is not followed."""
        try:
            hops = proxy_jump_hops(conn.ssh_config.get("proxyjump") or "none")
        except ValueError as exc:       # checked when the config was read; %h and the like expand later
            raise ConnectError(self.host.name, f"ssh config ProxyJump: {exc}") from None
        return [self._client(host, user, port, config.clone(), {}) for user, host, port in hops]

    @property
    def endpoint(self) -> str:
        port = self._conn.port
        return self._conn.host if port == 22 else f"[{self._conn.host}]:{port}"

    @property
    def link(self) -> paramiko.Transport | None:
        """The paramiko transport under the connection (images.via ssh forwards a port through it)."""
        return self._conn.transport

    def open(self) -> "SSHTransport":
        self._check_key_files()
        self._dialling = self._conn
        try:
            sock = self._open_hops()
            self._dialling = self._conn
            self._conn.connect_kwargs.pop("sock", None)
            if sock is not None:
                self._conn.connect_kwargs["sock"] = sock
            self._conn.open()
            _no_delay(self._conn.client.get_transport())
            _keepalive(self._conn.client.get_transport())
        except paramiko.BadHostKeyException as exc:
            raise HostKeyError(self.host.name, self._changed_key_message(exc)) from exc
        except RevokedHostKey as exc:
            raise HostKeyError(self.host.name, f"host key of {self._where()} is REVOKED: {exc}; rosdeploy "
                                               "refuses it. Replace the robot's host key") from exc
        except paramiko.SSHException as exc:
            if "not found in known_hosts" in str(exc):
                raise HostKeyError(self.host.name, self._unknown_key_message(getattr(exc, "key", None),
                                                                             self._dialling)) from exc
            raise ConnectError(self.host.name, f"SSH to {self._where()} failed: {self._why(exc)}") from exc
        except (socket.timeout, TimeoutError) as exc:
            raise ConnectError(self.host.name, f"unreachable: no answer from {self._where()} within "
                                               f"{self.options.connect_timeout:g}s (ssh.connect_timeout)") from exc
        except OSError as exc:
            raise ConnectError(self.host.name, f"unreachable: {self._where()}: {exc.strerror or exc}") from exc
        except UnicodeError as exc:    # the resolver's IDNA codec: a name known only now (`HostName %h..x`)
            raise ConnectError(self.host.name, f"{self._where()} is not a valid host name ({exc}): fix its "
                                               "ansible_host, or the ssh config's HostName/ProxyJump") from exc
        return self

    def _open_hops(self) -> paramiko.Channel | None:
        """Each ProxyJump host over the one before it, each verified as the robot is (_trust);
        the channel from the last one to the robot, or None without jump hosts."""
        sock = None
        for hop, after in zip(self._hops, [*self._hops[1:], self._conn][:len(self._hops)], strict=True):
            hop.close()                  # a reconnect builds the chain afresh
            hop.connect_kwargs.pop("sock", None)
            if sock is not None:
                hop.connect_kwargs["sock"] = sock
            self._dialling = hop
            hop.open()
            try:
                sock = hop.transport.open_channel("direct-tcpip", (after.host, int(after.port)), ("", 0),
                                                  timeout=self.options.connect_timeout)
            except paramiko.ChannelException as exc:
                raise ConnectError(self.host.name, f"unreachable: {self._where()} could not connect "
                                                   f"to {_endpoint(after.host, after.port)}: {exc.text}") from exc
        return sock

    def _where(self) -> str:
        """The host being dialled, for a message: the robot, or which jump host."""
        conn = self._dialling
        where = _endpoint(conn.host, conn.port)
        return where if conn is self._conn else f"jump host {where} (ProxyJump, for {self.endpoint})"

    def _why(self, exc: paramiko.SSHException) -> str:
        """paramiko's words, and what to check: its own ("No existing session") say neither."""
        user = self._conn.user
        key = self.host.key_file or "ssh-agent and ~/.ssh/id_*"
        if isinstance(exc, paramiko.AuthenticationException) or "No authentication methods" in str(exc):
            return (f"{exc} (login as {user!r} with {key}): check ansible_user and "
                    "ansible_ssh_private_key_file, and that the key is in the robot's authorized_keys")
        if "No existing session" in str(exc) or "Error reading SSH protocol banner" in str(exc):
            return (f"{exc}: the SSH handshake did not finish within ssh.connect_timeout; check that sshd "
                    "answers on that port (or the ssh config's ProxyCommand/ProxyJump)")
        return str(exc)

    def _check_key_files(self) -> None:
        """Key files are checked before paramiko reads them, whole and unbounded: a fifo hung the
        run past connect_timeout, /dev/zero filled memory, a directory or a .pub file was "unreachable"
        or a bare paramiko error naming neither the file nor where it was set. OpenSSH skips a
        missing IdentityFile of the ssh config, and so do we; a missing ansible_ssh_private_key_file
        is an error (its var named)."""
        if self.host.key_file:
            key = os.path.expanduser(self.host.key_file)
            why = key_file_problem(key) or (None if os.path.lexists(key) else "does not exist")
            if why:
                raise KeyFileError(self.host.name, f"SSH key file {key} {why}; it is set by "
                                   f"{self.host.key_file_var or 'ansible_ssh_private_key_file'}: fix the path "
                                   "(a relative one is taken from the working directory, as in Ansible; write "
                                   "'{{ inventory_dir }}/...' for one beside the inventory)")
        for conn in (*self._hops, self._conn):
            given = self.host.key_file if conn is self._conn else None
            self._check_identity_files(conn, [os.path.expanduser(given)] if given else [])

    def _check_identity_files(self, conn: Connection, explicit: list[str]) -> None:
        """The ssh config's IdentityFiles of one connection: a missing one is dropped (paramiko's
        FileNotFoundError was "unreachable"), one that cannot be a key is an error naming it."""
        configured = [k for k in conn.connect_kwargs.get("key_filename", []) if k not in explicit]
        for key in configured:
            why = key_file_problem(os.path.expanduser(key))
            if why:
                raise KeyFileError(self.host.name, f"SSH key file {key} {why}; it is an IdentityFile of the ssh "
                                   f"config ({', '.join(ssh_config_files(self.options))}) for "
                                   f"{_endpoint(conn.host, conn.port)}: fix or remove that line")
        kept = [*explicit, *(k for k in configured if os.path.lexists(os.path.expanduser(k)))]
        conn.connect_kwargs.pop("key_filename", None)
        if kept:
            conn.connect_kwargs["key_filename"] = kept

    def _known_hosts_setting(self, path: str) -> str:
        """What to fix for a known_hosts file that cannot be used, by where it was chosen."""
        if self.host.vars.get("rosdeploy_known_hosts"):
            where = "the inventory's `rosdeploy_known_hosts` for this robot"
        elif self.options.known_hosts:
            where = "`ssh.known_hosts` in the fleet file"
        else:
            where = ""
        if where and path == os.path.expanduser(str(self.host.vars.get("rosdeploy_known_hosts")
                                                     or self.options.known_hosts)):
            return f"point {where} at a known_hosts file (a regular file of host keys)"
        return f"replace {path} with a regular known_hosts file of host keys, or remove it"

    def _changed_key_message(self, exc: paramiko.BadHostKeyException) -> str:
        paths = known_hosts_for(self.host, self.options)
        return (f"HOST KEY CHANGED for {self._where()}: it offered {exc.key.get_name()} "
                f"{exc.key.fingerprint} but {', '.join(paths)} expects {exc.expected_key.fingerprint}. "
                f"This can be an attack; if the robot was reinstalled, verify the new key and run "
                f"`ssh-keygen -f {shlex.quote(paths[0])} -R '{_endpoint(self._dialling.host, self._dialling.port)}'` "
                "then add the new key.")

    def _unknown_key_message(self, offered: paramiko.PKey | None, conn: Connection | None = None) -> str:
        """`conn`: the robot's connection (the default) or the jump host whose key is unknown."""
        conn = conn or self._conn
        paths = known_hosts_for(self.host, self.options)
        skipped = " ".join(w for path in paths for w in known_hosts_warnings(path))
        key = f" (it offered {offered.get_name()} {offered.fingerprint})" if offered is not None else ""
        what = _endpoint(conn.host, conn.port) if conn is self._conn else self._where()
        return (f"host key of {what}{key} is not in {', '.join(paths)}; rosdeploy never trusts an "
                f"unknown key. Verify the robot's fingerprint, then add it (e.g. `ssh-keyscan -p {conn.port} "
                f"{conn.host} >> {shlex.quote(paths[0])}`) or point `rosdeploy_known_hosts` at a file that "
                "has it." + (f" Note: {skipped}" if skipped else ""))

    def run(self, command: Command) -> Result:
        """Run one command; a non-zero exit is a Result, not an exception (see `check`)."""
        if not self._conn.is_connected:
            if not self.reconnect and self._conn.transport is not None:
                raise ConnectError(self.host.name, f"connection lost before `{command.display()}`")
            self.open()
        started = time.monotonic()
        timeout = command.timeout or self.options.command_timeout
        try:
            chan = self._conn.transport.open_session(timeout=self.options.connect_timeout)
        except (paramiko.SSHException, OSError, EOFError) as exc:
            raise ChannelRefused(self.host.name, f"connection lost before `{command.display()}`: {exc}") from exc
        try:
            answers = functools.partial(_answers, self._conn.transport)
            with execwait.bounded(chan, min(timeout, EXEC_REPLY)):
                chan.exec_command(command.wire())
            if command.stdin is not None:
                _send(chan, command.stdin, started + timeout, answers)
                chan.shutdown_write()
            out, err = _drain(chan, started + timeout, answers)
            code = chan.recv_exit_status()
            if code == -1 and not self._conn.transport.is_active():
                raise EOFError("the SSH connection dropped")
        except execwait.NoReply as exc:
            raise ConnectError(self.host.name, f"connection lost during `{command.display()}`: sshd did not "
                                               f"answer the request to run it ({exc})") from exc
        except TimeoutError as exc:
            raise ConnectError(self.host.name, f"`{command.display()}` timed out after {timeout:g}s") from exc
        except OutputTooLarge as exc:
            raise ConnectError(self.host.name, f"`{command.display()}` printed more than {MAX_OUTPUT >> 20} MB: "
                                               "stopped; no rosdeploy command prints that much, so check what "
                                               "answers on this robot's SSH port") from exc
        except (paramiko.SSHException, OSError, EOFError) as exc:
            raise ConnectError(self.host.name, f"connection lost during `{command.display()}`: {exc}") from exc
        return Result(command.display(), out, err, code, time.monotonic() - started)

    def check(self, command: Command, what: str = "") -> Result:
        return succeeded(self.host, self.run(command), what or command.display())

    def close(self) -> None:
        self._conn.close()
        for hop in reversed(self._hops):     # fabric never closed its gateway hops
            hop.close()


def succeeded(host: Host, result: Result, what: str) -> Result:
    """Transport.check's verdict on a result: itself, or CommandFailed on a non-zero exit."""
    if not result.ok:
        raise CommandFailed(host.name, result, what)
    return result


def _no_delay(transport: paramiko.Transport | None) -> None:
    """Send each small SSH packet at once: without it every command waits on a delayed
    ACK (measured: 45-49 ms per command on an open connection, 3-4 ms with it)."""
    sock = getattr(transport, "sock", None)
    if isinstance(sock, socket.socket):
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)


def _keepalive(transport: paramiko.Transport | None) -> None:
    """Notice a silently dropped link (Wi-Fi gone, robot powered off) within seconds, not at
    the command's timeout: keepalives keep data in flight, and the kernel gives up on the
    connection when none of it is acknowledged for LINK_TIMEOUT."""
    if transport is None:
        return
    transport.set_keepalive(int(KEEPALIVE))
    sock = getattr(transport, "sock", None)
    if isinstance(sock, socket.socket) and hasattr(socket, "TCP_USER_TIMEOUT"):
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_USER_TIMEOUT, int(LINK_TIMEOUT * 1000))


class UnknownHostKey(paramiko.SSHException):
    """The robot's key is in no known_hosts file; `key` is the one it offered."""

    def __init__(self, message: str, key: paramiko.PKey) -> None:
        super().__init__(message)
        self.key = key


class RevokedHostKey(paramiko.SSHException):
    """The robot offered a key a known_hosts file marks `@revoked`."""


@dataclass(frozen=True)
class KnownHosts:
    """One known_hosts file as rosdeploy trusts it.

    paramiko cannot verify host certificates: it never asks a server for a certificate host
    key type (its client offers plain key types only) and its HostKeys parser raises
    InvalidHostKey on an `@cert-authority` line, which stopped `status` for the whole fleet
    (issue 18). So `@cert-authority` lines are skipped with a warning and the plain keys in
    the file are verified as always; `@revoked` keys are never trusted, and a robot that
    offers one is refused by name rather than reported unknown.
    """

    entries: tuple[tuple[str, paramiko.PKey], ...]    # (host names field: patterns, or one `|1|` hash; key)
    plain: Mapping[str, tuple[int, ...]]              # a plain name (lower case) -> its entries
    hashed: tuple[int, ...]                           # the entries of hashed names
    patterned: tuple[int, ...]                        # entries with a `*`, `?` or `!` pattern
    revoked: frozenset[tuple[str, bytes]]             # (key type, key blob)
    path: str = ""
    skipped: tuple[tuple[int, str, str], ...] = ()    # (line, kind, why it was skipped): every skipped line

    @property
    def notes(self) -> tuple[tuple[int, str], ...]:
        """The skipped lines grouped by kind: one note each (a HostKeyError's message)."""
        kinds = {kind: [n for n, k, _ in self.skipped if k == kind] for kind in ("authority", "unreadable", "revoked")}
        return _notes(kinds["authority"], kinds["unreadable"], kinds["revoked"])

    @property
    def warnings(self) -> tuple[str, ...]:
        return tuple(f"{self.path}:{line}: {note}" if line else f"{self.path}: {note}" for line, note in self.notes)

    def keys_for(self, name: str) -> list[paramiko.PKey]:
        """Every key listed for `name`, in file order. Looked up for the one name, never through a
        HostKeys of the whole file: its add() scans every entry, so 20,000 lines took over 30 s
        for every robot's connection. Names match without regard to case, as in OpenSSH."""
        name = name.lower()
        found = [i for i in self.hashed if hmac.compare_digest(paramiko.HostKeys.hash_host(name, self.entries[i][0]),
                                                               self.entries[i][0])]
        found += [i for i in self.patterned if _host_matches(name, self.entries[i][0])]
        return [self.entries[i][1] for i in sorted({*self.plain.get(name, ()), *found})]


def _host_matches(name: str, field: str) -> bool:
    """OpenSSH's match_hostname: `*` and `?` wildcards; a negated pattern that matches excludes
    the line whatever else matches (`[a]:22,![a]:22` is no line for a)."""
    positive = False
    for pattern in field.lower().split(","):
        negated = pattern.startswith("!")
        if _wildcard(pattern[negated:]).fullmatch(name):
            if negated:
                return False
            positive = True
    return positive


@functools.lru_cache(maxsize=4096)
def _wildcard(pattern: str) -> re.Pattern[str]:
    # not fnmatch: `[` is a character class there, and every `[host]:port` would be one
    return re.compile("".join(".*" if c == "*" else "." if c == "?" else re.escape(c) for c in pattern), re.DOTALL)


def _distinct(keys: Iterable[paramiko.PKey]) -> list[paramiko.PKey]:
    """The keys without repeats: the same line in two files is one key."""
    seen: dict[tuple[str, bytes], paramiko.PKey] = {}
    for key in keys:
        seen.setdefault((key.get_name(), key.asbytes()), key)
    return list(seen.values())


class _RejectUnknown(paramiko.MissingHostKeyPolicy):
    """paramiko's RejectPolicy, naming a revoked key as revoked."""

    def __init__(self, files: list[KnownHosts]) -> None:
        self.revoked = frozenset().union(*(f.revoked for f in files))
        self.listed: dict[str, list[paramiko.PKey]] = {}    # names with two keys of one type

    def missing_host_key(self, client: paramiko.SSHClient, hostname: str, key: paramiko.PKey) -> None:
        offered = (key.get_name(), key.asbytes())
        if offered in self.revoked:
            raise RevokedHostKey(f"it offered {key.get_name()} {key.fingerprint}, marked @revoked in known_hosts")
        listed = self.listed.get(hostname, [])
        if any((k.get_name(), k.asbytes()) == offered for k in listed):
            return
        if listed:
            same_type = [k for k in listed if k.get_name() == key.get_name()]
            raise paramiko.BadHostKeyException(hostname, key, (same_type or listed)[0])
        raise UnknownHostKey(f"Server {hostname!r} not found in known_hosts", key)




class UnusableKnownHosts(Exception):
    """A known_hosts file that is not a regular file, or too big to be one: refused, never read."""

    def __init__(self, path: str, message: str) -> None:
        self.path = path
        super().__init__(f"known_hosts file {path} {message}")


@functools.lru_cache(maxsize=32)
def _host_keys_file(path: str, mtime_ns: int) -> KnownHosts:
    # lines end at \n only, as OpenSSH reads them: str.splitlines() also broke at \x0c, \x85 or
    # \u2028, and the rest of a commented-out line became a trusted key
    return parse_known_hosts([line.removesuffix("\r") for line in _read_known_hosts(path).split("\n")], path)


def _read_known_hosts(path: str) -> str:
    """The file's text, read only when it is a regular file of at most MAX_KNOWN_HOSTS bytes: a
    fifo would hang the run and /dev/zero fill its memory. Opened without blocking (a fifo with
    no writer) and checked on the open descriptor, so a file swapped after a stat is caught too."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0))
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise UnusableKnownHosts(path, f"is {_file_kind(mode)}, not a regular file")
        chunks: list[bytes] = []
        size = 0
        while size <= MAX_KNOWN_HOSTS and (chunk := os.read(fd, min(1 << 20, MAX_KNOWN_HOSTS + 1 - size))):
            chunks.append(chunk)
            size += len(chunk)
    finally:
        os.close(fd)
    if size > MAX_KNOWN_HOSTS:
        raise UnusableKnownHosts(path, f"is larger than {MAX_KNOWN_HOSTS >> 20} MB: that is no known_hosts file")
    data = b"".join(chunks)
    if data[:2] in (b"\xff\xfe", b"\xfe\xff") or b"\0" in data[:2]:
        # (a BOM, or ASCII's zero high bytes) every line of it would be skipped as an unknown key type
        raise UnusableKnownHosts(path, "is not UTF-8 (it looks like UTF-16): save it as UTF-8, as ssh-keyscan "
                                       "writes it")
    # any other stray byte: only the lines that hold one and are then unreadable are skipped, saying so
    return data.decode("utf-8", errors="replace")


def _file_kind(mode: int) -> str:
    kinds = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a named pipe (fifo)"), (stat.S_ISCHR, "a device"),
             (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))
    return next((what for test, what in kinds if test(mode)), "not a file")


def parse_known_hosts(lines: list[str], path: str) -> KnownHosts:
    """Plain entries (hashed or not), minus @revoked keys; the rest skipped with a warning."""
    revoked: set[tuple[str, bytes]] = set()
    skipped: list[tuple[int, str, str]] = []        # (line, kind, why)
    entries: list[tuple[int, paramiko.hostkeys.HostKeyEntry]] = []
    for number, line in enumerate(lines, 1):
        line = line.strip(" \t")        # OpenSSH's blanks only: a \x0c or \x85 is part of the line
        if not line or line.startswith("#"):
            continue
        fields = [f for f in re.split("[ \t]+", line) if f]
        if fields[0] == "@cert-authority":
            skipped.append((number, "authority", _CERT_AUTHORITY))
        elif fields[0] == "@revoked":
            blob = _key_blob(fields[2:4]) if len(fields) >= 4 else None
            (skipped.append((number, "revoked", _BAD_REVOKED)) if blob is None else revoked.add(blob))
        # one blank between fields, as paramiko splits them: OpenSSH takes any run of blanks
        elif (entry := None if fields[0].startswith("@") else _entry(" ".join(fields))) is None:
            # an unknown marker (`@REVOKED` too, as in OpenSSH) or not a key
            skipped.append((number, "unreadable", _why_unreadable(fields)))
        else:
            entries.append((number, entry))
    # a revoked key is never trusted, whatever else the file says
    kept = [(",".join(e.hostnames), e.key) for _, e in entries if (e.key.get_name(), e.key.asbytes()) not in revoked]
    plain: dict[str, list[int]] = {}
    hashed, patterned = [], []
    for i, (field, _) in enumerate(kept):
        if field.startswith("|1|"):
            hashed.append(i)
        elif any(c in field for c in "*?!"):
            patterned.append(i)
        else:
            for name in field.lower().split(","):
                plain.setdefault(name, []).append(i)
    return KnownHosts(tuple(kept), {name: tuple(found) for name, found in plain.items()}, tuple(hashed),
                      tuple(patterned), frozenset(revoked), path, tuple(skipped))


_CERT_AUTHORITY = ("an @cert-authority line, skipped: rosdeploy cannot verify SSH host certificates (paramiko does "
                   "not); list the robots' plain host keys in known_hosts")
_BAD_REVOKED = ("an @revoked line that cannot be read: the key it means to revoke is NOT revoked; write `@revoked "
                "HOSTS TYPE BASE64`")
_KEY_TYPE = re.compile(r"[A-Za-z0-9@._+-]{1,64}")


def _why_unreadable(fields: list[str]) -> str:
    """Why a line is no host key rosdeploy can read, named without its text (it may be any bytes)."""
    if any("\ufffd" in field for field in fields):     # what _read_known_hosts put for a byte not UTF-8
        return "holds a byte that is not UTF-8, skipped; save the file as UTF-8"
    if fields[0].startswith("@"):
        return ("an unknown marker, skipped (OpenSSH knows @cert-authority and @revoked, in lower case); fix or "
                "remove it")
    if len(fields) < 3:
        return "not a host key line (HOSTS TYPE BASE64), skipped; fix or remove it"
    names = fields[0].split(",")
    if any(name.startswith("|") for name in names) and (len(names) != 1 or not _readable_name(names[0])):
        return "a hashed host name that is not one `|1|SALT|HASH` of base64, skipped; fix or remove it"
    kind = f"key type {fields[1]}" if _KEY_TYPE.fullmatch(fields[1]) else "its key type"
    try:
        paramiko.PKey.from_type_string(fields[1], base64.decodebytes(fields[2].encode()))
    except UnknownKeyType:
        return f"{kind} is one rosdeploy (paramiko) cannot use, skipped; list another key of the robot's"
    except Exception:   # noqa: BLE001 - binascii.Error, SSHException, ValueError...: what _entry refused
        return f"its key is not base64 of a key of {kind}, skipped; fix or remove it"
    return "not a host key rosdeploy can read, skipped; fix or remove it"


def _entry(line: str) -> paramiko.hostkeys.HostKeyEntry | None:
    try:
        entry = paramiko.hostkeys.HostKeyEntry.from_line(line)
    except Exception:   # noqa: BLE001 - InvalidHostKey (not an SSHException), binascii.Error, ValueError...
        # A line that is not a key is skipped, as OpenSSH does; _warnings names it by line number only,
        # never by its text (it may be any bytes).
        return None
    if entry is None or entry.key is None:
        return None
    hashed = [name for name in entry.hostnames if name.startswith("|")]
    if hashed and (len(entry.hostnames) != 1 or not _readable_name(hashed[0])):   # OpenSSH: one hash per line
        return None
    return entry


def _readable_name(name: str) -> bool:
    """A hashed name (`|1|salt|hash`) whose salt and hash are base64: paramiko decodes the salt
    only on lookup, where a bad one raised out of every connection (an internal error)."""
    if not name.startswith("|1|"):
        return False
    parts = name[3:].split("|")
    try:
        return len(parts) == 2 and all(base64.b64decode(part, validate=True) for part in parts)
    except binascii.Error:
        return False


def _key_blob(fields: list[str]) -> tuple[str, bytes] | None:
    """(type, blob) of `TYPE BASE64` fields, checked by loading them as a paramiko key."""
    entry = _entry(" ".join(["revoked.invalid", *fields])) if len(fields) == 2 else None
    return (entry.key.get_name(), entry.key.asbytes()) if entry else None


def _notes(authorities: list[int], unreadable: list[int], bad_revoked: list[int]) -> tuple[tuple[int, str], ...]:
    out = []
    if authorities:
        out.append((authorities[0], f"{len(authorities)} @cert-authority line(s) skipped: rosdeploy cannot verify SSH "
                                    "host certificates (paramiko does not); list the robots' plain host keys in "
                                    "known_hosts."))
    if bad_revoked:
        out.append((bad_revoked[0], f"@revoked line(s) {_numbers(bad_revoked)} cannot be read: the key they mean to "
                                    "revoke is NOT revoked; write `@revoked HOSTS TYPE BASE64`."))
    if unreadable:
        out.append((unreadable[0], f"line(s) {_numbers(unreadable)} skipped: not a host key rosdeploy can read "
                                   "(OpenSSH skips them too); fix or remove them."))
    return tuple(out)


def _numbers(lines: list[int]) -> str:
    more = f" and {len(lines) - 10} more" if len(lines) > 10 else ""
    return ", ".join(map(str, lines[:10])) + more


def known_hosts_warnings(path: str) -> tuple[str, ...]:
    """What was skipped in a known_hosts file (or why none of it was read), for a command that wants to show it."""
    try:
        return _parsed_host_keys(os.path.expanduser(path)).warnings
    except UnusableKnownHosts as exc:
        return (f"{exc}.",)


def known_hosts_problems(hosts: Iterable[Host], options: SSHOptions) -> list[Problem]:
    """One warning per skipped line of the robots' known_hosts files, saying why (the first
    MAX_SKIPPED_SHOWN of a file, then how many more), an unusable file as an error, each file
    once: for status and apply to show whether or not a robot's key is found. validate and check
    do not read known_hosts: its keys need paramiko, whose import alone is 0.2 s."""
    found: list[Problem] = []
    for path in dict.fromkeys(p for host in hosts for p in known_hosts_for(host, options)):
        try:
            known = _parsed_host_keys(path)
        except UnusableKnownHosts as exc:
            found.append(Problem(path, None, "", f"{exc}".removeprefix(f"known_hosts file {path} ")))
            continue
        found += [Problem(path, line, "", note, severity="warning") for line, note in _each_line(known)]
    return found


MAX_SKIPPED_SHOWN = 20     # lines named one by one in a file; a summary for the rest


def _each_line(known: KnownHosts) -> tuple[tuple[int | None, str], ...]:
    shown, rest = known.skipped[:MAX_SKIPPED_SHOWN], known.skipped[MAX_SKIPPED_SHOWN:]
    more = ((rest[0][0], f"and {len(rest)} more line(s) skipped from here on, not named one by one"),) if rest else ()
    return (*((n, why) for n, _, why in shown), *more)


def _parsed_host_keys(path: str) -> KnownHosts:
    """A known_hosts file parsed once per run, not once per robot (that grows with fleet size squared).
    A missing file lists no key (each robot's error says so); one that cannot be read (a symlink
    loop, no permission) is refused, as a directory is: "not in known_hosts" would send the user astray."""
    try:
        return _host_keys_file(path, os.stat(path).st_mtime_ns)
    except (FileNotFoundError, NotADirectoryError):
        return KnownHosts((), {}, (), (), frozenset(), path)
    except OSError as exc:
        raise UnusableKnownHosts(path, f"cannot be read: {exc.strerror or exc}") from None


def _answers(transport: paramiko.Transport) -> bool:
    """Does the robot still answer on this connection? A channel open is answered by sshd
    itself (no process starts on the robot). A TCP-level timeout cannot tell when a proxy
    (ProxyJump, docker-proxy, a NAT box) acknowledges for the robot."""
    try:
        transport.open_session(timeout=LINK_TIMEOUT).close()
    except paramiko.ChannelException:
        return True                  # refused (sshd's MaxSessions): an answer all the same
    except (paramiko.SSHException, OSError, EOFError):
        return False
    return True


def _stopped_answering() -> EOFError:
    return EOFError(f"the robot stopped answering (no reply within {LINK_TIMEOUT:g}s)")


SEND_CHUNK = 32768     # paramiko sends at most one packet (32 KiB) per Channel.send


def _send(chan: paramiko.Channel, data: bytes, deadline: float, answers: Callable[[], bool]) -> None:
    """Channel.sendall, noticing a dead link: a send waits for the robot to open its window
    again, which a cut link never does, and sendall would wait so until the command's timeout
    (600 s by default). After LINK_QUIET s of a shut window, ask whether the robot answers."""
    sent = 0
    while sent < len(data):
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError()
        chan.settimeout(min(LINK_QUIET, left))
        try:
            n = chan.send(data[sent:sent + SEND_CHUNK])
        except socket.timeout:
            if time.monotonic() < deadline and not answers():
                raise _stopped_answering() from None
            continue
        if n == 0:
            raise EOFError("the robot closed the channel")
        sent += n
    chan.settimeout(None)


MAX_OUTPUT = 64 << 20    # bytes of stdout and stderr together: rosdeploy's commands print KBs


class OutputTooLarge(Exception):
    """A command printed more than MAX_OUTPUT bytes."""


def _drain(chan: paramiko.Channel, deadline: float, answers: Callable[[], bool] | None = None) -> tuple[str, str]:
    """Read stdout and stderr together until the remote side closes or the deadline passes.
    `answers`: asked after LINK_QUIET s without a byte; False ends the read as a lost link."""
    out: list[bytes] = []
    err: list[bytes] = []
    heard = time.monotonic()
    size = 0
    while True:
        if chan.recv_ready() or chan.recv_stderr_ready():
            heard = time.monotonic()
        elif answers is not None and time.monotonic() - heard >= LINK_QUIET:
            if not answers():
                chan.close()
                raise _stopped_answering()
            heard = time.monotonic()
        for ready, recv, into in ((chan.recv_ready, chan.recv, out), (chan.recv_stderr_ready, chan.recv_stderr, err)):
            while ready():
                into.append(recv(65536))
                size += len(into[-1])
                if size > MAX_OUTPUT:      # a command without end (or a hostile sshd) must not fill this memory
                    chan.close()
                    raise OutputTooLarge()
        if chan.exit_status_ready() and not chan.recv_ready() and not chan.recv_stderr_ready():
            # eof_received: the exit status can arrive before the last data packet
            if chan.eof_received or chan.closed:
                break
        left = deadline - time.monotonic()
        if left <= 0:
            chan.close()
            raise TimeoutError()
        select.select([chan], [], [], min(left, 1.0))
    return b"".join(out).decode("utf-8", "replace"), b"".join(err).decode("utf-8", "replace")


CONNECT_TRIES = 3     # a Wi-Fi blip is not an outage: tries within one ssh.connect_timeout
UNREACHABLE_HINT = ": is the robot on and on the network? Check its ansible_host and ansible_port"


def connect(host: Host, options: SSHOptions, config: Config | None = None) -> SSHTransport:
    """Up to CONNECT_TRIES tries, each with an equal share of what is left of the
    connect_timeout budget, a short jitter between them; a wrong host key or a refused
    login is not retried (it would only be refused again)."""
    budget = options.connect_timeout
    deadline = time.monotonic() + budget
    for attempt in range(1, CONNECT_TRIES + 1):
        left = deadline - time.monotonic()
        share = left / (CONNECT_TRIES - attempt + 1)
        try:
            return SSHTransport(host, replace(options, connect_timeout=max(1.0, share)), config).open()
        except ConnectError as exc:
            refused_login = (isinstance(exc.__cause__, paramiko.AuthenticationException)
                             or "No authentication methods" in str(exc.__cause__))
            final = (attempt == CONNECT_TRIES or isinstance(exc, (HostKeyError, KeyFileError))
                     or deadline - time.monotonic() < 1.5
                     or refused_login)
            if final:
                tries = f" ({attempt} tries within {budget:g}s)" if attempt > 1 else ""
                hint = UNREACHABLE_HINT if exc.detail.startswith("unreachable:") else ""
                if tries or hint:
                    raise ConnectError(host.name, f"{exc.detail}{tries}{hint}") from exc
                raise
        time.sleep(random.uniform(0.1, min(0.5, max(0.1, deadline - time.monotonic() - 1.0))))
    raise AssertionError("unreachable: the last try raises")


def local_user_at_host() -> str:
    """Who deployed, for the manifest and history: user@machine of the operator."""
    try:
        user = getpass.getuser()   # $USER/$LOGNAME, else the password database (CI has no $USER)
    except (KeyError, OSError):
        user = str(os.getuid())
    return f"{user}@{socket.gethostname()}"



class EarlyConnect:
    """Connections opened in the background while the controller renders and checks the release.

    A no-op `apply` is one connection and one round trip per robot; most of a connection is
    waiting for the robot (key exchange, login), and rendering is work on this machine, so the
    two overlap instead of adding up (README "Performance"). Only the first wave's robots: a
    later wave may start minutes later. A failed connect raises where the run connects; one the
    run never takes (declined, input error) is closed when it is done, without waiting for it
    (daemon threads: an unreachable robot does not hold up an input error for connect_timeout).
    """

    def __init__(self, hosts: Sequence[Host], options: SSHOptions,
                 connect: Callable[[Host, SSHOptions], Transport] = connect) -> None:
        self.options, self.plain = options, connect
        self.pending = {h.name: _background(functools.partial(connect, h, options)) for h in hosts}

    def connect(self, host: Host, options: SSHOptions) -> Transport:
        future = self.pending.pop(host.name, None)
        if future is None or options != self.options:
            return self.plain(host, options)
        return future.result()

    def close(self) -> None:
        for future in self.pending.values():
            future.add_done_callback(_close_unused)
        self.pending.clear()


class Handoff:
    """Connections one part of a run hands to the next: a rollout's pre-check (rollout._precheck)
    leaves the robots that need the release connected. Whatever the next part does not take
    is closed with close(); a robot it takes a second time connects anew (`fallback`)."""

    def __init__(self, kept: dict[str, Transport], fallback: Callable[[Host, SSHOptions], Transport]) -> None:
        self.kept, self.fallback = kept, fallback

    def connect(self, host: Host, options: SSHOptions) -> Transport:
        kept = self.kept.pop(host.name, None)
        return kept if kept is not None else self.fallback(host, options)

    def keep_only(self, names: set[str]) -> None:
        for name in [n for n in self.kept if n not in names]:
            self.kept.pop(name).close()

    def close(self) -> None:
        self.keep_only(set())


def _close_unused(future: "Future[Transport]") -> None:
    if future.exception() is None:
        future.result().close()


def _background(work: Callable[[], Transport]) -> "Future[Transport]":
    future: Future[Transport] = Future()

    def target() -> None:
        try:
            future.set_result(work())
        except BaseException as exc:     # re-raised by .result() in the robot's thread
            future.set_exception(exc)
    threading.Thread(target=target, name="early-connect", daemon=True).start()
    return future
