"""One error root for everything rosdeploy reports to a user.

Every error carries the exit code the CLI returns for it, so the CLI never has
to guess which kind of failure it is looking at.
"""
from __future__ import annotations

import itertools
import re
from dataclasses import dataclass
from typing import Any, Iterable, Iterator

EXIT_OK = 0
EXIT_INTERNAL = 1      # a bug in rosdeploy: traceback goes to the run log
EXIT_INPUT = 2         # bad inventory, fleet file, template, vault, usage: nothing touched
EXIT_PARTIAL = 3       # some robots failed, rolled back or were unreachable
EXIT_ABORTED = 4       # a rollout stopped on max_fail (fleet-level rollback may have run)
EXIT_DECLINED = 5      # the operator answered no at the confirmation: nothing was done
EXIT_INTERRUPTED = 130

# Characters of a user value quoted in a message: enough to recognise it beside the file:line or
# key the message names. Values were quoted whole, so a 5,000-character `window.tz` or `--limit`
# made a message (and a --json document) of several KB.
SHOWN_CHARS = 100
# A path in a message: real ones are far shorter; a 100 KB one was echoed whole (the JSON
# document's `file` field still holds it whole, once).
SHOWN_PATH = 400


@dataclass(frozen=True)
class Problem:
    """One thing wrong with the user's input, located as precisely as we can."""

    file: str
    line: int | None
    key: str
    message: str
    severity: str = "error"  # "error" | "warning"
    rule: str = ""           # check rule id, e.g. "image-unversioned"

    def __str__(self) -> str:
        """One line: a file name or value with a newline (`validate $'a\\nerror: b.yml'`) must not
        print a line that reads as another error; its control characters are shown escaped."""
        file = self.file
        if len(file) > SHOWN_PATH:
            file = f"{file[:SHOWN_PATH]}... ({len(file)} characters)"
        where = f"{file}:{self.line}" if self.line else file
        text = f"{self.key}: {self.message}" if self.key else self.message
        return one_line(f"{where}: {text}" if where else text)   # no file (a registry, a flag): no empty prefix


# Characters a message shows escaped, never obeyed (a regular expression's character class): C0
# and C1 controls and DEL; the bidi controls (U+061C, U+200E-F, U+202A-E, U+2066-9), which turn
# the rest of a line around on screen; the zero-width ones (U+200B-D, U+2060, U+FEFF) and the
# rest of U+2060-206F, which hide text; and U+2028/U+2029 (U+0085 is a C1 control), at which
# `splitlines()` and log viewers split one line in two.
UNSEEN = "\x00-\x1f\x7f-\x9f\u061c\u200b-\u200f\u2028-\u202e\u2060-\u206f\ufeff"
_CONTROL = re.compile(f"[{UNSEEN}]")


def one_line(text: str) -> str:
    """`text` with the UNSEEN characters escaped (`\\n`, `\\x1b`, `\\u202e`): one line, as output.one_line."""
    return _CONTROL.sub(lambda m: repr(m[0])[1:-1], text)


def shown(value: object, limit: int = SHOWN_CHARS) -> str:
    """repr() of a user value for a message; past `limit` characters its head, `...` and its length.
    A container is never written out whole: a list holding one list 16 times, ten levels deep
    (a few KB in memory), is 2**40 items written out, and repr() of it took all memory."""
    if isinstance(value, str):
        return repr(value) if len(value) <= limit else f"{value[:limit]!r}... ({len(value)} characters)"
    try:
        head = "".join(itertools.islice(_repr_pieces(value, set()), limit + 1))
        if len(head) <= limit:
            return head
        total = _repr_length(value, {}, set())
    except ValueError:      # an int past Python's 4,300-digit str() bound
        return "a number too long to show"
    except RecursionError:
        return f"a {type(value).__name__} nested too deeply to show"
    return f"{head[:limit]}... ({total} characters)"


# The containers shown item by item, and how repr() opens and closes them (a set's `{}`).
_OPENED: dict[type, tuple[str, str]] = {list: ("[", "]"), tuple: ("(", ")"), dict: ("{", "}"), set: ("{", "}"),
                                        frozenset: ("frozenset({", "})")}
