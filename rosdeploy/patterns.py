"""Ansible's host patterns (`--limit`), evaluated over plain names: no I/O, no Host objects.

    amr-n1            a host or a group by name
    robot*  site_?    shell globs (case-sensitive, like Ansible)
    ~amr-[ns]\\d       a regular expression, matched from the start of the name
    all  *            every host
    a:b  a,b          union; with a comma present, Ansible splits on commas only (`a:b,c` is `a:b` and `c`)
    a:&b              intersection
    a:!b              exclusion
    site[0]  site[1:3]  subscripts of a group in Ansible's host order for it, end inclusive
    @file             the patterns in a file, one a line (Ansible's `--limit @retry_file`)

Like Ansible, unions are applied first, then intersections, then exclusions,
whatever order they were written in, and a pattern made only of `&`/`!` terms
starts from `all`. A union or intersection term that matches no host and no
group is a warning, as in Ansible (`web:nomatch` selects web). Two places are
stricter: an *exclusion* that matches nothing is an error (a misspelt
`all:!amr-n9` would deploy to the very robot the operator meant to leave out),
and so is a pattern that selects no robot at all (Ansible runs nothing and
exits 0). `localhost` is not Ansible's implicit localhost: rosdeploy deploys
over SSH to inventory hosts only, so an absent localhost is refused with how to
add it. A `[` or `]` without its pair is refused (Ansible's split drops it, so
`~r[` selected every host starting with r), and so is a `~regex` whose matching
takes more than REGEX_BUDGET seconds (catastrophic backtracking, `~(a+)+b`), and a control
character (`--limit "$(cat list)"`: Ansible splits on the newline, so a list went out unnoticed).
A subscript past the group's end selects nothing (a warning, as above); one of
more than MAX_INDEX_DIGITS digits is refused (Python's int() refuses 4300, where
Ansible fails with an internal error), and so is an `@file` that is not a
regular file of at most MAX_LIMIT_FILE bytes.
"""
from __future__ import annotations

import fnmatch
import os
import re
import stat
import signal
import threading
from contextlib import contextmanager
from typing import Callable, Iterator, Mapping, Sequence

from rosdeploy import suggest
from rosdeploy.errors import InventoryError, Problem, shown

_GLOB_CHARS = frozenset("*?[")
# Ansible's subscript: `group[3]`, `group[-1]`, `group[1:4]`, `group[2:]`.
_SUBSCRIPT = re.compile(r"^(?P<base>.+)\[(?:(?P<index>-?[0-9]+)|(?P<start>[0-9]+):(?P<end>[0-9]*))\]$")
# Ansible's split on ':' keeps a bracketed expression whole (`web[0:2]:db`).
_TERM = re.compile(r"(?:[^\s:\[\]]|\[[^\]]*\])+")
# A term as written, a stray bracket kept: `~r[:web` is the words `~r[` and `web`.
_WORD = re.compile(r"(?:[^\s:\[\]]|\[[^\]]*\]|[\[\]])+")
_HOST_PORT = re.compile(r"[^:\[\]\s]+:[0-9]+")
_LOCALHOST = ("localhost", "127.0.0.1", "::1")
_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")
# Seconds all the matching of one pattern may take. A `~regex` is Python's `re`, as in Ansible, so
# `~(a+)+b` backtracks exponentially on a long host name; normal patterns over thousands of hosts
# take milliseconds, so one second is far from any real selection and well within a prompt reply.
REGEX_BUDGET = 1.0
# A subscript of more digits than this is no host position (and int() of 4300 digits raises); up
# to it, an index past the group selects nothing, as in Ansible.
MAX_INDEX_DIGITS = 18
# An `@file` of hosts: 1 MB holds some 50,000 host names; a fifo or /dev/zero would never end.
MAX_LIMIT_FILE = 1 << 20
# Unmatched terms a "selects no robot" message explains; the rest are counted.
MAX_SHOWN_TERMS = 5


class _OverBudget(Exception):
    """Raised by the SIGALRM handler inside a runaway match (the regex engine checks for signals)."""


