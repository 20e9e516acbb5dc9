"""A rendered .env and compose.yml read as Compose v2 reads them on the robot.

`check` judges what Compose will run, so it must read the .env as compose-go's dotenv parser
does (inline comments, quoted values across lines, `export`, values of earlier lines) and
interpolate `${VAR}` with every form Compose v2 knows (`:-`, `-`, `:+`, `+`, `:?`, `?`, nesting,
`$$`). A line Compose v1 reads otherwise, and a variable the .env does not set (it comes from the
robot's environment, unseen here), are reported rather than guessed: see checks._unread.
"""
from __future__ import annotations

import re
from typing import Any, Mapping


def parse_env(text: str) -> dict[str, str]:
    """The .env's values as Compose v2 reads them (read_env)."""
    return read_env(text)[0]


# One statement of a .env as compose-go's dotenv parser starts it: blank lines and `#` lines skipped,
# then `export `, the key and what ends it (`=`, YAML's `:`, or the line: "take it from the environment").
_ENV_SKIP = re.compile(r"(?:\s+|#[^\n]*)*")
_ENV_KEY = re.compile(r"(?:export[ \t]+)?([A-Za-z0-9_.\[\]\- \t\r\f\v]*?)[ \t\r\f\v]*([=:\n]|\Z)")
_ENV_SPACE = re.compile(r"[ \t\r\f\v]*")
_ENV_AFTER_QUOTE = re.compile(r"[ \t\r\f\v]*(?:#[^\n]*)?(?:\n|\Z)")
_ENV_PLAIN = re.compile(r"(?:[ \t]*(?:#[^\n]*)?(?:\n|\Z)|[A-Za-z_][A-Za-z0-9_]*="
                        r"(?:[A-Za-z0-9_./:@%+,=-]*|'[^'\\\n]*')[ \t]*(?:\n|\Z))*")
_ENV_PLAIN_LINE = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)=(?:'([^'\n]*)'|([^\s']*))", re.MULTILINE)
_ENV_SIMPLE = re.compile(r"[A-Za-z0-9_./:@%+,=-]*")         # render.env_value's unquoted text
_GO_ESCAPE = {"a": "\a", "b": "\b", "f": "\f", "n": "\n", "r": "\r", "t": "\t", "v": "\v", "\\": "\\",
              '"': '"', "'": "'", "$": "$$"}      # compose-go's expandEscapes: Go's escapes, and `\$` as `$$`


def read_env(text: str) -> tuple[dict[str, str], list[str]]:
    """A .env as Compose v2 reads it (compose-go's dotenv parser: a ` #` comment after an unquoted
    value, a quoted value across lines, `export `, `${VAR}` of earlier lines), and "line N: why"
    for each line Compose v1 (python-dotenv) reads otherwise, or that takes a value from the
    robot's environment, which `check` cannot see. The built-in env.j2 writes neither."""
    if _ENV_PLAIN.fullmatch(text):     # the built-in env.j2's lines (render.env_value): read the quick way
        return {m[1]: m[3] if m[2] is None else m[2] for m in _ENV_PLAIN_LINE.finditer(text)}, []
    env: dict[str, str] = {}
    problems: list[str] = []
    pos = 0
    while True:
        pos = _skip(_ENV_SKIP, text, pos)
        if pos >= len(text):
            return env, problems
        start = pos
        key = _ENV_KEY.match(text, pos)
        name = key[1].strip() if key else ""
        if key is None or not name or " " in name or "\t" in name:
            problems.append(f"line {_line_of(text, start)}: `{_first_line(text, start)}` is not KEY=VALUE "
                            "(Compose refuses the .env)")
            pos = _next_line(text, pos)
            continue
        pos = key.end()
        if key[2] != "=":
            problems.append(f"line {_line_of(text, start)}: `{_first_line(text, start)}` " + (
                f"takes {name} from the robot's environment, which `check` cannot see: write `{name}=<value>`"
                if key[2] != ":" else "is YAML's `KEY: value`, which Compose v1 does not read: write `KEY=value`"))
            if key[2] != ":":
                continue
        pos = _skip(_ENV_SPACE, text, pos)
        value, pos, why = _env_value(text, pos, env)
        if why:
            problems.append(f"line {_line_of(text, start)}: {name}'s value {why}")
        env[name] = value


def _skip(pattern: re.Pattern[str], text: str, pos: int) -> int:
    """Past what `pattern` (which matches the empty string too) matches at `pos`."""
    found = pattern.match(text, pos)
    return found.end() if found else pos


def _env_value(text: str, pos: int, env: Mapping[str, str]) -> tuple[str, int, str]:
    """(value, where the next statement starts, why Compose v1 would read it otherwise, or "")."""
    quote = text[pos:pos + 1]
    if quote not in ("'", '"'):
        end = text.find("\n", pos)
        end = len(text) if end < 0 else end
        written = text[pos:end]
        if _ENV_SIMPLE.fullmatch(written):          # the built-in env.j2's unquoted values: as written
            return written, end, ""
        value = written.split(" #", 1)[0].rstrip()
        tab = "has a `#` after a tab, which Compose v1 reads as a comment and v2 as text" \
            if re.search(r"\s#", value) else ""
        return _expanded_at(value, env, tab, end)
    close = text.find(quote, pos + 1)
    if close > 0 and "\\" not in text[pos:close] and (quote == "'" or "$" not in text[pos:close]):
        return _quoted(text, pos, close, text[pos + 1:close], env)     # no escapes: the built-in's quoting
    chars: list[str] = []
    escaped = False
    for i in range(pos + 1, len(text)):
        char = text[i]
        if char == quote and not escaped:
            return _quoted(text, pos, i, "".join(chars), env)
        if char == "\\" and not escaped:
            escaped = True
            continue
        chars.append("\\" + char if escaped and char != quote else char)   # only the quote is unescaped
        escaped = False
    return "", len(text), "has no closing quote (Compose refuses the .env)"


