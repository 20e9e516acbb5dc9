"""YAML loading that remembers where every value came from.

Error messages must say `file:line: key.path: ...`, so we compose the YAML node
tree ourselves and record each mapping key's line while building plain Python
values. Values stay plain dicts/lists/scalars: nothing downstream has to know.
"""
from __future__ import annotations

import os
import re
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, cast

import yaml

from rosdeploy.errors import InputError, Problem, shown

KeyPath = tuple[Any, ...]


# libyaml's composer when PyYAML was built with it (10x faster on a 5,000-robot inventory);
# the pure-Python one otherwise. Only composing uses it: values are built by _build below.
_Composer = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

# Bounds that keep a hostile or broken file from taking the controller down:
MAX_DEPTH = 200            # nesting levels (libyaml's composer recurses in C and would crash)
MAX_EXPANSION = 10         # aliases may multiply the document's nodes this much ("billion laughs")
MIN_BUDGET = 100_000       # ... but a small file may always expand to this many nodes
MAX_FILE_BYTES = 64 << 20  # a 5,000-robot inventory is ~1 MiB
# Values a document may build (its nodes, aliases expanded). The byte cap above does not bound the
# cost: `x: [1,1,...]` is 2 bytes a value, and each value costs ~500 bytes and ~6 µs by the time a
# robot is rendered (5 MB of it: 15 s, 1.2 GB). A 5,000-robot inventory is ~60,000 values.
MAX_NODES = 250_000
# A string's length: sandbox.MAX_LENGTH, the renderer's bound on any value (it imports this module).
# A longer one could never be used; refused as the file is read, at its line, before libyaml builds it
# (a 64 MiB scalar costs libyaml four times its size: near 300 MB).
MAX_STRING = 1_000_000
# An integer's size. Python refuses to write one of over 4,300 digits (str() raises ValueError),
# and `0x` + 4,000 hex digits builds one: every message or JSON that shows it would crash.
MAX_INT_BITS = 14_000      # about 4,200 decimal digits
_INT_DIGITS = 4_300        # sys.get_int_max_str_digits()'s default: the digits int() reads


_COLLECTION_TAGS = ("tag:yaml.org,2002:map", "tag:yaml.org,2002:seq")

# Inventory keys rosdeploy reads as numbers. YAML 1.1 (PyYAML, as Ansible reads it) takes a plain
# `017` for octal 15: the robot would join another ROS domain, ssh another port. Read so all the
# same, as Ansible does, with a warning. Only these keys: `mode: 0644` is octal on purpose.
_NUMBER_KEYS = frozenset({"ros_domain_id", "ansible_port", "ansible_ssh_port"})
# The fleet file is rosdeploy's own, read the same way: its numbers are ports, counts and ids
# (`ports: [017]`, `vars: {domain: 017}`), so every key's is warned of but a mode's (`mode: 0440`).
_MODE_KEY = re.compile(r".*mode|umask", re.IGNORECASE)
_OCTAL = re.compile(r"[-+]?0[0-7_]+")
_INT_TAG = "tag:yaml.org,2002:int"

# Code points no file rosdeploy writes may hold, wherever a value comes from (a YAML escape, an INI
# literal, a Jinja string escape, a script's JSON): a lone surrogate is half of a UTF-16 pair, not a
# character, so UTF-8 cannot encode it (writing it crashed); the noncharacters are outside YAML's
# printable set (Compose refuses the compose.yml) and XML's.
_NOT_TEXT = re.compile("[\ud800-\udfff\ufdd0-\ufdef\ufffe\uffff"
                       + "".join(chr(plane << 16 | 0xfffe) + chr(plane << 16 | 0xffff) for plane in range(1, 17))
                       + "]")
# A NUL written as an escape (`"a\0b"` in YAML, `"\u0000"` in JSON, a raw byte or `"\x00"` in INI):
# no environment variable, command line or file name can hold one, so it is refused at its
# file:line, as a lone surrogate is, rather than at whatever fleet key later uses it. Other control
# characters stay (`"\e[1;32m"` in a motd, `"D:\build"`): Ansible takes them, a var rosdeploy never
# reads must not fail the inventory, and where one lands (an environment value) it is refused there.
_CONTROL = re.compile("\x00")
# What json.dumps writes for a character past U+FFFF: an escaped surrogate pair, which JSON (and
# Ansible, reading .json with a JSON parser) joins into one character, and libyaml refuses.
_JSON_PAIR = re.compile(r"(?<!\\)((?:\\\\)*)\\u([dD][89abAB][0-9a-fA-F]{2})\\u([dD][c-fC-F][0-9a-fA-F]{2})")


