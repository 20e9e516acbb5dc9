"""Every print, table and prompt goes through here; nothing below the CLI prints.

`Output` writes human text to a terminal and, with json=True, keeps stdout for
one JSON document so CI can parse it while humans still see errors on stderr.
Secrets registered with `mask()` are replaced in every line written, and in every string value
of the JSON document before it is serialized (its keys, numbers, booleans and nulls never).

Text from robots (history, lock owners, manifests, container labels) goes into these lines,
and a robot may be corrupt or hostile: every control character written is shown escaped
(`\x1b`), never obeyed, so no robot sets the terminal's title, clears it, or fakes another
robot's lines. Only the colour Output paints itself reaches the terminal as escape codes.
"""
from __future__ import annotations

import json
import os
import re
import secrets
import sys
import threading
from types import CodeType, FunctionType, ModuleType
from typing import Any, Callable, Iterable, Mapping, Sequence, TextIO

from rosdeploy.errors import UNSEEN

MASK = "********"
LONG_SECRET = 8     # characters from which a secret is masked inside words too (Output.masked)


class Output:
    def __init__(self, stdout: TextIO | None = None, stderr: TextIO | None = None,
                 as_json: bool = False, color: bool | str | None = None, hold: bool = False) -> None:
        """`color`: "auto" (or None), "always", "never", or a bool for both streams. `hold`: the
        JSON document waits for finish(), which adds the exit code (the CLI's main())."""
        self.stdout = stdout or sys.stdout
        self.stderr = stderr or sys.stderr
        self.as_json = as_json
        self.color_out = use_color(self.stdout, color)
        self.color_err = use_color(self.stderr, color)
        self.interactive = _isatty(self.stdout) and not as_json     # live progress, tables for people
        # A question needs a person at the keyboard, not a terminal on stdout: `apply F | tee log`
        # and `--json apply F > out.json`, typed at a terminal, ask on stderr.
        self.can_ask = _isatty(sys.stdin)
        self.documented = False          # the one JSON document of this run was written (or held)
        self.hold = hold
        self._held: dict | None = None
        self._also: dict[str, Any] = {}   # fields for the document, known before it is built (also())
        self._secrets: set[str] = set()
        self._pattern: re.Pattern[str] | None = None
        self._wording: tuple[int, tuple[str, ...]] | None = None   # (modules looked at, _ours())
        self._lock = threading.Lock()   # progress lines come from many robot threads
        self._live: list[str] = []      # lines drawn at the bottom of the terminal (see live)

    @property
    def color(self) -> bool:
        """Whether `line()`'s stream is painted (stderr in --json mode, else stdout)."""
        return self.color_err if self.as_json else self.color_out

    # --- secrets --------------------------------------------------------------
    def mask(self, secrets: Iterable[str]) -> None:
        # Shorter than 4 characters ("1", "on"): not masked, it would mask innocent text everywhere;
        # check warns about vault values that short.
        self._secrets.update(s for s in secrets if s and len(s) >= 4)
        self._pattern = None
        self._wording = None

    def masked(self, text: str) -> str:
        """Every secret replaced. One of LONG_SECRET characters or more anywhere: it is no word of
        ours. A shorter one only where it stands as a whole word, not inside a word or a path
        (`_`, `-`, `.`, `/` join them; a full stop ends a word): masked inside them it garbled
        them, and gave it away. Nor where it is a word of rosdeploy's own wording (see _ours):
        password `wrong` made "cannot decrypt: ******** vault password", which told it, as a mask
        in text everyone can read in the source tells the word it hides; left as it is, that text
        is the same whatever the password, so it tells nothing."""
        return self._mask(text, 0)

    def _mask(self, text: str, kept: int) -> str:
        """`text` masked but for its first `kept` characters (a line's head, see _masked_text)."""
        if not self._secrets:
            return text
        spans: list[tuple[int, int]] | None = None

        def replace(match: re.Match[str]) -> str:
            nonlocal spans
            if match.end() <= kept:
                return match[0]
            if len(match[0]) < LONG_SECRET:
                spans = self._our_spans(text) if spans is None else spans
                if any(start <= match.start() and match.end() <= end for start, end in spans):
                    return match[0]
            return MASK
        return self._compiled().sub(replace, text)

    def _compiled(self) -> re.Pattern[str]:
        if self._pattern is None:
            parts = [re.escape(s) if len(s) >= LONG_SECRET else _whole_word(s)
                     for s in sorted(self._secrets, key=len, reverse=True)]
            self._pattern = re.compile("|".join(parts))
        return self._pattern

    def _our_spans(self, text: str) -> list[tuple[int, int]]:
        """Where `text` holds a piece of rosdeploy's own wording that a short secret is a word of."""
        spans = []
        for piece in self._ours():
            at = text.find(piece)
            while at >= 0:
                spans.append((at, at + len(piece)))
                at = text.find(piece, at + 1)
        return spans

    def _ours(self) -> tuple[str, ...]:
        """The literal text of rosdeploy's messages (the string constants of its loaded code) that
        holds a short secret as a word beside _OTHER_CHARS other visible characters: such a piece,
        found whole in a line, is our wording there, not a value. A piece that is about the secret
        alone (`"wrong"`, or `" robot "` of an f-string) is no evidence, so the word stays masked. Looked up again
        when more of rosdeploy is loaded (commands import modules as they need them)."""
        loaded = tuple(module for name, module in list(sys.modules.items())
                       if name == "rosdeploy" or name.startswith("rosdeploy."))
        if self._wording is None or self._wording[0] != len(loaded):
            short = [s for s in self._secrets if len(s) < LONG_SECRET]
            words = re.compile("|".join(_whole_word(s) for s in short)) if short else None
            pieces = () if words is None else tuple(
                piece for piece in _literals(loaded)
                if words.search(piece) and len("".join(words.sub("", piece).split())) >= _OTHER_CHARS)
            self._wording = (len(loaded), tuple(sorted(pieces, key=len, reverse=True)))
        return self._wording[1]

    def _masked_text(self, text: str) -> str:
        """Human text masked, but for the `error:` / `warning[rule]` a line starts with, which
        scripts grep for: a vault password `error` made every error line `********: ...`. A
        secret running past that head is masked whole, head included. Elsewhere in the text a
        secret equal to one of our words is masked unless it is part of our wording (see masked)."""
        head = _HEAD.match(text)
        return self._mask(text, head.end() if head else 0)

    # --- writing --------------------------------------------------------------
    def line(self, text: str = "") -> None:
        """Human text: stdout normally, stderr in --json mode (stdout is for the document)."""
        stream = self.stderr if self.as_json else self.stdout
        self._write(stream, text)

    def note(self, text: str) -> None:
        """Plain text on stderr, whatever the mode (e.g. a usage line above its error)."""
        self._write(self.stderr, text)

    def error(self, text: str) -> None:
        self._write(self.stderr, _paint(text, "red", self.color_err))

    def warn(self, text: str) -> None:
        self._write(self.stderr, _paint(text, "yellow", self.color_err))

    def also(self, fields: dict[str, Any]) -> None:
        """Fields the run's document carries whoever builds it (the command, or a failure's error),
        unless it has them itself: what loading the fleet warned about is known before either."""
        self._also.update(fields)

    def document(self, data: Any) -> None:
        """The one JSON document of a --json run; held until finish() when `hold` is set."""
        if isinstance(data, dict):
            data = {**self._also, **data}
        if self.hold and isinstance(data, dict):
            self._held = dict(data)
            self.documented = True
            return
        self._write_document(data)

    def amend(self, fields: dict, replace: bool = True) -> None:
        """Add to the held document (a failure after the command built it: its error); with
        replace=False, only the fields it does not have yet."""
        if self._held is not None:
            self._held.update(fields if replace else {k: v for k, v in fields.items() if k not in self._held})

    def finish(self, code: int) -> None:
        """Write the held document with `ok` and `exit_code`: every document carries them, a
        report that found a robot unreachable (exit 3) included, so CI reads one field."""
        if self._held is not None:
            held, self._held = self._held, None
            self._write_document({**held, "ok": code == 0, "exit_code": code})

    def _write_document(self, data: Any) -> None:
        """Masked as data, then serialized, never the other way round: masking the JSON text missed
        a secret json.dumps had escaped (`S\\u00e9cr\\u00e9t`, `back\\\\slash\\"`), and a secret equal
        to a word of the document (`null`, `true`, `1252`, `exit_code`) rewrote its syntax into
        text no JSON reader takes, or took its `exit_code` away."""
        data = masked_values(data, self.masked)
        text = json.dumps(data, indent=2, sort_keys=True)
        if "\\udc" in text:    # a non-UTF-8 byte from argv or a file name: a lone surrogate, not Unicode
            text = json.dumps(_unicode(data), indent=2, sort_keys=True)
        self._write(self.stdout, text, mask=False)   # json.dumps escaped every control character already
        self.documented = True

    def table(self, header: Sequence[str], rows: Iterable[Sequence[Any]]) -> None:
        rows = [[one_line(c) for c in row] for row in rows]   # a cell is one line, escaped before it is measured
        widths = [max([len(h)] + [len(r[i]) for r in rows]) for i, h in enumerate(header)]
        fmt = "  ".join(f"{{:<{w}}}" for w in widths)
        # one write: a line each was a flush (a syscall) and a masking pass per robot
        self.line("\n".join([self.paint(fmt.format(*header).rstrip(), "bold"),
                             *(fmt.format(*row).rstrip() for row in rows)]))

    def paint(self, text: str, style: str) -> str:
        """`text` styled for `line()` (its stream's colour decision; error/warn paint their own)."""
        return _paint(text, style, self.color)

    def live(self, lines: Sequence[str]) -> None:
        """Redraw the region at the bottom of the terminal with `lines` (each shorter than the
        terminal is wide); text written meanwhile appears above it. Terminal runs only: a CI
        log gets plain lines instead (see cli.report.progress_view)."""
        with self._lock:
            self._erase_live()
            self._live = [one_line(self.masked(line)) for line in lines]   # the region's height is its line count
            self._draw_live()

    def _erase_live(self) -> None:
        if self._live:   # to the start of the region's first line, then clear to the end
            self.stdout.write(f"\033[{len(self._live)}F\033[J")
            self.stdout.flush()

    def _draw_live(self) -> None:
        if self._live:
            self.stdout.write("".join(_shown(line) + "\n" for line in self._live))   # its painted marks too
            self.stdout.flush()

    def _write(self, stream: TextIO, text: str, mask: bool = True) -> None:
        with self._lock:
            self._erase_live()
            stream.write(_shown(self._masked_text(text) if mask else text) + "\n")
            stream.flush()
            self._draw_live()


