"""Finding the inventory files (a file or a directory of them) and reading them, vault included."""
from __future__ import annotations

import errno
import json
import os
import re
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

from rosdeploy import yamlsrc
from rosdeploy.errors import InputError, Problem, VaultError
from rosdeploy.inventory.draft import Draft, Origin
from rosdeploy.inventory.ini_parser import check_undeclared, parse_ini
from rosdeploy.inventory.known import MAYBE_NOT_INVENTORY, SCRIPT_EXTS, SKIPPED_EXTS, YAML_EXTS
from rosdeploy.inventory.script import is_script, parse_script
from rosdeploy.inventory.toml_source import parse_toml
from rosdeploy.inventory.yaml_parser import parse_yaml
from rosdeploy.vault import Vault, WrongPassword, is_encrypted
from rosdeploy.yamlsrc import Doc, Encrypted, KeyPath


BOM = "\ufeff".encode()


class Reader:
    """Reads files, decrypting vault ones in memory, and turns YAML into Docs."""

    def __init__(self, vault: Vault, warnings: list[Problem]) -> None:
        self.vault = vault
        self.warnings = warnings   # duplicate keys: Ansible warns and keeps the last, so do we

    def text(self, path: Path, problems: list[Problem]) -> tuple[str, bool] | None:
        try:
            data = yamlsrc.read_bytes(str(path), what="an inventory or vars file (YAML or INI)")
        except InputError as exc:
            problems.extend(exc.problems)
            return None
        if data.startswith(BOM) and is_encrypted(data[len(BOM):]):
            # Not stripped: ansible-vault reads it as plain text too. It was refused as "a vars file
            # must be a mapping", the header read as a YAML string.
            problems.append(Problem(str(path), 1, "", "the file starts with a byte-order mark (U+FEFF) before its "
                                                      "vault header, so it does not read as encrypted (in Ansible "
                                                      "either): save it as UTF-8 without BOM"))
            return None
        plain, secret = self.vault.read(str(path), data)
        try:
            return yamlsrc.decoded(str(path), plain), secret
        except InputError as exc:    # at its line, as the fleet file's
            problems.extend(exc.problems)
            return None

    def doc(self, path: Path, problems: list[Problem]) -> Origin | None:
        """A YAML file, `!vault` values decrypted, as the origin of its root mapping."""
        read = self.text(path, problems)
        return None if read is None else self.load(path, read[0], read[1], problems)

    def load(self, path: Path, text: str, secret: bool, problems: list[Problem]) -> Origin | None:
        try:
            doc = yamlsrc.load(path, text, duplicates=self.warnings)
        except InputError as exc:
            problems.extend(exc.problems)
            return None
        revealed: set[str] = set()
        data = self._reveal(doc.data, doc, (), revealed)
        return Origin(Doc(doc.path, data, doc.lines), (), secret, frozenset(revealed))

    def _reveal(self, value: Any, doc: Doc, kp: KeyPath, revealed: set[str]) -> Any:
        """`value` with every `!vault` scalar (Ansible's encrypt_string) decrypted."""
        if isinstance(value, Encrypted):
            plain = self._open(value, doc, kp)
            revealed.add(plain)
            return plain
        if isinstance(value, dict):
            return {key: self._reveal(item, doc, kp + (key,), revealed) for key, item in value.items()}
        if isinstance(value, list):
            return [self._reveal(item, doc, kp + (i,), revealed) for i, item in enumerate(value)]
        return value

    def _open(self, value: Encrypted, doc: Doc, kp: KeyPath) -> str:
        """One `!vault` value's plaintext. Its problems are reported at its key's line: decrypting
        knows only the file, and a vars file may hold many of them."""
        data = value.encode("ascii", "replace")
        name = kp[-1] if kp and isinstance(kp[-1], str) else "NAME"
        command = f"`rosdeploy vault encrypt-string --name {name}` and paste its output here"
        if not is_encrypted(data):   # never quoted: it may be the secret itself, pasted unencrypted
            raise VaultError([doc.problem(kp, "this `!vault` value has no $ANSIBLE_VAULT or $ROSDEPLOY_VAULT "
                                              f"header, so it is not encrypted: encrypt it with {command}")])
        try:
            plain = self.vault.decrypt(data, doc.path).decode("utf-8")
        except WrongPassword as exc:
            hint = f"; if it was encrypted with another password, re-encrypt it with {command}"
            raise WrongPassword(_at(exc, doc, kp, hint)) from None
        except VaultError as exc:
            raise VaultError(_at(exc, doc, kp)) from None
        except UnicodeDecodeError:
            raise VaultError([doc.problem(kp, "a !vault value is not UTF-8 text once decrypted: "
                                              "encrypt text only")]) from None
        why = yamlsrc.not_text(plain, controls=True)
        if why is not None:    # as any other value, named by its code point only
            raise VaultError([doc.problem(kp, f"this !vault value {why}")])
        return plain


def _at(error: VaultError, doc: Doc, kp: KeyPath, hint: str = "") -> list[Problem]:
    """The problems of `error` about `doc` moved to the line of `kp` (those about a password file stay)."""
    return [doc.problem(kp, p.message + hint) if p.file == doc.path else p for p in error.problems]