class Encrypted(str):
    """A `!vault`-tagged scalar (Ansible's encrypt_string): still ciphertext.

    Only the inventory decrypts these (it holds the vault); anywhere else the
    value stays ciphertext, which is useless but harmless.
    """


class _Constructor(yaml.constructor.SafeConstructor):
    """Builds scalars (and resolves `<<` merges); refusing duplicate keys is _build_mapping's job."""

    # Whether the text holds a backslash: only an escape (`\u`, `\0`, `\x1b`...) builds a string
    # not_text refuses (libyaml refuses the characters written raw), so only then is each string searched.
    escapes = True
    # Whether a control character (an escape's) is refused here: in an inventory (load's `duplicates`
    # given). The fleet file refuses them itself, each key once (fleet.Reader.scan_control_chars).
    controls = False
    # Where octal-looking numbers are warned of (load's `duplicates` or `warnings`), and whether at
    # every key but a mode's (the fleet file) or at the inventory's _NUMBER_KEYS only.
    octal: list[Problem] | None = None
    octal_anywhere = False


class Unsafe(str):
    """An `!unsafe` scalar: Ansible never templates it, and neither does the inventory."""


def _scalar(kind: type[str]) -> Any:
    """A constructor for a tagged scalar (construct_scalar refuses any other node, at its line)."""
    return lambda c, node: kind(c.construct_scalar(cast(yaml.ScalarNode, node)))


def _encrypted(c: Any, node: yaml.Node) -> Encrypted:   # Any: as _scalar's constructors (stubs want a loader)
    """A `!vault` value whose header is checked now, at its line (decrypting it later knows only the file).
    Text with no vault header at all is left to the caller: the fleet file refuses any `!vault` with
    its own advice."""
    from rosdeploy import vault   # imports this module

    value = Encrypted(c.construct_scalar(cast(yaml.ScalarNode, node)))
    data = value.encode("ascii", "replace")
    if not vault.is_encrypted(data):
        return value
    try:
        vault.check_header(data, "")
    except InputError as exc:
        raise yaml.constructor.ConstructorError(None, None, f"!vault value: {exc.problems[0].message}",
                                                node.start_mark) from None
    return value


_Constructor.add_constructor("!vault", _encrypted)
_Constructor.add_constructor("!unsafe", _scalar(Unsafe))


@dataclass(frozen=True)
class Doc:
    """A parsed YAML document plus the line of every key path in it."""

    path: str
    data: Any
    lines: Mapping[KeyPath, int] = field(default_factory=dict)

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
    """`a.b[0]`; a key that is no string is bracketed and spelt as YAML spells it (`hosts[true]`,
    `hosts[1.5]`: `hosts.1.5` read as a path, `[True]` as Python)."""
    out = ""
    for part in keypath:
        if isinstance(part, str):
            out += f".{part}" if out else part
        else:
            out += f"[{_yaml_spelling(part)}]"
    return out


def _yaml_spelling(key: Any) -> str:
    if key is None or isinstance(key, bool):
        return {None: "null", True: "true", False: "false"}[key]
    return str(key)


