"""Ansible inventories, read the way Ansible reads them, turned into frozen `Host`s.

A team's existing inventory must work unchanged, so this follows Ansible's own
rules rather than inventing better ones:

* formats: YAML (`all:`/`children:`/`hosts:`/`vars:`; `.yml`, `.yaml`, `.json`)
  and INI (`[g]`, `[g:vars]`, `[g:children]`, inline `k=v` parsed with
  `ast.literal_eval` like Ansible, `host[01:03]` ranges, `host:port`); any other
  name without an extension is INI, as in Ansible.
* `-i DIR` reads every inventory file below DIR (hidden files, `group_vars/`,
  `host_vars/` and docs/backups skipped), in sorted order.
* `group_vars/` and `host_vars/` beside the inventory: `NAME`, `NAME.yml`,
  `NAME.yaml`, `NAME.json`, or a directory `NAME/` of such files (sorted).
* precedence, low to high, exactly Ansible's default VARIABLE_PRECEDENCE:
  inline vars of `all` < inline vars of the other groups < group_vars/all <
  group_vars of the other groups < inline host vars < host_vars files. Groups
  are ordered by (depth, ansible_group_priority, name), so a child beats its
  parent and, at equal depth, the alphabetically later group wins. Top-level
  keys replace, nested maps are not merged (Ansible's hash_behaviour=replace).

Stricter than Ansible where silence would deploy the wrong thing: every
problem is collected (file, line, key path, fix) and raised as one
InventoryError; a near-miss of a variable rosdeploy reads (`ros_domian_id`) is
an error, not a new free-form variable.
"""
from __future__ import annotations

import ast
import difflib
import os
import re
import shlex
import string
import warnings
from dataclasses import dataclass, field
from itertools import chain
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping

from rosdeploy import patterns, yamlsrc
from rosdeploy.errors import InputError, InventoryError, Problem, VaultError
from rosdeploy.model import Host, UdevDevice, frozen_map
from rosdeploy.vault import Vault
from rosdeploy.yamlsrc import Doc, Encrypted, KeyPath

# ------------------------------------------------------------------ public values


@dataclass(frozen=True)
class Group:
    name: str
    hosts: tuple[str, ...]       # every host in the group or a descendant group, inventory order
    children: tuple[str, ...]
    parents: tuple[str, ...]
    vars: Mapping[str, Any]      # the group's own vars: inline, then its group_vars files
    source: str                  # "file:line" where it was first declared


@dataclass(frozen=True)
class Inventory:
    path: str
    hosts: Mapping[str, Host]    # declaration order
    groups: Mapping[str, Group]

    def select(self, pattern: str | None) -> tuple[Host, ...]:
        """Hosts an Ansible pattern (`--limit`) selects, inventory order; None → all."""
        members = {name: group.hosts for name, group in self.groups.items()}
        names = patterns.select(pattern, tuple(self.hosts), members)
        return tuple(self.hosts[name] for name in names)


def load_inventory(path: str, vault: Vault | None = None) -> Inventory:
    """Read an inventory file or directory; InventoryError listing every problem found.

    Without a `vault`, vault files are decrypted with the password from the
    environment (ROSDEPLOY_VAULT_PASSWORD[_FILE]) and never with a prompt.
    """
    root = Path(path)
    reader = _Reader(vault or Vault())
    draft = _Draft(str(root))
    base = _parse_sources(root, reader, draft)
    _attach_vars_files(base, reader, draft)
    graph = _Graph.build(draft)
    inventory = _assemble(draft, graph, root, base) if graph else None
    if draft.problems or inventory is None:
        raise InventoryError(dict.fromkeys(draft.problems))
    return inventory


# ------------------------------------------------------------------ known vars

ROSDEPLOY_VARS = ("ros_domain_id", "ros_network", "devices", "gpu", "udev",
                  "rosdeploy_images_via", "rosdeploy_images_max_rate",   # read by rosdeploy/images
                  "rosdeploy_known_hosts")  # the last one is read by transport.py, from Host.vars
CONNECTION_VARS = ("ansible_host", "ansible_port", "ansible_user", "ansible_ssh_private_key_file")
# Older spellings Ansible still honours; the primary name wins when both are set.
ALIASES = {"ansible_ssh_host": "ansible_host", "ansible_ssh_port": "ansible_port",
           "ansible_ssh_user": "ansible_user", "ansible_private_key_file": "ansible_ssh_private_key_file"}
CONSUMED_VARS = (*ROSDEPLOY_VARS, *CONNECTION_VARS, *ALIASES)
# Real Ansible variables that merely look like the ones above: never "did you mean".
_ANSIBLE_VARS = frozenset({
    "ansible_become", "ansible_become_user", "ansible_become_pass", "ansible_become_password",
    "ansible_become_method", "ansible_become_exe", "ansible_become_flags", "ansible_connection",
    "ansible_password", "ansible_ssh_pass", "ansible_ssh_password", "ansible_python_interpreter",
    "ansible_shell_type", "ansible_shell_executable", "ansible_ssh_common_args", "ansible_ssh_extra_args",
    "ansible_sftp_extra_args", "ansible_scp_extra_args", "ansible_ssh_pipelining", "ansible_pipelining",
    "ansible_ssh_executable", "ansible_host_key_checking", "ansible_ssh_host_key_checking",
    "ansible_group_priority", "ansible_timeout", "ansible_ssh_timeout", "ansible_ssh_retries",
    "ansible_remote_tmp", "ansible_network_os", "ansible_hostname", "ansible_user_id", "ansible_user_dir",
    "ansible_user_shell", "ansible_docker_extra_args", "ansible_port_forwarding", "ansible_host_pattern",
})
_NEAR_MISS_CUTOFF = 0.85

