"""execwait: a wait with no timeout of its own ends within its bound, and only then."""
from __future__ import annotations

import threading
import time

import pytest

from rosdeploy import execwait


class Channel:
    """A wait that ends only when the channel is closed (as paramiko's exec_command wait does)."""

    def __init__(self, close_fails: bool = False) -> None:
        self.closed = threading.Event()
        self.close_fails = close_fails

    def close(self) -> None:
        self.closed.set()
        if self.close_fails:
            raise OSError("Socket is closed")

    def wait_for_reply(self, reply_after: float | None = None) -> None:
        if self.closed.wait(reply_after):
            raise EOFError("Channel closed.")


@pytest.fixture(autouse=True)
def quick(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(execwait, "TICK", 0.02)
    monkeypatch.setattr(execwait, "IDLE", 0.2)


def watchers() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "rosdeploy-execwait"]


def test_a_wait_that_outlives_its_bound_is_closed_and_says_so() -> None:
    chan = Channel()
    began = time.monotonic()
    with pytest.raises(execwait.NoReply, match=r"no reply within 0\.3s"):
        with execwait.bounded(chan, 0.3):
            chan.wait_for_reply()
    assert chan.closed.is_set()
    assert 0.3 <= time.monotonic() - began < 1.5


def test_a_reply_within_the_bound_leaves_the_channel_open() -> None:
    chan = Channel()
    with execwait.bounded(chan, 1.0):
        chan.wait_for_reply(reply_after=0.1)
    time.sleep(1.2)                    # past the bound: the watcher no longer looks at it
    assert not chan.closed.is_set()


def test_an_error_of_its_own_is_not_called_no_reply() -> None:
    with pytest.raises(KeyError):
        with execwait.bounded(Channel(), 5.0):
            raise KeyError("refused")


def test_each_wait_has_its_own_bound() -> None:
    slow, quick_ = Channel(), Channel()
    outcomes: dict[str, str] = {}

    def waits(name: str, chan: Channel, bound: float, reply_after: float) -> None:
        try:
            with execwait.bounded(chan, bound):
                chan.wait_for_reply(reply_after)
            outcomes[name] = "replied"
        except execwait.NoReply:
            outcomes[name] = "no reply"

    threads = [threading.Thread(target=waits, args=("slow", slow, 0.2, 3.0)),
               threading.Thread(target=waits, args=("quick", quick_, 2.0, 0.4))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(5)
    assert outcomes == {"slow": "no reply", "quick": "replied"}
    assert slow.closed.is_set() and not quick_.closed.is_set()


def test_the_watcher_thread_ends_when_nothing_waits() -> None:
    """A process done with SSH is single-threaded again: forked.mapped forks only then."""
    with execwait.bounded(Channel(), 5.0):
        assert len(watchers()) == 1
    deadline = time.monotonic() + 3
    while watchers() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert watchers() == []
    with execwait.bounded(Channel(), 5.0):       # and starts again when needed
        assert len(watchers()) == 1


def test_a_close_that_fails_does_not_stop_the_watcher() -> None:
    """The first channel's close raises (its link is dead already); the next wait is still bounded."""
    first, second = Channel(close_fails=True), Channel()
    for chan in (first, second):
        with pytest.raises(execwait.NoReply):
            with execwait.bounded(chan, 0.2):
                chan.wait_for_reply(reply_after=3.0)
    assert second.closed.is_set()


def test_short_waits_keep_the_watcher_alive() -> None:
    """Waits of microseconds, which the watcher's looks seldom catch: it stays while they come
    (one thread for the whole deploy, not one started every IDLE seconds)."""
    seen: list[threading.Thread] = []
    for _ in range(20):                # 1 s of registrations, five times the idle time
        with execwait.bounded(Channel(), 5.0):
            pass
        seen.extend(watchers())
        time.sleep(0.05)
    assert len(seen) == 20 and all(t is seen[0] for t in seen)