def load(path: str | Path, text: str | None = None, duplicates: list[Problem] | None = None,
         warnings: list[Problem] | None = None) -> Doc:
    """Parse one YAML file; any problem becomes an InputError naming file and line.

    A duplicate key is an error, unless `duplicates` is given: then, as in Ansible
    (inventories), it is a warning appended there and the last value wins. That list
    (the inventory's warnings) also gets one for an octal-looking number (_octal_warning)
    at a key the inventory reads as a number. `warnings` (the fleet file's, whose
    duplicate keys stay errors) gets one for an octal-looking number at any key but a mode.
    An inventory's (`duplicates` given) control character written as an escape (`"a\\0b"`) is
    refused at its line, as libyaml refuses it written raw.

    Bounded for every caller (fleet file, inventory, vars files, rendered compose files):
    nesting deeper than MAX_DEPTH and alias expansion beyond MAX_EXPANSION times the
    document's own size are refused before anything is built, and so is a string longer
    than MAX_STRING, at its line.
    """
    path = str(path)
    if text is None:
        text = read_text(path)
    if path.endswith(".json") and "\\u" in text:
        text = _joined_pairs(text)
    try:
        _check_depth(text)
        node = yaml.compose(text, Loader=_Composer)
    except _TooLong as exc:
        raise InputError([Problem(path, exc.line, exc.key, str(exc))]) from None
    except yaml.YAMLError as exc:
        kind = "JSON" if path.endswith(".json") else "YAML"   # read as YAML, which JSON is
        raise InputError([Problem(path, _error_line(exc, text), "", f"invalid {kind}: {_syntax_text(exc, text)}")]) \
            from exc
    except RecursionError as exc:   # the bound above should make this unreachable; never a crash
        raise InputError([Problem(path, None, "", "invalid YAML: nested too deeply")]) from exc
    if node is None:
        return Doc(path, None, {})
    _check_expansion(node, path, text)
    lines: dict[KeyPath, int] = {}
    constructor = _Constructor()
    constructor.escapes = "\\" in text
    constructor.controls = duplicates is not None
    constructor.octal = warnings if warnings is not None else duplicates
    constructor.octal_anywhere = warnings is not None
    return Doc(path, _build(node, (), lines, path, constructor, duplicates), lines)


def load_data(text: str, path: str = "<text>") -> Any:
    """Plain values of a YAML text (no line map), with load()'s bounds: for files rosdeploy wrote itself."""
    try:
        _check_depth(text)
        node = yaml.compose(text, Loader=_Composer)
    except _TooLong as exc:
        raise InputError([Problem(path, exc.line, exc.key, str(exc))]) from None
    except yaml.YAMLError as exc:
        raise InputError([Problem(path, _error_line(exc, text), "", f"invalid YAML: {_syntax_text(exc, text)}")]) \
            from exc
    if node is None:
        return None
    _check_expansion(node, path, text)
    try:
        return _Constructor().construct_document(node)
    except (yaml.YAMLError, TypeError, ValueError) as exc:   # an unhashable key; an int of 4,300+ digits
        why = "an integer of more than 4,300 digits" if isinstance(exc, ValueError) and "digits" in str(exc) else exc
        raise InputError([Problem(path, node.start_mark.line + 1, "", f"invalid YAML: {why}")]) from exc


def read_bytes(path: str, limit: int = MAX_FILE_BYTES, what: str = "a YAML file") -> bytes:
    """A configuration file's bytes: a regular file of at most `limit` bytes, or a file problem
    (`what` the file should be, for the message)."""
    try:
        # O_NONBLOCK: opening a FIFO for reading would otherwise wait for a writer, forever.
        with os.fdopen(os.open(path, os.O_RDONLY | os.O_NONBLOCK), "rb") as handle:
            info = os.fstat(handle.fileno())
            if not stat.S_ISREG(info.st_mode):   # /dev/zero, a FIFO: reading would never end
                raise InputError([Problem(path, None, "", f"not a regular file: give the path of {what}")])
            data = handle.read(limit + 1)
    except OSError as exc:
        raise InputError([Problem(path, None, "", f"cannot read file: {exc.strerror}")]) from exc
    if len(data) > limit:
        raise InputError([Problem(path, None, "", f"larger than {_size(limit)}: not {what} rosdeploy will read")])
    return data


def _size(limit: int) -> str:
    return f"{limit >> 20} MiB" if limit >= 1 << 20 else f"{limit >> 10} KiB"


def read_text(path: str) -> str:
    """A file's text as UTF-8; an unreadable file or a stray byte is a file:line problem (never its content)."""
    return decoded(path, read_bytes(path))