_STYLES = {"red": "31", "green": "32", "yellow": "33", "bold": "1", "dim": "2"}

# Colour is painted as a mark, turned into its escape code only when written: the key is random
# per process (private-use characters, which no secret holds), so text from a robot cannot carry
# a mark, and every escape code it does carry is escaped with the rest of its control characters.
_KEY = "".join(chr(0xF0000 + secrets.randbelow(0xFFFE)) for _ in range(4))
_MARK = re.compile(f"{_KEY}([0-9]+){_KEY}")
# What errors.one_line escapes (controls, and the characters that reverse, hide or split a line);
# lone surrogates too (no terminal encoding writes them).
_CONTROL = re.compile(f"[{UNSEEN}\ud800-\udfff]")
# The severity a line of ours starts with (after its colour, if painted): kept when masking.
_HEAD = re.compile(f"(?:{_KEY}[0-9]+{_KEY})?(?:error|warning|info)(?:: |\\[[a-z0-9-]+\\] )")


# Visible characters beside a short secret that make a piece of our wording evidence (Output._ours):
# `" robot(s) to "`, `"/<robot>/"` are; `" robot "`, `"robot:"` would leave every plain one unmasked.
_OTHER_CHARS = 3


def _whole_word(secret: str) -> str:
    """A short secret as a whole word: not inside a word or a path (see Output.masked)."""
    return rf"(?<![\w./-]){re.escape(secret)}(?![\w/-]|\.\w)"