# Characters a shell, ssh or compose would give meaning to. Commands are quoted
# anyway; refusing them here is defence in depth and catches copy-paste junk.
_SHELL_UNSAFE = frozenset(string.whitespace + "\0;&|$`'\"<>(){}[]*?!\\#~")
_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")
_SYMLINK = re.compile(r"[A-Za-z0-9_.-]+(/[A-Za-z0-9_.-]+)*")
_HEX4 = re.compile(r"[0-9a-fA-F]{4}")
_SERIAL = re.compile(r"[A-Za-z0-9_.:/+-]+")
_UNIX_GROUP = re.compile(r"[a-z_][a-z0-9_-]*")
_SUBSYSTEM = re.compile(r"[a-z0-9_]+")
_MODE = re.compile(r"0?[0-7]{3}")
_UDEV_KEYS = ("symlink", "subsystem", "vendor", "product", "serial", "group", "mode")
_UDEV_REQUIRED = ("symlink", "subsystem", "vendor", "product")
_GROUP_KEYS = ("hosts", "vars", "children")
_YAML_EXTS = (".yml", ".yaml", ".json")
_VARS_EXTS = ("", *_YAML_EXTS)
_SKIPPED_EXTS = (".md", ".txt", ".rst", ".orig", ".bak", ".swp", ".pyc", ".pyo", ".retry", ".cfg", ".rpm", "~",
                 ".example", ".sample", ".j2")
# Dynamic inventories (scripts, plugin configs) that Ansible would run: refused, not misread as INI.
_SCRIPT_EXTS = (".py", ".sh", ".toml", ".js", ".rb", ".pl", ".ps1", ".exe")
_TRUE = ("true", "yes", "on", "1", "y", "t")
_FALSE = ("false", "no", "off", "0", "n", "f")


# ------------------------------------------------------------------ layers of vars


@dataclass(frozen=True)
class _Origin:
    """Where a vars mapping sits: a Doc (YAML file or INI lines) and the key path into it."""

    doc: Doc
    base: KeyPath = ()
    secret: bool = False    # came from a vault-encrypted file
    inline_secrets: frozenset[str] = frozenset()   # plaintexts of `!vault` values in the doc

    def problem(self, keypath: KeyPath, message: str) -> Problem:
        return self.doc.problem(self.base + keypath, message)

    def child(self, key: Any) -> "_Origin":
        return _Origin(self.doc, self.base + (key,), self.secret, self.inline_secrets)

    @property
    def where(self) -> str:
        return f"{self.doc.path}:{self.doc.line(self.base) or 1}"


@dataclass(frozen=True)
class _Layer:
    vars: Mapping[str, Any]
    origin: _Origin
    secrets: frozenset[str] = frozenset()


def _layer(data: Mapping[str, Any], origin: _Origin) -> _Layer:
    secrets: frozenset[str] = frozenset()
    if origin.secret or origin.inline_secrets:
        texts = (text for _, text in _strings(data, ()))
        secrets = frozenset(t for t in texts if origin.secret or t in origin.inline_secrets)
    return _Layer(data, origin, secrets)


def _strings(value: Any, keypath: KeyPath) -> Iterator[tuple[KeyPath, str]]:
    """Every string value inside `value`, with its key path."""
    if isinstance(value, str):
        yield keypath, value
    elif isinstance(value, Mapping):
        for key, item in value.items():
            yield from _strings(item, keypath + (key,))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            yield from _strings(item, keypath + (index,))


# ------------------------------------------------------------------ parse state


@dataclass
class _GroupDraft:
    name: str
    source: str
    hosts: dict[str, None] = field(default_factory=dict)         # ordered set of direct members
    children: dict[str, _Origin] = field(default_factory=dict)   # child -> where the edge was written
    inline: list[_Layer] = field(default_factory=list)
    files: list[_Layer] = field(default_factory=list)
    declared: bool = True   # False while only an INI [g:vars] or [p:children] entry names it


@dataclass
class _HostDraft:
    name: str
    source: str
    inline: list[_Layer] = field(default_factory=list)
    files: list[_Layer] = field(default_factory=list)


class _Draft:
    """Everything read so far, mutable until assembled into frozen values."""

    def __init__(self, root: str) -> None:
        self.groups: dict[str, _GroupDraft] = {}
        self.hosts: dict[str, _HostDraft] = {}
        self.problems: list[Problem] = []
        self.group("all", root)
        self.group("ungrouped", root)

    def group(self, name: str, source: str, declared: bool = True) -> _GroupDraft:
        found = self.groups.get(name)
        if found is None:
            found = self.groups[name] = _GroupDraft(name, source, declared=declared)
        found.declared = found.declared or declared
        return found

    def add_host(self, group: str, name: str, origin: _Origin, layer: _Layer | None) -> None:
        host = self.hosts.get(name)
        if host is None:
            host = self.hosts[name] = _HostDraft(name, origin.where)
        if layer is not None and layer.vars:
            host.inline.append(layer)
        self.groups[group].hosts[name] = None


# ------------------------------------------------------------------ reading files


class _Reader:
    """Reads files, decrypting vault ones in memory, and turns YAML into Docs."""

    def __init__(self, vault: Vault) -> None:
        self.vault = vault

    def text(self, path: Path, problems: list[Problem]) -> tuple[str, bool] | None:
        try:
            data = path.read_bytes()
        except OSError as exc:
            problems.append(Problem(str(path), None, "", f"cannot read file: {exc.strerror}"))
            return None
        plain, secret = self.vault.read(str(path), data)
        try:
            return plain.decode("utf-8"), secret
        except UnicodeDecodeError as exc:
            problems.append(Problem(str(path), None, "", f"not UTF-8 text ({exc.reason} at byte "
                                                         f"{exc.start}): save the file as UTF-8"))
            return None

    def doc(self, path: Path, problems: list[Problem]) -> _Origin | None:
        """A YAML file, `!vault` values decrypted, as the origin of its root mapping."""
        read = self.text(path, problems)
        return None if read is None else self.load(path, read[0], read[1], problems)

    def load(self, path: Path, text: str, secret: bool, problems: list[Problem]) -> _Origin | None:
        try:
            doc = yamlsrc.load(path, text)
        except InputError as exc:
            problems.extend(exc.problems)
            return None
        revealed: set[str] = set()
        data = self._reveal(doc.data, str(path), revealed)
        return _Origin(Doc(doc.path, data, doc.lines), (), secret, frozenset(revealed))

    def _reveal(self, value: Any, path: str, revealed: set[str]) -> Any:
        """`value` with every `!vault` scalar (Ansible's encrypt_string) decrypted."""
        if isinstance(value, Encrypted):
            try:
                plain = self.vault.decrypt(value.encode("ascii", "replace"), path).decode("utf-8")
            except UnicodeDecodeError:
                raise VaultError([Problem(path, None, "", "a !vault value is not UTF-8 text once "
                                                          "decrypted: encrypt text only")]) from None
            revealed.add(plain)
            return plain
        if isinstance(value, dict):
            return {key: self._reveal(item, path, revealed) for key, item in value.items()}
        if isinstance(value, list):
            return [self._reveal(item, path, revealed) for item in value]
        return value