def is_dir(path: Path) -> bool:
    """Path.is_dir(), False for a path that cannot be looked at: Python 3.11 raises on EACCES
    (a folder under /proc, or another user's), where the caller only asks whether to walk it."""
    try:
        return path.is_dir()
    except OSError:
        return False


def _exists(path: Path) -> bool:
    try:
        return path.exists()
    except OSError:
        return False


def _not_found(root: Path) -> str:
    """Why `root` is not there. A symbolic link loop fails exists() as a missing file does, and
    was reported as one: the path is there, and the link is what to fix."""
    try:
        os.stat(root)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return ("a symbolic link loop (a link that leads back to itself, directly or through other "
                    "links): fix the link, or check -i / the fleet file's `inventory:` path")
    except ValueError:
        pass
    return "inventory not found: check -i / the fleet file's `inventory:` path"


def parse_sources(root: Path, reader: Reader, draft: Draft) -> Path:
    """Parse the inventory file(s); returns the directory holding group_vars/ and host_vars/."""
    if is_dir(root):
        files, base = _inventory_files(root, draft.problems), root
        if not files and not draft.problems:
            draft.problems.append(Problem(str(root), None, "", "no inventory file in this directory: "
                                                               "add hosts.yml (YAML) or hosts (INI)"))
    elif root.is_file():
        files, base = [root], root.parent
    elif _exists(root):     # /dev/null, a fifo, a socket: there, but nothing to read an inventory from
        draft.problems.append(Problem(str(root), None, "", "not a regular file or folder: give the path of an "
                                                           "inventory file or folder (-i / the fleet file's "
                                                           "`inventory:`)"))
        return root
    else:
        draft.problems.append(Problem(str(root), None, "", _not_found(root)))
        return root
    for path in files:
        if is_password_file(path, reader):
            # never read: Ansible would take the password for a host name, and print it
            draft.problems.append(Problem(str(path), None, "", "this is the vault password file, not an inventory: "
                                          + ("move it out of the inventory folder, where every file is read as "
                                             "inventory" if path != root else "check -i / the fleet file's "
                                             "`inventory:`")))
            continue
        if is_script(path):
            parse_script(path, draft)
            continue
        read = reader.text(path, draft.problems)
        if read is None:
            continue
        ext = os.path.splitext(path.name)[1]   # Ansible's test: `hosts.` has the extension "."
        if ext == ".toml":
            parse_toml(path, read[0], read[1], draft)
        elif not ext or ext in YAML_EXTS:
            _parse_yaml_or_ini(path, read, reader, draft)
        elif path.name.endswith(MAYBE_NOT_INVENTORY) and is_dir(root):
            _parse_ini_or_skip(path, read, draft)
        else:
            parse_ini(path, read[0], read[1], draft)
    check_undeclared(draft)
    return base


def _same_file(path: Path | str) -> tuple[int, int] | None:
    try:
        found = os.stat(path)
    except (OSError, ValueError):
        return None
    return found.st_dev, found.st_ino


def is_password_file(path: Path, reader: Reader) -> bool:
    """Whether `path` is a vault password file: such a file is never read as inventory or vars."""
    found = _same_file(path)
    return found is not None and found in {_same_file(p) for p in reader.vault.password_files}


def _parse_yaml_or_ini(path: Path, read: tuple[str, bool], reader: Reader, draft: Draft) -> None:
    """A `.yml`/`.yaml`/`.json` file, or one with no extension. Ansible tries its yaml plugin on
    these, then its ini plugin: a YAML document that is a mapping is a YAML inventory, anything
    else (INI text, which seldom parses as YAML, or a bare list of host names) is read as INI."""
    tried: list[Problem] = []
    warned = len(draft.warnings)
    origin = reader.load(path, read[0], read[1], tried)
    if origin is not None and (origin.doc.data is None or isinstance(origin.doc.data, dict)):
        parse_yaml(origin, draft)
        return
    if origin is None and not any(p.message.startswith(_SYNTAX) for p in tried):
        draft.problems.extend(tried)    # YAML that parsed, with a value it refuses: no INI reading of it
        return
    del draft.warnings[warned:]   # duplicate keys or octal numbers of a reading that was dropped
    if origin is not None:
        tried.append(origin.doc.problem((), f"{_kind(path)} that is not a mapping: an inventory is a mapping of "
                                            "group names, starting with `all:`"))
    if _is_json(path):
        tried = [_json_problem(path, read[0], tried[0])]
    before = len(draft.problems)
    parse_ini(path, read[0], read[1], draft)
    if len(draft.problems) == before:
        if os.path.splitext(path.name)[1]:   # named YAML, read as INI: say so, the next reader may not
            draft.warnings.append(Problem(str(path), None, "", f"not {_kind(path)} but INI: read as INI, as "
                                          f"Ansible does; name it {path.stem}.ini", severity="warning"))
        return
    draft.problems[before:] = _both_failed(path, draft.problems[before:], tried[0], read[0])


# How yamlsrc.load words a document it could not parse (then Ansible's next plugin, INI, is tried)
_SYNTAX = ("invalid YAML", "invalid JSON")


