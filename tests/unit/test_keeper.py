"""The connection keeper: its private directory, its wire format, and a real keeper serving
fake SSH transports over a real unix socket (no network). The SSH side runs against real
robots in tests/integration/test_deploy.py."""
from __future__ import annotations

import os
import shutil
import socket
import tempfile
import threading
import time
from pathlib import Path

import pytest

from rosdeploy import keeper
from rosdeploy.commands import Command
from rosdeploy.errors import ChannelRefused, ConnectError, HostKeyError
from rosdeploy.model import Host
from rosdeploy.transport import Result, SSHOptions

ROBOT = Host("robot1", ("all",), {"rosdeploy_known_hosts": "/fleet/known_hosts"}, "10.0.0.5", port=2201,
             user="robot", key_file="/keys/id")


class FakeSSH:
    """Stands in for SSHTransport inside the keeper: counts connections and runs."""

    opened: list[str] = []
    fail_next_channel = 0

    def __init__(self, host: Host) -> None:
        self.host = host
        self.closed = False
        self.runs: list[Command] = []
        self.endpoint = f"[{host.address}]:{host.port}"
        FakeSSH.opened.append(host.name)

    def run(self, command: Command) -> Result:
        if FakeSSH.fail_next_channel:
            FakeSSH.fail_next_channel -= 1
            raise ChannelRefused(self.host.name, "connection lost before `x`")
        self.runs.append(command)
        stdin = (command.stdin or b"").decode()
        return Result(command.display(), f"{self.host.name}:{' '.join(command.argv)}:{stdin}", "err", 3, 0.01)

    def close(self) -> None:
        self.closed = True