def _parse_sources(root: Path, reader: _Reader, draft: _Draft) -> Path:
    """Parse the inventory file(s); returns the directory holding group_vars/ and host_vars/."""
    if root.is_dir():
        files, base = _inventory_files(root, draft.problems), root
        if not files and not draft.problems:
            draft.problems.append(Problem(str(root), None, "", "no inventory file in this directory: "
                                                               "add hosts.yml (YAML) or hosts (INI)"))
    elif root.is_file():
        files, base = [root], root.parent
    else:
        draft.problems.append(Problem(str(root), None, "", "inventory not found: check -i / the fleet "
                                                           "file's `inventory:` path"))
        return root
    for path in files:
        read = reader.text(path, draft.problems)
        if read is None:
            continue
        if path.suffix not in _YAML_EXTS:
            _parse_ini(path, read[0], read[1], draft)
        elif (origin := reader.load(path, read[0], read[1], draft.problems)) is not None:
            _parse_yaml(origin, draft)
    _check_undeclared(draft)
    return base


def _inventory_files(root: Path, problems: list[Problem]) -> list[Path]:
    found: list[Path] = []
    for entry in sorted(root.iterdir()):
        if entry.name.startswith(".") or entry.name in ("group_vars", "host_vars"):
            continue
        if entry.is_dir():
            found.extend(_inventory_files(entry, problems))
        elif entry.name.endswith(_SKIPPED_EXTS):
            continue
        elif entry.suffix in _SCRIPT_EXTS:
            problems.append(Problem(str(entry), None, "", "dynamic inventory scripts and plugins are not "
                                    "supported (rosdeploy reads YAML and INI inventories): export the hosts "
                                    "to a YAML file, or move this file out of the inventory directory"))
        else:
            found.append(entry)  # like Ansible: YAML by extension, anything else is INI
    return found


# ------------------------------------------------------------------ YAML inventory


def _parse_yaml(root: _Origin, draft: _Draft) -> None:
    doc = root.doc
    if doc.data is None:
        return
    if not isinstance(doc.data, dict):
        draft.problems.append(doc.problem((), "an inventory must be a mapping of group names, "
                                              "starting with `all:`"))
        return
    if "plugin" in doc.data:
        draft.problems.append(doc.problem(("plugin",), "inventory plugins are not supported: "
                                                       "export the hosts to a YAML inventory"))
        return
    for name, entry in doc.data.items():
        if name in _GROUP_KEYS:
            draft.problems.append(doc.problem((name,), f"`{name}:` at the top level: put it under "
                                                       "a group, e.g. `all:`"))
            continue
        _yaml_group(root.child(name), str(name), entry, draft)


def _yaml_group(origin: _Origin, name: str, entry: Any, draft: _Draft) -> None:
    if not _valid_name(name, origin, draft, "group"):
        return
    draft.group(name, origin.where)
    entry = _as_mapping(origin, entry, f"group {name!r} must be a mapping with hosts:, vars: and/or "
                                       "children:", draft)
    for key, value in entry.items():
        sub = origin.child(key)
        if key == "hosts":
            _yaml_hosts(sub, name, value, draft)
        elif key == "vars":
            _yaml_group_vars(sub, name, value, draft)
        elif key == "children":
            _yaml_children(sub, name, value, draft)
        else:
            draft.problems.append(sub.problem((), f"unknown key in group {name!r}: a group holds only "
                                                  f"hosts:, vars: and children:{_misplaced_hint(key)}"))


def _misplaced_hint(key: Any) -> str:
    if str(key) in CONSUMED_VARS or str(key).startswith("ansible_"):
        # The classic slip: a host indented under children:, so it was read as a group.
        return ("; this looks like a variable: put it under vars:, or, if the group above is really a "
                "host, list it under hosts:")
    return _did_you_mean(key, _GROUP_KEYS)


def _as_mapping(origin: _Origin, value: Any, message: str, draft: _Draft) -> dict[Any, Any]:
    """`value` if it is a mapping, {} for null (Ansible allows `hosts:` with nothing), else report."""
    if value is None:
        return {}
    if isinstance(value, dict):
        return value
    draft.problems.append(origin.problem((), message))
    return {}


def _yaml_hosts(origin: _Origin, group: str, hosts: Any, draft: _Draft) -> None:
    hosts = _as_mapping(origin, hosts, "hosts: must be a mapping of host names, each followed by ':' "
                                       "(and its vars, or nothing)", draft)
    for raw, host_vars in hosts.items():
        host_origin = origin.child(raw)
        host_vars = _as_mapping(host_origin, host_vars, "host vars must be a mapping of name: value "
                                                        "(or nothing after the ':')", draft)
        _add_hosts(str(raw), group, dict(host_vars), host_origin, draft)


def _yaml_group_vars(origin: _Origin, group: str, data: Any, draft: _Draft) -> None:
    data = _as_mapping(origin, data, "vars: must be a mapping of name: value", draft)
    if data:
        draft.groups[group].inline.append(_layer(data, origin))