def _expanded_at(value: str, env: Mapping[str, str], why: str, nxt: int) -> tuple[str, int, str]:
    expanded, why = _env_expand(value, env, why)
    return expanded, nxt, why


def _quoted(text: str, start: int, end: int, value: str, env: Mapping[str, str]) -> tuple[str, int, str]:
    """A quoted value's reading, from its opening quote at `start` to its closing one at `end`."""
    after = _ENV_AFTER_QUOTE.match(text, end + 1)
    why = "" if after else "has text after its closing quote, which Compose v2 reads as another line"
    written = text[start + 1:end]
    if "\\" in written and (text[start] == '"' or "\\\\" in written or "\\'" in written):
        why = why or "has a backslash escape, which Compose v1 and v2 read differently: write the text plainly"
    nxt = after.end() if after else end + 1
    if text[start] == "'":
        return value, nxt, why          # single quotes: no escapes, no `${VAR}`
    return _expanded_at(_GO_ESCAPES.sub(lambda m: _GO_ESCAPE.get(m[0][1], m[0]), value), env, why, nxt)


def _env_expand(value: str, env: Mapping[str, str], why: str) -> tuple[str, str]:
    """An unquoted or double-quoted value with `${VAR}` of earlier lines filled in, as v2 does; v1's
    python-dotenv fills in only `${VAR}` and `${VAR:-default}`, and leaves `$VAR` and `$$` alone."""
    if "$" not in value:
        return value, why
    missing: list[str] = []
    expanded = substitute(value, env, missing)
    if missing:
        why = why or (f"depends on ${{{missing[0]}}}, which no earlier line sets, so it comes from the robot's "
                      "environment, which `check` cannot see: write the value")
    elif _V1_UNREAD.search(value):
        why = why or "has `$$`, `$NAME` or a `${...}` form that Compose v1 reads otherwise: write the value"
    return expanded, why


_GO_ESCAPES = re.compile(r"\\.", re.DOTALL)
_V1_UNREAD = re.compile(r"\$(?!\{[A-Za-z_][A-Za-z0-9_]*(?::-[^${}]*)?\})")


def _line_of(text: str, pos: int) -> int:
    return text.count("\n", 0, pos) + 1


def _first_line(text: str, pos: int) -> str:
    return text[pos:_next_line(text, pos)].strip()[:80]


def _next_line(text: str, pos: int) -> int:
    end = text.find("\n", pos)
    return len(text) if end < 0 else end + 1


def interpolate(value: Any, env: Mapping[str, str], missing: list[str] | None = None) -> Any:
    """Every string with compose's interpolation (substitute), recursively; the names it needed
    and .env does not set (the robot's environment, unseen here) are added to `missing`."""
    if isinstance(value, dict):
        return {k: interpolate(v, env, missing) for k, v in value.items()}
    if isinstance(value, list):
        return [interpolate(v, env, missing) for v in value]
    if not isinstance(value, str) or "$" not in value:
        return value
    return substitute(value, env, [] if missing is None else missing)


_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_BRACED = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)(?:(:?[-+?])(.*))?", re.DOTALL)


def substitute(text: str, env: Mapping[str, str], missing: list[str], depth: int = 0) -> str:
    """`text` as Compose v2 (compose-go's template) interpolates it: `$$`, `$NAME`, `${NAME}`,
    `${NAME:-default}`, `${NAME-default}`, `${NAME:+alt}`, `${NAME+alt}`, `${NAME:?err}`, `${NAME?err}`,
    with `${...}` nested in a default or alternative."""
    out, i = [], 0
    while (j := text.find("$", i)) >= 0:
        out.append(text[i:j])
        nxt = text[j + 1:j + 2]
        if nxt == "$":
            out.append("$")
            i = j + 2
        elif nxt == "{":
            end = _closing_brace(text, j + 1)
            if end < 0 or depth > 20:       # compose refuses an unclosed or absurdly nested one
                missing.append(text[j:j + 40])
                return "".join(out)
            out.append(_braced(text[j + 2:end], env, missing, depth))
            i = end + 1
        elif name := _NAME.match(text, j + 1):
            out.append(_lookup(name[0], env, missing) or "")
            i = name.end()
        else:
            out.append("$")
            i = j + 1
    out.append(text[i:])
    return "".join(out)


def _closing_brace(text: str, start: int) -> int:
    """compose-go's getFirstBraceClosingIndex from the `{` at `start`: every `{` opens one (and
    the character after it is skipped), the `}` that closes the first ends the variable."""
    depth, i = 0, start
    while i < len(text):
        if text[i] == "}":
            depth -= 1
            if depth == 0:
                return i
        if text[i] == "{":
            depth += 1
            i += 1
        i += 1
    return -1


def _braced(body: str, env: Mapping[str, str], missing: list[str], depth: int) -> str:
    found = _BRACED.fullmatch(body)
    if found is None:                       # `${}`, `${1}`: compose refuses the file ("invalid template")
        missing.append("${" + body[:40] + "}")
        return ""
    name, op, arg = found[1], found[2] or "", found[3] or ""
    value = _lookup(name, env, missing)
    unset = value is None or (op.startswith(":") and value == "")
    if op.endswith("-"):
        return substitute(arg, env, missing, depth + 1) if unset else str(value)
    if op.endswith("+"):
        return "" if unset else substitute(arg, env, missing, depth + 1)
    return value or ""


def _lookup(name: str, env: Mapping[str, str], missing: list[str]) -> str | None:
    value = env.get(name)
    if value is None:
        missing.append(name)
    return value
