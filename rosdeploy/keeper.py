"""SSH connections that outlive one command, for the read-only commands (status, plan, history).

Opening an SSH connection costs the robot's sshd a key exchange and a process; over a
hundred robots that is most of what `status` takes (measured: 1.2-1.3 s of 3 s). Like
OpenSSH's ControlPersist, which Ansible turns on by default, a per-user *keeper* process
holds the connections for `ssh.persist` seconds after their last use, and later commands
run their work through it.

Trust: the keeper listens on a unix socket in a directory only the operator can enter
(0700, owner checked, never a symlink), and on Linux it also checks each caller's uid
(SO_PEERCRED). A caller can only do what the operator's own SSH keys already let it do.
Host keys are verified when the keeper connects, exactly as in a direct connection, and a
change to a known_hosts or ssh_config file means a fresh connection.

Only commands that change nothing use it: a deploy or rollback keeps its own connections,
so Ctrl-C, locks and the health gate stay with the process that owns them.
"""
from __future__ import annotations

import base64
import contextlib
import fcntl
import hashlib
import json
import os
import socket
import stat
import struct
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

from rosdeploy import __version__
from rosdeploy.commands import Command
from rosdeploy.errors import ChannelRefused, ConnectError, HostKeyError, RemoteError
from rosdeploy.model import Host
from rosdeploy.transport import (Result, SSHOptions, SSHTransport, connect, known_hosts_for, mtime_ns, port_given,
                                 ssh_config_files, succeeded)

PROTOCOL = 1
MAX_SOCKET_PATH = 107     # bytes: sockaddr_un's sun_path, less its NUL
SPAWN_WAIT = 5.0          # seconds a caller waits for a keeper it started to listen
REAP_EVERY = 1.0
_HEADER = struct.Struct("!I")
_MAX_MESSAGE = 64 << 20   # a robot's state or logs are kilobytes; this bounds a bad peer


class KeeperUnavailable(Exception):
    """No keeper can be used here; the caller connects directly instead."""


# --------------------------------------------------------------- the place

def control_dir() -> Path:
    """Where the socket lives: $ROSDEPLOY_CONTROL_DIR, else $XDG_RUNTIME_DIR/rosdeploy, else ~/.cache/rosdeploy/cp.
    A relative one is refused (KeeperUnavailable): it would be made under whatever folder the
    command ran in, and a keeper started in one folder is never found from another."""
    chosen = os.environ.get("ROSDEPLOY_CONTROL_DIR")
    if chosen:
        return _absolute(Path(chosen), "ROSDEPLOY_CONTROL_DIR")
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime and os.path.isabs(runtime) and os.path.isdir(runtime):   # the XDG spec: ignore a relative one
        return Path(runtime) / "rosdeploy"
    return _absolute(Path.home() / ".cache" / "rosdeploy" / "cp", "HOME")


def _absolute(path: Path, source: str) -> Path:
    if not path.is_absolute():
        raise KeeperUnavailable(f"its folder {path} is a relative path (from ${source}): set {source} to an "
                                "absolute path")
    return path


def private_dir(path: Path) -> Path:
    """The directory, created 0700 if missing; refused unless it is ours alone."""
    try:
        path.mkdir(mode=0o700, parents=True, exist_ok=True)
        info = os.lstat(path)
    except OSError as exc:
        raise KeeperUnavailable(f"{path}: {exc.strerror or exc}") from exc
    if not stat.S_ISDIR(info.st_mode):
        raise KeeperUnavailable(f"{path} is not a directory (a symlink is refused)")
    if info.st_uid != os.getuid():
        raise KeeperUnavailable(f"{path} belongs to uid {info.st_uid}, not to you")
    if info.st_mode & 0o077:
        raise KeeperUnavailable(f"{path} is open to others (mode {stat.S_IMODE(info.st_mode):o}); "
                                f"`chmod 700 {path}` to use shared connections")
    return path


