"""Ansible's host patterns (`--limit`), evaluated over plain names: no I/O, no Host objects.

    amr-n1            a host or a group by name
    robot*  site_?    shell globs (case-sensitive, like Ansible)
    ~amr-[ns]\\d       a regular expression, matched from the start of the name
    all  *            every host
    a:b  a,b          union
    a:&b              intersection
    a:!b              exclusion
    site[0]  site[0:2]  subscripts of a group, end inclusive (Ansible's)

Like Ansible, unions are applied first, then intersections, then exclusions,
whatever order they were written in, and a pattern made only of `&`/`!` terms
starts from `all`. Unlike Ansible, a term that matches no host and no group is
an error rather than a warning: a misspelt exclusion (`all:!amr-n9`) would
otherwise deploy to the very robot the operator meant to leave out.
"""
from __future__ import annotations

import difflib
import fnmatch
import re
from typing import Callable, Mapping, Sequence

from rosdeploy.errors import InventoryError, Problem

_GLOB_CHARS = frozenset("*?[")
# Ansible's subscript: `group[3]`, `group[-1]`, `group[1:4]`, `group[2:]`.
_SUBSCRIPT = re.compile(r"^(?P<base>[^~].*?)\[(?P<start>-?\d+)(?::(?P<end>-?\d*))?\]$")


def select(pattern: str | None, hosts: Sequence[str], groups: Mapping[str, Sequence[str]],
           where: str = "--limit") -> tuple[str, ...]:
    """Names of the hosts `pattern` selects, in inventory order.

    `hosts` is every host name in inventory order; `groups` maps each group name
    to all of its hosts (descendant groups included). Raises InventoryError when
    a term matches nothing or the whole pattern selects no host.
    """
    if pattern is None:
        return tuple(hosts)
    terms = split(pattern)
    if not terms:
        raise _error(where, f"pattern {pattern!r} is empty: give host or group names, e.g. 'site_north:!amr-n2'")
    chosen = _evaluate(terms, hosts, groups, where)
    if not chosen:
        raise _error(where, f"pattern {pattern!r} selects no robot: every term names something, but "
                            "together (&, !, [n]) they leave nothing; loosen the pattern")
    order = {name: i for i, name in enumerate(hosts)}
    return tuple(sorted(chosen, key=order.__getitem__))


def split(pattern: str) -> list[str]:
    """Terms of a pattern, split on ',' and on ':' outside brackets (so `web[0:2]` stays whole)."""
    terms: list[str] = []
    for part in pattern.split(","):
        terms.extend(_split_colons(part))
    return [t.strip() for t in terms if t.strip()]


def _split_colons(part: str) -> list[str]:
    out, depth, start = [], 0, 0
    for i, char in enumerate(part):
        if char == "[":
            depth += 1
        elif char == "]":
            depth = max(0, depth - 1)
        elif char == ":" and depth == 0:
            out.append(part[start:i])
            start = i + 1
    out.append(part[start:])
    return out


def _evaluate(terms: list[str], hosts: Sequence[str], groups: Mapping[str, Sequence[str]],
              where: str) -> set[str]:
    unions = [t for t in terms if t[0] not in "&!"]
    intersections = [t[1:] for t in terms if t[0] == "&"]
    exclusions = [t[1:] for t in terms if t[0] == "!"]
    problems: list[Problem] = []

    def resolve(term: str) -> set[str]:
        found = _match_term(term, hosts, groups, where)
        if found is None:
            problems.append(_unmatched(term, hosts, groups, where))
            return set()
        return found

    chosen: set[str] = set()
    for term in unions or ["all"]:
        chosen |= resolve(term)
    for term in intersections:
        chosen &= resolve(term)
    for term in exclusions:
        chosen -= resolve(term)
    if problems:
        raise InventoryError(problems)
    return chosen


def _match_term(term: str, hosts: Sequence[str], groups: Mapping[str, Sequence[str]],
                where: str) -> set[str] | None:
    """Hosts one term names, or None when it names no host and no group at all."""
    if term in ("all", "*"):
        return set(hosts)
    base, subscript = _split_subscript(term)
    matcher = _matcher(base, where)
    matched_groups = [g for g in groups if matcher(g)]
    members: list[str] = []
    for group in matched_groups:
        members.extend(groups[group])
    # Ansible looks at host names only when no group matched, or the term is a glob/regex.
    is_wildcard = base.startswith("~") or "." in base or bool(_GLOB_CHARS & set(base))
    if not matched_groups or is_wildcard:
        members.extend(h for h in hosts if matcher(h))
    if not matched_groups and not members:
        return None
    if subscript is not None:
        members = _apply_subscript(_dedupe(members), subscript)
    return set(members)


def _matcher(base: str, where: str) -> Callable[[str], bool]:
    if base.startswith("~"):
        try:
            regex = re.compile(base[1:])
        except re.error as exc:
            raise _error(where, f"invalid regular expression {base!r}: {exc}; fix it or use a glob") from exc
        return lambda name: regex.match(name) is not None
    if _GLOB_CHARS & set(base):
        return lambda name: fnmatch.fnmatchcase(name, base)
    return lambda name: name == base


def _split_subscript(term: str) -> tuple[str, tuple[int, int | None] | None]:
    found = _SUBSCRIPT.match(term)
    if not found:
        return term, None
    start = int(found["start"])
    if found["end"] is None:
        return found["base"], (start, start)
    end = int(found["end"]) if found["end"] not in ("", None) else None
    return found["base"], (start, end)


def _apply_subscript(members: list[str], subscript: tuple[int, int | None]) -> list[str]:
    start, end = subscript
    if end == start:
        return [members[start]] if -len(members) <= start < len(members) else []
    return members[start:] if end is None else members[start:end + 1]


def _dedupe(names: list[str]) -> list[str]:
    return list(dict.fromkeys(names))


def _unmatched(term: str, hosts: Sequence[str], groups: Mapping[str, Sequence[str]], where: str) -> Problem:
    close = difflib.get_close_matches(term, [*groups, *hosts], n=1, cutoff=0.7)
    hint = f"did you mean {close[0]!r}?" if close else "check the spelling against the inventory"
    return Problem(where, None, "", f"{term!r} matches no host or group: {hint}")


def _error(where: str, message: str) -> InventoryError:
    return InventoryError([Problem(where, None, "", message)])