@pytest.fixture
def served(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """A keeper on a thread, connecting through FakeSSH; yields (keeper, socket path)."""
    FakeSSH.opened, FakeSSH.fail_next_channel = [], 0

    def fake_connect(host: Host, options: SSHOptions) -> FakeSSH:
        if host.address == "badkey":
            raise HostKeyError(host.name, "HOST KEY CHANGED for badkey")
        return FakeSSH(host)

    monkeypatch.setattr(keeper, "connect", fake_connect)
    k, path, thread = _serving(tmp_path, monkeypatch, persist=30)
    yield k, path
    k.stop.set()
    thread.join(5)


def _serving(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
             persist: float) -> tuple[keeper.Keeper, Path, threading.Thread]:
    monkeypatch.setattr(keeper, "REAP_EVERY", 0.05)
    path = tmp_path / "k.sock"
    k = keeper.Keeper(path, persist=persist)
    thread = threading.Thread(target=k.serve, daemon=True)
    thread.start()
    _wait_for(lambda: _listening(path))   # the socket file exists from bind(), before listen()
    return k, path, thread


def _listening(path: Path) -> bool:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as probe:
        try:
            probe.connect(str(path))
        except OSError:
            return False
    return True


def _wait_for(predicate, seconds: float = 5.0) -> None:
    deadline = time.monotonic() + seconds
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def _client(path: Path, host: Host = ROBOT, persist: float = 30) -> keeper.KeptTransport:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.connect(str(path))
    return keeper.KeptTransport(host, SSHOptions(connect_timeout=2), sock).open(persist)


# ------------------------------------------------------------ the directory

def test_private_dir_is_created_for_the_owner_only(tmp_path: Path) -> None:
    made = keeper.private_dir(tmp_path / "a" / "cp")
    assert made.stat().st_mode & 0o777 == 0o700


def test_a_directory_open_to_others_is_refused_with_the_fix(tmp_path: Path) -> None:
    shared = tmp_path / "shared"
    shared.mkdir(mode=0o755)
    shared.chmod(0o755)
    with pytest.raises(keeper.KeeperUnavailable, match="chmod 700"):
        keeper.private_dir(shared)


def test_a_symlinked_directory_is_refused(tmp_path: Path) -> None:
    real = tmp_path / "real"
    real.mkdir(mode=0o700)
    (tmp_path / "link").symlink_to(real)
    with pytest.raises(keeper.KeeperUnavailable, match="symlink"):
        keeper.private_dir(tmp_path / "link")


def test_control_dir_follows_the_environment(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("ROSDEPLOY_CONTROL_DIR", str(tmp_path / "x"))
    assert keeper.control_dir() == tmp_path / "x"
    monkeypatch.delenv("ROSDEPLOY_CONTROL_DIR")
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    assert keeper.control_dir() == tmp_path / "rosdeploy"


# ---------------------------------------------------------------- the wire

def test_messages_cross_a_socket_intact_and_a_clean_close_is_none() -> None:
    a, b = socket.socketpair()
    big = {"op": "run", "text": "é" * 500_000}     # larger than a socket buffer: read in pieces
    sender = threading.Thread(target=keeper.send, args=(a, big))
    sender.start()
    assert keeper.receive(b) == big
    sender.join()
    a.close()
    assert keeper.receive(b) is None


def test_a_message_cut_short_or_oversized_is_an_error() -> None:
    a, b = socket.socketpair()
    a.sendall(keeper._HEADER.pack(10) + b"{}")
    a.close()
    with pytest.raises(ConnectionError, match="mid-message"):
        keeper.receive(b)
    c, d = socket.socketpair()
    c.sendall(keeper._HEADER.pack(keeper._MAX_MESSAGE + 1))
    with pytest.raises(ConnectionError, match="refused"):
        keeper.receive(d)


def test_commands_and_hosts_round_trip() -> None:
    command = Command(("sh", "-c", "cat >x", "prog", "a b"), stdin=b"\x00\xffsecret", timeout=7.0, label="put x")
    assert keeper.command_from(keeper.command_doc(command)) == command
    host = keeper.host_from(keeper.host_doc(ROBOT))
    assert (host.name, host.address, host.port, host.user, host.key_file) == ("robot1", "10.0.0.5", 2201, "robot",
                                                                              "/keys/id")
    assert host.vars["rosdeploy_known_hosts"] == "/fleet/known_hosts"


def test_an_edited_known_hosts_file_means_a_new_connection(tmp_path: Path) -> None:
    known = tmp_path / "known_hosts"
    known.write_text("a\n")
    options = SSHOptions(known_hosts=str(known))
    host = Host("r", ("all",), {}, "10.0.0.5")
    before = keeper.connection_key(host, options)
    os.utime(known, ns=(1, 1))
    assert keeper.connection_key(host, options) != before
    assert keeper.connection_key(Host("r", ("all",), {}, "10.0.0.5", user="root"), options) != \
        keeper.connection_key(host, options)


# ------------------------------------------------------------- the keeper

def test_runs_go_through_one_held_connection_per_robot(served) -> None:
    k, path = served
    first = _client(path)
    result = first.run(Command(("echo", "hi"), stdin=b"in"))
    assert (result.stdout, result.stderr, result.exited) == ("robot1:echo hi:in", "err", 3)
    first.close()
    second = _client(path)
    assert second.run(Command(("true",))).stdout == "robot1:true:"
    second.close()
    assert FakeSSH.opened == ["robot1"], "the second command reused the connection"
    assert [c["robot"] for c in k.listing()] == ["robot1"]


def test_check_through_the_keeper_raises_on_a_failed_command_like_a_direct_connection(served) -> None:
    from rosdeploy.errors import CommandFailed

    _, path = served
    client = _client(path)
    try:
        with pytest.raises(CommandFailed) as failed:
            client.check(Command(("echo", "hi")), "the echo step")     # FakeSSH's commands exit 3
        assert str(failed.value).startswith("robot1: the echo step failed (exit 3)")
        assert failed.value.result.stdout == "robot1:echo hi:"
    finally:
        client.close()


def test_concurrent_callers_for_one_robot_open_one_connection(served) -> None:
    _, path = served
    clients = []
    threads = [threading.Thread(target=lambda: clients.append(_client(path))) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(clients) == 8 and FakeSSH.opened == ["robot1"]
    for c in clients:
        c.close()


def test_a_host_key_error_reaches_the_caller_as_one(served) -> None:
    _, path = served
    bad = Host("robot9", ("all",), {}, "badkey")
    with pytest.raises(HostKeyError) as caught:
        _client(path, bad)
    assert str(caught.value) == "robot9: HOST KEY CHANGED for badkey"


def test_a_connection_that_died_while_idle_is_reopened_once(served) -> None:
    k, path = served
    client = _client(path)
    FakeSSH.fail_next_channel = 1
    assert client.run(Command(("uptime",))).stdout == "robot1:uptime:"
    FakeSSH.fail_next_channel = 2
    with pytest.raises(ConnectError, match="connection lost"):
        client.run(Command(("uptime",)))


def test_idle_connections_close_and_the_keeper_leaves_no_socket(tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(keeper, "connect", lambda host, options: FakeSSH(host))
    k, path, thread = _serving(tmp_path, monkeypatch, persist=0.2)
    client = _client(path, persist=0.2)
    client.run(Command(("true",)))
    held = next(iter(k.held.values())).transport
    client.close()
    thread.join(5)
    assert not thread.is_alive() and held.closed and not path.exists()


def test_a_caller_of_another_uid_is_refused() -> None:
    if os.getuid() != 0:
        pytest.skip("needs root to act as another uid (CI runs as root)")
    open_dir = Path(tempfile.mkdtemp(prefix="rosdeploy-peer-"))    # reachable by "nobody"
    open_dir.chmod(0o777)
    path = open_dir / "s.sock"
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(str(path))
    path.chmod(0o777)
    server.listen(1)
    server.settimeout(10)
    pid = os.fork()
    if pid == 0:                    # the child becomes "nobody" and dials in
        try:
            os.setgid(65534)
            os.setuid(65534)
            socket.socket(socket.AF_UNIX, socket.SOCK_STREAM).connect(str(path))
            time.sleep(1)
        finally:
            os._exit(0)
    mine, _peer = socket.socketpair(socket.AF_UNIX)
    try:
        stranger, _ = server.accept()
        with stranger:
            assert not keeper.same_user(stranger)
        assert keeper.same_user(mine)
    finally:
        os.waitpid(pid, 0)
        for s in (mine, _peer, server):
            s.close()
        shutil.rmtree(open_dir)


def test_without_a_usable_directory_commands_connect_directly(tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o755)
    monkeypatch.setenv("ROSDEPLOY_CONTROL_DIR", str(shared))
    direct = object()
    monkeypatch.setattr(keeper, "connect", lambda host, options: direct)
    assert keeper.kept_connect(60)(ROBOT, SSHOptions()) is direct


def test_a_real_keeper_process_is_started_once_and_answers(tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ROSDEPLOY_CONTROL_DIR", str(tmp_path / "cp"))
    assert keeper.ask({"op": "list"}) is None, "nothing runs yet"
    keeper.dial(5).close()
    keeper.dial(5).close()               # the second dial finds the running keeper
    listed = keeper.ask({"op": "list"})
    assert listed is not None and listed["connections"] == [] and listed["persist"] == 5
    sockets = list((tmp_path / "cp").glob("keeper-*.sock"))
    assert len(sockets) == 1 and sockets[0].stat().st_mode & 0o777 == 0o600
    assert keeper.ask({"op": "exit"}) == {"closing": 0}
    _wait_for(lambda: not sockets[0].exists())
    _wait_for(lambda: not _alive(listed["pid"]))


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as stat:   # a zombie waits for its parent, it is not serving
        return stat.read().split(")")[-1].split()[0] != "Z"


def test_a_keeper_that_goes_away_at_open_means_a_direct_connection(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(str(tmp_path / "dying.sock"))
    server.listen(1)

    def dial_a_dying_keeper(persist: float) -> socket.socket:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.connect(str(tmp_path / "dying.sock"))
        server.accept()[0].close()          # it hangs up without a word, as a stopping keeper does
        return sock

    direct = object()
    monkeypatch.setattr(keeper, "dial", dial_a_dying_keeper)
    monkeypatch.setattr(keeper, "connect", lambda host, options: direct)
    assert keeper.kept_connect(60)(ROBOT, SSHOptions()) is direct
    server.close()


def test_after_exit_the_next_command_starts_a_new_keeper(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ROSDEPLOY_CONTROL_DIR", str(tmp_path / "cp"))
    keeper.dial(5).close()
    first = keeper.ask({"op": "list"})["pid"]
    keeper.ask({"op": "exit"})
    keeper.dial(5).close()                  # at once: the old one's socket is already gone
    second = keeper.ask({"op": "list"})["pid"]
    assert second != first
    keeper.ask({"op": "exit"})


def test_another_ssh_agent_means_another_keeper(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SSH_AUTH_SOCK", "/tmp/ssh-a/agent.1")
    first = keeper.socket_path(tmp_path)
    monkeypatch.setenv("SSH_AUTH_SOCK", "/tmp/ssh-b/agent.2")
    assert keeper.socket_path(tmp_path) != first
    monkeypatch.setenv("SSH_AUTH_SOCK", "/tmp/ssh-a/agent.1")
    assert keeper.socket_path(tmp_path) == first


def test_a_keeper_that_cannot_start_is_given_up_at_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ROSDEPLOY_CONTROL_DIR", str(tmp_path / "cp"))
    monkeypatch.setattr(keeper.sys, "executable", "/bin/false")     # exits at once, never listens
    started = time.monotonic()
    with pytest.raises(keeper.KeeperUnavailable, match="did not start"):
        keeper.dial(5)
    assert time.monotonic() - started < keeper.SPAWN_WAIT / 2


def test_starting_a_keeper_removes_the_files_of_other_builds_whose_keeper_is_gone(tmp_path: Path) -> None:
    import fcntl
    import socket as sockets
    ours = tmp_path / "keeper-new.sock"
    for build in ("gone", "starting", "running"):
        for suffix in (".lock", ".log"):
            (tmp_path / f"keeper-{build}{suffix}").write_text("")
    (tmp_path / "keeper-gone.sock").write_text("")                  # left by a keeper that died
    running = sockets.socket(sockets.AF_UNIX)
    running.bind(str(tmp_path / "keeper-running.sock"))
    running.listen()
    with open(tmp_path / "keeper-starting.lock") as starting:       # another caller spawns that build now
        fcntl.flock(starting, fcntl.LOCK_EX)
        keeper.remove_old_builds(ours)
    running.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "keeper-running.lock", "keeper-running.log", "keeper-running.sock",
        "keeper-starting.lock", "keeper-starting.log"]


@pytest.mark.parametrize("why", ["open to others", "path too long"])
def test_connections_says_why_no_keeper_can_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                capsys: pytest.CaptureFixture, why: str) -> None:
    # it said "no connection keeper is running", as if one could, and status fell back without a word
    from rosdeploy.cli import main
    if why == "open to others":
        control = tmp_path / "cp"
        control.mkdir(mode=0o755)
        control.chmod(0o755)
        expected = f"{control} is open to others (mode 755); `chmod 700 {control}`"
    else:
        control = tmp_path / ("d" * 100)
        expected = "is longer than a unix socket allows (107 bytes): set ROSDEPLOY_CONTROL_DIR"
    monkeypatch.setenv("ROSDEPLOY_CONTROL_DIR", str(control))
    assert main(["connections"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("no connection keeper can run: ") and expected in text, text
    assert main(["--json", "connections"]) == 0
    assert expected in __import__("json").loads(capsys.readouterr().out)["unavailable"]


def test_connections_without_a_keeper_says_when_one_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture) -> None:
    from rosdeploy.cli import main
    monkeypatch.setenv("ROSDEPLOY_CONTROL_DIR", str(tmp_path / "cp"))
    assert main(["connections"]) == 0
    assert "no connection keeper is running: status, plan and history start one" in capsys.readouterr().out


def test_a_socket_path_too_long_starts_no_keeper(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # a keeper was started at every command, failed to listen, and the command waited for it
    monkeypatch.setenv("ROSDEPLOY_CONTROL_DIR", str(tmp_path / ("d" * 100)))
    monkeypatch.setattr(keeper, "_spawn", lambda path, persist: pytest.fail("a keeper was started"))
    with pytest.raises(keeper.KeeperUnavailable, match="longer than a unix socket allows"):
        keeper.dial(5)


def test_connections_says_when_the_keepers_socket_takes_the_call_and_never_answers(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    # it waited 10 s, then said no keeper was running
    from rosdeploy.cli import main
    monkeypatch.setenv("ROSDEPLOY_CONTROL_DIR", str(tmp_path / "cp"))
    monkeypatch.setattr(keeper, "ASK_TIMEOUT", 0.5)
    path = keeper.usable_socket_path()
    silent = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    silent.bind(str(path))
    silent.listen(1)
    try:
        assert main(["connections"]) == 0
    finally:
        silent.close()
    text = capsys.readouterr().out
    assert f"no connection keeper can run: a process holds its socket {path} but did not answer" in text, text