def _yaml_children(origin: _Origin, group: str, children: Any, draft: _Draft) -> None:
    children = _as_mapping(origin, children, "children: must be a mapping of group names, each followed "
                                             "by ':'", draft)
    for child, entry in children.items():
        child_origin = origin.child(child)
        draft.groups[group].children.setdefault(str(child), child_origin)
        _yaml_group(child_origin, str(child), entry, draft)


# ------------------------------------------------------------------ INI inventory

_SECTION = re.compile(r"\[(?P<name>[^:\]\s]+)(?::(?P<kind>\w+))?\]\s*(?:[#;].*)?")
_INI_GROUP_LINE = re.compile(r"(?P<name>[^:\]\s]+)\s*(?:[#;].*)?")


@dataclass
class _IniState:
    path: Path
    secret: bool
    group: str = "ungrouped"
    kind: str = "hosts"
    section_vars: dict[str, Any] | None = None
    section_lines: dict[KeyPath, int] | None = None


def _parse_ini(path: Path, text: str, secret: bool, draft: _Draft) -> None:
    state = _IniState(path, secret)
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line[0] in "#;":
            continue
        if line.startswith("["):
            _end_vars_section(state, draft)
            _ini_section(state, line, number, draft)
        elif state.kind == "hosts":
            _ini_host(state, line, number, draft)
        elif state.kind == "vars":
            _ini_var(state, line, number, draft)
        elif state.kind == "children":
            _ini_child(state, line, number, draft)
    _end_vars_section(state, draft)


def _ini_origin(state: _IniState, number: int, data: Any = None,
                lines: dict[KeyPath, int] | None = None) -> _Origin:
    return _Origin(Doc(str(state.path), data, lines if lines is not None else {(): number}), (), state.secret)


def _ini_section(state: _IniState, line: str, number: int, draft: _Draft) -> None:
    found = _SECTION.fullmatch(line)
    origin = _ini_origin(state, number)
    state.kind = "skip"  # until a valid header: lines under a broken one are not guessed at
    if not found:
        draft.problems.append(origin.problem((), f"invalid section header {line!r}: write [group], "
                                                 "[group:vars] or [group:children], without spaces"))
        return
    name, kind = found["name"], found["kind"] or "hosts"
    if kind not in _GROUP_KEYS:
        draft.problems.append(origin.problem((), f"unknown section type {kind!r} in {line!r}: use :vars "
                                                 f"or :children{_did_you_mean(kind, _GROUP_KEYS)}"))
        return
    if not _valid_name(name, origin, draft, "group"):
        return
    draft.group(name, origin.where, declared=kind != "vars")
    state.group, state.kind = name, kind
    if kind == "vars":
        state.section_vars, state.section_lines = {}, {(): number}


def _end_vars_section(state: _IniState, draft: _Draft) -> None:
    if state.section_vars and state.section_lines:
        origin = _ini_origin(state, 0, state.section_vars, state.section_lines)
        draft.groups[state.group].inline.append(_layer(state.section_vars, origin))
    state.section_vars = state.section_lines = None


def _ini_host(state: _IniState, line: str, number: int, draft: _Draft) -> None:
    origin = _ini_origin(state, number)
    try:
        tokens = shlex.split(line, comments=True)
    except ValueError as exc:
        draft.problems.append(origin.problem((), f"cannot parse host line ({exc}): close the quote"))
        return
    if not tokens:
        return
    host_vars: dict[str, Any] = {}
    for token in tokens[1:]:
        key, eq, value = token.partition("=")
        if not eq or not key:
            draft.problems.append(origin.problem((), f"expected key=value after the host name, got "
                                                     f"{token!r}: quote values that hold spaces"))
            return
        host_vars[key] = _ini_value(value)
    layer_origin = _ini_origin(state, number, host_vars)
    _add_hosts(tokens[0], state.group, host_vars, layer_origin, draft)


def _ini_var(state: _IniState, line: str, number: int, draft: _Draft) -> None:
    key, eq, value = (part.strip() for part in line.partition("="))
    if not eq or not key:
        draft.problems.append(_ini_origin(state, number).problem(
            (), f"expected key=value in [{state.group}:vars], got {line!r}"))
        return
    assert state.section_vars is not None and state.section_lines is not None
    state.section_vars[key] = _ini_value(value)
    state.section_lines[(key,)] = number


def _ini_child(state: _IniState, line: str, number: int, draft: _Draft) -> None:
    origin = _ini_origin(state, number)
    found = _INI_GROUP_LINE.fullmatch(line)
    if not found:
        draft.problems.append(origin.problem((), f"expected a group name in [{state.group}:children], "
                                                 f"got {line!r}"))
        return
    child = found["name"]
    if _valid_name(child, origin, draft, "group"):
        draft.group(child, origin.where, declared=False)
        draft.groups[state.group].children.setdefault(child, origin)


