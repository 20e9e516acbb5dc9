"""Host entries: `name:port`, `name[01:03]` ranges, and the names Ansible allows."""
from __future__ import annotations

import re
from typing import Any

from rosdeploy.inventory.draft import Draft, Origin, make_layer
from rosdeploy.inventory.known import NAME


_RANGE = re.compile(r"\[([0-9a-zA-Z]*):([0-9a-zA-Z]*)(?::(\d+))?\]")
# Ten times the largest fleet rosdeploy is measured with: a range past it is a typo in a
# bound (`[1:10000000]`), and expanding it would take the machine's memory first.
MAX_RANGE_HOSTS = 50_000
MAX_HOSTS = 100_000      # the same bound for an inventory's ranges taken together


def add_hosts(raw: str, group: str, host_vars: dict[str, Any], origin: Origin, draft: Draft) -> None:
    """Add one host entry (maybe `name:port` or a `name[01:03]` range) to a group."""
    spec, port = _split_port(raw)
    try:
        names = _expand_range(spec)
    except ValueError as exc:
        draft.problems.append(origin.problem((), f"invalid host range {raw!r}: {exc}"))
        return
    if len(draft.hosts) + len(names) > MAX_HOSTS:
        draft.problems.append(origin.problem((), f"host range {raw!r} takes this inventory past {MAX_HOSTS} "
                                                 "hosts: check the ranges' bounds"))
        return
    if port is not None:
        host_vars = {"ansible_port": port, **host_vars}
    layer = make_layer(host_vars, origin) if host_vars else None
    for name in names:
        if valid_name(name, origin, draft, "host"):
            draft.add_host(group, name, origin, layer)


def _split_port(raw: str) -> tuple[str, int | None]:
    found = re.fullmatch(r"(.+):(\d+)", raw)
    return (found[1], int(found[2])) if found else (raw, None)


def _expand_range(spec: str) -> list[str]:
    """`amr-[01:03]` → amr-01, amr-02, amr-03 (Ansible: zero padding kept, `[a:c]`, `[0:9:2]`)."""
    count = _range_count(spec)
    if count > MAX_RANGE_HOSTS:
        raise ValueError(f"it names {count} hosts, more than {MAX_RANGE_HOSTS}: check its bounds")
    return _expanded(spec)


def _range_count(spec: str) -> int:
    """How many names a spec expands to, without expanding it."""
    count = 1
    for found in _RANGE.finditer(spec):
        start, end, stride = found[1] or "0", found[2], int(found[3] or 1)
        if stride < 1:
            continue          # refused with its own message when expanded
        if start.isdigit() and end.isdigit():
            count *= max(0, (int(end) - int(start)) // stride + 1)
        elif len(start) == len(end) == 1:
            count *= max(0, (ord(end) - ord(start)) // stride + 1)
    return count


def _expanded(spec: str) -> list[str]:
    found = _RANGE.search(spec)
    if not found:
        return [spec]
    head, tail = spec[:found.start()], spec[found.end():]
    items = _range_items(found[1] or "0", found[2], int(found[3] or 1))
    rests = _expanded(tail)
    return [head + item + rest for item in items for rest in rests]


def _range_items(start: str, end: str, stride: int) -> list[str]:
    if stride < 1:
        raise ValueError("the step must be 1 or more")
    if start.isdigit() and end.isdigit():
        # Ansible pads only when the start is zero-padded (`[01:10]`); a lone 0 is just zero (`[0:11]`).
        padded = start.startswith("0") and len(start) > 1
        if padded and len(start) != len(end):
            raise ValueError("zero-padded bounds must have equal width, e.g. [01:10]")
        width = len(start) if padded else 0
        numbers = range(int(start), int(end) + 1, stride)
        items = [str(n).zfill(width) for n in numbers]
    elif len(start) == 1 and len(end) == 1 and start.isalpha() and end.isalpha():
        items = [chr(c) for c in range(ord(start), ord(end) + 1, stride)]
    else:
        raise ValueError("bounds must be both numbers or both single letters, e.g. [1:3] or [a:c]")
    if not items:
        raise ValueError("the start is after the end")
    return items


def valid_name(name: str, origin: Origin, draft: Draft, what: str) -> bool:
    if NAME.fullmatch(name):
        return True
    if what == "group" and name and not any(c.isspace() or not c.isprintable() for c in name):
        # Ansible keeps such a group name, with a warning (TRANSFORM_INVALID_GROUP_CHARS=never).
        draft.warnings.append(origin.problem((), f"group name {name!r} holds characters other than letters, "
                                                 "digits, '_', '-' and '.': kept, as Ansible does, but patterns "
                                                 "and shells may read it differently; rename it",
                                             severity="warning"))
        return True
    draft.problems.append(origin.problem((), f"invalid {what} name {name!r}: use letters, digits, "
                                             "'_', '-' and '.' (other characters clash with patterns "
                                             "and shells)"))
    return False