def select(pattern: str | None, hosts: Sequence[str], groups: Mapping[str, Sequence[str]],
           where: str = "--limit", warnings: list[Problem] | None = None) -> tuple[str, ...]:
    """Names of the hosts `pattern` selects, in inventory order.

    `hosts` is every host name in inventory order; `groups` maps each group name
    to all of its hosts (descendant groups included) in Ansible's order. Raises
    InventoryError when an exclusion matches nothing or the whole pattern selects
    no host; other unmatched terms go to `warnings`.
    """
    if pattern is None:
        return tuple(hosts)
    _refuse_control(pattern, where)
    terms = _read_files(split(pattern), where)
    if not terms:
        what = "names no host or group (a `[` without its `]`?)" if pattern.strip(" ,:") else "is empty"
        raise _error(where, f"pattern {shown(pattern)} {what}: give host or group names, e.g. 'site_north:!amr-n2'")
    _refuse_stray_bracket(pattern, where)
    _refuse_huge_index(terms, where)
    unmatched: list[Problem] = []
    with _budget(pattern if "@" not in pattern else ",".join(terms), where):   # an @file may hold ~regexes
        chosen = _evaluate(terms, hosts, groups, where, unmatched)
    if warnings is not None:
        warnings.extend(unmatched)
    if not chosen:
        if any(term.strip("&!") in _LOCALHOST for term in terms) and not set(_LOCALHOST) & set(hosts):
            raise _error(where, "localhost is not in the inventory: rosdeploy deploys over SSH to inventory "
                                "hosts only (no implicit localhost as in Ansible); to target this machine, add "
                                "it, e.g. `localhost: {ansible_host: 127.0.0.1}`")
        raise _error(where, f"pattern {shown(pattern)} selects no robot: {_why_nothing(unmatched)}")
    order = {name: i for i, name in enumerate(hosts)}
    return tuple(sorted(chosen, key=order.__getitem__))


def _refuse_control(pattern: str, where: str) -> None:
    """No host name holds a control character. A newline (`--limit "$(cat list)"`) was read as a
    separator, as Ansible's split on whitespace reads it, so a pasted list deployed to all of it
    unnoticed; a tab or ESC is a paste accident. Say how to write a list instead."""
    found = _CONTROL.search(pattern)
    if found:
        raise _error(where, f"pattern {shown(pattern)} holds a control character ({found.group()!r}): "
                            "separate patterns with `:` or `,` (e.g. 'r1:r2'), or list them one a line in "
                            "a file and give @FILE")


def _why_nothing(unmatched: list[Problem]) -> str:
    """The unmatched terms of a pattern that selects nothing, the first few only: a 5,000-character
    `a1:a2:...` made one message of 100 KB (each term is still a warning line of its own)."""
    if not unmatched:
        return "every term names something, but together (&, !, [n]) they leave nothing; loosen the pattern"
    more = len(unmatched) - MAX_SHOWN_TERMS
    return "; ".join(p.message for p in unmatched[:MAX_SHOWN_TERMS]) + \
        (f"; and {more} more term(s) that match no host or group" if more > 0 else "")


def split(pattern: str) -> list[str]:
    """Terms of a pattern, as Ansible splits it (split_host_pattern)."""
    if "," in pattern:
        parts = pattern.split(",")
    elif _HOST_PORT.fullmatch(pattern.strip()):
        parts = [pattern]   # `host:22` is one address, not two terms
    else:
        parts = _TERM.findall(pattern)
    return [p.strip() for p in parts if p.strip()]


def _read_files(terms: list[str], where: str) -> list[str]:
    """`@path` terms replaced by the file's lines, one pattern each (Ansible's subset(); blank lines skipped)."""
    out: list[str] = []
    for term in terms:
        if not term.startswith("@"):
            out.append(term)
            continue
        for line in filter(None, (text.strip() for text in _limit_file(term[1:], where).split("\n"))):
            _refuse_stray_bracket(line, where)
            out.append(line)
    return out


def _limit_file(path: str, where: str) -> str:
    """The text of an `@file`, stat'ed before it is read: no fifo, device or huge file."""
    try:
        info = os.stat(path)
    except (OSError, ValueError):
        raise _error(where, f"unable to find limit file {shown(path)} (`@` reads host patterns from a file): "
                            "fix the path, or drop the `@`") from None
    if not stat.S_ISREG(info.st_mode):
        raise _error(where, f"limit file {shown(path)} is not a regular file (a directory, fifo or device): "
                            "give a file of host patterns, one a line")
    if info.st_size > MAX_LIMIT_FILE:
        raise _error(where, f"limit file {shown(path)} is larger than {MAX_LIMIT_FILE >> 20} MB: that is no list "
                            "of hosts; give a file of host patterns, one a line")
    try:
        with open(path, "rb") as handle:
            return handle.read(MAX_LIMIT_FILE + 1).decode("utf-8")
    except OSError as exc:
        raise _error(where, f"cannot read limit file {shown(path)}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise _error(where, f"limit file {shown(path)} is not UTF-8 text: give a file of host patterns, "
                            "one a line") from None


def _refuse_stray_bracket(pattern: str, where: str) -> None:
    """Ansible's ':' split silently drops a `[` or `]` it cannot pair, so `~r[` becomes `~r` and
    selects every host starting with r: more robots than written. Refuse it instead."""
    if "," in pattern or not set("[]") & set(_TERM.sub("", pattern)):
        return
    for word in _WORD.findall(pattern):
        if word.lstrip("&!").startswith("~"):
            _matcher(word.lstrip("&!"), where)      # an invalid regex is named with the regex error
    raise _error(where, f"pattern {shown(pattern)} has a `[` or `]` without its pair (Ansible would drop it and "
                        f"select other hosts than written): close the bracket, e.g. 'site_north[0:2]'")


