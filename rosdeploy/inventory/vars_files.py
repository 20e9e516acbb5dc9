"""`group_vars/` and `host_vars/` beside the inventory: files and directories of them."""
from __future__ import annotations

import errno
import os
import re
import stat
from pathlib import Path

from rosdeploy import suggest
from rosdeploy.errors import Problem, shown
from rosdeploy.inventory import discovery
from rosdeploy.inventory.discovery import Reader, TooBig, is_dir, tally
from rosdeploy.inventory.draft import Draft, Layer, make_layer
from rosdeploy.inventory.known import SKIPPED_EXTS, VARS_EXTS, YAML_EXTS


def attach_vars_files(base: Path, reader: Reader, draft: Draft) -> None:
    for kind, entities in (("group_vars", draft.groups), ("host_vars", draft.hosts)):
        for name, chosen in _vars_files(base / kind, draft).items():
            target = entities.get(name)
            # a NAME/ folder is walked only for a known name: `group_vars -> /` walks no disk
            files = _vars_dir(chosen, draft) if target is not None and is_dir(chosen) else [chosen]
            if target is None:
                # NAME.yml/ is NAME's vars folder (judged under NAME) and, rarely, that of a group `NAME.yml`
                named = chosen.suffix in YAML_EXTS and chosen.name == name
                if kind == "group_vars" and not named and not _empty_dir(chosen):
                    _unknown_group_vars(chosen, name, list(entities), draft)
                continue
            for path in files:
                layer = _read_vars_file(path, reader, draft)
                if layer is not None:
                    target.files.append(layer)


def _empty_dir(path: Path) -> bool:
    try:
        return is_dir(path) and next(path.iterdir(), None) is None
    except OSError:
        return False


def _vars_files(folder: Path, draft: Draft) -> dict[str, Path]:
    """Entity name → its vars file or folder, chosen as Ansible's find_vars_files does."""
    if not is_dir(folder):
        why = _not_a_folder(folder)
        if why is not None:
            draft.problems.append(Problem(str(folder), None, "", why))
        return {}
    candidates: dict[str, list[Path]] = {}
    for entry in _listing(folder, draft):
        if entry.name.startswith(".") or entry.name.endswith("~"):
            continue
        # Not is_file(): a fifo, a device or a dangling symlink named NAME.yml is still NAME's vars
        # file, and reading it gives the error ("not a regular file") rather than losing its vars.
        if entry.suffix in YAML_EXTS:
            # a folder NAME.yml/ too: Ansible looks for NAME.yml and reads a folder found there
            candidates.setdefault(entry.stem, []).append(entry)
        if entry.suffix not in YAML_EXTS or is_dir(entry):
            if not entry.name.endswith(SKIPPED_EXTS):   # NAME/ or NAME: host names may hold dots
                candidates.setdefault(entry.name, []).append(entry)
    out: dict[str, Path] = {}
    for name, found in candidates.items():
        # Ansible takes the first of NAME (file or directory), NAME.yml, NAME.yaml, NAME.json.
        found.sort(key=lambda p: VARS_EXTS.index(p.suffix) if p.name != name else -1)
        chosen = f"{found[0]}{'/' if is_dir(found[0]) else ''}"
        for ignored in found[1:]:
            draft.warnings.append(Problem(str(ignored), None, "", f"ignored: {chosen} already holds the vars of "
                                          f"{shown(name)}, and Ansible reads only the first of NAME, NAME.yml, "
                                          "NAME.yaml, NAME.json; merge them", severity="warning"))
        out[name] = found[0]
    return out


def _not_a_folder(folder: Path) -> str | None:
    """Why `folder` (group_vars or host_vars), there but not a folder, is refused; None when it is absent.

    Ansible warns and skips it; skipped, every robot would deploy without the vars it holds, and
    nothing would name the folder (only downstream errors, or none at all)."""
    name = folder.name
    try:
        info = os.lstat(folder)
    except OSError as exc:
        if exc.errno in (errno.ENOENT, errno.ENOTDIR):
            return None
        return f"cannot look at this {name} folder ({exc.strerror or exc}): fix its permissions or remove it"
    if stat.S_ISLNK(info.st_mode):
        target = shown(_readlink(folder))
        if _loops(folder):
            return f"a symlink loop (through {target}): the vars in {name} would be lost; fix the link or remove it"
        if not folder.exists():
            return (f"a symlink to {target}, which does not exist: the vars in {name} would be lost; "
                    "fix the link or remove it")
        return (f"a symlink to {target}, {_kind(folder)}, where the {name} folder belongs: its vars would be lost "
                "(Ansible skips it); link to a folder of vars files, or remove it")
    return (f"{_kind(folder)} where the {name} folder belongs: its vars would be lost (Ansible skips it); "
            f"make {name} a folder of NAME.yml files, or remove it")


