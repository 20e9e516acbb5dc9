"""Parse state: vars layers with their origin, and the mutable drafts of groups and hosts."""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Iterator, Mapping

from rosdeploy.errors import Problem
from rosdeploy.yamlsrc import Doc, KeyPath


@dataclass(frozen=True)
class Origin:
    """Where a vars mapping sits: a Doc (YAML file or INI lines) and the key path into it."""

    doc: Doc
    base: KeyPath = ()
    secret: bool = False    # came from a vault-encrypted file
    inline_secrets: frozenset[str] = frozenset()   # plaintexts of `!vault` values in the doc

    def problem(self, keypath: KeyPath, message: str, severity: str = "error") -> Problem:
        found = self.doc.problem(self.base + keypath, message, severity=severity)
        # A name holding a newline must not split the message (or fake a line of its own).
        printable = "".join(c if c.isprintable() else repr(c)[1:-1] for c in found.key)
        return found if printable == found.key else replace(found, key=printable)

    def child(self, key: Any) -> "Origin":
        return Origin(self.doc, self.base + (key,), self.secret, self.inline_secrets)

    @property
    def where(self) -> str:
        return f"{self.doc.path}:{self.doc.line(self.base) or 1}"


@dataclass(frozen=True)
class Layer:
    vars: Mapping[str, Any]
    origin: Origin
    secrets: frozenset[str] = frozenset()


def make_layer(data: Mapping[str, Any], origin: Origin) -> Layer:
    secrets: frozenset[str] = frozenset()
    if origin.secret or origin.inline_secrets:
        texts = (text for _, text in strings(data, ()))
        secrets = frozenset(t for t in texts if origin.secret or t in origin.inline_secrets)
    return Layer(data, origin, secrets)


def strings(value: Any, keypath: KeyPath) -> Iterator[tuple[KeyPath, str]]:
    """Every string value inside `value`, with its key path."""
    if isinstance(value, str):
        yield keypath, value
    elif isinstance(value, Mapping):
        for key, item in value.items():
            yield from strings(item, keypath + (key,))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            yield from strings(item, keypath + (index,))


# ------------------------------------------------------------------ parse state


@dataclass
class GroupDraft:
    name: str
    source: str
    hosts: dict[str, None] = field(default_factory=dict)         # ordered set of direct members
    children: dict[str, Origin] = field(default_factory=dict)   # child -> where the edge was written
    inline: list[Layer] = field(default_factory=list)
    files: list[Layer] = field(default_factory=list)
    declared: bool = True   # False while only an INI [g:vars] or [p:children] entry names it


@dataclass
class HostDraft:
    name: str
    source: str
    inline: list[Layer] = field(default_factory=list)
    files: list[Layer] = field(default_factory=list)


class Draft:
    """Everything read so far, mutable until assembled into frozen values."""

    def __init__(self, root: str) -> None:
        self.groups: dict[str, GroupDraft] = {}
        self.hosts: dict[str, HostDraft] = {}
        self.problems: list[Problem] = []
        self.warnings: list[Problem] = []
        # group names Ansible warns about, each once: risky ones warned at their first mention, the
        # plain ones (`site-north`, `2nd_floor`) in one warning for the inventory, as Ansible's one line
        self.odd_groups: dict[str, Origin] = {}
        self.group("all", root)
        self.group("ungrouped", root)

    def group(self, name: str, source: str, declared: bool = True) -> GroupDraft:
        found = self.groups.get(name)
        if found is None:
            found = self.groups[name] = GroupDraft(name, source, declared=declared)
        found.declared = found.declared or declared
        return found

    def add_host(self, group: str, name: str, origin: Origin, layer: Layer | None) -> None:
        if len(name.encode()) > MAX_HOST_NAME:
            # It names the robot's folders (render output, run records): refused here, not by the
            # file system halfway through a render.
            self.problems.append(origin.problem((), f"host name {name[:40]!r}... is {len(name.encode())} bytes "
                                                    f"long: at most {MAX_HOST_NAME} (a DNS name's limit)"))
            return
        host = self.hosts.get(name)
        if host is None:
            host = self.hosts[name] = HostDraft(name, origin.where)
        if layer is not None and layer.vars:
            host.inline.append(layer)
        self.groups[group].hosts[name] = None


MAX_HOST_NAME = 253


def split_where(where: str) -> tuple[str, int | None]:
    """("file", line) from a "file:line" source."""
    path, _, line = where.rpartition(":")
    return (path, int(line)) if line.isdigit() else (where, None)