def _refuse_huge_index(terms: list[str], where: str) -> None:
    """A subscript of more than MAX_INDEX_DIGITS digits: no inventory reaches it, and int() may refuse it."""
    for term in terms:
        found = _SUBSCRIPT.match(term) if not term.lstrip("&!").startswith("~") else None
        digits = [found[k] for k in ("index", "start", "end") if found and found[k]]
        if any(len(d.lstrip("-0")) > MAX_INDEX_DIGITS for d in digits):
            raise _error(where, f"subscript in {shown(term, 60)} is past any "
                                f"inventory (more than {MAX_INDEX_DIGITS} digits): give a host position "
                                "in the group, e.g. 'site_north[0:9]'")


@contextmanager
def _budget(pattern: str, where: str) -> Iterator[None]:
    """Interrupt matching that runs past REGEX_BUDGET, via SIGALRM (the CLI selects in the main thread;
    elsewhere, or when a timer is already armed, nothing is bounded, as signals can only go there)."""
    usable = (hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread()
              and "~" in pattern and signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0))
    if not usable:
        yield
        return
    armed = [True]      # cleared before disarming: a signal landing in `finally` must not raise there

    def expire(signum: int, frame: object) -> None:
        if armed[0]:
            raise _OverBudget

    previous = signal.signal(signal.SIGALRM, expire)
    try:
        signal.setitimer(signal.ITIMER_REAL, REGEX_BUDGET)
        yield
    except _OverBudget:
        raise _error(where, f"pattern {shown(pattern)} took more than {REGEX_BUDGET:g} s to match the host names "
                            "(a regular expression that backtracks, like `(a+)+`): simplify the regex, "
                            "or use a glob such as 'amr-*'") from None
    finally:
        armed[0] = False
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, signal.SIG_DFL if previous is None else previous)


def _evaluate(terms: list[str], hosts: Sequence[str], groups: Mapping[str, Sequence[str]],
              where: str, unmatched: list[Problem]) -> set[str]:
    unions = [t for t in terms if t[0] not in "&!"]
    intersections = [t[1:] for t in terms if t[0] == "&"]
    exclusions = [t[1:] for t in terms if t[0] == "!"]
    errors: list[Problem] = []
    known = set(hosts)

    def resolve(term: str, strict: bool = False) -> set[str]:
        if term in known:       # a plain host name is never read as a pattern (Ansible)
            return {term}
        found = _match_term(term, hosts, groups, where)
        if found is None:
            (errors if strict else unmatched).append(_unmatched(term, hosts, groups, where, strict))
            return set()
        return found

    chosen: set[str] = set()
    for term in unions or ["all"]:
        chosen |= resolve(term)
    for term in intersections:
        chosen &= resolve(term)
    for term in exclusions:
        chosen -= resolve(term, strict=True)
    if errors:
        raise InventoryError(errors)
    return chosen


def _match_term(term: str, hosts: Sequence[str], groups: Mapping[str, Sequence[str]],
                where: str) -> set[str] | None:
    """Hosts one term names, or None when it names no host and no group at all."""
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
        except (re.error, OverflowError, RecursionError) as exc:   # `a{99999999999}`: OverflowError
            raise _error(where, f"invalid regular expression {shown(base)}: {exc}; fix it or use a glob") from exc
        return lambda name: regex.match(name) is not None
    if _GLOB_CHARS & set(base):
        return lambda name: fnmatch.fnmatchcase(name, base)
    return lambda name: name == base


def _split_subscript(term: str) -> tuple[str, tuple[int, int | None] | None]:
    found = _SUBSCRIPT.match(term) if not term.startswith("~") else None
    if not found:
        return term, None
    if found["index"] is not None:
        return found["base"], (int(found["index"]), None)
    return found["base"], (int(found["start"]), int(found["end"]) if found["end"] else -1)


def _apply_subscript(members: list[str], subscript: tuple[int, int | None]) -> list[str]:
    # Ansible's _apply_subscript, including its quirks: `[x:]` runs to the end, and an end
    # of 0 (`[0:0]`, `[2:0]`) is read as "no end", i.e. the single host at x.
    start, end = subscript
    if end:
        return members[start:(len(members) - 1 if end == -1 else end) + 1]
    return [members[start]] if -len(members) <= start < len(members) else []


def _dedupe(names: list[str]) -> list[str]:
    return list(dict.fromkeys(names))


def _unmatched(term: str, hosts: Sequence[str], groups: Mapping[str, Sequence[str]], where: str,
               strict: bool) -> Problem:
    hint = suggest.did_you_mean(term, [*groups, *hosts]) or "check the spelling against the inventory"
    if strict:
        return Problem(where, None, "", f"exclusion {shown(term)} matches no host or group: {hint} (an exclusion "
                                        "that excludes nothing would deploy to the robots meant to be left out)")
    return Problem(where, None, "", f"{shown(term)} matches no host or group, ignored (as Ansible does): {hint}",
                   severity="warning")


def _error(where: str, message: str) -> InventoryError:
    return InventoryError([Problem(where, None, "", message)])
