"""TOML inventories (`.toml`), read as Ansible's toml plugin reads them, then by the YAML reader.

Ansible's toml plugin takes top-level tables as groups, each with `hosts` (a table of host name ->
vars table), `vars` (a table) and `children` (a list of group names). That is the YAML inventory's
shape but for `children`, so the file is turned into it and read by parse_yaml: every check and
message of a YAML inventory applies. tomllib knows no lines: problems name the file and key path.
"""
from __future__ import annotations

import re
import sys
from pathlib import Path
from typing import Any

from rosdeploy.errors import Problem
from rosdeploy.inventory.draft import Draft, Origin
from rosdeploy.inventory.yaml_parser import parse_yaml
from rosdeploy.yamlsrc import MAX_DEPTH, MAX_INT_BITS, MAX_NODES, Doc, KeyPath, not_text

TO_YAML = "convert it to YAML (ansible-inventory -i FILE --list -y)"
_AT = re.compile(r"\s*\(at line (\d+), column (\d+)\)$")


def parse_toml(path: Path, text: str, secret: bool, draft: Draft) -> None:
    """Read one TOML inventory into `draft`; its problems go to draft.problems."""
    doc = Doc(str(path), None, {})
    data = _load(doc, text, draft.problems)
    if data is None:
        return
    before = len(draft.problems)
    _check_values(doc, data, draft.problems)
    if len(draft.problems) == before:
        parse_yaml(Origin(Doc(doc.path, _as_yaml(doc, data, draft.problems)), (), secret), draft)


def _load(doc: Doc, text: str, problems: list[Problem]) -> dict[str, Any] | None:
    # tomllib is pure Python and unbounded: a value costs at least one `=` or `,`, so this bounds
    # the values (the YAML bound) before any is built.
    if text.count("=") + text.count(",") > MAX_NODES:
        problems.append(doc.problem((), f"more than {MAX_NODES} values: not an inventory rosdeploy will read"))
        return None
    if sys.version_info >= (3, 11):   # Ansible's toml plugin reads with tomllib too
        return _parsed(doc, text, problems)
    problems.append(doc.problem((), f"TOML inventories need Python 3.11 or later: {TO_YAML}"))
    return None


if sys.version_info >= (3, 11):
    import tomllib

    def _parsed(doc: Doc, text: str, problems: list[Problem]) -> dict[str, Any] | None:
        try:
            return tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            found = _AT.search(str(exc))
            line = int(found[1]) if found else None
            column = f" (column {found[2]})" if found else ""
            problems.append(Problem(doc.path, line, "", f"invalid TOML: {_AT.sub('', str(exc))}{column}"))
        except RecursionError:
            problems.append(doc.problem((), f"invalid TOML: nested more than {MAX_DEPTH} levels deep"))
        except ValueError as exc:     # an integer of over 4,300 digits (Python refuses to read it)
            problems.append(doc.problem((), f"invalid TOML: {exc}"))
        return None


def _check_values(doc: Doc, data: dict[str, Any], problems: list[Problem]) -> None:
    """The YAML reader's bounds, which tomllib does not have: nesting, value count, integer size,
    and text no written file may hold. Iterative: the nesting is what is being checked."""
    stack: list[tuple[KeyPath, Any]] = [((), data)]
    count = 0
    while stack:
        keypath, value = stack.pop()
        count += 1
        why = _bad_value(keypath, value, count)
        if why is not None:
            problems.append(doc.problem(keypath, why))
            return
        if isinstance(value, dict):
            stack.extend((keypath + (key,), item) for key, item in value.items())
        elif isinstance(value, list):
            stack.extend((keypath + (index,), item) for index, item in enumerate(value))


def _bad_value(keypath: KeyPath, value: Any, count: int) -> str | None:
    if len(keypath) > MAX_DEPTH:
        return f"nested more than {MAX_DEPTH} levels deep"
    if count > MAX_NODES:
        return f"more than {MAX_NODES} values: not an inventory rosdeploy will read"
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > MAX_INT_BITS:
        return f"an integer of {value.bit_length()} bits: at most {MAX_INT_BITS}"
    if keypath and isinstance(keypath[-1], str) and (why := not_text(keypath[-1], controls=True)) is not None:
        return f"this key {why}"
    if isinstance(value, str) and (why := not_text(value, controls=True)) is not None:
        return f"this value {why}"
    return None


def _as_yaml(doc: Doc, data: dict[str, Any], problems: list[Problem]) -> dict[str, Any]:
    """The YAML inventory `data` stands for: each group's `children` list becomes a mapping."""
    return {name: _group(doc, name, entry, problems) for name, entry in data.items()}


def _group(doc: Doc, name: str, entry: Any, problems: list[Problem]) -> Any:
    if not isinstance(entry, dict):
        problems.append(doc.problem((name,), f"group {name!r} must be a table (`[{name}]`, `[{name}.hosts]`, "
                                             f"...), as Ansible's toml plugin requires; it is "
                                             f"{_kind(entry)}"))
        return None
    group = dict(entry)
    for key, shape in (("hosts", "a table of host names (`[GROUP.hosts]`, then `NAME = {}`)"),
                       ("vars", "a table of name = value (`[GROUP.vars]`)")):
        if key in group and not isinstance(group[key], dict):
            problems.append(doc.problem((name, key), f"{key} must be {shape}; it is {_kind(group[key])}"))
            del group[key]
    if "hosts" in group:
        group["hosts"] = _hosts(doc, name, group["hosts"], problems)
    if "children" in group:
        group["children"] = _children(doc, name, group["children"], problems)
    return group


def _hosts(doc: Doc, name: str, hosts: dict[str, Any], problems: list[Problem]) -> dict[str, Any]:
    """The hosts whose vars are a table; the others reported in TOML's words, not YAML's."""
    for host, host_vars in hosts.items():
        if not isinstance(host_vars, dict):
            problems.append(doc.problem((name, "hosts", host), "a host's vars must be a table "
                                        f"(`NAME = {{ var = value }}`, or `NAME = {{}}`); it is "
                                        f"{_kind(host_vars)}"))
    return {host: host_vars for host, host_vars in hosts.items() if isinstance(host_vars, dict)}


def _children(doc: Doc, name: str, children: Any, problems: list[Problem]) -> dict[Any, None]:
    """`children = ["a", "b"]` as the YAML reader's `children: {a: , b: }` (each child's own
    hosts and vars are in its own top-level table, as in Ansible)."""
    if isinstance(children, list) and all(isinstance(child, str) for child in children):
        return dict.fromkeys(children)
    problems.append(doc.problem((name, "children"), "children must be a list of group names "
                                "(`children = [\"a\", \"b\"]`), as Ansible's toml plugin requires; it is "
                                f"{_kind(children)}" + (" holding a non-string" if isinstance(children, list)
                                                        else "")))
    return {}


def _kind(value: Any) -> str:
    """`value`'s TOML type, with its article."""
    return {dict: "a table", list: "a list", str: "a string", bool: "a boolean", int: "an integer",
            float: "a float"}.get(type(value), f"a {type(value).__name__}")
