"""Host entries: `name:port`, `name[01:03]` ranges, and the names Ansible allows."""
from __future__ import annotations

import ipaddress
import re
import string
import unicodedata
import weakref
from typing import Any

from rosdeploy.errors import Problem, shown
from rosdeploy.inventory.draft import Draft, Origin, make_layer
from rosdeploy.inventory.known import NAME


_RANGE = re.compile(r"\[([0-9a-zA-Z]*):([0-9a-zA-Z]*)(?::(\d+))?\]")
# An inventory's distinct hosts: four times the 5,000 robots the issue asks to check in 5 s and
# 300 MB. A robot costs ~17 KB and ~0.45 ms to validate (its vars templated): a 4-line INI of 20,000
# took 370 MB and 6-15 s (a loaded machine), where the former 100,000 took 45 s and 1.7 GB. It is
# also about what the YAML value bound (yamlsrc.MAX_NODES) admits of robots with a dozen vars. A
# range past it is a typo in a bound (`[1:10000000]`), refused from its count, before a name is built.
MAX_HOSTS = 20_000
MAX_RANGE_HOSTS = MAX_HOSTS   # one range alone
# Host entries an inventory may write in all, ranges expanded: the same 25,000 hosts written in 2,000
# groups are 50 million group memberships (20 s, 2 GB). An entry costs ~40 bytes and ~0.4 us
# (400,000: ~16 MB): 5,000 robots may each sit in 80 groups.
MAX_ENTRIES = 400_000
# Ansible's letter ranges index this (a-z, then A-Z): `[a:Z]` is 52 letters, `[A:z]` an error.
LETTERS = string.ascii_letters

# Entries written so far, per draft (Draft belongs to the parsers; this bound is the ranges' own).
_entries: "weakref.WeakKeyDictionary[Draft, int]" = weakref.WeakKeyDictionary()


def add_hosts(raw: str, group: str, host_vars: dict[str, Any], origin: Origin, draft: Draft) -> None:
    """Add one host entry (maybe `name:port` or a `name[01:03]` range) to a group."""
    spec, port = _split_port(raw)
    try:
        count = _range_count(spec)
        if count > MAX_RANGE_HOSTS:
            raise ValueError(f"it names {count} hosts, more than {MAX_RANGE_HOSTS}: check its bounds")
        names = _expanded(spec) if _spend(draft, count, raw, origin) else []
    except ValueError as exc:
        draft.problems.append(origin.problem((), f"invalid host range {shown(raw)}: {exc}"))
        return
    # Counted, not built: the names (at most MAX_RANGE_HOSTS) are only looked up when the count
    # alone would cross the bound, and no host is added past it.
    if len(draft.hosts) + len(names) > MAX_HOSTS and \
            len(draft.hosts) + sum(name not in draft.hosts for name in names) > MAX_HOSTS:
        draft.problems.append(origin.problem((), f"host range {shown(raw)} takes this inventory past {MAX_HOSTS} "
                                                 "hosts: check the ranges' bounds"))
        _entries[draft] = MAX_ENTRIES + 1    # refused: later entries are skipped, not each reported
        return
    if port is not None:
        host_vars = {"ansible_port": port, **host_vars}
    layer = make_layer(host_vars, origin) if host_vars else None
    for name in names:
        if valid_name(name, origin, draft, "host"):
            draft.add_host(group, name, origin, layer)


# Ansible's parse_address: `[v6]:port`, or `host:port` where the host holds no `:` but in a range;
# ASCII digits only (`robot1:２２` is a host name there, refused here as one).
_BRACKETED_PORT = re.compile(r"\[([^\[\]]*:[^\[\]]*:[^\[\]]*)\]:([0-9]+)")
_HOST_PORT = re.compile(r"((?:[^:\[\]]|\[[^\[\]]*\])+):([0-9]+)")


def _split_port(raw: str) -> tuple[str, int | None]:
    """`name:port` or `[v6]:port` split, as Ansible does; anything else (an IPv6 address such as
    `fe80::1:22`) is all name."""
    found = _BRACKETED_PORT.fullmatch(raw) or _HOST_PORT.fullmatch(raw)
    return (found[1], int(found[2])) if found else (raw, None)


def _spend(draft: Draft, count: int, raw: str, origin: Origin) -> bool:
    """Count `count` more entries against MAX_ENTRIES; False (and one problem, at the entry that
    crossed the bound) once the inventory has written more, so later entries cost nothing."""
    before = _entries.get(draft, 0)
    _entries[draft] = after = before + count
    if after > MAX_ENTRIES >= before:
        draft.problems.append(origin.problem((), f"host entry {shown(raw)} takes this inventory past {MAX_ENTRIES} "
                                                 "host entries, ranges expanded (the same hosts written in many "
                                                 "groups): list them in one group and make it a child of the others"))
    return after <= MAX_ENTRIES


def entries_left(draft: Draft) -> bool:
    """Whether the inventory may still add host entries (a parser skips host lines once it may not)."""
    return _entries.get(draft, 0) <= MAX_ENTRIES


