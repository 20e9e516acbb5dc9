"""Ansible's host patterns (`--limit`), evaluated over plain names: no I/O, no Host objects.

    amr-n1            a host or a group by name
    robot*  site_?    shell globs (case-sensitive, like Ansible)
    ~amr-[ns]\\d       a regular expression, matched from the start of the name
    all  *            every host
    a:b  a,b          union; with a comma present, Ansible splits on commas only (`a:b,c` is `a:b` and `c`)
    fe80::1  host:22  without a comma, a pattern that reads as one address is one term (Ansible)
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
character (`--limit "$(cat list)"`: Ansible splits on the newline, so a list went out unnoticed;
an `@file` line holding one is refused by its line number, the line unquoted: `@/proc/self/environ`
would have quoted the environment). Globs and regexes are tested against every host and group
name, so a pattern needing more than MAX_MATCH_WORK such tests is refused (host names are looked
up, at any count); of the terms that match nothing, the first MAX_SHOWN_TERMS are named (with a
did-you-mean), the rest counted.
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
import warnings as pywarnings
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
# Ansible keeps a pattern without a comma whole when it reads as one host address (parse_address):
# `name:22` or `[v6]:22` (the port split off, bracketed first, then plain), then a host name, IPv4
# or IPv6 address, each maybe with `[a:b]` ranges. So `fe80::1` and `[::1]:2223` are one term each.
_BRACKETED_PORT = re.compile(r"\[(.+)\]:[0-9]+")
_PLAIN_PORT = re.compile(r"((?:[^:\[\]]|\[[^\]]*\])*):[0-9]+")
# A host name's label: starts with a word character or a range, then word characters, `-` or ranges,
# and does not end in `_` or `-` (Unicode letters are word characters there: `bücher`).
_NAME_RANGE = r"\[(?:[a-zA-Z]:[a-zA-Z]|[0-9]+:[0-9]+)(?::[0-9]+)?\]"
_LABEL = re.compile(rf"(?:\w|{_NAME_RANGE})(?:[\w-]|{_NAME_RANGE})*(?<![_-])")
# An IPv6 address: hexadecimal groups (or `[hex:hex]` ranges, one group each), `:`, `.` for a
# trailing IPv4 part.
_V6_TEXT = re.compile(r"[0-9a-fA-F:.\[\]]+")
_V6_RANGE = re.compile(r"\[[0-9a-fA-F]+:[0-9a-fA-F]+(?::[0-9]+)?\]")
_V6_GROUP = re.compile(r"[0-9a-fA-F]{1,4}|r")      # `r` stands for a range
# The only forms of an IPv6 address ending in IPv4 notation that Ansible reads as one.
_V4_IN_V6 = ("::", "::ffff:", "0:0:0:0:0:0:", "0:0:0:0:0:ffff:")
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
# Unmatched terms a "selects no robot" message explains (and warnings name); the rest are counted:
# each named one costs a did-you-mean against every name (difflib, ~10 ms over 10,000 hosts), so
# 20,000 of them took minutes.
MAX_SHOWN_TERMS = 5
# Glob and regex tests (distinct wildcard terms x host and group names) one pattern may cost: each
# is ~0.1 microsecond, so this is about a second. 2,000 globs in an @file over 10,000 hosts took 30 s.
MAX_MATCH_WORK = 10_000_000


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
        return _everyone(hosts, groups, where)
    _refuse_control(pattern, where)
    terms = _read_files(split(pattern), where)
    if not terms:
        what = "names no host or group (a `[` without its `]`?)" if pattern.strip(" ,:") else "is empty"
        raise _error(where, f"pattern {shown(pattern)} {what}: give host or group names, e.g. 'site_north:!amr-n2'")
    _refuse_stray_bracket(pattern, where)
    _refuse_huge_index(terms, where)
    names = _Names(hosts, groups, where)
    _refuse_much_work(pattern, terms, names)
    with _budget(pattern if "@" not in pattern else ",".join(terms), where):   # an @file may hold ~regexes
        chosen, missed = _evaluate(terms, names)
    unmatched = _unmatched(missed, names, strict=False)
    if warnings is not None:
        warnings.extend(names.notes)
        warnings.extend(unmatched)
    if not chosen:
        if any(term.strip("&!") in _LOCALHOST for term in terms) and not set(_LOCALHOST) & set(hosts):
            raise _error(where, "localhost is not in the inventory: rosdeploy deploys over SSH to inventory "
                                "hosts only (no implicit localhost as in Ansible); to target this machine, add "
                                "it, e.g. `localhost: {ansible_host: 127.0.0.1}`")
        why = "; ".join([_why_nothing(unmatched, len(missed), terms), *(note.message for note in names.notes[:1])])
        raise _error(where, f"pattern {shown(pattern)} selects no robot: {why}")
    order = {name: i for i, name in enumerate(hosts)}
    return tuple(sorted(chosen, key=order.__getitem__))


def _everyone(hosts: Sequence[str], groups: Mapping[str, Sequence[str]], where: str) -> tuple[str, ...]:
    """No pattern is Ansible's `all`: every host but those in no group at all (listed under an
    `ungrouped` that another group holds), which only their own name selects."""
    every = groups.get("all")
    if every is None or len(every) == len(hosts):
        return tuple(hosts)
    members = frozenset(every)
    chosen = tuple(name for name in hosts if name in members)
    if not chosen:
        raise _error(where, "no robot is in the inventory's `all` group (each is listed under an `ungrouped` that "
                            "another group holds): put the robots in a group of their own, or name them")
    return chosen


def _refuse_control(pattern: str, where: str) -> None:
    """No host name holds a control character. A newline (`--limit "$(cat list)"`) was read as a
    separator, as Ansible's split on whitespace reads it, so a pasted list deployed to all of it
    unnoticed; a tab or ESC is a paste accident. Say how to write a list instead."""
    found = _CONTROL.search(pattern)
    if found:
        raise _error(where, f"pattern {shown(pattern)} holds a control character ({found.group()!r}): "
                            "separate patterns with `:` or `,` (e.g. 'r1:r2'), or list them one a line in "
                            "a file and give @FILE")


def _why_nothing(unmatched: list[Problem], count: int, terms: list[str]) -> str:
    """The unmatched terms of a pattern that selects nothing, the first few only: a 5,000-character
    `a1:a2:...` made one message of 100 KB. `unmatched` is their warnings (the named ones and the
    count of the rest); `count` how many terms matched nothing."""
    if not count and not any(t[0] in "&!" or _split_subscript(t)[1] for t in terms):
        return "the groups it names hold no host"
    if not count:
        return "every term names something, but together (&, !, [n]) they leave nothing; loosen the pattern"
    more = count - MAX_SHOWN_TERMS
    return "; ".join(p.message for p in unmatched[:MAX_SHOWN_TERMS]) + \
        (f"; and {more:,} more term(s) that match no host or group" if more > 0 else "")


def split(pattern: str) -> list[str]:
    """Terms of a pattern, as Ansible splits it (split_host_pattern)."""
    if "," in pattern:
        parts = pattern.split(",")
    elif _is_address(pattern.strip()):
        parts = [pattern]   # `host:22`, `fe80::1`, `[::1]:2223`: one address, not several terms
    else:
        parts = _TERM.findall(pattern)
    return [p.strip() for p in parts if p.strip()]


def _is_address(text: str) -> bool:
    """Whether Ansible's split reads `text` as one host address (a name, IPv4 or IPv6 address,
    ranges allowed, maybe with a port), which it then keeps whole."""
    host = _without_port(text)
    return _is_host_name(host) or _is_ipv6(host)


def _without_port(text: str) -> str:
    # In this order, each at most once, as Ansible does: `[web:22]:33` is the host `web`.
    found = _BRACKETED_PORT.fullmatch(text)
    text = found[1] if found else text
    found = _PLAIN_PORT.fullmatch(text)
    return found[1] if found else text


def _is_host_name(text: str) -> bool:
    return all(_LABEL.fullmatch(label) for label in text.split("."))


def _is_ipv6(text: str) -> bool:
    if not _V6_TEXT.fullmatch(text):
        return False
    plain = _V6_RANGE.sub("r", text)
    if "." in plain:
        head, _, v4 = plain.rpartition(":")
        parts = v4.split(".")
        return len(parts) == 4 and all(_V6_GROUP.fullmatch(p) for p in parts) and \
            head.lower() + ":" in _V4_IN_V6
    sides = plain.split("::")
    groups = [side.split(":") if side else [] for side in sides]
    if len(sides) > 2 or not all(_V6_GROUP.fullmatch(g) for side in groups for g in side):
        return False
    if len(sides) == 1:
        return len(groups[0]) == 8
    # `::` stands for at least one zero group, and Ansible writes at most six groups on a side.
    return len(groups[0]) + len(groups[1]) <= 7 and max(map(len, groups)) <= 6


def _read_files(terms: list[str], where: str) -> list[str]:
    """`@path` terms replaced by the file's lines, one pattern each (Ansible's subset(); blank lines skipped)."""
    out: list[str] = []
    for term in terms:
        if not term.startswith("@"):
            out.append(term)
            continue
        for number, text in enumerate(_limit_file(term[1:], where).split("\n"), start=1):
            line = text.strip()
            if line:
                _refuse_file_control(term[1:], number, line, where)
                _refuse_stray_bracket(line, where)
                out.append(line)
    return out


def _refuse_file_control(path: str, number: int, line: str, where: str) -> None:
    """A control character in an `@file` line is refused as one in `--limit` is (`r2\\0` was the term
    'r2\\x00'). The line is not quoted: such a file is no host list, and may be a secret's
    (`@/proc/self/environ` quoted the whole environment)."""
    found = _CONTROL.search(line)
    if found:
        raise _error(where, f"limit file {shown(path)} line {number} holds a control character "
                            f"({found.group()!r}), so it is no list of host patterns (the line is not shown): "
                            "give a text file of host patterns, one a line")


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


class _Names:
    """The names one pattern is matched against, looked up by name (a host or group name costs
    one dictionary lookup, whatever the count), with each wildcard's compiled test kept."""

    def __init__(self, hosts: Sequence[str], groups: Mapping[str, Sequence[str]], where: str) -> None:
        self.hosts, self.groups, self.where = hosts, groups, where
        self.known = frozenset(hosts)
        self.tests: dict[str, Callable[[str], bool]] = {}
        self.notes: list[Problem] = []      # warnings from compiling a regex

    def test(self, base: str) -> Callable[[str], bool]:
        if base not in self.tests:
            self.tests[base] = _matcher(base, self.where, self.notes)
        return self.tests[base]