def _ini_value(text: str) -> Any:
    """Ansible's INI value parsing: a Python literal if it is one (3, True, [1, 2]), else the text."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SyntaxWarning)
            value = ast.literal_eval(text)
    except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError):
        return text
    return _plain(value, text)


def _plain(value: Any, text: str) -> Any:
    if isinstance(value, (tuple, set, list)):
        return [_plain(item, str(item)) for item in value]
    if isinstance(value, dict):
        return {k: _plain(v, str(v)) for k, v in value.items()}
    if value is None or isinstance(value, (str, int, float, bool)):
        return value
    return text  # bytes, complex, Ellipsis: not variable types, keep what was written


def _check_undeclared(draft: _Draft) -> None:
    """Like Ansible, an INI group known only from [g:vars] or [p:children] is a mistake."""
    declared = [name for name, group in draft.groups.items() if group.declared]
    for group in draft.groups.values():
        if not group.declared:
            hint = _did_you_mean(group.name, declared)
            draft.problems.append(Problem(*_split_where(group.source), group.name,
                                          f"group {group.name!r} is never declared: add a [{group.name}] "
                                          f"section (it may be empty){hint}"))


def _split_where(where: str) -> tuple[str, int | None]:
    path, _, line = where.rpartition(":")
    return (path, int(line)) if line.isdigit() else (where, None)


# ------------------------------------------------------------------ host names


_RANGE = re.compile(r"\[([0-9a-zA-Z]*):([0-9a-zA-Z]*)(?::(\d+))?\]")


def _add_hosts(raw: str, group: str, host_vars: dict[str, Any], origin: _Origin, draft: _Draft) -> None:
    """Add one host entry (maybe `name:port` or a `name[01:03]` range) to a group."""
    spec, port = _split_port(raw)
    try:
        names = _expand_range(spec)
    except ValueError as exc:
        draft.problems.append(origin.problem((), f"invalid host range {raw!r}: {exc}"))
        return
    if port is not None:
        host_vars = {"ansible_port": port, **host_vars}
    layer = _layer(host_vars, origin) if host_vars else None
    for name in names:
        if _valid_name(name, origin, draft, "host"):
            draft.add_host(group, name, origin, layer)


def _split_port(raw: str) -> tuple[str, int | None]:
    found = re.fullmatch(r"(.+):(\d+)", raw)
    return (found[1], int(found[2])) if found else (raw, None)


def _expand_range(spec: str) -> list[str]:
    """`amr-[01:03]` → amr-01, amr-02, amr-03 (Ansible: zero padding kept, `[a:c]`, `[0:9:2]`)."""
    found = _RANGE.search(spec)
    if not found:
        return [spec]
    head, tail = spec[:found.start()], spec[found.end():]
    items = _range_items(found[1] or "0", found[2], int(found[3] or 1))
    rests = _expand_range(tail)
    return [head + item + rest for item in items for rest in rests]


def _range_items(start: str, end: str, stride: int) -> list[str]:
    if stride < 1:
        raise ValueError("the step must be 1 or more")
    if start.isdigit() and end.isdigit():
        if start.startswith("0") and len(start) != len(end):
            raise ValueError("zero-padded bounds must have equal width, e.g. [01:10]")
        width = len(start) if start.startswith("0") else 0
        numbers = range(int(start), int(end) + 1, stride)
        items = [str(n).zfill(width) for n in numbers]
    elif len(start) == 1 and len(end) == 1 and start.isalpha() and end.isalpha():
        items = [chr(c) for c in range(ord(start), ord(end) + 1, stride)]
    else:
        raise ValueError("bounds must be both numbers or both single letters, e.g. [1:3] or [a:c]")
    if not items:
        raise ValueError("the start is after the end")
    return items


def _valid_name(name: str, origin: _Origin, draft: _Draft, what: str) -> bool:
    if _NAME.fullmatch(name):
        return True
    draft.problems.append(origin.problem((), f"invalid {what} name {name!r}: use letters, digits, "
                                             "'_', '-' and '.' (other characters clash with patterns "
                                             "and shells)"))
    return False


# ------------------------------------------------------------------ group_vars/, host_vars/


def _attach_vars_files(base: Path, reader: _Reader, draft: _Draft) -> None:
    for kind, entities in (("group_vars", draft.groups), ("host_vars", draft.hosts)):
        for name, files in _vars_files(base / kind, draft.problems).items():
            target = entities.get(name)
            if target is None:
                if kind == "group_vars" and files:
                    _unknown_group_vars(files[0], name, list(entities), draft)
                continue
            for path in files:
                layer = _read_vars_file(path, reader, draft)
                if layer is not None:
                    target.files.append(layer)


def _vars_files(folder: Path, problems: list[Problem]) -> dict[str, list[Path]]:
    """Entity name → its vars files in load order."""
    if not folder.is_dir():
        return {}
    candidates: dict[str, list[Path]] = {}
    for entry in sorted(folder.iterdir()):
        if entry.name.startswith(".") or entry.name.endswith("~"):
            continue
        if entry.suffix in _YAML_EXTS and entry.is_file():
            candidates.setdefault(entry.stem, []).append(entry)
        elif not entry.name.endswith(_SKIPPED_EXTS):   # NAME/ or NAME: host names may hold dots
            candidates.setdefault(entry.name, []).append(entry)
    out: dict[str, list[Path]] = {}
    for name, found in candidates.items():
        if len(found) > 1:
            listed = " and ".join(str(p) + ("/" if p.is_dir() else "") for p in found)
            problems.append(Problem(str(found[0]), None, "", f"{listed} both hold vars for {name!r}; Ansible "
                                    "would read only one of them: merge them into one"))
        out[name] = _dir_files(found[0]) if found[0].is_dir() else [found[0]]
    return out


def _dir_files(folder: Path) -> list[Path]:
    found: list[Path] = []
    for entry in sorted(folder.iterdir()):
        if entry.name.startswith(".") or entry.name.endswith("~"):
            continue
        if entry.is_dir() and not entry.suffix:
            found.extend(_dir_files(entry))
        elif entry.is_file() and entry.suffix in _VARS_EXTS:
            found.append(entry)
    return found


def _read_vars_file(path: Path, reader: _Reader, draft: _Draft) -> _Layer | None:
    origin = reader.doc(path, draft.problems)
    if origin is None or origin.doc.data is None:
        return None
    if not isinstance(origin.doc.data, dict):
        draft.problems.append(origin.problem((), "a vars file must be a mapping of name: value"))
        return None
    return _layer(origin.doc.data, origin)


def _unknown_group_vars(path: Path, name: str, known: list[str], draft: _Draft) -> None:
    # Vars for a group another inventory defines are normal (shared group_vars); only a
    # misspelt name is worth stopping for, as its vars would silently never apply.
    # Names that differ only in numbers (site_3 vs site_1) are other groups, not typos;
    # host_vars are not judged at all: leftovers of retired robots are common and harmless.
    close = difflib.get_close_matches(name, known, n=1, cutoff=0.75)
    if close and re.sub(r"\d+", "#", close[0]) != re.sub(r"\d+", "#", name):
        draft.problems.append(Problem(str(path), None, "", f"no group named {name!r} in the inventory: "
                                      f"did you mean {close[0]!r}? rename the file or directory"))


# ------------------------------------------------------------------ group graph


@dataclass(frozen=True)
class _Graph:
    """Parents, depth and ancestors of every group, computed once for all hosts."""

    parents: Mapping[str, tuple[str, ...]]
    order: Mapping[str, tuple[int, int, str]]     # Ansible's sort key: depth, priority, name
    ancestors: Mapping[str, frozenset[str]]       # the group itself included

    @staticmethod
    def build(draft: _Draft) -> "_Graph | None":
        """None when the groups form a cycle (reported in draft.problems)."""
        _reconcile(draft)
        if _report_cycles(draft):
            return None
        parents: dict[str, list[str]] = {name: [] for name in draft.groups}
        for name, group in draft.groups.items():
            for child in group.children:
                parents[child].append(name)
        frozen = {name: tuple(found) for name, found in parents.items()}
        depth: dict[str, int] = {}
        ancestors: dict[str, frozenset[str]] = {}
        for name in draft.groups:
            _walk_up(name, frozen, depth, ancestors)
        order = {name: (depth[name], _priority(draft.groups[name], draft), name) for name in draft.groups}
        return _Graph(frozen, order, ancestors)


def _reconcile(draft: _Draft) -> None:
    """Ansible's fix-ups: orphan groups go under `all`; hosts in no other group are `ungrouped`."""
    has_parent = {child for group in draft.groups.values() for child in group.children}
    root = draft.groups["all"]
    for name, group in draft.groups.items():
        if name != "all" and name not in has_parent:
            root.children.setdefault(name, _Origin(Doc(group.source, None)))
    member_of: dict[str, set[str]] = {name: set() for name in draft.hosts}
    for name, group in draft.groups.items():
        for host in group.hosts:
            member_of[host].add(name)
    ungrouped = draft.groups["ungrouped"].hosts
    for host, groups in member_of.items():
        if groups - {"all", "ungrouped"}:
            ungrouped.pop(host, None)
        else:
            ungrouped[host] = None


