"""A bound on the one wait of a command that paramiko leaves unbounded.

`Channel.exec_command` waits for sshd's reply to the exec request with no timeout. A dead
link ends that wait only when the TCP connection fails, and behind anything that
acknowledges for the robot (docker-proxy, a NAT box, a jump host) it never fails: a link
cut at that moment held a deploy's controller until it was killed, past the moment the
robot's guard acted (the guard test on the simulated fleet caught it, about 1 CI run in 10).

sshd answers an exec request itself, in milliseconds (and a port-forward request, which
paramiko's `request_port_forward` waits for the same way). `bounded(chan, seconds)` registers
the wait; one watcher thread for the whole process closes the channel (or the connection) of a
wait that outlives its bound, and the close ends paramiko's wait with an error that `bounded`
turns into `NoReply`. One thread, not a timer per command: a deploy runs dozens of commands
per robot. It exits once no wait has been registered for IDLE seconds, so a process that is done with
SSH is single-threaded again (forked.mapped forks only then).
"""
from __future__ import annotations

import threading
import time
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass
from typing import Iterator, Protocol

TICK = 0.25     # s between the watcher's looks: the bound is met to within this
IDLE = 5.0      # s without a registered wait before the watcher thread exits


class Closable(Protocol):
    def close(self) -> None: ...


class NoReply(EOFError):
    """The robot did not answer within the bound: the link is taken as lost."""

    @classmethod
    def after(cls, seconds: float) -> "NoReply":
        return cls(f"no reply within {seconds:g}s")


@dataclass
class _Wait:
    chan: Closable
    until: float                 # monotonic: when the watcher gives up on it
    expired: bool = False        # the watcher gave up (and closes the channel)


class _Watcher:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._waits: dict[int, _Wait] = {}      # by id(chan)
        self._running = False
        self._registered = 0.0       # when the last wait was registered (monotonic)

    @contextmanager
    def bounded(self, chan: Closable, seconds: float) -> Iterator[None]:
        key = id(chan)
        with self._lock:
            self._registered = time.monotonic()
            self._waits[key] = _Wait(chan, self._registered + seconds)
            if not self._running:
                self._running = True
                threading.Thread(target=self._watch, name="rosdeploy-execwait", daemon=True).start()
        try:
            yield
        except Exception as exc:
            if self._release(key):
                raise NoReply.after(seconds) from exc
            raise
        # Claimed by the watcher just as the reply came: the channel is being closed anyway.
        if self._release(key):
            raise NoReply.after(seconds)

    def _release(self, key: int) -> bool:
        """Unregister a wait; True if the watcher had already given up on it."""
        with self._lock:
            return self._waits.pop(key).expired

    def _watch(self) -> None:
        while True:
            time.sleep(TICK)
            now = time.monotonic()
            with self._lock:
                late = [w for w in self._waits.values() if not w.expired and w.until <= now]
                for wait in late:
                    wait.expired = True
                if not self._waits and now - self._registered >= IDLE:
                    self._running = False
                    return
            for wait in late:         # outside the lock: close() sends a message on the link
                try:
                    wait.chan.close()
                except Exception:     # a link already dead: the wait ends all the same, and
                    pass              # this thread must live on for the other waits


_WATCHER = _Watcher()


def bounded(chan: Closable, seconds: float) -> AbstractContextManager[None]:
    """Within this block, a wait on `chan` longer than `seconds` closes it and raises NoReply."""
    return _WATCHER.bounded(chan, seconds)