def decoded(path: str, data: bytes) -> str:
    """`data` (a file's bytes, or a vault file's plaintext) as UTF-8 text; a stray byte is a
    file:line problem naming the byte, never the text around it."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        column = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        utf16 = " (the file looks like UTF-16)" if data[:2] in (b"\xff\xfe", b"\xfe\xff") or b"\0" in data[:2] else ""
        raise InputError([Problem(path, line, "", f"byte 0x{data[exc.start]:02x} at column {column} is not UTF-8"
                                                  f"{utf16}: save the file as UTF-8")]) from None


def not_text(value: Any, controls: bool = False) -> str | None:
    """Why `value` (a string, or a list or mapping holding strings, keys included) cannot be written
    into a file rosdeploy writes, or None: a lone surrogate or a noncharacter (see _NOT_TEXT), and
    with `controls` (a value read from a file: the inventory's) a control character (see _CONTROL).
    The reason names the code point, never the value (it may be a secret)."""
    if isinstance(value, str):      # most calls
        found = _search_not_text(value, controls)
        return None if found is None else _not_text_reason(found[0])
    stack, seen = [value], set()
    while stack:
        item = stack.pop()
        if isinstance(item, str):
            found = _search_not_text(item, controls)
            if found is not None:
                return _not_text_reason(found.group())
        elif isinstance(item, (list, tuple, dict)) and id(item) not in seen:
            seen.add(id(item))
            stack.extend(item.items() if isinstance(item, dict) else item)
    return None


def _search_not_text(text: str, controls: bool = False) -> re.Match[str] | None:
    # isascii() first: 60 ns, where the search (its class holds astral characters) takes 2 µs;
    # isprintable() (false for any control character) spares the control search most strings
    found = None if text.isascii() else _NOT_TEXT.search(text)
    if found is None and controls and not text.isprintable():
        found = _CONTROL.search(text)
    return found


def _not_text_reason(char: str) -> str:
    code = f"U+{ord(char):04X}"
    if char == "\0":     # "NUL byte", as the checks of paths and environment values say
        return (f"holds a NUL byte ({code}), which no environment variable, command line or file name can "
                "hold: remove it")
    if 0xD800 <= ord(char) <= 0xDFFF:
        return (f"holds a lone surrogate ({code}, half of a UTF-16 pair): not a character, so no file can hold "
                "it; write the character itself (a pair such as \\ud83d\\ude00 in JSON is fine)")
    return (f"holds the noncharacter {code}, which YAML files (compose.yml) and XML may not hold: "
            "remove it")


def _joined_pairs(text: str) -> str:
    """A JSON text with each escaped surrogate pair written as the one character it stands for (on
    the same line, so lines stay right). Only for .json: in YAML `'\\ud83d'` is four letters."""
    def joined(found: re.Match[str]) -> str:
        high, low = int(found[2], 16), int(found[3], 16)
        return found[1] + chr(0x10000 + ((high - 0xD800) << 10) + (low - 0xDC00))
    return _JSON_PAIR.sub(joined, text)


def _error_line(exc: yaml.YAMLError, text: str) -> int | None:
    mark = getattr(exc, "problem_mark", None)
    if mark is not None:
        return mark.line + 1
    position = getattr(exc, "position", None)     # a ReaderError (a control character) has no mark
    return text.count("\n", 0, position) + 1 if isinstance(position, int) else None


# YAML's limit on an implicit ("simple") key, the kind written `key: value`: on one line, and at
# most 1024 characters before its `:`. Past it libyaml says "could not find expected ':'" or
# "mapping values are not allowed in this context" (misleading: the `:` is there), at that `:`.
MAX_SIMPLE_KEY = 1024
_KEY_ERRORS = ("could not find expected ':'", "mapping values are not allowed in this context",
               "did not find expected ',' or '}'",     # libyaml; then PyYAML's words:
               "mapping values are not allowed here", "expected ',' or '}', but got ':'")
_KEY_LEAD = re.compile(r"^(?:\s|[-?](?=\s))*")     # indentation, and `- ` / `? ` indicators
_YAML_BREAK = re.compile(r"\r\n|[\n\r\x85\u2028\u2029]")


def _syntax_text(exc: yaml.YAMLError, text: str) -> str:
    """A syntax error in words; a key past MAX_SIMPLE_KEY named as such, not as a missing `:`."""
    length = _long_key(exc, text)
    if length is None:
        return _error_text(exc)
    return (f"a key of {length} characters: YAML allows at most {MAX_SIMPLE_KEY} in a key written "
            "`key: value`; use a shorter key")


def _long_key(exc: yaml.YAMLError, text: str) -> int | None:
    """The length of the key whose `:` the error points at, when past MAX_SIMPLE_KEY; else None.

    Found by hand on the error's line (no regex backtracking over a line that may be megabytes)."""
    mark = getattr(exc, "problem_mark", None)
    if getattr(exc, "problem", None) not in _KEY_ERRORS or mark is None or mark.column <= MAX_SIMPLE_KEY:
        return None
    before = _line_of(text, mark.line)[:mark.column + 1]
    if not before.endswith(":"):
        return None
    before = before[:-1].rstrip()
    if before[-1:] in ("'", '"'):     # a quoted key, from its opening quote
        start = before.rfind(before[-1], 0, len(before) - 1)
    else:                             # a plain key: after a flow `{`, `[` or `,`, else the whole line
        start = max(before.rfind(c) for c in "{[,") + 1
    lead, key = before[:start], before[start:]
    if before[-1:] not in ("'", '"'):
        key = _KEY_LEAD.sub("", key)
    elif not (_KEY_LEAD.fullmatch(lead) or lead.rstrip().endswith(("{", "[", ","))):
        return None                   # `a: "b": c`: a quoted value, not a key
    if ": " in key and key[:1] not in ("'", '"'):
        return None                   # `a: b: c`: the usual error, whatever the length
    return len(key) if len(key) > MAX_SIMPLE_KEY else None


def _line_of(text: str, number: int) -> str:
    """Line `number` (0-based) of `text`, split where YAML breaks lines."""
    start = 0
    for count, found in enumerate(_YAML_BREAK.finditer(text)):
        if count == number:
            return text[start:found.start()]
        start = found.end()
    return text[start:]


def _error_text(exc: yaml.YAMLError) -> str:
    if isinstance(exc, yaml.reader.ReaderError):
        return f"character {shown(exc.character)} is not allowed in YAML ({exc.reason})" \
            if isinstance(exc.character, str) else f"{exc.reason}"
    return getattr(exc, "problem", None) or str(exc).splitlines()[0]


def _check_depth(text: str) -> None:
    """Refuse nesting deeper than MAX_DEPTH, or more than MAX_NODES values, before a composer
    builds them (composing costs ~4 µs a value, the event scan ~1 µs, and it stops at the bound).

    Block nesting needs a column per level, so depth <= longest line + flow brackets, and each
    value takes a character at least: only a file where either bound is high pays for the scan.
    """
    # len(text) first: the longest line is found over a copy of every line, 64 MiB for a big file
    if len(text) <= MAX_NODES and text.count("[") + text.count("{") + max(map(len, text.splitlines()),
                                                                         default=0) <= MAX_DEPTH:
        return
    if len(text) > MAX_STRING:
        _check_long_lines(text)
    depth = count = 0
    for event in yaml.parse(text, Loader=_Composer):
        if isinstance(event, yaml.NodeEvent):     # a scalar, an alias or a collection's start
            count += 1
            if count > MAX_NODES:
                _refuse_at(event, f"the document holds over {MAX_NODES} values: {_TOO_MANY_FIX}")
            # a `!vault` scalar is ciphertext, about four times its secret: not the value's length
            if isinstance(event, yaml.ScalarEvent) and len(event.value) > MAX_STRING and event.tag != "!vault":
                line = cast(yaml.Mark, event.start_mark).line
                raise _TooLong(_too_long(len(event.value)), line + 1, _key_on(_line_of(text, line)))
        if isinstance(event, yaml.CollectionStartEvent):
            depth += 1
            if depth > MAX_DEPTH:
                _refuse_at(event, f"nested more than {MAX_DEPTH} levels deep")
        elif isinstance(event, yaml.CollectionEndEvent):
            depth -= 1


_TOO_MANY_FIX = ("the value past the limit is here; split the data, or keep large data in a file the service reads "
                 "rather than in variables (each value costs memory and time for every robot)")


def _refuse_at(event: yaml.Event, problem: str) -> None:
    raise yaml.MarkedYAMLError(problem=problem, problem_mark=cast(yaml.Mark, event.start_mark))


class _TooLong(Exception):
    """A string past MAX_STRING, found before the document is built: its message, line and key."""

    def __init__(self, message: str, line: int, key: str) -> None:
        super().__init__(message)
        self.line, self.key = line, key


def _too_long(length: int) -> str:
    return (f"a string of {length:,} characters, more than the {MAX_STRING:,} any value may have: keep large "
            "data in a file the service reads (a `files:` source), not in a variable")


# `key: value` (or `- key: value`) at a line's start, the value neither a collection, an anchor, an
# alias, a tag nor a block scalar: a line that holds one scalar after its key.
_KEY = (r"[ \t]*(?:-[ \t]+)*(?P<key>[^\s#'\"{}\[\],&*!|>%@`-][^:#\n]{0,1023}?|\"[^\"\\\n]{0,1024}\""
        r"|'[^'\n]{0,1024}')[ \t]*:")
_KEY_VALUE = re.compile(_KEY + r"[ \t]+(?P<quote>[^\s\[{&*!|>#])")
_KEY_AT = re.compile(_KEY + r"(?:[ \t]|$)")


def _key_on(line: str) -> str:
    """The key a line starts with (`zz` of `  zz: x`), else "": named in a message about its value."""
    found = _KEY_AT.match(line[:2100])
    return found["key"].strip("'\"") if found else ""


def _check_long_lines(text: str) -> None:
    """Refuse `key: <a scalar of over MAX_STRING characters>` on one line before libyaml parses it (it
    would hold the scalar three times over). Only a line past MAX_STRING can hold one; a window of
    half that with no line break is inside such a line, so only len/half windows are searched. A line
    this cannot judge (a flow list, a comment, a quoted escape) is left to the parse, which counts."""
    half = MAX_STRING // 2
    for window in range(0, len(text), half):
        if text.find("\n", window, window + half) != -1:
            continue
        start = text.rfind("\n", 0, window) + 1
        end = text.find("\n", window)
        end = len(text) if end == -1 else end
        found = _KEY_VALUE.match(text, start, min(end, start + 2100))
        if end - start <= MAX_STRING or found is None:
            continue
        value, quote = found.start("quote"), found["quote"]
        while text[end - 1] in " \t\r":
            end -= 1
        # another line break of YAML's (a lone CR, NEL, U+2028/9) may start another key
        if any(text.find(c, value, end) != -1 for c in "\r\x85\u2028\u2029"):
            continue
        if quote in ("'", '"'):
            # closed at the line's end and not before, with no escape: its length is the line's
            if text[end - 1] != quote or text.find(quote, value + 1, end - 1) != -1 or \
                    text.find("\\", value, end) != -1:
                continue
            length = end - value - 2
        elif any(text.find(c, value, end) != -1 for c in (" #", "\t#", ",", "[", "]", "{", "}")):
            continue    # a comment ends it, and in a flow collection a `,` or bracket may
        else:
            length = end - value
        if length > MAX_STRING:
            raise _TooLong(_too_long(length), text.count("\n", 0, start) + 1, found["key"].strip("'\""))


def _check_expansion(root: yaml.Node, path: str, text: str) -> None:
    """Refuse a document whose aliases expand it beyond its budget, at the line that overflows.

    Each distinct node's expanded size is computed once (bottom-up, memoized), so a
    billion-laughs file is refused in microseconds and nothing is ever expanded.
    A text without `*` has no alias (nor `<<: *merge`): every node is in the tree once, so it
    is within its budget (and MAX_NODES, counted by _check_depth) and cannot contain itself;
    the walk is skipped (0.1 s on 5,000 robots).
    """
    if "*" not in text:
        return
    sizes: dict[int, int] = {}
    order = _postorder(root, path)
    budget = min(max(MIN_BUDGET, MAX_EXPANSION * len(order)), MAX_NODES)
    for node in order:
        children = _children(node)
        size = 1 + sum(sizes[id(c)] for c in children)
        if size > budget:
            raise InputError([Problem(path, node.start_mark.line + 1, "", (
                f"aliases here expand to over {budget} values: refused as an alias bomb; "
                "write the values out or use fewer nested aliases"))])
        sizes[id(node)] = size


def _postorder(root: yaml.Node, path: str) -> list[yaml.Node]:
    """Every distinct node once, children before parents, without recursion; an alias inside
    its own anchor (`a: &a [*a]`, a structure that contains itself) is refused at its line."""
    state: dict[int, int] = {}          # 1: its children are being visited, 2: done
    out: list[yaml.Node] = []
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, expanded = stack.pop()
        if expanded:
            state[id(node)] = 2
            out.append(node)
            continue
        if id(node) in state:
            continue
        state[id(node)] = 1
        stack.append((node, True))
        for child in _children(node):
            if state.get(id(child)) == 1:
                raise InputError([Problem(path, child.start_mark.line + 1, "", (
                    "an alias refers to the anchor it is inside of (a structure that contains itself): "
                    "write the values out"))])
            if id(child) not in state:
                stack.append((child, False))
    return out


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    return []


def _build(node: yaml.Node, keypath: KeyPath, lines: dict[KeyPath, int], path: str, c: _Constructor,
           duplicates: list[Problem] | None = None) -> Any:
    lines.setdefault(keypath, node.start_mark.line + 1)
    if isinstance(node, yaml.CollectionNode) and node.tag in _TAGGED_COLLECTIONS:
        return _tagged_collection(node, keypath, lines, path, c, duplicates)
    if not isinstance(node, yaml.ScalarNode) and node.tag not in _COLLECTION_TAGS:
        raise InputError([Problem(path, node.start_mark.line + 1, dotted(keypath),
                                  f"unsupported YAML tag {shown(node.tag)}: write a plain list or mapping")])
    if isinstance(node, yaml.MappingNode):
        return _build_mapping(node, keypath, lines, path, c, duplicates)
    if isinstance(node, yaml.SequenceNode):
        return [_build(item, keypath + (i,), lines, path, c, duplicates) for i, item in enumerate(node.value)]
    value = _scalar_value(node, keypath, path, c)
    if c.octal is not None and node.tag == _INT_TAG and _octal_key(keypath, c.octal_anywhere):
        c.octal.extend(_octal_warning(node, value, keypath, path, c.octal_anywhere))
    return value


def _octal_key(keypath: KeyPath, anywhere: bool) -> bool:
    """Whether an octal-looking number at keypath is likely a mistake (see _NUMBER_KEYS, _MODE_KEY)."""
    if not anywhere:
        return bool(keypath) and keypath[-1] in _NUMBER_KEYS
    key = next((k for k in reversed(keypath) if isinstance(k, str)), "")    # a list item: its list's key
    return not _MODE_KEY.fullmatch(key)


def _octal_warning(node: yaml.Node, value: Any, keypath: KeyPath, path: str, fleet: bool = False) -> list[Problem]:
    """A warning for a plain `017` (read as 15), none for `07` or `0` (the same read either way)."""
    text = node.value if isinstance(node, yaml.ScalarNode) and not node.style and node.tag == _INT_TAG else ""
    if not _OCTAL.fullmatch(text) or int(text.replace("_", ""), 10) == value:
        return []
    # in the fleet file a quoted number is a string, which a port or a count is not
    advice = f"write {value}, or {int(text.replace('_', ''), 10)} if that is meant" if fleet else \
        f"write {value}, or quote it"
    return [Problem(path, node.start_mark.line + 1, dotted(keypath),
                    f"`{text}` is read as octal ({value}), as Ansible reads it; {advice}", severity="warning")]


_SET_TAG = "tag:yaml.org,2002:set"
_TAGGED_COLLECTIONS = ("!unsafe", _SET_TAG)


def _tagged_collection(node: yaml.CollectionNode, keypath: KeyPath, lines: dict[KeyPath, int], path: str,
                       c: _Constructor, duplicates: list[Problem] | None) -> Any:
    """`!unsafe` on a list or mapping: every string in it is Unsafe (Ansible templates none of them);
    `!!set {a, b}`: the list of its members, as Ansible writes a set. A copy of the node, untagged,
    is built: the node may be reached again through an alias."""
    tag = _COLLECTION_TAGS[0] if isinstance(node, yaml.MappingNode) else _COLLECTION_TAGS[1]
    plain = type(node)(tag, node.value, node.start_mark, node.end_mark, node.flow_style)
    value = _build(plain, keypath, lines, path, c, duplicates)
    if node.tag == _SET_TAG:
        return list(value) if isinstance(value, dict) else value
    return _unsafe(value)


def _unsafe(value: Any) -> Any:
    if isinstance(value, str):
        return Unsafe(value)
    if isinstance(value, dict):
        return {key: _unsafe(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_unsafe(item) for item in value]
    return value


def _scalar_value(node: yaml.Node, keypath: KeyPath, path: str, c: _Constructor) -> Any:
    """A key's or a value's scalar, refused at its line when Python cannot hold or write it."""
    try:
        value = c.construct_object(node, deep=True)
    except yaml.YAMLError as exc:
        raise InputError([Problem(path, node.start_mark.line + 1, dotted(keypath),
                                  f"invalid value: {_error_text(exc)}")]) from exc
    except ValueError as exc:   # an integer of over 4,300 digits (Python's own bound): said in our words
        digits = sum(map(str.isdigit, node.value)) if isinstance(node, yaml.ScalarNode) else 0
        why = (f"an integer of {digits:,} digits, more than Python reads ({_INT_DIGITS:,}): no setting takes one; "
               "write a smaller number, or quote it for text") if digits > _INT_DIGITS else \
            f"invalid value: {str(exc)[:120]}"
        raise InputError([Problem(path, node.start_mark.line + 1, dotted(keypath), why)]) from None
    if isinstance(value, int) and value.bit_length() > MAX_INT_BITS:
        raise InputError([Problem(path, node.start_mark.line + 1, dotted(keypath),
                                  "a number of over 4,000 digits: no setting takes one; write a smaller "
                                  "number, or quote it for text")])
    if isinstance(value, str) and c.escapes and (found := _search_not_text(value, c.controls)):   # `"\ufffe"`, `"\0"`
        raise InputError([Problem(path, node.start_mark.line + 1, dotted(keypath), _not_text_reason(found[0]))])
    if isinstance(value, bytes):   # written out it was Python's b'...' (Ansible cannot print it either)
        raise InputError([Problem(path, node.start_mark.line + 1, dotted(keypath),
                                  "a !!binary value: rosdeploy reads text only; write the text itself (or keep "
                                  "binary data in a `files:` source)")])
    return value


def _build_mapping(node: yaml.MappingNode, keypath: KeyPath, lines: dict[KeyPath, int], path: str,
                   c: _Constructor, duplicates: list[Problem] | None) -> dict:
    explicit = {id(key_node) for key_node, _ in node.value}
    try:
        c.flatten_mapping(node)  # resolves `<<: *anchor` merges
    except yaml.YAMLError as exc:
        raise InputError([Problem(path, node.start_mark.line + 1, dotted(keypath),
                                  f"invalid merge: {_error_text(exc)}")]) from exc
    out: dict[Any, Any] = {}
    written: set[Any] = set()     # the keys written in this mapping, not merged into it by `<<`
    for key_node, value_node in node.value:
        if not isinstance(key_node, yaml.ScalarNode):
            raise InputError([Problem(path, key_node.start_mark.line + 1, dotted(keypath),
                                      "a mapping key must be a plain value, not a list or mapping")])
        key = _scalar_value(key_node, keypath, path, c)
        child = keypath + (key,)
        if id(key_node) in explicit:
            # a key over one merged by `<<` overrides it: what `<<` means (merged pairs come first)
            if key in written:
                _duplicate(path, key_node, child, duplicates)
            written.add(key)
        lines[child] = key_node.start_mark.line + 1
        out[key] = _build(value_node, child, lines, path, c, duplicates)
    return out


def _duplicate(path: str, key_node: yaml.Node, child: KeyPath, duplicates: list[Problem] | None) -> None:
    """A key written twice in one mapping: an error, or (inventories) a warning as in Ansible."""
    then = "keep one" if duplicates is None else "the last one is used, as in Ansible; keep one"
    duplicate = Problem(path, key_node.start_mark.line + 1, dotted(child),
                        f"duplicate key: it is defined twice in the same mapping; {then}",
                        severity="error" if duplicates is None else "warning")
    if duplicates is None:
        raise InputError([duplicate])
    duplicates.append(duplicate)