def _range_count(spec: str) -> int:
    """How many names a spec expands to, without expanding it."""
    count = 1
    for found in _RANGE.finditer(spec):
        start, end, stride = found[1] or "0", found[2], int(found[3] or 1)
        if stride < 1:
            continue          # refused with its own message when expanded
        if start.isdigit() and end.isdigit():
            count *= max(0, (int(end) - int(start)) // stride + 1)
        elif start in LETTERS and end in LETTERS and len(start) == len(end) == 1:
            count *= max(0, (LETTERS.index(end) - LETTERS.index(start)) // stride + 1)
    return count


def _expanded(spec: str) -> list[str]:
    """`amr-[01:03]` → amr-01, amr-02, amr-03 (Ansible: zero padding kept, `[a:c]`, `[0:9:2]`)."""
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
    elif len(start) == 1 and len(end) == 1 and start in LETTERS and end in LETTERS:
        items = list(LETTERS[LETTERS.index(start):LETTERS.index(end) + 1:stride])
    else:
        raise ValueError("bounds must be both numbers or both single letters, e.g. [1:3] or [a:c]")
    if not items:
        order = ": letters run a-z then A-Z, as in Ansible ([a:Z] is all 52)" if start.isalpha() else ""
        raise ValueError(f"the start is after the end{order}")
    return items


def valid_name(name: str, origin: Origin, draft: Draft, what: str) -> bool:
    if what == "group":
        return _valid_group(name, origin, draft)
    if NAME.fullmatch(name) or _ipv6(name) or _idna(name):
        return True
    if name[:1] in ("-", ".") and NAME.fullmatch("x" + name):
        draft.problems.append(origin.problem((), f"invalid {what} name {shown(name)}: it may not start with "
                                                 f"{shown(name[0])} (a command line would read it as an option, or "
                                                 "a path); start it with a letter, digit or '_'"))
        return False
    draft.problems.append(origin.problem((), f"invalid {what} name {shown(name)}: use letters, digits, "
                                             "'_', '-' and '.' (other characters clash with patterns "
                                             "and shells)"))
    return False


# Ansible's rule for a group name, a variable name: word characters (Unicode letters count), not
# starting with a digit. It keeps any other name, with "Invalid characters were found in group names".
_ANSIBLE_GROUP = re.compile(r"[^\W\d]\w*")
_NOT_WORD = re.compile(r"\W")
# What a `--limit` pattern, a shell or a path reads as its own.
_PATTERN_CHARS = frozenset(":,!&*?[]~@$`'\"\\/;|<>(){}#%^=+")


def _valid_group(name: str, origin: Origin, draft: Draft) -> bool:
    if _ANSIBLE_GROUP.fullmatch(name):
        return True
    if not name or any(c.isspace() or not c.isprintable() for c in name):
        draft.problems.append(origin.problem((), f"invalid group name {shown(name)}: use letters, digits, "
                                                 "'_', '-' and '.' (other characters clash with patterns "
                                                 "and shells)"))
        return False
    if name not in draft.odd_groups:
        draft.odd_groups[name] = origin
        if _risky(name):
            draft.warnings.append(origin.problem((), _odd_group(name), severity="warning"))
    return True


def _risky(name: str) -> bool:
    """A group name a pattern, a shell or a command line reads otherwise (its own warning)."""
    return name[0] in "-." or bool(_PATTERN_CHARS & set(name))


def plain_odd_groups_warning(draft: Draft) -> Problem | None:
    """One warning for the group names Ansible warns about that nothing misreads (`site-north`,
    `2nd_floor`), at the first one: Ansible prints one line for them all, and a fleet with many
    such groups (kolla's 121) must not get a page of warnings on every command."""
    plain = [(name, origin) for name, origin in draft.odd_groups.items() if not _risky(name)]
    if not plain:
        return None
    name, origin = plain[0]
    if len(plain) == 1:
        return origin.problem((), _odd_group(name), severity="warning")
    more = f" (and {len(plain) - 5} more)" if len(plain) > 5 else ""
    shown_names = ", ".join(shown(n) for n, _ in plain[:5]) + more
    return origin.problem((), f"{len(plain)} group names hold characters Ansible warns about: {shown_names}: "
                              "Ansible warns \"Invalid characters were found in group names\" (its group names are "
                              "letters, digits and '_', not starting with a digit) and keeps them, as rosdeploy "
                              "does; rename them (e.g. '-' and '.' to '_') to silence this", severity="warning")


def _odd_group(name: str) -> str:
    """Why Ansible warns about a group name it keeps (TRANSFORM_INVALID_GROUP_CHARS=never), and
    whether it matters beyond the warning."""
    causes = []
    if name[0] == "-":
        causes.append("starts with '-' (a command line reads it as an option)")
    elif name[0].isdigit():
        causes.append("starts with a digit")
    odd = sorted(set(_NOT_WORD.findall(name[1:] if name[0] == "-" else name)))
    if odd:
        causes.append("holds " + ", ".join(shown(c) for c in odd))
    risky = _risky(name)
    better = _NOT_WORD.sub("_", name)
    better = "_" + better if better[0].isdigit() else better
    advice = ("patterns and shells may read it differently: rename it" if risky else
              f"rename it (e.g. {shown(better)}) to silence this")
    return (f"group name {shown(name)} {' and '.join(causes)}: Ansible warns \"Invalid characters were found in "
            "group names\" (its group names are letters, digits and '_', not starting with a digit) and keeps it, "
            f"as rosdeploy does; {advice}")


def _idna(name: str) -> bool:
    """A host name with non-ASCII letters (`bücher.example`), as Ansible takes it and the resolver
    reaches it (IDNA). Only letters, marks, ASCII digits, '-', '_' and '.', so nothing a shell or a
    path reads; in NFKC form, so `ｒ1` is no second spelling of `r1`; not starting with '-' or '.'."""
    if name.isascii() or name[:1] in ("-", ".", "") or unicodedata.normalize("NFKC", name) != name:
        return False
    if not all(c.isalnum() or c in "-_." if c.isascii() else unicodedata.category(c)[0] in "LM" for c in name):
        return False
    try:
        name.encode("idna")     # a label too long or empty, or mixed writing directions
    except UnicodeError:
        return False
    return True


def _ipv6(name: str) -> bool:
    """An IPv6 address as a host name (`::1`, `fe80::1`): Ansible takes it as it is."""
    try:
        ipaddress.IPv6Address(name)
    except ValueError:
        return False
    return True
