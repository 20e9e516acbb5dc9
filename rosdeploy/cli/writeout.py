"""`render --out DIR`: every robot's release on disk, written while the next robots render.

Creating files is kernel time (500 robots are 3,500 files and 1,500 folders: 0.1-0.35 s on
ext4, a quarter of the command), rendering is Python time. So a child process writes each
release as soon as it is rendered, while this one renders the rest and runs the checks: the
two overlap on two cores (threads would not: every syscall waits for the GIL the renderer
holds). The child writes into a staging folder inside DIR and moves the robots' folders into
place only once every check passed; a refused fleet leaves DIR as it was, and no DIR when
there was none. Where there is no fork() (Windows), the releases are written afterwards.
"""
from __future__ import annotations

import functools
import os
import pickle
import shutil
import tempfile
from pathlib import Path
from typing import IO, Any, Callable, Iterable, Iterator, Mapping

from rosdeploy.errors import InputError, Problem
from rosdeploy.model import RenderedRelease

STAGE_PREFIX = ".rosdeploy-render-"
PIPE_BYTES = 1 << 20     # /proc/sys/fs/pipe-max-size's default
Files = list[tuple[str, int, bytes]]     # (name inside the robot's folder, mode, content)


def files_of(release: RenderedRelease) -> Files:
    for f in release.files:
        if f.name.startswith("/") or ".." in f.name.split("/"):
            raise InputError([Problem(f.name, None, "", "a rendered file name leaves the release folder; "
                                                        "rename the template")])
    return [(f.name, f.mode, f.content.encode("utf-8")) for f in release.files]


def write_release(folder: str, files: Files) -> None:
    """Every file under `folder`, with its mode (.env stays 0600 whatever the umask or an old file's mode)."""
    made: set[str] = set()
    for name, mode, data in files:
        target = os.path.join(folder, name)
        parent = os.path.dirname(target)
        if parent not in made:
            os.makedirs(parent, exist_ok=True)
            made.add(parent)
        fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
        try:
            os.fchmod(fd, mode)   # O_CREAT's mode is cut by the umask; an old file kept its own
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
        finally:
            os.close(fd)


def cannot_write(exc: OSError, root: Path) -> InputError:
    reason = exc.strerror or str(exc)
    return InputError([Problem(str(exc.filename or root), None, "--out",
                               f"cannot write there ({reason}): give a folder you can write to")])


class Writer:
    """Releases sent with send() are written by a child process; finish(commit=True) puts them in place."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.created, self.stage = _staging(root)
        data_r, data_w = os.pipe()
        status_r, status_w = os.pipe()
        self.pid = os.fork()
        if self.pid == 0:                       # the child: never returns into the caller's code
            try:
                os.close(data_w)
                os.close(status_r)
                _child(data_r, status_w, self.stage, self.root, self.created)
            finally:
                os._exit(1)
        os.close(data_r)
        os.close(status_w)
        _widen(data_w)
        self.pipe: IO[bytes] = os.fdopen(data_w, "wb")
        self.status = status_r

    def send(self, release: RenderedRelease) -> None:
        pickle.dump((release.host, files_of(release)), self.pipe, protocol=pickle.HIGHEST_PROTOCOL)

    def finish(self, commit: bool) -> None:
        """Commit (move into place) or drop what was written. The child's OSError is raised here on a
        commit; when dropping, the caller is failing already (a refusal, Ctrl-C) and says why."""
        try:
            if commit:
                pickle.dump(None, self.pipe)
            self.pipe.close()
        except BrokenPipeError:
            pass                                 # the child is gone: its status says why
        os.waitpid(self.pid, 0)
        with os.fdopen(self.status, "rb") as status:
            failed = status.read().decode("utf-8", "replace")
        if failed and commit:
            filename, _, reason = failed.partition("\0")
            raise OSError(0, reason, filename or None)


def write_all(root: Path, releases: Mapping[str, RenderedRelease]) -> None:
    """Where no child can write: every release after the checks, the same way (staged, then moved
    into place; a failure leaves no staging folder, and no `root` when this made it)."""
    created, stage = _staging(root)
    done = False
    try:
        for name, release in releases.items():
            write_release(os.path.join(stage, name), files_of(release))
        _move_into_place(stage, root, releases)
        done = True
    finally:
        _clean(stage, root, drop_root=created and not done)


def _staging(root: Path) -> tuple[bool, str]:
    """Whether `root` is made now, and a new staging folder inside it."""
    created = not root.exists()
    root.mkdir(parents=True, exist_ok=True)
    return created, tempfile.mkdtemp(prefix=STAGE_PREFIX, dir=root)


def _clean(stage: str, root: Path, drop_root: bool) -> None:
    shutil.rmtree(stage, ignore_errors=True)
    if drop_root:
        shutil.rmtree(root, ignore_errors=True)


def _widen(fd: int) -> None:
    """A 1 MB pipe (Linux) instead of 64 KB: the renderer runs ~100 robots ahead of a disk that
    stalls for a moment (a journal commit) instead of ~6, and waits only at the end if at all."""
    try:
        import fcntl
        fcntl.fcntl(fd, fcntl.F_SETPIPE_SZ, PIPE_BYTES)
    except (ImportError, AttributeError, OSError):
        pass


def _child(data_fd: int, status_fd: int, stage: str, root: Path, created: bool) -> None:
    failed, commit, names = "", False, []
    try:
        with os.fdopen(data_fd, "rb") as pipe:
            for message in _messages(pipe):
                if message is None:
                    commit = True
                elif not failed:               # after a failure: only drain, so the sender never blocks
                    names.append(message[0])
                    failed = _attempt(functools.partial(write_release, os.path.join(stage, message[0]), message[1]))
        if commit and not failed:
            failed = _attempt(lambda: _move_into_place(stage, root, names))
    except BaseException as exc:               # Ctrl-C reaches the child too: clean up all the same
        failed = failed or f"\0{exc!r}"
    finally:
        _clean(stage, root, drop_root=created and bool(failed or not commit))
        os.write(status_fd, failed.encode("utf-8"))
        os._exit(1 if failed else 0)           # not sys.exit: the parent's buffers are not ours to flush


def _messages(pipe: IO[bytes]) -> Iterator[Any]:
    while True:
        try:
            yield pickle.load(pipe)
        except EOFError:
            return


def _attempt(work: Callable[[], None]) -> str:
    try:
        work()
    except OSError as exc:
        return f"{exc.filename or ''}\0{exc.strerror or exc}"
    return ""


def _move_into_place(stage: str, root: Path, names: Iterable[str]) -> None:
    """A robot's folder moves in one rename; over an existing folder, file by file (what else is there stays)."""
    for name in names:
        source, target = os.path.join(stage, name), os.path.join(root, name)
        if not os.path.lexists(target):
            os.rename(source, target)
            continue
        for folder, _, files in os.walk(source):
            into = os.path.join(target, os.path.relpath(folder, source))
            os.makedirs(into, exist_ok=True)
            for file in files:
                os.replace(os.path.join(folder, file), os.path.join(into, file))
