"""Pure work over many items on every core: `mapped(func, items)`, results in the items' order.

Rendering 5,000 robots is Python time, one core's worth; a laptop has several. The items are cut
into contiguous slices; forked children compute all slices but the first and send back their
results (pickled, through a pipe) while this process computes the first. fork() shares the
loaded inventory without copying it, where a spawned pool would have to load it again.

Nothing rests on a child: a slice whose child fails in any way (an exception, a result that
does not pickle, a signal) is computed again here, so the results, and any exception, are the
ones the serial loop would give. Where fork() is missing, or another thread runs (a child could
inherit a lock that thread held), or the items are too few to pay for a fork, it is the serial
loop.
"""
from __future__ import annotations

import os
import pickle
import signal
import sys
from typing import IO, Any, Callable, Generator, Sequence, TypeVar

T = TypeVar("T")
R = TypeVar("R")

MIN_ITEMS = 100       # a fork and the pickling cost ~10 ms; 100 robots render in ~50 ms
MAX_WORKERS = 4       # this process reads every child's results in turn: more children, less gain
PR_SET_PDEATHSIG = 1   # linux/prctl.h: the signal a child gets when its parent dies
PARENT_SHARE = 1.25  # the child also forks, faults in pages and pickles (1.0-2.0: the same within the noise)


def can_fork() -> bool:
    """fork() exists and this process runs one thread (a child of a threaded process could
    inherit a lock some other thread held)."""
    import threading
    return hasattr(os, "fork") and threading.active_count() == 1


def workers(items: int) -> int:
    """How many processes `mapped` uses for this many items (1: the serial loop)."""
    if items < MIN_ITEMS or not can_fork():
        return 1
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(cores, MAX_WORKERS, items // (MIN_ITEMS // 2)))


def mapped(func: Callable[[T], R], items: Sequence[T]) -> Generator[R, None, None]:
    """func(item) for each item, in order; the first slice's results come as they are computed."""
    count = workers(len(items))
    if count == 1:
        yield from map(func, items)
        return
    slices = _slices(items, count)
    sys.stdout.flush()
    sys.stderr.flush()
    children: list[_Child] = []
    try:
        children.extend(_Child(func, part) for part in slices[1:])
        yield from map(func, slices[0])
        for child in children:
            yield from child.results()
    finally:
        for child in children:
            child.stop()


def _die_with(parent: int) -> None:
    """End this child when its parent ends: a parent killed outright (SIGKILL, the OOM killer)
    cleans nothing up, and its children went on writing robots' folders into a staging folder
    no one would remove. On Linux the kernel sends SIGKILL; elsewhere _orphan checks per item."""
    if sys.platform.startswith("linux"):
        import ctypes
        try:
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):    # no prctl: _orphan's check is what is left
            pass
    _orphan(parent)


def _computed(func: Callable[[T], R], part: Sequence[T], parent: int) -> list[R]:
    results = []
    for item in part:
        _orphan(parent)
        results.append(func(item))
    return results


def _orphan(parent: int) -> None:
    """Exit at once when `parent` is gone (this process was handed to another)."""
    if os.getppid() != parent:
        os._exit(1)


def _slices(items: Sequence[T], count: int) -> list[Sequence[T]]:
    """`count` contiguous slices, the first PARENT_SHARE times the others' size: a child also
    forks, faults in the pages it writes, and pickles, which takes it longer than this process
    takes to unpickle."""
    total = PARENT_SHARE + count - 1
    bounds = [0, *(round(len(items) * (PARENT_SHARE + i) / total) for i in range(count - 1)), len(items)]
    return [items[bounds[i]:bounds[i + 1]] for i in range(count)]


class _Child:
    """One forked child computing `part`, and the read end of the pipe its results come through."""

    def __init__(self, func: Callable[[T], R], part: Sequence[T]) -> None:
        self.func, self.part = func, part
        read_fd, write_fd = os.pipe()
        parent = os.getpid()
        self.pid: int | None = os.fork()
        if self.pid == 0:                 # the child: never returns into the caller's code
            code = 1
            try:
                os.close(read_fd)
                for name in ("SIGINT", "SIGTERM", "SIGHUP"):    # they end it; the parent says so
                    if hasattr(signal, name):
                        signal.signal(getattr(signal, name), signal.SIG_DFL)
                _die_with(parent)
                data = pickle.dumps(_computed(func, part, parent), protocol=pickle.HIGHEST_PROTOCOL)
                with os.fdopen(write_fd, "wb") as pipe:
                    pipe.write(data)
                code = 0
            finally:
                os._exit(code)
        os.close(write_fd)
        self.pipe: IO[bytes] | None = os.fdopen(read_fd, "rb")

    def results(self) -> list[Any]:
        """The child's results; computed here instead when it did not deliver them whole."""
        assert self.pipe is not None and self.pid is not None
        data = self.pipe.read()
        self.pipe.close()
        self.pipe = None
        _, status = os.waitpid(self.pid, 0)
        self.pid = None
        if os.waitstatus_to_exitcode(status) == 0:
            try:
                results = pickle.loads(data)
            except Exception:         # noqa: BLE001 - a broken result is recomputed, never trusted
                results = None
            if isinstance(results, list) and len(results) == len(self.part):
                return results
        return [self.func(item) for item in self.part]

    def stop(self) -> None:
        """Close the pipe and end the child if its results were never read (the caller stopped early)."""
        if self.pipe is not None:
            self.pipe.close()
            self.pipe = None
        if self.pid is not None:
            os.kill(self.pid, signal.SIGKILL)
            os.waitpid(self.pid, 0)
            self.pid = None