def _literals(modules: Iterable[ModuleType]) -> set[str]:
    """The string constants of `modules`' functions, methods and classes (their message wording,
    f-strings' fixed parts included), and their UPPER_CASE module constants (HOW_TO_GIVE_PASSWORD).
    No other module variable: one may hold a value read at run time."""
    found: set[str] = set()
    seen: set[int] = set()

    def code(obj: CodeType) -> None:
        for const in obj.co_consts:
            if isinstance(const, str):
                found.add(const)
            elif isinstance(const, CodeType):
                code(const)

    def walk(names: Mapping[str, Any], owner: str) -> None:
        for name, value in list(names.items()):
            if id(value) in seen:
                continue
            seen.add(id(value))
            if isinstance(value, (staticmethod, classmethod)):
                value = value.__func__
            if isinstance(value, property):
                for part in (value.fget, value.fset):
                    if isinstance(part, FunctionType):
                        code(part.__code__)
            elif isinstance(value, FunctionType) and value.__module__ == owner:
                code(value.__code__)
            elif isinstance(value, type) and value.__module__ == owner:
                walk(vars(value), owner)
            elif isinstance(value, str) and name.isupper():
                found.add(value)

    for module in modules:
        walk(vars(module), module.__name__)
    return found


def one_line(value: object) -> str:
    """`value` as text on one line: a newline inside a value must not start a line of its own
    (one robot's text would read as another robot's line)."""
    return _CONTROL.sub(_escaped, str(value))


