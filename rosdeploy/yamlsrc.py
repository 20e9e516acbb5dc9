"""YAML loading that remembers where every value came from.

Error messages must say `file:line: key.path: ...`, so we compose the YAML node
tree ourselves and record each mapping key's line while building plain Python
values. Values stay plain dicts/lists/scalars: nothing downstream has to know.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from rosdeploy.errors import InputError, Problem

KeyPath = tuple[Any, ...]


class _Loader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate mapping keys (a silent override is a bug)."""


class Encrypted(str):
    """A `!vault`-tagged scalar (Ansible's encrypt_string): still ciphertext.

    Only the inventory decrypts these (it holds the vault); anywhere else the
    value stays ciphertext, which is useless but harmless.
    """


class Unsafe(str):
    """An `!unsafe` scalar: Ansible never templates it, and neither does the inventory."""


_Loader.add_constructor("!vault", lambda loader, node: Encrypted(loader.construct_scalar(node)))
_Loader.add_constructor("!unsafe", lambda loader, node: Unsafe(loader.construct_scalar(node)))


@dataclass(frozen=True)
class Doc:
    """A parsed YAML document plus the line of every key path in it."""

    path: str
    data: Any
    lines: dict[KeyPath, int] = field(default_factory=dict)

    def line(self, keypath: KeyPath) -> int | None:
        """Line of the deepest known prefix of keypath (1-based)."""
        for cut in range(len(keypath), -1, -1):
            found = self.lines.get(tuple(keypath[:cut]))
            if found is not None:
                return found
        return None

    def problem(self, keypath: KeyPath, message: str, **kw: Any) -> Problem:
        return Problem(self.path, self.line(keypath), dotted(keypath), message, **kw)


def dotted(keypath: KeyPath) -> str:
    out = ""
    for part in keypath:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def load(path: str | Path, text: str | None = None, duplicates: list[Problem] | None = None) -> Doc:
    """Parse one YAML file; a syntax error becomes an InputError naming file and line.

    A duplicate key is an error, unless `duplicates` is given: then, as in Ansible
    (inventories), it is a warning appended there and the last value wins.
    """
    path = str(path)
    if text is None:
        try:
            text = Path(path).read_text(encoding="utf-8")
        except OSError as exc:
            raise InputError([Problem(path, None, "", f"cannot read file: {exc.strerror}")]) from exc
    try:
        node = yaml.compose(text, Loader=_Loader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark else None
        what = getattr(exc, "problem", None) or str(exc)
        raise InputError([Problem(path, line, "", f"invalid YAML: {what}")]) from exc
    lines: dict[KeyPath, int] = {}
    data = None if node is None else _build(node, (), lines, path, duplicates)
    return Doc(path, data, lines)


def _build(node: yaml.Node, keypath: KeyPath, lines: dict[KeyPath, int], path: str,
           duplicates: list[Problem] | None = None) -> Any:
    lines.setdefault(keypath, node.start_mark.line + 1)
    if isinstance(node, yaml.MappingNode):
        return _build_mapping(node, keypath, lines, path, duplicates)
    if isinstance(node, yaml.SequenceNode):
        return [_build(item, keypath + (i,), lines, path, duplicates) for i, item in enumerate(node.value)]
    try:
        return _Loader(" ").construct_object(node, deep=True)
    except yaml.YAMLError as exc:
        raise InputError([Problem(path, node.start_mark.line + 1, dotted(keypath), f"invalid value: {exc}")]) from exc


def _build_mapping(node: yaml.MappingNode, keypath: KeyPath, lines: dict[KeyPath, int], path: str,
                   duplicates: list[Problem] | None) -> dict:
    loader = _Loader(" ")
    loader.flatten_mapping(node)  # resolves `<<: *anchor` merges
    out: dict[Any, Any] = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        child = keypath + (key,)
        if key in out:
            then = "keep one" if duplicates is None else "the last one is used, as in Ansible; keep one"
            duplicate = Problem(path, key_node.start_mark.line + 1, dotted(child),
                                f"duplicate key: it is defined twice in the same mapping; {then}",
                                severity="error" if duplicates is None else "warning")
            if duplicates is None:
                raise InputError([duplicate])
            duplicates.append(duplicate)
        lines[child] = key_node.start_mark.line + 1
        out[key] = _build(value_node, child, lines, path, duplicates)
    return out
