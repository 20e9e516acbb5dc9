"""apply's early connections (transport.EarlyConnect), with a scripted connect."""
from __future__ import annotations

import threading

import pytest

from rosdeploy.errors import ConnectError
from rosdeploy.model import Host
from rosdeploy.transport import EarlyConnect, SSHOptions

HOSTS = [Host(f"r{i}", ("all",), {}, "127.0.0.1", port=2200 + i, user="robot") for i in range(3)]
OPTIONS = SSHOptions(known_hosts="/dev/null")


class Link:
    def __init__(self, host: Host) -> None:
        self.host, self.closed = host, False

    def close(self) -> None:
        self.closed = True


def test_the_run_takes_the_connection_opened_early_and_unused_ones_are_closed() -> None:
    opened: list[Link] = []
    release = threading.Event()

    def connect(host: Host, options: SSHOptions) -> Link:
        release.wait(5)
        if host.name == "r2":
            raise ConnectError(host.name, "no route to host")
        opened.append(Link(host))
        return opened[-1]

    early = EarlyConnect(HOSTS, OPTIONS, connect)   # type: ignore[arg-type]
    release.set()
    first = early.connect(HOSTS[0], OPTIONS)
    assert first in opened and not first.closed
    with pytest.raises(ConnectError, match="no route"):
        early.connect(HOSTS[2], OPTIONS)
    early.close()
    left: list[Link] = []
    for _ in range(100):     # r1's connect may still be under way in its thread: it closes once done
        left = [link for link in opened if link is not first]
        if left and all(link.closed for link in left):
            break
        threading.Event().wait(0.01)
    assert [link.host.name for link in left] == ["r1"] and left[0].closed and not first.closed


def test_a_robot_not_connected_early_connects_the_plain_way() -> None:
    calls: list[str] = []
    early = EarlyConnect(HOSTS[:1], OPTIONS, lambda h, o: calls.append(h.name) or Link(h))  # type: ignore[arg-type]
    early.connect(HOSTS[1], OPTIONS)
    early.close()
    assert calls.count("r1") == 1 and calls.count("r0") == 1