def _refuse_much_work(pattern: str, terms: list[str], names: _Names) -> None:
    """Refuse a pattern whose globs and regexes need more than MAX_MATCH_WORK name tests."""
    wildcards = {base for base in (_split_subscript(t.lstrip("&!"))[0] for t in terms) if _is_wildcard(base)}
    work = len(wildcards) * (len(names.hosts) + len(names.groups))
    if work > MAX_MATCH_WORK:
        raise _error(names.where, f"pattern {shown(pattern)} has {len(wildcards):,} globs or regular expressions to "
                                  f"test against {len(names.hosts) + len(names.groups):,} host and group names: "
                                  f"more than {MAX_MATCH_WORK:,} tests; list host names (any number is fine), "
                                  "or use fewer, broader globs such as 'amr-*'")


def _is_wildcard(base: str) -> bool:
    return base.startswith("~") or bool(_GLOB_CHARS & set(base))


def _evaluate(terms: list[str], names: _Names) -> tuple[set[str], list[str]]:
    """The hosts chosen, and the union/intersection terms that match nothing (each once).
    Raises InventoryError when an exclusion matches nothing."""
    unions = [t for t in terms if t[0] not in "&!"]
    intersections = [t[1:] for t in terms if t[0] == "&"]
    exclusions = [t[1:] for t in terms if t[0] == "!"]
    missed: dict[str, None] = {}
    missed_strict: dict[str, None] = {}
    found: dict[str, set[str] | None] = {}

    def resolve(term: str, strict: bool = False) -> set[str]:
        if term in names.known:       # a plain host name is never read as a pattern (Ansible)
            return {term}
        if term not in found:        # a term repeated 20,000 times is matched once
            found[term] = _match_term(term, names)
        if found[term] is None:
            (missed_strict if strict else missed)[term] = None
        return found[term] or set()

    chosen: set[str] = set()
    for term in unions or ["all"]:
        chosen |= resolve(term)
    for term in intersections:
        chosen &= resolve(term)
    for term in exclusions:
        chosen -= resolve(term, strict=True)
    if missed_strict:
        raise InventoryError(_unmatched(list(missed_strict), names, strict=True))
    return chosen, list(missed)