def _report_cycles(draft: _Draft) -> bool:
    state: dict[str, int] = {}   # 1: on the current path, 2: done
    found = False

    def visit(name: str, path: list[str]) -> None:
        nonlocal found
        state[name] = 1
        for child, origin in draft.groups[name].children.items():
            if state.get(child) == 1 or child == "all":
                cycle = " -> ".join(path[path.index(child):] + [child]) if child in path else f"{name} -> all"
                draft.problems.append(origin.problem((), f"group cycle {cycle}: a group cannot contain "
                                                         "itself (or `all`); remove this children entry"))
                found = True
            elif child not in state:
                visit(child, path + [child])
        state[name] = 2

    for name in draft.groups:
        if name not in state:
            visit(name, [name])
    return found


def _walk_up(name: str, parents: Mapping[str, tuple[str, ...]], depth: dict[str, int],
             ancestors: dict[str, frozenset[str]]) -> None:
    if name in depth:
        return
    for parent in parents[name]:
        _walk_up(parent, parents, depth, ancestors)
    # Ansible's depth is the longest path from `all`: a group is deeper than every parent.
    depth[name] = 1 + max((depth[p] for p in parents[name]), default=-1)
    ancestors[name] = frozenset({name}).union(*(ancestors[p] for p in parents[name]))


def _priority(group: _GroupDraft, draft: _Draft) -> int:
    # Only inline vars set it, as in Ansible (group_vars files are read too late to reorder).
    for layer in reversed(group.inline):
        if "ansible_group_priority" in layer.vars:
            try:
                return _to_int(layer.vars["ansible_group_priority"], "an integer, e.g. 10")
            except _Invalid as bad:
                draft.problems.append(layer.origin.problem(("ansible_group_priority",), bad.message))
    return 1


# ------------------------------------------------------------------ assembling hosts


def _assemble(draft: _Draft, graph: _Graph, root: Path, base: Path) -> Inventory:
    for layer in _all_layers(draft):
        draft.problems.extend(_check_layer(layer))
    hosts: dict[str, Host] = {}
    members: dict[str, list[str]] = {name: [] for name in draft.groups}
    direct = _direct_groups(draft)
    for name, host in draft.hosts.items():
        groups = _host_groups(direct[name], graph)
        for group in groups:
            members[group].append(name)
        built = _build_host(host, groups, draft, base)
        if built is not None:
            hosts[name] = built
    if not draft.hosts and not draft.problems:
        draft.problems.append(Problem(str(base), None, "", "the inventory defines no hosts: add robots "
                                                           "under a group's hosts:"))
    groups = {name: _group(group, members[name], graph) for name, group in draft.groups.items()}
    return Inventory(str(root), frozen_map(hosts), frozen_map(groups))


def _all_layers(draft: _Draft) -> Iterator[_Layer]:
    for entity in chain(draft.groups.values(), draft.hosts.values()):
        yield from entity.inline
        yield from entity.files


def _direct_groups(draft: _Draft) -> dict[str, list[str]]:
    """Host -> the groups listing it directly: one pass, not one scan of all groups per host."""
    index: dict[str, list[str]] = {name: [] for name in draft.hosts}
    for group_name, group in draft.groups.items():
        for host in group.hosts:
            index[host].append(group_name)
    return index


def _host_groups(direct: list[str], graph: _Graph) -> tuple[str, ...]:
    every = frozenset({"all"}).union(*(graph.ancestors[g] for g in direct))
    return tuple(sorted(every, key=graph.order.__getitem__))


def _group(group: _GroupDraft, hosts: list[str], graph: _Graph) -> Group:
    merged, _ = _merge(chain(group.inline, group.files))
    return Group(group.name, tuple(hosts), tuple(group.children), graph.parents[group.name],
                 frozen_map(merged), group.source)