_EMPTY: dict[type, str] = {list: "[]", tuple: "()", dict: "{}", set: "set()", frozenset: "frozenset()"}


def _items(value: Any) -> Iterator[tuple[Any, ...]]:
    """A container's items as repr() writes them: (key, value) pairs of a dict, single items else."""
    return iter(value.items()) if isinstance(value, dict) else ((item,) for item in value)


def _repr_pieces(value: Any, open_: set[int]) -> Iterator[str]:
    """repr(value) in pieces, built only as far as they are taken (a container's items lazily)."""
    kind = type(value)
    if kind not in _OPENED:      # a scalar or any other object (a subclass writes itself its own way)
        yield repr(value)
        return
    if not value:
        yield _EMPTY[kind]
        return
    start, end = _OPENED[kind]
    if id(value) in open_:       # a container inside itself, as repr() writes it
        yield f"{start[-1]}...{end[0]}"
        return
    open_.add(id(value))
    yield start
    for index, item in enumerate(_items(value)):
        if index:
            yield ", "
        yield from _repr_pieces(item[0], open_)
        if len(item) == 2:
            yield ": "
            yield from _repr_pieces(item[1], open_)
    yield "," + end if kind is tuple and len(value) == 1 else end
    open_.discard(id(value))


def _repr_length(value: Any, known: dict[int, int], open_: set[int]) -> int:
    """len(repr(value)), each container counted once (memoised by id) however often it is held."""
    kind = type(value)
    if kind not in _OPENED or not value:
        return len(_EMPTY[kind]) if kind in _OPENED else len(repr(value))
    if id(value) in known:
        return known[id(value)]
    if id(value) in open_:
        return 5                # `[...]`
    open_.add(id(value))
    start, end = _OPENED[kind]
    total = len(start) + len(end) + 2 * (len(value) - 1) + (kind is tuple and len(value) == 1)
    for item in _items(value):
        total += sum(_repr_length(part, known, open_) for part in item) + 2 * (len(item) - 1)
    open_.discard(id(value))
    known[id(value)] = total
    return total


class RosdeployError(Exception):
    exit_code = EXIT_INTERNAL


class InputError(RosdeployError):
    """Anything wrong with what the user wrote. Raised before any robot is touched."""

    exit_code = EXIT_INPUT

    def __init__(self, problems: Iterable[Problem] | str) -> None:
        if isinstance(problems, str):
            problems = [Problem("", None, "", problems)]
        self.problems: tuple[Problem, ...] = tuple(problems)
        super().__init__("\n".join(str(p) for p in self.problems))


class InventoryError(InputError):
    pass


class FleetSpecError(InputError):
    pass


class RenderError(InputError):
    pass


class VaultError(InputError):
    pass


class RemoteError(RosdeployError):
    """Something went wrong on or on the way to one robot."""

    exit_code = EXIT_PARTIAL

    def __init__(self, host: str, message: str) -> None:
        self.host = host
        self.detail = message
        super().__init__(f"{host}: {message}")


class ConnectError(RemoteError):
    pass


class HostKeyError(ConnectError):
    pass


class ChannelRefused(ConnectError):
    """An open connection could not start a command: it died since its last use. Nothing ran."""


class CommandFailed(RemoteError):
    def __init__(self, host: str, result: "object", what: str = "") -> None:
        self.result = result
        detail = getattr(result, "stderr", "") or getattr(result, "stdout", "")
        tail = "\n".join(str(detail).strip().splitlines()[-5:])
        code = getattr(result, "exited", "?")
        super().__init__(host, f"{what or 'command'} failed (exit {code}): {tail}")


class GuardTookOver(RemoteError):
    """The robot's deploy guard acted (its deadline passed) before this run could activate."""


class LockHeld(RemoteError):
    pass


class SimError(RosdeployError):
    """The simulated fleet could not be brought up or down."""

    exit_code = EXIT_PARTIAL