def _match_term(term: str, names: _Names) -> set[str] | None:
    """Hosts one term names, or None when it names no host and no group at all."""
    base, subscript = _split_subscript(term)
    if _is_wildcard(base):
        test = names.test(base)
        matched_groups = [g for g in names.groups if test(g)]
        members: list[str] = []
        for group in matched_groups:
            members.extend(names.groups[group])
        members.extend(filter(test, names.hosts))   # a wildcard looks at host names too (Ansible)
    else:
        # Ansible looks at host names only when no group matched, or the name holds a `.`.
        matched_groups = [base] if base in names.groups else []
        members = list(names.groups[base]) if matched_groups else []
        if base in names.known and (not matched_groups or "." in base):
            members.append(base)
    if not matched_groups and not members:
        return None
    if subscript is not None:
        members = _apply_subscript(_dedupe(members), subscript)
    return set(members)


def _matcher(base: str, where: str, notes: list[Problem] | None = None) -> Callable[[str], bool]:
    """The test of a glob or `~regex`. A regex Python warns about (`[a&&b]`, `[[:alpha:]]`: read as
    plain characters today, maybe as set operations later) is a warning of ours in `notes`:
    Python's own went to stderr with rosdeploy's source line, splitting the output."""
    if base.startswith("~"):
        with pywarnings.catch_warnings(record=True) as caught:
            pywarnings.simplefilter("always")
            try:
                regex = re.compile(base[1:])
            except (re.error, OverflowError, RecursionError) as exc:   # `a{99999999999}`: OverflowError
                raise _error(where, f"invalid regular expression {shown(base)}: {exc}; fix it or use a glob") from exc
        for warned in caught[:1]:
            if notes is not None:
                notes.append(Problem(where, None, "", f"regular expression {shown(base)}: {warned.message} (Python "
                                                      "reads it as plain characters, a later Python may read a set "
                                                      "operation): escape the character (`\\&`, `\\-`, `\\[`) to match "
                                                      "it as itself", severity="warning"))
        return lambda name: regex.match(name) is not None
    if _GLOB_CHARS & set(base):
        return re.compile(fnmatch.translate(base)).match    # type: ignore[return-value]  # a match is truthy
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


