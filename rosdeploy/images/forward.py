"""A registry on the robot's 127.0.0.1, through the SSH connection rosdeploy already holds.

The controller asks the robot's sshd for a reverse port forward (`ssh -R`, paramiko's
`request_port_forward`) on 127.0.0.1:<port> of the robot; every connection the robot's
dockerd opens there comes back over the SSH link as a channel, and is piped to the real
registry (or to the bundle server) from the controller. dockerd speaks the registry API
to 127.0.0.1:<port> as to any registry: it asks only for the layers it lacks, and 127.0.0.1
is an insecure-allowed registry by default, so the robot needs no daemon.json change, no
route to the registry and no credentials.

The pipe counts the bytes it sends to the robot and paces them through Limiters (the
robot's cap and the fleet-wide cap).
"""
from __future__ import annotations

import select
import socket
import threading
import time
from typing import Callable

import paramiko

from rosdeploy import execwait
from rosdeploy.errors import ConnectError
from rosdeploy.transport import EXEC_REPLY

CHUNK = 16 * 1024     # paced unit: 128 sleeps a second at 2 MB/s keep the rate even


class Limiter:
    """A byte rate shared by every pipe that takes from it (None: no cap).

    A virtual clock: each chunk books len/rate seconds after the previous booking and the
    taker sleeps until its booking ends. Idle time gives back at most `burst` seconds of
    credit, so a cap holds over any window longer than that."""

    def __init__(self, rate: float | None, burst: float = 0.2) -> None:
        self.rate = rate
        self.burst = burst
        self._lock = threading.Lock()
        self._booked = time.monotonic()

    def take(self, n: int) -> None:
        if not self.rate:
            return
        with self._lock:
            now = time.monotonic()
            self._booked = max(self._booked, now - self.burst) + n / self.rate
            wait = self._booked - now
        if wait > 0:
            time.sleep(wait)


class Meter:
    """Bytes sent to one robot, and when: for the progress line and the run's record."""

    def __init__(self) -> None:
        self.sent = 0
        self.started: float | None = None
        self.last = 0.0
        self._lock = threading.Lock()

    def add(self, n: int) -> None:
        with self._lock:
            now = time.monotonic()
            if self.started is None:
                self.started = now
            self.sent += n
            self.last = now

    @property
    def seconds(self) -> float:
        return (self.last - self.started) if self.started is not None else 0.0

    @property
    def rate(self) -> float:
        return self.sent / self.seconds if self.seconds > 0 else 0.0


class Forward:
    """`with Forward(link, upstream, limiters) as port:` the robot reaches upstream at 127.0.0.1:port."""

    def __init__(self, link: paramiko.Transport, upstream: Callable[[], socket.socket],
                 limiters: tuple[Limiter, ...], meter: Meter, host: str) -> None:
        self.link = link
        self.upstream = upstream
        self.limiters = limiters
        self.meter = meter
        self.host = host
        self.port = 0
        self._open: set[object] = set()
        self._lock = threading.Lock()

    def __enter__(self) -> int:
        try:
            # paramiko waits for the answer with no timeout (see execwait)
            with execwait.bounded(self.link, EXEC_REPLY):
                self.port = self.link.request_port_forward("127.0.0.1", 0, handler=self._accept)
        except execwait.NoReply as exc:
            raise ConnectError(self.host, f"connection lost: sshd did not answer the request for a reverse port "
                                          f"forward ({exc})") from exc
        except (paramiko.SSHException, OSError, EOFError) as exc:
            why = (f"the robot's sshd refused a reverse port forward ({exc}): images.via ssh needs "
                   "`AllowTcpForwarding yes` (or `remote`) in its sshd_config")
            raise ConnectError(self.host, why) from exc
        return self.port

    def __exit__(self, *exc: object) -> None:
        try:
            # Not paramiko's cancel_port_forward: it waits for the answer, forever on a link
            # that dropped silently. The forward dies with the connection anyway.
            self.link.global_request("cancel-tcpip-forward", ("127.0.0.1", self.port), wait=False)
        except (paramiko.SSHException, OSError, EOFError):
            pass    # the link is gone: so is the forward
        with self._lock:
            for end in list(self._open):
                end.close()     # type: ignore[attr-defined]

    def _accept(self, chan: paramiko.Channel, origin: tuple, server: tuple) -> None:
        # Called on paramiko's transport thread: hand over at once.
        threading.Thread(target=self._pipe, args=(chan,), daemon=True, name=f"forward-{self.host}").start()

    def _pipe(self, chan: paramiko.Channel) -> None:
        try:
            up = self.upstream()
        except OSError:
            chan.close()    # dockerd sees a refused connection and says so
            return
        with self._lock:
            self._open.update((chan, up))
        try:
            self._relay(chan, up)
        except (OSError, EOFError, paramiko.SSHException):
            pass            # either end went away: dockerd retries or reports it
        finally:
            with self._lock:
                self._open.difference_update((chan, up))
            chan.close()
            up.close()

    def _relay(self, chan: paramiko.Channel, up: socket.socket) -> None:
        up.settimeout(None)
        while True:
            ready, _, _ = select.select([chan, up], [], [], 60)    # type: ignore[type-var]  # Channel has fileno()
            if not ready:
                continue
            if chan in ready:
                data = chan.recv(65536)
                if not data:
                    return
                up.sendall(data)
            if up in ready:
                data = up.recv(CHUNK)
                if not data:
                    return
                for limiter in self.limiters:
                    limiter.take(len(data))
                chan.sendall(data)
                self.meter.add(len(data))