def _merge(layers: Iterable[_Layer]) -> tuple[dict[str, Any], dict[str, _Origin]]:
    merged: dict[str, Any] = {}
    origins: dict[str, _Origin] = {}
    for layer in layers:
        merged.update(layer.vars)
        origins.update(dict.fromkeys(layer.vars, layer.origin))
    merged.pop("ansible_group_priority", None)  # a group setting, not a variable (as in Ansible)
    return merged, origins


def _host_layers(host: _HostDraft, groups: tuple[str, ...], draft: _Draft) -> list[_Layer]:
    """Ansible's precedence, lowest first (see the module docstring)."""
    others = [draft.groups[g] for g in groups if g != "all"]
    root = draft.groups["all"]
    return [*root.inline, *chain.from_iterable(g.inline for g in others),
            *root.files, *chain.from_iterable(g.files for g in others),
            *host.inline, *host.files]


def _build_host(host: _HostDraft, groups: tuple[str, ...], draft: _Draft, base: Path) -> Host | None:
    layers = _host_layers(host, groups, draft)
    merged, origins = _merge(layers)
    fields, problems = _host_fields(host, merged, origins, base)
    draft.problems.extend(problems)
    if problems:
        return None
    secrets = frozenset().union(*(layer.secrets for layer in layers))
    return Host(name=host.name, groups=groups, vars=frozen_map(merged), secret_values=secrets,
                source=host.source, **fields)


# ------------------------------------------------------------------ checks of values


def _check_layer(layer: _Layer) -> list[Problem]:
    """Checks that depend on one layer only: done once, not once per host that inherits it."""
    problems: list[Problem] = []
    for key in layer.vars:
        if not isinstance(key, str):
            problems.append(layer.origin.problem((key,), "variable names must be strings: quote it"))
        elif close := _near_miss(key):
            problems.append(layer.origin.problem((key,), f"unknown variable {key!r}: did you mean {close!r}? "
                                                         f"rename it (a free-form variable needs a name not "
                                                         f"this close to one rosdeploy reads)"))
    for keypath, text in _strings(layer.vars, ()):
        if "\n" in text or "\0" in text:
            what = "a newline" if "\n" in text else "a NUL byte"
            problems.append(layer.origin.problem(keypath, f"value contains {what}: host vars end up in .env "
                                                          "files and commands, where it would start a new "
                                                          "entry; put multi-line content in a file and give "
                                                          "its path"))
    return problems


def _near_miss(name: str) -> str | None:
    if name in CONSUMED_VARS or name in _ANSIBLE_VARS:
        return None
    close = difflib.get_close_matches(name, CONSUMED_VARS, n=1, cutoff=_NEAR_MISS_CUTOFF)
    return close[0] if close else None