def socket_path(directory: Path) -> Path:
    """One keeper per rosdeploy build and ssh-agent: a keeper started by other code is never
    asked to run ours, and one started from another login never offers its stale agent."""
    here = Path(__file__).resolve().parent
    stamp = "".join(str(os.stat(here / name).st_mtime_ns) for name in ("keeper.py", "transport.py"))
    agent = os.environ.get("SSH_AUTH_SOCK", "")
    build = hashlib.sha256(f"{__version__}/{PROTOCOL}/{stamp}/{agent}".encode()).hexdigest()[:12]
    return directory / f"keeper-{build}.sock"


# ---------------------------------------------------------------- framing

def send(sock: socket.socket, message: dict) -> None:
    data = json.dumps(message).encode()
    sock.sendall(_HEADER.pack(len(data)) + data)


def receive(sock: socket.socket) -> dict | None:
    """The next message, or None when the peer closed between messages."""
    header = _read(sock, _HEADER.size, allow_eof=True)
    if header is None:
        return None
    (size,) = _HEADER.unpack(header)
    if size > _MAX_MESSAGE:
        raise ConnectionError(f"message of {size} bytes refused")
    body = _read(sock, size, allow_eof=False)
    return json.loads(body or b"{}")


def _read(sock: socket.socket, size: int, allow_eof: bool) -> bytes | None:
    chunks: list[bytes] = []
    left = size
    while left:
        chunk = sock.recv(min(left, 1 << 20))
        if not chunk:
            if allow_eof and left == size:
                return None
            raise ConnectionError("connection closed mid-message")
        chunks.append(chunk)
        left -= len(chunk)
    return b"".join(chunks)


# ------------------------------------------------ what crosses the socket

def host_doc(host: Host) -> dict:
    """What a transport reads of a Host: its address, and which known_hosts to trust."""
    return {"name": host.name, "address": host.address, "port": host.port, "user": host.user,
            "key_file": host.key_file, "known_hosts": host.vars.get("rosdeploy_known_hosts"),
            "port_given": port_given(host), "key_file_var": host.key_file_var}


def host_from(doc: dict) -> Host:
    known = {"rosdeploy_known_hosts": doc["known_hosts"]} if doc.get("known_hosts") else {}
    # an explicit ansible_port (22 too) wins over the ssh config's Port here as in a direct connection
    given = {"ansible_port": int(doc["port"])} if doc.get("port_given") else {}
    return Host(name=doc["name"], groups=(), vars={**known, **given}, address=doc["address"], port=int(doc["port"]),
                user=doc.get("user"), key_file=doc.get("key_file"), key_file_var=str(doc.get("key_file_var") or ""))


def command_doc(command: Command) -> dict:
    stdin = None if command.stdin is None else base64.b64encode(command.stdin).decode()
    return {"argv": list(command.argv), "stdin": stdin, "timeout": command.timeout, "label": command.label}


def command_from(doc: dict) -> Command:
    stdin = None if doc.get("stdin") is None else base64.b64decode(doc["stdin"])
    return Command(tuple(doc["argv"]), stdin=stdin, timeout=doc.get("timeout"), label=doc.get("label", ""))


def error_doc(exc: RemoteError) -> dict:
    return {"kind": "host_key" if isinstance(exc, HostKeyError) else "connect", "message": exc.detail}


def raise_error(host: str, doc: dict) -> None:
    kind = HostKeyError if doc.get("kind") == "host_key" else ConnectError
    raise kind(host, doc.get("message", "connection keeper failed"))


def connection_key(host: Host, options: SSHOptions) -> tuple:
    """Same robot, same user and key, same trust files and ssh configs as they are now: same
    connection. File mtimes are part of it, so an edited known_hosts or ssh config is honoured at once."""
    files = [*known_hosts_for(host, options), *ssh_config_files(options)]    # Included configs too
    return (host.address, host.port, port_given(host), host.user, host.key_file, options.connect_timeout,
            options.ssh_config, tuple((f, mtime_ns(f)) for f in files))


# ------------------------------------------------------------------ client

