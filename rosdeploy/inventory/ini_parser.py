"""INI inventories: `[g]`, `[g:vars]`, `[g:children]`, inline `k=v`, like Ansible's ini plugin."""
from __future__ import annotations

import ast
import re
import shlex
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

from rosdeploy.errors import Problem, shown
from rosdeploy.inventory.draft import Draft, Origin, make_layer, split_where
from rosdeploy.inventory.known import GROUP_KEYS, did_you_mean_hint
from rosdeploy.inventory.ranges import add_hosts, entries_left, valid_name
from rosdeploy.yamlsrc import MAX_INT_BITS, MAX_NODES, Doc, KeyPath, not_text


# A UTF-8 byte-order mark (older Windows editors write one) is refused rather than skipped: Ansible's
# INI plugin decodes the file as plain UTF-8 and keeps the mark in the first line, so `\ufeff[lab]`
# is no section header there and the inventory it reads differs from ours. Refused, the fix is
# one save, and then both tools read the same hosts. (YAML files keep their mark: PyYAML skips it,
# in Ansible as here, so both read them alike.)
BOM = "\ufeff"
BOM_FIX = ("the file starts with a byte-order mark (U+FEFF), which Ansible's INI reader takes as part of the "
           "first line: save it as UTF-8 without BOM")
_SECTION = re.compile(r"\[(?P<name>[^:\]\s]+)(?::(?P<kind>\w+))?\]\s*(?:#.*)?")   # Ansible's: no `;` after
_INI_GROUP_LINE = re.compile(r"(?P<name>[^:\]\s]+)\s*(?:[#;].*)?")
# The 64 MiB file cap does not bound the cost of what a file builds: shlex reads ~1 MB/s, and
# ast.literal_eval of `[0,0,...]` takes ~200 bytes of memory per byte (10 MB: 2 GB). So a line is
# at most MAX_LINE characters, and a file's values (a `k=v` each, plus one per two characters of a
# [list] or {dict} literal) at most MAX_NODES, the bound a YAML file has. A 5,000-robot INI is ~50,000.
MAX_LINE = 64 << 10
# A line of only these characters splits on blanks exactly as shlex splits it, 10x faster.
_PLAIN_LINE = re.compile(r"[A-Za-z0-9_.:=\[\],@/+%{}\- \t]*")


@dataclass
class _IniState:
    path: Path
    secret: bool
    group: str = "ungrouped"
    kind: str = "hosts"
    section_vars: dict[str, Any] | None = None
    section_lines: dict[KeyPath, int] | None = None
    values: int = 0         # spent of MAX_NODES
    stopped: bool = False   # a bound was passed (and reported): the rest of the file is not read


def parse_ini(path: Path, text: str, secret: bool, draft: Draft) -> None:
    state = _IniState(path, secret)
    if text.startswith(BOM):
        draft.problems.append(_ini_origin(state, 1).problem((), BOM_FIX))
        return
    for number, raw in enumerate(_lines(text), 1):
        line = raw.strip()
        if not line or line[0] in "#;":
            continue
        if len(line) > MAX_LINE:
            _stop(state, number, draft, f"line of {len(line)} characters, more than {MAX_LINE}: an inventory "
                                        "line is a host with its vars; put large values in a group_vars YAML file")
        if state.stopped or not entries_left(draft):
            break       # already refused: reading on would only spend time
        if _SECTION.fullmatch(line) or (line.startswith("[") and line.endswith("]")):
            # as Ansible: `[::1]:2222` is a host line (an IPv6 address and a port), not a header
            _end_vars_section(state, draft)
            _ini_section(state, line, number, draft)
        elif state.kind == "hosts":
            _ini_host(state, line, number, draft)
        elif state.kind == "vars":
            _ini_var(state, line, number, draft)
        elif state.kind == "children":
            _ini_child(state, line, number, draft)
    _end_vars_section(state, draft)


_WORD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
# Where str.splitlines (and so Ansible's INI plugin) breaks lines.
_LINE_BREAK = re.compile("\r\n|[\n\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029]")


def _lines(text: str) -> Iterator[str]:
    """text.splitlines(), one line at a time: 20 million short lines as a list take 1.4 GB."""
    start = 0
    for found in _LINE_BREAK.finditer(text):
        yield text[start:found.start()]
        start = found.end()
    if start < len(text):
        yield text[start:]


def _stop(state: _IniState, number: int, draft: Draft, message: str) -> None:
    draft.problems.append(_ini_origin(state, number).problem((), f"{message} (the rest of the file is not read)"))
    state.stopped = True