def _did_you_mean(word: Any, choices: Iterable[str]) -> str:
    close = difflib.get_close_matches(str(word), list(choices), n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


class _Invalid(Exception):
    """A var's value is wrong; `subpath` points inside it (e.g. ("lidar",) in devices)."""

    def __init__(self, message: str, subpath: KeyPath = ()) -> None:
        super().__init__(message)
        self.message = message
        self.subpath = subpath


def _host_fields(host: _HostDraft, merged: Mapping[str, Any], origins: Mapping[str, _Origin],
                 base: Path) -> tuple[dict[str, Any], list[Problem]]:
    converters: dict[str, tuple[str, Callable[[Any], Any]]] = {
        "ansible_host": ("address", _to_address),
        "ansible_port": ("port", _to_port),
        "ansible_user": ("user", _to_user),
        "ansible_ssh_private_key_file": ("key_file", lambda v: _to_key_file(v, base)),
        "ros_domain_id": ("ros_domain_id", _to_domain_id),
        "devices": ("devices", _to_devices),
        "gpu": ("gpu", _to_bool),
        "udev": ("udev", _to_udev),
        "ros_network": ("network", _to_network),
    }
    fields: dict[str, Any] = {"address": host.name}
    problems: list[Problem] = []
    for var, (name, convert) in converters.items():
        used = var if var in merged else next((a for a, p in ALIASES.items() if p == var and a in merged), None)
        if used is None:
            continue
        try:
            fields[name] = convert(merged[used])
        except _Invalid as bad:
            problems.append(origins[used].problem((used, *bad.subpath), bad.message))
    if "ros_domain_id" not in merged:
        problems.append(_missing_domain_id(host))
    return fields, problems


def _missing_domain_id(host: _HostDraft) -> Problem:
    path, line = _split_where(host.source)
    return Problem(path, line, f"{host.name}.ros_domain_id",
                   f"robot {host.name!r} has no ros_domain_id: add `ros_domain_id: N` (0-232) to "
                   f"host_vars/{host.name}.yml, to its entry here, or to its group's vars (robots on "
                   "one ros_network need distinct IDs)")


def _to_int(value: Any, what: str) -> int:
    # Ansible accepts "2222" where it wants a number; so do we, but nothing looser.
    if isinstance(value, int) and not isinstance(value, bool):
        return value
    if isinstance(value, str) and value.strip().isdigit():
        return int(value)
    raise _Invalid(f"must be {what}, got {value!r}")


def _to_port(value: Any) -> int:
    port = _to_int(value, "a port number (an integer 1-65535)")
    if not 1 <= port <= 65535:
        raise _Invalid(f"must be a port number 1-65535, got {port}")
    return port


def _to_domain_id(value: Any) -> int:
    domain = _to_int(value, "an integer 0-232 (the ROS_DOMAIN_ID)")
    if not 0 <= domain <= 232:
        raise _Invalid(f"must be 0-232 (DDS maps higher IDs to ports outside the valid range), got {domain}")
    return domain


def _to_bool(value: Any) -> bool:
    if isinstance(value, bool):
        return value
    # Ansible's boolean(): INI writes `gpu=true` as a string.
    if isinstance(value, str) and value.strip().lower() in _TRUE + _FALSE:
        return value.strip().lower() in _TRUE
    raise _Invalid(f"must be true or false, got {value!r}")


def _safe_text(value: Any, what: str, extra_unsafe: str = "") -> str:
    if not isinstance(value, str) or not value:
        raise _Invalid(f"must be {what} (a non-empty string), got {value!r}")
    bad = sorted(set(value) & (_SHELL_UNSAFE | set(extra_unsafe)))
    if bad:
        shown = ", ".join(repr(c) for c in bad)
        raise _Invalid(f"{what} {value!r} contains {shown}: whitespace and shell metacharacters are not "
                       "allowed here; fix the value")
    return value


def _to_address(value: Any) -> str:
    address = _safe_text(value, "a host name or IP address")
    if address.startswith("-"):
        raise _Invalid(f"{address!r} starts with '-', which ssh would read as an option; fix the address")
    return address


def _to_user(value: Any) -> str:
    user = _safe_text(value, "a user name")
    if user.startswith("-"):
        raise _Invalid(f"{user!r} starts with '-', which ssh would read as an option; fix the user name")
    return user


def _to_key_file(value: Any, base: Path) -> str:
    if not isinstance(value, str) or not value:
        raise _Invalid(f"must be a path to a private key file, got {value!r}")
    path = os.path.expanduser(value)
    if not os.path.isabs(path):  # relative to the inventory, not to wherever rosdeploy runs
        path = os.path.normpath(os.path.join(os.path.abspath(base), path))
    return _safe_text(path, "a key file path")


def _to_network(value: Any) -> str:
    if isinstance(value, str) and _NAME.fullmatch(value):
        return value
    raise _Invalid(f"must be a network name (letters, digits, '_', '-', '.'), got {value!r}")


def _to_devices(value: Any) -> Mapping[str, str]:
    if not isinstance(value, Mapping):
        raise _Invalid("must be a mapping of logical name to device path, e.g. "
                       "{lidar: /dev/robot/lidar}")
    out: dict[str, str] = {}
    for name, path in value.items():
        if not isinstance(name, str) or not _NAME.fullmatch(name):
            raise _Invalid(f"invalid device name {name!r}: use letters, digits, '_', '-', '.'", (name,))
        out[name] = _device_path(path, (name,))
    return frozen_map(out)


def _device_path(path: Any, subpath: KeyPath) -> str:
    try:
        # ':' and ',' separate fields in compose's `devices:` entries.
        text = _safe_text(path, "an absolute device path", extra_unsafe=":,")
    except _Invalid as bad:
        raise _Invalid(bad.message, subpath) from None
    if not text.startswith("/") or "/../" in text + "/":
        raise _Invalid(f"must be an absolute device path on the robot (e.g. /dev/robot/lidar), got {text!r}",
                       subpath)
    return text


def _to_udev(value: Any) -> tuple[UdevDevice, ...]:
    if not isinstance(value, list):
        raise _Invalid("must be a list of devices, each {symlink, subsystem, vendor, product}")
    devices = tuple(_udev_device(entry, index) for index, entry in enumerate(value))
    seen: set[str] = set()
    for index, device in enumerate(devices):
        if device.symlink in seen:
            raise _Invalid(f"symlink {device.symlink!r} is listed twice: keep one entry", (index, "symlink"))
        seen.add(device.symlink)
    return devices


def _udev_device(entry: Any, index: int) -> UdevDevice:
    if not isinstance(entry, Mapping):
        raise _Invalid("each udev entry must be a mapping with symlink, subsystem, vendor, product", (index,))
    for key in entry:
        if key not in _UDEV_KEYS:
            raise _Invalid(f"unknown key {key!r}{_did_you_mean(key, _UDEV_KEYS)} "
                           f"(known: {', '.join(_UDEV_KEYS)})", (index, key))
    for key in _UDEV_REQUIRED:
        if key not in entry:
            raise _Invalid(f"missing {key}: every udev entry needs {', '.join(_UDEV_REQUIRED)}", (index,))
    return UdevDevice(
        symlink=_udev_symlink(entry["symlink"], (index, "symlink")),
        subsystem=_udev_text(entry["subsystem"], _SUBSYSTEM, "a subsystem like tty or video4linux",
                             (index, "subsystem")),
        vendor=_udev_hex(entry["vendor"], (index, "vendor")),
        product=_udev_hex(entry["product"], (index, "product")),
        serial=_udev_optional(entry, "serial", _SERIAL, "a serial number (letters, digits, _.:/+-)", index),
        group=_udev_optional(entry, "group", _UNIX_GROUP, "a Unix group name like dialout", index),
        mode=_udev_mode(entry.get("mode", "0660"), (index, "mode")),
    )


def _udev_text(value: Any, pattern: re.Pattern[str], what: str, subpath: KeyPath) -> str:
    if isinstance(value, str) and pattern.fullmatch(value):
        return value
    quote = " (quote it: YAML reads unquoted digits as a number)" if isinstance(value, int) else ""
    raise _Invalid(f"must be {what}, got {value!r}{quote}", subpath)


def _udev_optional(entry: Mapping[str, Any], key: str, pattern: re.Pattern[str], what: str,
                   index: int) -> str | None:
    value = entry.get(key)
    return None if value is None else _udev_text(value, pattern, what, (index, key))


def _udev_hex(value: Any, subpath: KeyPath) -> str:
    return _udev_text(value, _HEX4, "4 hex digits as a string, e.g. \"0403\"", subpath).lower()


def _udev_symlink(value: Any, subpath: KeyPath) -> str:
    if isinstance(value, str) and value.startswith("/dev/"):
        raise _Invalid(f"write the symlink relative to /dev: {value[5:]!r}", subpath)
    link = _udev_text(value, _SYMLINK, "a path relative to /dev, e.g. robot/lidar", subpath)
    if ".." in link.split("/"):
        raise _Invalid(f"must stay inside /dev, got {link!r}", subpath)
    return link


def _udev_mode(value: Any, subpath: KeyPath) -> str:
    mode = _udev_text(value, _MODE, "an octal mode as a string, e.g. \"0660\"", subpath)
    return mode.zfill(4)
