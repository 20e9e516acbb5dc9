"""The SSH transport on a link cut at each wait of a command, against a robot's real sshd
behind docker-proxy, which acknowledges for the robot as a NAT box or a jump host does (so
TCP never notices the cut): each wait ends within its bound with a ConnectError, never at the
command's timeout (600 s by default) and never not at all; so does the reverse port
forward's request (`images.via: ssh`).

The cut is put in at the exact moment a paramiko.Channel call starts, so each test hits the
wait it names, every run; the guard test on the fleet had hit the exec wait 1 run in ~10.
"""
from __future__ import annotations

import socket
import threading
import time
from typing import Callable, Iterator

import paramiko
import pytest

from rosdeploy import sim
from rosdeploy.commands import Command
from rosdeploy.errors import ConnectError
from rosdeploy.images.forward import Forward, Meter
from rosdeploy.model import Host
from rosdeploy.sim import SimFleet
from rosdeploy.transport import EXEC_REPLY, LINK_QUIET, LINK_TIMEOUT, SSHOptions, SSHTransport, connect

ROBOT = "robot2"
SLACK = 4.0          # s over a bound: a loaded 2-core CI machine, and the sim's own docker exec for the cut


@pytest.fixture
def link(sim_fleet: SimFleet) -> Iterator[SSHTransport]:
    robot = sim_fleet.robot(ROBOT)
    host = Host(name=ROBOT, groups=("all",), vars={}, address=robot.host, port=robot.ssh_port, user="robot",
                key_file=str(sim_fleet.key_file))
    transport = connect(host, SSHOptions(known_hosts=str(sim_fleet.known_hosts)))   # command_timeout: 600 s
    transport.reconnect = False
    try:
        yield transport
    finally:
        sim.heal(ROBOT)
        transport.close()
    again = connect(host, SSHOptions(known_hosts=str(sim_fleet.known_hosts)))
    assert again.run(Command(("true",))).ok, "the robot answers again once healed"
    again.close()


def cut_at_first(monkeypatch: pytest.MonkeyPatch, method: str, of: type = paramiko.Channel) -> None:
    """Cut the robot's link as paramiko's <of>.<method> is first called."""
    original = getattr(of, method)

    def cutting(self: object, *args: object, **kwargs: object) -> object:
        monkeypatch.setattr(of, method, original)
        sim.cut(ROBOT)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(of, method, cutting)


def lost_within(transport: SSHTransport, command: Command, bound: float) -> str:
    return lost_doing(lambda: transport.run(command), bound)


def lost_doing(action: Callable[[], object], bound: float) -> str:
    """The ConnectError `action` raises, within the bound (+ SLACK)."""
    began = time.monotonic()
    with pytest.raises(ConnectError) as caught:
        action()
    took = time.monotonic() - began
    assert took < bound + SLACK, f"noticed after {took:.1f}s, bound {bound:g}s: {caught.value}"
    return str(caught.value)


def test_a_cut_before_sshd_answers_the_exec_request(link: SSHTransport, monkeypatch: pytest.MonkeyPatch) -> None:
    """paramiko's exec_command waits for the reply with no timeout: before execwait, forever."""
    cut_at_first(monkeypatch, "exec_command")
    message = lost_within(link, Command(("true",)), EXEC_REPLY)
    assert f"connection lost during `true`: sshd did not answer the request to run it (no reply within " \
           f"{EXEC_REPLY:g}s)" in message


def test_a_cut_while_stdin_is_sent(link: SSHTransport, monkeypatch: pytest.MonkeyPatch) -> None:
    """3 MB of stdin, more than sshd's window (2 MB) but less than the buffers between (where
    more would fill them and TCP would notice): the send waits for a window a cut link never
    reopens (before: until the command's timeout)."""
    cut_at_first(monkeypatch, "send")
    message = lost_within(link, Command(("sh", "-c", "cat >/dev/null"), stdin=b"x" * (3 << 20)),
                          LINK_QUIET + LINK_TIMEOUT)
    assert "connection lost during `sh -c 'cat >/dev/null'`: the robot stopped answering" in message


def test_a_cut_while_a_command_runs(link: SSHTransport) -> None:
    """No byte for LINK_QUIET s: the transport asks sshd, which cannot answer."""
    cut = threading.Timer(1.0, sim.cut, args=(ROBOT,))
    cut.start()
    try:
        message = lost_within(link, Command(("sleep", "60")), 1.0 + LINK_QUIET + LINK_TIMEOUT)
    finally:
        cut.join()
    assert "connection lost during `sleep 60`: the robot stopped answering" in message


def test_a_cut_before_sshd_answers_the_port_forward_request(link: SSHTransport,
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """`images.via: ssh` asks for a reverse port forward; paramiko waits for the answer with no timeout."""
    cut_at_first(monkeypatch, "request_port_forward", of=paramiko.Transport)

    def forward() -> None:
        with Forward(link.link, socket.socket, (), Meter(), ROBOT):
            pass

    message = lost_doing(forward, EXEC_REPLY)
    assert "connection lost: sshd did not answer the request for a reverse port forward" in message
    with pytest.raises(ConnectError, match="connection lost before `true`"):
        link.run(Command(("true",)))        # the connection is given up, not left half-open