def _shown(text: str) -> str:
    """Text as written: control characters escaped but the newlines and tabs a multi-line text
    is made of; the marks painted as colour."""
    parts = _MARK.split(text)
    parts[::2] = [_CONTROL.sub(lambda m: m[0] if m[0] in "\n\t" else _escaped(m), p) for p in parts[::2]]
    parts[1::2] = [f"\033[{code}m" for code in parts[1::2]]
    return "".join(parts)


def _escaped(match: re.Match[str]) -> str:
    code = ord(match[0])
    named = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}.get(match[0])
    return named or (f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}")


def masked_values(data: Any, masked: Callable[[str], str]) -> Any:
    """`data` (a document about to be serialized) with every string value passed through `masked`.
    Keys are rosdeploy's own names and stay; numbers, booleans and null are never rewritten (a
    secret `1252` is no `line`, a secret `null` no `fix`)."""
    if isinstance(data, str):
        return masked(data)
    if isinstance(data, dict):
        return {key: masked_values(value, masked) for key, value in data.items()}
    if isinstance(data, (list, tuple)):
        return [masked_values(value, masked) for value in data]
    if data is None or isinstance(data, (bool, int, float)):
        return data
    return masked(str(data))    # a Path, a set: written as its text, so masked as text


def _unicode(data: Any) -> Any:
    """`data` with each undecodable byte (Python's surrogate escape) as U+FFFD, which every JSON
    reader takes; a lone surrogate is valid JSON text but not a character."""
    if isinstance(data, str):
        try:
            raw = data.encode("utf-8", "surrogateescape")
        except UnicodeEncodeError:    # a surrogate no byte was escaped to
            raw = data.encode("utf-8", "surrogatepass")
        return raw.decode("utf-8", "replace")
    if isinstance(data, dict):
        return {_unicode(k): _unicode(v) for k, v in data.items()}
    if isinstance(data, (list, tuple)):
        return [_unicode(v) for v in data]
    return data


def _paint(text: str, style: str, color: bool) -> str:
    return f"{_KEY}{_STYLES[style]}{_KEY}{text}{_KEY}0{_KEY}" if color else text


def _isatty(stream: TextIO) -> bool:
    return hasattr(stream, "isatty") and stream.isatty()


def use_color(stream: TextIO, mode: bool | str | None = "auto") -> bool:
    """Colour for one stream: --color always/never wins; else NO_COLOR (any non-empty value: an
    empty one is ignored, as no-color.org says) turns it off, FORCE_COLOR (any value but empty or
    0: `FORCE_COLOR=0` is off, as in Node's supports-color and most tools that read it) on, and
    otherwise only a terminal gets it. NO_COLOR beats FORCE_COLOR, as in CPython's own REPL and
    tracebacks: escape codes in a log file are the worse mistake."""
    if isinstance(mode, bool):
        return mode
    if mode in ("always", "never"):
        return mode == "always"
    if os.environ.get("NO_COLOR"):
        return False
    if os.environ.get("FORCE_COLOR", "") not in ("", "0"):
        return True
    return _isatty(stream)


def confirm(out: Output, question: str) -> bool:
    """Ask at the keyboard; never called without one (callers check out.can_ask). The question
    goes to stdout when people read it, else to stderr, out of the way of a piped report."""
    stream = out.stdout if out.interactive else out.stderr
    stream.write(f"{question} [y/N] ")
    stream.flush()
    try:
        return input().strip().lower() in ("y", "yes")
    except EOFError:
        return False