def _kind(path: Path) -> str:
    return "JSON" if _is_json(path) else "YAML"


def _is_json(path: Path) -> bool:
    return os.path.splitext(path.name)[1] == ".json"


def _json_problem(path: Path, text: str, problem: Problem) -> Problem:
    """A `.json` file's syntax error in JSON's words: a YAML parser's ("did not find expected
    <document start>") under a JSON label misleads. YAML's stays when JSON reads the file."""
    try:
        json.loads(text)
    except json.JSONDecodeError as exc:
        return Problem(problem.file, exc.lineno, "", f"invalid JSON: {exc.msg} (column {exc.colno})")
    except (ValueError, RecursionError):   # a 4,300-digit number, deep nesting: YAML said it already
        pass
    return problem


def _both_failed(path: Path, ini: list[Problem], tried: Problem, text: str) -> list[Problem]:
    """What each reader said, briefly. With an extension, the YAML/JSON reader's (the extension says
    what was meant) and INI's first. With none, INI's all (an INI file with a typo is the common
    case), then YAML's unless a line starts with `[`: no YAML mapping has one, INI sections do."""
    if os.path.splitext(path.name)[1]:
        others = len(ini) - 1
        more = f" (and {others} more INI problem{'s' * (others > 1)})" if others else ""
        where = f"line {ini[0].line}: " if ini[0].line else ""
        return [replace(tried, message=f"{tried.message}; not INI either, which Ansible tries next "
                                       f"({where}{ini[0].message}{more})")]
    if _INI_SECTION.search(text):
        return ini
    return [*ini, replace(tried, message=f"not YAML either ({tried.message}): a file with no extension is "
                                         "read as YAML when it holds a mapping, else as INI, as Ansible does; "
                                         f"name it {path.name}.yml or {path.name}.ini to have it read one way")]


_INI_SECTION = re.compile(r"^\[", re.MULTILINE)


def _parse_ini_or_skip(path: Path, read: tuple[str, bool], draft: Draft) -> None:
    """`hosts.example` & co: Ansible tries them as INI and only warns when that fails."""
    before = len(draft.problems)
    parse_ini(path, read[0], read[1], draft)
    if len(draft.problems) > before:
        first = draft.problems[before]
        del draft.problems[before:]
        draft.warnings.append(Problem(str(path), first.line, "", f"not an inventory ({first.message}): skipped, "
                                      "as Ansible skips a file it cannot parse", severity="warning"))


# An inventory directory holds a few dozen files. Past this many entries the path is almost
# surely wrong (`inventory: /`, `../..`): stop before walking, or running scripts in, a whole disk.
MAX_DIR_ENTRIES = 5000


def _inventory_files(root: Path, problems: list[Problem]) -> list[Path]:
    found: list[Path] = []
    seen: set[Path] = set()
    walked = [0]
    before = len(problems)

    def walk(folder: Path) -> None:
        real = folder.resolve()
        if real in seen:   # a symlink loop, or two links to one folder: read it once
            return
        seen.add(real)
        try:
            entries = sorted(folder.iterdir())
        except OSError as error:
            raise _Unreadable(folder, error.strerror or str(error)) from None
        tally(walked, entries)
        for entry in entries:
            _sort_entry(entry, walk, found, problems)

    try:
        walk(root)
    except _Unreadable as error:
        problems.append(Problem(str(error.folder), None, "", f"cannot read this inventory folder ({error.reason})"))
        return []
    except TooBig:
        del problems[before:]   # what the walk met on a whole disk (`chmod +x` for every *.py) hides the cause
        problems.append(Problem(str(root), None, "", f"more than {MAX_DIR_ENTRIES} entries under this inventory "
                                "directory: it does not look like an inventory; point -i / the fleet file's "
                                "`inventory:` at the folder that holds hosts.yml (or the file itself)"))
        return []
    return found


class _Unreadable(Exception):
    def __init__(self, folder: Path, reason: str) -> None:
        super().__init__(reason)
        self.folder, self.reason = folder, reason


class TooBig(Exception):
    """More than MAX_DIR_ENTRIES entries met by one walk."""


def tally(walked: list[int], entries: list[Path]) -> None:
    """Count a folder's entries into one walk's total: TooBig past MAX_DIR_ENTRIES."""
    walked[0] += len(entries)
    if walked[0] > MAX_DIR_ENTRIES:
        raise TooBig


def _sort_entry(entry: Path, walk: Callable[[Path], None], found: list[Path], problems: list[Problem]) -> None:
    if entry.name.startswith(".") or entry.name in ("group_vars", "host_vars"):
        return
    if is_dir(entry):
        walk(entry)
    elif entry.name.endswith(SKIPPED_EXTS):
        return
    elif entry.suffix in SCRIPT_EXTS and not is_script(entry):
        problems.append(Problem(str(entry), None, "", "looks like a dynamic inventory script but is not "
                                "executable: `chmod +x` it to have it run (as Ansible does), or move it "
                                "out of the inventory directory"))
    else:
        found.append(entry)  # which reader takes it is parse_sources' choice, by extension as Ansible