def _unmatched(terms: list[str], names: _Names, strict: bool) -> list[Problem]:
    """One problem for each of the first MAX_SHOWN_TERMS terms, with its did-you-mean, and one that
    counts the rest: a suggestion for every term of a 20,000-line @file took minutes, and printed
    20,000 lines."""
    found = [_one_unmatched(term, names, strict) for term in terms[:MAX_SHOWN_TERMS]]
    more = len(terms) - MAX_SHOWN_TERMS
    if more > 0 and strict:
        found.append(Problem(names.where, None, "", f"and {more:,} more exclusion(s) that match no host or group"))
    elif more > 0:
        found.append(Problem(names.where, None, "", f"and {more:,} more term(s) that match no host or group, "
                                                    "ignored", severity="warning"))
    return found


def _one_unmatched(term: str, names: _Names, strict: bool) -> Problem:
    reading = _misread(term, names)
    what = f"{shown(term)} reads as {reading}, which selects no host" if reading else \
        f"{shown(term)} matches no host or group"
    where = names.where
    if strict:
        return Problem(where, None, "", f"exclusion {what}: {_hint(term, names)} (an exclusion that excludes "
                                        "nothing would deploy to the robots meant to be left out)")
    return Problem(where, None, "", f"{what}, ignored (as Ansible does): {_hint(term, names)}", severity="warning")


def _misread(term: str, names: _Names) -> str | None:
    """How a pattern reads a term that is also a group's exact name (`g[0]`, `~i`): the group exists,
    but the pattern looks for something else, as Ansible's does."""
    if term not in names.groups:
        return None
    if term.startswith("~"):
        return f"the regular expression {shown(term[1:])}"
    base, subscript = _split_subscript(term)
    if subscript is not None:
        start, end = subscript
        items = f"item {start}" if end is None else f"items {start} to {'the end' if end == -1 else end}"
        return f"{items} of group {shown(base)}"
    return "a glob" if _is_wildcard(term) else "a pattern"


def _hint(term: str, names: _Names) -> str:
    """What to write instead; never the term itself."""
    if _misread(term, names):
        return (f"group {shown(term)} exists, but a pattern cannot name it: rename the group (letters, digits, "
                "'_', '-' and '.')")
    host = _without_port(term)
    if host != term and host in names.known:
        return f"a pattern names a host without its port: did you mean {shown(host)}?"
    choices = (name for name in (*names.groups, *names.hosts) if name != term)
    return suggest.did_you_mean(term, choices) or "check the spelling against the inventory"


def _error(where: str, message: str) -> InventoryError:
    return InventoryError([Problem(where, None, "", message)])
