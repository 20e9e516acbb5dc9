"""`render --out DIR`: every robot's release on disk, written by the process that rendered it.

Creating files is kernel time (500 robots are 3,500 files and 1,500 folders: 0.1-0.35 s on
ext4, a quarter of the command). A large fleet renders in forked children (rosdeploy.forked),
so each child writes the robots it rendered, on its own core, instead of sending their files
back to be written here. Everything lands in a staging folder first; the robots' folders move
into place only once every check passed, so a refused fleet leaves DIR as it was, and no DIR
(nor the folders above it that it made) when there was none. A new DIR is staged beside itself
and lands in one rename (500 robots' folders moved one by one took 14 ms); an existing one is
staged inside and filled robot by robot.
"""
from __future__ import annotations

import errno
import os
import secrets
import shutil
import tempfile
from pathlib import Path
from typing import Iterable

from rosdeploy.errors import InputError, Problem
from rosdeploy.model import RenderedRelease

STAGE_PREFIX = ".rosdeploy-render-"
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


class Staged:
    """A staging folder for `root`: write(release) puts a robot's folder there, from whichever
    process rendered it; finish(commit=True) moves every robot's folder into place. Any finish
    leaves no staging folder, and no `root` (nor a folder above it that it made) when there was
    none and nothing landed.

    A write that fails does not stop the render: the fleet's own errors, found later, say more
    than "cannot write" does. The failure is kept and raised by finish(commit=True). A forked
    child cannot keep it (its memory is gone when it exits), so there it raises: the child fails,
    and forked.mapped renders its robots again here, where the same write fails and is kept."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.made = _parents(root)     # created here: a refusal removes them again
        try:
            self.beside, self.stage = _staging(root)
        except OSError:
            _remove_empty(self.made)
            raise
        self.pid = os.getpid()
        self.failed: OSError | None = None

    def write(self, release: RenderedRelease) -> None:
        if self.failed is not None:
            return
        # cached on the release: computed on the core that rendered it, and a forked child sends
        # it back with the release, instead of this process hashing 500 robots' files for the table
        _ = release.digest
        try:
            write_release(os.path.join(self.stage, release.host), files_of(release))
        except OSError as exc:
            if os.getpid() != self.pid:
                raise
            self.failed = exc

    def finish(self, commit: bool, names: Iterable[str] = ()) -> None:
        """Move `names` into place (commit), or drop what was written (the caller is failing)."""
        landed = False
        try:
            if commit:
                if self.failed is not None:
                    raise self.failed
                if not (self.beside and _renamed_whole(self.stage, self.root)):
                    _move_into_place(self.stage, self.root, names)
                landed = True
        finally:
            shutil.rmtree(self.stage, ignore_errors=True)
            if not landed:
                _remove_empty(self.made)


def _parents(root: Path) -> list[str]:
    """The missing folders above `root`, created, outermost first. A refused `render --out a/b/c`
    left `a` and `a/b` behind; these are the only ones a refusal may remove."""
    missing = []
    parent = root.parent
    while not os.path.lexists(parent) and parent != parent.parent:
        missing.append(str(parent))
        parent = parent.parent
    made: list[str] = []
    try:
        for folder in reversed(missing):
            try:
                os.mkdir(folder)
            except FileExistsError:     # made meanwhile by another process: its folder, not ours
                continue
            made.append(folder)
    except OSError as exc:
        _remove_empty(made)
        raise OSError(exc.errno, exc.strerror, str(root)) from exc
    return made


def _remove_empty(folders: list[str]) -> None:
    """Remove `folders` (made by _parents), innermost first, each only while empty: anything
    another process put there meanwhile stays, with the folders that hold it."""
    for folder in reversed(folders):
        try:
            os.rmdir(folder)
        except OSError:
            return


def _staging(root: Path) -> tuple[bool, str]:
    """A new staging folder, and whether it is beside `root` (there is no root yet: the stage
    becomes it) or inside it. A failure names `root`, the folder the user gave."""
    try:
        if os.path.lexists(root):
            return False, tempfile.mkdtemp(prefix=STAGE_PREFIX, dir=root)
        # not mkdtemp: its 0700 would become the root's mode; mkdir's 0777 less the umask is what
        # a root made by `mkdir` always had
        stage = root.parent / f"{STAGE_PREFIX}{secrets.token_hex(6)}"   # short: any root's name fits
        stage.mkdir()
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror, str(root)) from exc
    return True, str(stage)


def _renamed_whole(stage: str, root: Path) -> bool:
    """The stage renamed to `root`; False when a `root` appeared meanwhile (then robot by robot)."""
    try:
        os.rename(stage, root)
    except OSError as exc:
        if exc.errno in (errno.ENOTEMPTY, errno.EEXIST):
            return False
        raise OSError(exc.errno, exc.strerror, str(root)) from exc   # the user's path, not the stage's
    return True


def _move_into_place(stage: str, root: Path, names: Iterable[str]) -> None:
    """A robot's folder moves in one rename; over an existing folder, file by file (what else is there stays).
    Every conflict is looked for first: one found half-way left some robots updated, some not."""
    names = list(names)
    for name in names:
        _check(os.path.join(stage, name), os.path.join(root, name))
    for name in names:
        _merge(os.path.join(stage, name), os.path.join(root, name))


def _check(source: str, target: str) -> None:
    """Raise what _merge would meet moving `source` to `target`, naming `target` (the user's path)."""
    if not os.path.lexists(target):
        return
    if os.path.islink(target) or not os.path.isdir(target):
        _blocked(target)
    for entry in os.scandir(source):
        inside = os.path.join(target, entry.name)
        if entry.is_dir(follow_symlinks=False):
            _check(entry.path, inside)
        elif os.path.isdir(inside) and not os.path.islink(inside):
            raise OSError(errno.EISDIR, "a folder where the release has a file", inside)


def _blocked(target: str) -> None:
    what = "a symbolic link, which render does not write through" if os.path.islink(target) else "File exists"
    raise OSError(errno.EEXIST, what, target)


def _merge(source: str, target: str) -> None:
    """`source` at `target`, never through a symbolic link to a folder (`--out/robot1 -> inventory/
    host_vars/robot1` had the release written into the inventory): such a link, like a file where
    the release has a folder, is the user's to remove. A link where the release has a file is
    replaced, as the file would be."""
    if os.path.islink(target) or (os.path.lexists(target) and not os.path.isdir(target)):
        _blocked(target)
    if not os.path.lexists(target):
        os.rename(source, target)
        return
    for entry in os.scandir(source):
        inside = os.path.join(target, entry.name)
        if entry.is_dir(follow_symlinks=False):
            _merge(entry.path, inside)
        else:
            os.replace(entry.path, inside)
