"""INI inventories: `[g]`, `[g:vars]`, `[g:children]`, inline `k=v`, like Ansible's ini plugin."""
from __future__ import annotations

import ast
import re
import shlex
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rosdeploy.errors import Problem
from rosdeploy.inventory.draft import Draft, Origin, make_layer, split_where
from rosdeploy.inventory.known import GROUP_KEYS, did_you_mean_hint
from rosdeploy.inventory.ranges import add_hosts, valid_name
from rosdeploy.yamlsrc import Doc, KeyPath


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


def parse_ini(path: Path, text: str, secret: bool, draft: Draft) -> None:
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
                lines: dict[KeyPath, int] | None = None) -> Origin:
    return Origin(Doc(str(state.path), data, lines if lines is not None else {(): number}), (), state.secret)


def _ini_section(state: _IniState, line: str, number: int, draft: Draft) -> None:
    found = _SECTION.fullmatch(line)
    origin = _ini_origin(state, number)
    state.kind = "skip"  # until a valid header: lines under a broken one are not guessed at
    if not found:
        draft.problems.append(origin.problem((), f"invalid section header {line!r}: write [group], "
                                                 "[group:vars] or [group:children], without spaces"))
        return
    name, kind = found["name"], found["kind"] or "hosts"
    if kind not in GROUP_KEYS:
        draft.problems.append(origin.problem((), f"unknown section type {kind!r} in {line!r}: use :vars "
                                                 f"or :children{did_you_mean_hint(kind, GROUP_KEYS)}"))
        return
    if not valid_name(name, origin, draft, "group"):
        return
    draft.group(name, origin.where, declared=kind != "vars")
    state.group, state.kind = name, kind
    if kind == "vars":
        state.section_vars, state.section_lines = {}, {(): number}


def _end_vars_section(state: _IniState, draft: Draft) -> None:
    if state.section_vars and state.section_lines:
        origin = _ini_origin(state, 0, state.section_vars, state.section_lines)
        draft.groups[state.group].inline.append(make_layer(state.section_vars, origin))
    state.section_vars = state.section_lines = None


def _ini_host(state: _IniState, line: str, number: int, draft: Draft) -> None:
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
    add_hosts(tokens[0], state.group, host_vars, layer_origin, draft)


def _ini_var(state: _IniState, line: str, number: int, draft: Draft) -> None:
    key, eq, value = (part.strip() for part in line.partition("="))
    if not eq or not key:
        draft.problems.append(_ini_origin(state, number).problem(
            (), f"expected key=value in [{state.group}:vars], got {line!r}"))
        return
    assert state.section_vars is not None and state.section_lines is not None
    state.section_vars[key] = _ini_value(value)
    state.section_lines[(key,)] = number


def _ini_child(state: _IniState, line: str, number: int, draft: Draft) -> None:
    origin = _ini_origin(state, number)
    found = _INI_GROUP_LINE.fullmatch(line)
    if not found:
        draft.problems.append(origin.problem((), f"expected a group name in [{state.group}:children], "
                                                 f"got {line!r}"))
        return
    child = found["name"]
    if valid_name(child, origin, draft, "group"):
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


def check_undeclared(draft: Draft) -> None:
    """Like Ansible, an INI group known only from [g:vars] or [p:children] is a mistake."""
    declared = [name for name, group in draft.groups.items() if group.declared]
    for group in draft.groups.values():
        if not group.declared:
            hint = did_you_mean_hint(group.name, declared)
            draft.problems.append(Problem(*split_where(group.source), group.name,
                                          f"group {group.name!r} is never declared: add a [{group.name}] "
                                          f"section (it may be empty){hint}"))