class KeptTransport:
    """A Transport whose SSH connection lives in the keeper; one socket per robot thread."""

    def __init__(self, host: Host, options: SSHOptions, sock: socket.socket) -> None:
        self.host = host
        self.options = options
        self._sock = sock

    def _ask(self, message: dict, timeout: float) -> dict:
        message.update(host=host_doc(self.host), ssh=asdict(self.options))
        try:
            self._sock.settimeout(timeout)
            send(self._sock, message)
            reply = receive(self._sock)
        except (OSError, ValueError) as exc:
            raise KeeperUnavailable(f"connection keeper: {exc}") from exc
        if reply is None:
            raise KeeperUnavailable("the connection keeper went away")
        if "error" in reply:
            raise_error(self.host.name, reply["error"])
        return reply

    def open(self, persist: float) -> "KeptTransport":
        self._ask({"op": "open", "persist": persist}, self.options.connect_timeout + 5)
        return self

    def run(self, command: Command) -> Result:
        # The keeper enforces the command's timeout; this bounds a keeper that hangs.
        timeout = (command.timeout or self.options.command_timeout) + self.options.connect_timeout + 5
        try:
            reply = self._ask({"op": "run", "command": command_doc(command)}, timeout)
        except KeeperUnavailable as exc:
            raise ConnectError(self.host.name, f"{exc} during `{command.display()}`; run it again, "
                                               f"or set `ssh.persist: 0` to connect directly") from exc
        r = reply["result"]
        return Result(command.display(), r["stdout"], r["stderr"], int(r["exited"]), float(r["duration"]))

    def check(self, command: Command, what: str = "") -> Result:
        return succeeded(self.host, self.run(command), what or command.display())

    def close(self) -> None:
        self._sock.close()


def kept_connect(persist: float) -> Callable[[Host, SSHOptions], Any]:
    """A `connect` for RunContext: through the keeper, else (no keeper possible) directly."""
    def connect_kept(host: Host, options: SSHOptions):
        try:
            sock = dial(persist)
        except KeeperUnavailable:
            return connect(host, options)
        transport = KeptTransport(host, options, sock)
        try:
            return transport.open(persist)
        except KeeperUnavailable:
            transport.close()
            return connect(host, options)     # it was stopping as we came: nothing lost
        except BaseException:
            transport.close()
            raise
    return connect_kept


def dial(persist: float) -> socket.socket:
    """A socket to this build's keeper, starting one if none runs."""
    path = usable_socket_path()
    sock = _try_dial(path)
    if sock is not None:
        return sock
    with _spawn_lock(path):
        sock = _try_dial(path)        # another caller may have started it while we waited
        if sock is None:
            sock = _wait_dial(path, _spawn(path, persist))
    return sock


def _try_dial(path: Path) -> socket.socket | None:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        sock.connect(str(path))
        return sock
    except OSError:
        sock.close()
        return None


def _wait_dial(path: Path, keeper: subprocess.Popen) -> socket.socket:
    deadline = time.monotonic() + SPAWN_WAIT
    while time.monotonic() < deadline and keeper.poll() is None:
        sock = _try_dial(path)
        if sock is not None:
            return sock
        time.sleep(0.01)
    raise KeeperUnavailable(f"the connection keeper did not start (see {path.with_suffix('.log')})")


@contextlib.contextmanager
def _spawn_lock(path: Path) -> Iterator[None]:
    fd = os.open(path.with_suffix(".lock"), os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def _spawn(path: Path, persist: float) -> subprocess.Popen:
    with contextlib.suppress(FileNotFoundError):
        path.unlink()     # a keeper that died left its socket behind: nobody answers on it
    remove_old_builds(path)
    log = os.open(path.with_suffix(".log"), os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600)
    # This very rosdeploy, also when it runs from a checkout rather than an installed package.
    package_root = str(Path(__file__).resolve().parents[1])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [package_root, os.environ.get("PYTHONPATH")]))}
    try:
        return subprocess.Popen([sys.executable, "-m", "rosdeploy.keeper", str(path), str(persist)],
                                stdin=subprocess.DEVNULL, stdout=log, stderr=log, cwd="/", env=env,
                                start_new_session=True, close_fds=True)
    except OSError as exc:
        raise KeeperUnavailable(f"cannot start the connection keeper: {exc}") from exc
    finally:
        os.close(log)