def _kind(path: Path) -> str:
    """What a path that is not a folder is, in words."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return "something that cannot be read"
    if stat.S_ISREG(mode):
        return "a regular file"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "not a folder"


def _readlink(path: Path) -> str:
    try:
        return os.readlink(path)
    except OSError:
        return "?"


def _listing(folder: Path, draft: Draft) -> list[Path]:
    try:
        return sorted(folder.iterdir())
    except OSError as error:
        draft.problems.append(Problem(str(folder), None, "", f"cannot read this vars folder "
                                      f"({error.strerror or error}): fix its permissions or remove it"))
        return []


def _vars_dir(folder: Path, draft: Draft) -> list[Path]:
    """The files of a NAME/ folder, bounded: a link in it to `/` or a home would walk a whole disk
    and read every *.yml there."""
    try:
        return _dir_files(folder, draft, set(), [0])
    except TooBig:
        draft.problems.append(Problem(str(folder), None, "", f"more than {discovery.MAX_DIR_ENTRIES} entries under "
                                      "this vars folder (a symlink in it to / or to a home?): it does not look "
                                      "like a folder of vars files; fix the link or move the files"))
        return []


def _dir_files(folder: Path, draft: Draft, seen: set[str], walked: list[int]) -> list[Path]:
    real = _real(folder)
    if real in seen:   # a symlink back up the tree: Ansible would follow it ~40 levels deep
        draft.warnings.append(Problem(str(folder), None, "", f"symlink loop (back to {real}): its files are "
                                      "read once; remove the link", severity="warning"))
        return []
    seen = seen | {real}
    found: list[Path] = []
    entries = _listing(folder, draft)
    tally(walked, entries)
    for entry in entries:
        if entry.name.startswith(".") or entry.name.endswith("~"):
            continue
        if is_dir(entry) and not entry.suffix:
            found.extend(_dir_files(entry, draft, seen, walked))
        elif entry.suffix in VARS_EXTS and not is_dir(entry):   # not is_file(): see _vars_files
            found.append(entry)
    return list({_real(path): path for path in reversed(found)}.values())[::-1]   # each file once


def _real(path: Path) -> str:
    try:
        return os.path.realpath(path)
    except OSError:   # a link it may not read (EACCES under /proc): the path stands for itself
        return str(path)


def _read_vars_file(path: Path, reader: Reader, draft: Draft) -> Layer | None:
    if path.is_symlink() and not path.exists():
        target = shown(os.readlink(path))
        why = (f"a symlink loop (through {target})" if _loops(path)
               else f"a symlink to {target}, which does not exist")
        draft.problems.append(Problem(str(path), None, "", f"{why}: its vars would be lost; fix the link or remove it"))
        return None
    if discovery.is_password_file(path, reader):
        # never read: its text would be a YAML string, reported as "must be a mapping"
        draft.problems.append(Problem(str(path), None, "", "this is the vault password file, not a vars file: "
                                      "move it out of the inventory folder, where every file is read"))
        return None
    origin = reader.doc(path, draft.problems)
    if origin is None or origin.doc.data is None:
        return None
    if not isinstance(origin.doc.data, dict):
        draft.problems.append(origin.problem((), "a vars file must be a mapping of name: value"))
        return None
    return make_layer(origin.doc.data, origin)


def _loops(path: Path) -> bool:
    try:
        os.stat(path)
    except OSError as exc:
        return exc.errno == errno.ELOOP
    return False


def _unknown_group_vars(path: Path, name: str, known: list[str], draft: Draft) -> None:
    # Vars for a group another inventory defines are normal (shared group_vars); only a
    # misspelt name is worth stopping for, as its vars would silently never apply.
    # Names that differ only in numbers (site_3 vs site_1) are other groups, not typos;
    # host_vars are not judged at all: leftovers of retired robots are common and harmless.
    close = suggest.closest(name, known, cutoff=0.75)
    if close and re.sub(r"\d+", "#", close) != re.sub(r"\d+", "#", name):
        draft.problems.append(Problem(str(path), None, "", f"no group named {shown(name)} in the inventory: "
                                      f"did you mean {shown(close)}? rename the file or directory"))