def _spend(state: _IniState, value: str, number: int, draft: Draft) -> bool:
    """Count one `k=v` (and a literal list's or dict's items) against MAX_NODES; False past it."""
    state.values += 1 + (len(value) // 2 if value[:1] in "[{(" else 0)
    if state.values > MAX_NODES and not state.stopped:
        _stop(state, number, draft, f"this file's vars hold over {MAX_NODES} values: move large values to a "
                                    "group_vars YAML file, or keep large data in a file the service reads")
    return not state.stopped


def _ini_origin(state: _IniState, number: int, data: Any = None,
                lines: dict[KeyPath, int] | None = None) -> Origin:
    return Origin(Doc(str(state.path), data, lines if lines is not None else {(): number}), (), state.secret)


def _ini_section(state: _IniState, line: str, number: int, draft: Draft) -> None:
    found = _SECTION.fullmatch(line)
    origin = _ini_origin(state, number)
    state.kind = "skip"  # until a valid header: lines under a broken one are not guessed at
    if not found:
        draft.problems.append(origin.problem((), f"invalid section header {shown(line)}: write [group], "
                                                 "[group:vars] or [group:children], without spaces"))
        return
    name, kind = found["name"], found["kind"] or "hosts"
    if kind not in GROUP_KEYS:
        draft.problems.append(origin.problem((), f"unknown section type {shown(kind)} in {shown(line)}: use :vars "
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
        tokens = line.split() if _PLAIN_LINE.fullmatch(line) else shlex.split(line, comments=True)
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
                                                     f"{shown(token)}: quote values that hold spaces"))
            return
        if not _spend(state, value, number, draft):
            return
        host_vars[key] = _ini_value(value)
        if not _text_only(key, host_vars[key], origin, draft):
            return
    layer_origin = _ini_origin(state, number, host_vars)
    add_hosts(tokens[0], state.group, host_vars, layer_origin, draft)


def _ini_var(state: _IniState, line: str, number: int, draft: Draft) -> None:
    key, eq, value = (part.strip() for part in line.partition("="))
    if not eq or not key:
        draft.problems.append(_ini_origin(state, number).problem(
            (), f"expected key=value in [{state.group}:vars], got {shown(line)}"))
        return
    assert state.section_vars is not None and state.section_lines is not None
    if not _spend(state, value, number, draft):
        return
    state.section_vars[key] = _ini_value(value)
    state.section_lines[(key,)] = number
    if not _text_only(key, state.section_vars[key], _ini_origin(state, number), draft):
        del state.section_vars[key]


def _text_only(key: str, value: Any, origin: Origin, draft: Draft) -> bool:
    """False (and a problem at the var) for a value no file can hold: `"\\ud800"` is a literal
    Ansible's parser reads too, and writing it later crashed (see yamlsrc.not_text); a control
    character (a raw NUL byte, `"\\x00"`) is refused here as YAML refuses it, not at the fleet key
    that later uses the var."""
    why = not_text({key: value}, controls=True)
    if why is not None:
        draft.problems.append(origin.problem((key,), why))
    return why is None


def _ini_child(state: _IniState, line: str, number: int, draft: Draft) -> None:
    origin = _ini_origin(state, number)
    found = _INI_GROUP_LINE.fullmatch(line)
    if not found:
        draft.problems.append(origin.problem((), f"expected a group name in [{state.group}:children], "
                                                 f"got {shown(line)}"))
        return
    child = found["name"]
    if valid_name(child, origin, draft, "group"):
        draft.group(child, origin.where, declared=False)
        draft.groups[state.group].children.setdefault(child, origin)


def _ini_value(text: str) -> Any:
    """Ansible's INI value parsing: a Python literal if it is one (3, True, [1, 2]), else the text."""
    if _WORD.fullmatch(text) and text not in ("True", "False", "None"):
        return text     # what literal_eval would give, 20x faster: most values are words
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SyntaxWarning)
            return _plain(ast.literal_eval(text), text)
    except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError):
        return text


def _plain(value: Any, text: str | None) -> Any:
    """`value` in variable types; `text` (or the item's str()) for what is none."""
    if isinstance(value, (tuple, set, list)):
        return [_plain(item, None) for item in value]
    if isinstance(value, dict):
        return {_writable(k): _plain(v, None) for k, v in value.items()}
    if _writable(value) is None or isinstance(value, (str, int, float, bool)):
        return value
    return str(value) if text is None else text  # bytes, complex, Ellipsis: keep what was written


def _writable(value: Any) -> Any:
    # `0x` + 4,000 hex digits: no message or JSON could show it (str() raises ValueError)
    if isinstance(value, int) and value.bit_length() > MAX_INT_BITS:
        raise ValueError("integer too large to write")
    return value


def check_undeclared(draft: Draft) -> None:
    """Like Ansible, an INI group known only from [g:vars] or [p:children] is a mistake."""
    declared = [name for name, group in draft.groups.items() if group.declared]
    for group in draft.groups.values():
        if not group.declared:
            hint = did_you_mean_hint(group.name, declared)
            draft.problems.append(Problem(*split_where(group.source), group.name,
                                          f"group {shown(group.name)} is never declared: add a [{group.name}] "
                                          f"section (it may be empty){hint}"))