def remove_old_builds(path: Path) -> None:
    """Each rosdeploy build has its own keeper files; remove those of other builds whose
    keeper is gone (nobody answers, nobody is starting one), so upgrades leave nothing."""
    for lock in path.parent.glob("keeper-*.lock"):
        if lock == path.with_suffix(".lock"):
            continue
        sock = _try_dial(lock.with_suffix(".sock"))
        if sock is not None:      # that build's keeper still runs: it removes its socket itself
            sock.close()
            continue
        with contextlib.suppress(OSError), open(lock, "a") as held:
            fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)      # OSError: starting one now
            for old in (lock.with_suffix(".sock"), lock.with_suffix(".log"), lock):
                with contextlib.suppress(FileNotFoundError):
                    old.unlink()


def unavailable() -> str | None:
    """Why no keeper can run here, or None: status, plan and history then connect directly."""
    try:
        usable_socket_path()
    except KeeperUnavailable as exc:
        return str(exc)
    return None


def usable_socket_path() -> Path:
    """This build's socket in the control directory; KeeperUnavailable when there can be none
    (a keeper started for a path too long would fail to listen, at every command)."""
    path = socket_path(private_dir(control_dir()))
    if len(os.fsencode(path)) > MAX_SOCKET_PATH:
        raise KeeperUnavailable(f"its socket path {path} is longer than a unix socket allows "
                                f"({MAX_SOCKET_PATH} bytes): set ROSDEPLOY_CONTROL_DIR to a shorter directory")
    return path


ASK_TIMEOUT = 10.0        # seconds a running keeper has to answer `connections`


def ask(message: dict) -> dict | None:
    """One request to a running keeper (`rosdeploy connections`); None when none runs."""
    return ask_why(message)[0]


def ask_why(message: dict) -> tuple[dict | None, str | None]:
    """The keeper's answer, or None and why there is none when its socket took the call but gave
    no answer (a hung keeper, or another process holding the path); (None, None): none runs."""
    try:
        path = usable_socket_path()
    except KeeperUnavailable:
        return None, None
    sock = _try_dial(path)
    if sock is None:
        return None, None
    with sock:
        sock.settimeout(ASK_TIMEOUT)
        try:
            send(sock, message)
            return receive(sock), None
        except socket.timeout:
            return None, (f"a process holds its socket {path} but did not answer within {ASK_TIMEOUT:g} s: "
                          f"stop it, or remove the socket")
        except (OSError, ValueError):
            return None, None     # it was stopping as we asked


# ------------------------------------------------------------------ keeper

@dataclass
class _Held:
    transport: SSHTransport
    name: str
    opened: float
    used: float
    busy: int = 0


class Keeper:
    """The process that holds connections: one thread per caller, one reaper."""

    def __init__(self, path: Path, persist: float) -> None:
        self.path = path
        self.persist = persist
        self.held: dict[tuple, _Held] = {}
        self.opening: dict[tuple, threading.Lock] = {}
        self.lock = threading.Lock()
        self.callers = 0
        self.last_seen = time.monotonic()
        self.stop = threading.Event()
        self.inode = 0

    def serve(self) -> None:
        server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old = os.umask(0o177)          # the socket is born 0600
        try:
            server.bind(str(self.path))
        finally:
            os.umask(old)
        self.inode = os.stat(self.path).st_ino
        server.listen(512)
        server.settimeout(REAP_EVERY)
        try:
            while not self.stop.is_set() and not self._idle_out():
                try:
                    client, _ = server.accept()
                except socket.timeout:
                    continue
                threading.Thread(target=self._caller, args=(client,), daemon=True).start()
        finally:
            server.close()
            self._unlink()
            self._let_callers_finish(deadline=time.monotonic() + 2.0)
            self._close_all()

    def _let_callers_finish(self, deadline: float) -> None:
        """The reply to `exit` (and any command in flight) is sent before the process ends."""
        while self.callers and time.monotonic() < deadline:
            time.sleep(0.01)

    def _unlink(self) -> None:
        with contextlib.suppress(OSError):
            if os.stat(self.path).st_ino == self.inode:   # never remove a successor's socket
                self.path.unlink()

    def _idle_out(self) -> bool:
        """Close connections idle for `persist`; True when nothing is held or asked any more."""
        now = time.monotonic()
        with self.lock:
            for key, held in list(self.held.items()):
                if not held.busy and now - held.used > self.persist:
                    del self.held[key]
                    held.transport.close()
            return not self.held and not self.callers and now - self.last_seen > self.persist

    def _close_all(self) -> None:
        with self.lock:
            for held in self.held.values():
                held.transport.close()
            self.held.clear()

    def _caller(self, client: socket.socket) -> None:
        with self.lock:
            self.callers += 1
        try:
            with client:
                if not same_user(client):
                    return
                while (message := receive(client)) is not None:
                    send(client, self._answer(message))
        except (OSError, ValueError):
            pass   # the caller went away (Ctrl-C): its command's reply has nowhere to go
        finally:
            with self.lock:
                self.callers -= 1
                self.last_seen = time.monotonic()

    def _answer(self, message: dict) -> dict:
        op = message.get("op")
        if op == "list":
            return {"pid": os.getpid(), "persist": self.persist, "connections": self.listing()}
        if op == "exit":
            self.stop.set()
            self._unlink()     # the next command starts a new keeper instead of reaching this one
            return {"closing": len(self.held)}
        if op not in ("open", "run"):
            return {"error": {"kind": "connect", "message": f"unknown request {op!r}"}}
        host, options = host_from(message["host"]), SSHOptions(**message["ssh"])
        self.persist = float(message.get("persist", self.persist))
        try:
            with self._using(host, options) as transport:
                if op == "open":
                    return {}
                result = _run_again_if_gone(transport, command_from(message["command"]))
        except RemoteError as exc:
            return {"error": error_doc(exc)}
        return {"result": {"stdout": result.stdout, "stderr": result.stderr, "exited": result.exited,
                           "duration": result.duration}}

    @contextlib.contextmanager
    def _using(self, host: Host, options: SSHOptions) -> Iterator[SSHTransport]:
        key = connection_key(host, options)
        held = self._get(key, host, options)
        try:
            yield held.transport
        finally:
            with self.lock:
                held.busy -= 1
                held.used = self.last_seen = time.monotonic()

    def _get(self, key: tuple, host: Host, options: SSHOptions) -> _Held:
        with self.lock:
            gate = self.opening.setdefault(key, threading.Lock())
        with gate:       # two callers for one robot open one connection
            with self.lock:
                held = self.held.get(key)
                if held is not None:
                    held.busy += 1
                    return held
            transport = connect(host, options)
            now = time.monotonic()
            with self.lock:
                held = self.held[key] = _Held(transport, host.name, now, now, busy=1)
                return held

    def listing(self) -> list[dict]:
        now = time.monotonic()
        with self.lock:
            return [{"robot": h.name, "endpoint": h.transport.endpoint, "user": k[2],
                     "age": round(now - h.opened, 1), "idle": round(now - h.used, 1), "busy": h.busy}
                    for k, h in self.held.items()]


def _run_again_if_gone(transport: SSHTransport, command: Command) -> Result:
    """A held connection can die while idle (robot rebooted, Wi-Fi roamed); when it refuses to
    start the command, nothing ran, so connecting again and running it once more is safe."""
    try:
        return transport.run(command)
    except ChannelRefused:
        transport.close()
        return transport.run(command)      # reconnects, verifying the host key again


def same_user(client: socket.socket) -> bool:
    """On Linux, refuse a caller of another uid even if the directory's mode were widened."""
    option = getattr(socket, "SO_PEERCRED", None)
    if option is None:
        return True     # elsewhere the 0700 directory is the guard, as with OpenSSH's ControlPath
    _pid, uid, _gid = struct.unpack("3i", client.getsockopt(socket.SOL_SOCKET, option, struct.calcsize("3i")))
    return uid == os.getuid()


def main(argv: list[str]) -> int:
    path, persist = Path(argv[0]), float(argv[1])
    Keeper(path, persist).serve()
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
