"""Templated inventory values, resolved lazily with Ansible's inventory vars, in a sandbox.

    ansible_ssh_private_key_file: "{{ inventory_dir }}/../keys/id_ed25519"

Like Ansible, a value is templated when it is read, with the host's own vars
plus `inventory_hostname`, `inventory_hostname_short`, `inventory_dir`,
`inventory_file`, `group_names`, `groups` and `hostvars`; a value that is one
`{{ expression }}` keeps the expression's type (Ansible 2.19 does the same).

A host_vars file may be written by another system, so a template must not be
able to run code: Jinja2's SandboxedEnvironment (no `__globals__`, no
`__init__`, no private attributes), no globals but `range` and `dict`, no
`lookup`/`env` (nothing reads the process environment), and StrictUndefined.
"""
from __future__ import annotations

import contextlib
import functools
import math
import posixpath
import re
import threading
from typing import Any, Callable, Iterator, Mapping

import jinja2
from jinja2.sandbox import unsafe

from rosdeploy.sandbox import MAX_LENGTH, Failing, NotText, Sandbox, metered, weight

from rosdeploy.errors import InventoryError, Problem, shown
from rosdeploy.inventory.draft import Origin, strings
from rosdeploy.yamlsrc import Unsafe, not_text

_MARKERS = ("{{", "{%", "{#")
_WHOLE = re.compile(r"^\{\{(?P<expr>.*)\}\}$", re.S)


class TemplateFailed(Exception):
    """A value could not be templated; `key` is the var whose template failed."""

    def __init__(self, key: str, message: str, deep: bool = False, undefined: bool = False) -> None:
        super().__init__(message)
        self.key = key
        self.message = message
        self.deep = deep     # Python's stack ran out: every var on the way down failed with it
        self.undefined = undefined   # it reads a name nothing defines: `| default(..)` may stand in


class UnresolvedVar(InventoryError, jinja2.UndefinedError):
    """Using a var whose template failed: an input error, and, inside a fleet template, a
    template error the renderer reports like any other."""

    def __init__(self, problem: Problem) -> None:
        InventoryError.__init__(self, [problem])


class Unresolved(jinja2.StrictUndefined):
    """A var whose template reads an undefined name (`{{ ansible_facts.. }}` and `{{ playbook_dir }}`
    exist only in a play): Ansible fails only where it is used, so this is harmless until something
    reads it, then a clean error naming file and key, and `| default(..)` stands in for it, as in
    Ansible. A var whose template is broken (a syntax error, `1/0`) fails wherever it is read,
    `default` or not, as in Ansible: a typo must not quietly deploy the default. The vars rosdeploy
    itself reads are checked at load."""


class Broken(Unresolved, Failing):
    """A var whose template is broken: `default` and `is defined` fail on it (sandbox.Failing)."""


def _bool(value: Any) -> bool:
    return str(value).strip().lower() in ("1", "true", "yes", "on", "y", "t")


def _environment() -> Sandbox:
    # The fleet file's sandbox (bounded `*`, `**`, `%` and format widths), so a host_vars value
    # written by another system can no more exhaust memory than a fleet value can. Only the
    # sandbox's own bounded `range` and `dict` stay as globals: fewer objects, fewer ways in.
    env = Sandbox(keep_trailing_newline=True)
    env.globals = {"range": env.globals["range"], "dict": dict,
                   # Ansible's; refused by name, not left undefined, so `| default(..)` cannot stand in
                   # for what Ansible would have read (a host_vars file may come from another system)
                   **{name: _refused_global(name) for name in ("lookup", "query", "q", "now")}}
    # A few of Ansible's filters that inventories use for paths and names; all pure.
    from rosdeploy.sandbox import regex_replace     # bounded in time and size, unlike re.sub
    env.add_filters({"basename": posixpath.basename, "dirname": posixpath.dirname, "bool": _bool,
                        "regex_replace": regex_replace,
                        "ternary": lambda v, a, b=None: a if v else b})
    return env


def _refused_global(name: str) -> Callable[..., Any]:
    def refused(*args: Any, **kwargs: Any) -> Any:
        raise jinja2.sandbox.SecurityError(
            f"{name}() reads this machine (files, the environment, commands or the clock) in Ansible, which "
            "rosdeploy never does for an inventory; write the value itself")
    return refused


_ENV = _environment()
_LOCAL = threading.local()


@contextlib.contextmanager
def secret_reads() -> Iterator[dict[str, str]]:
    """While active, collects the vars read (from outside any var's own template) whose value
    came from a vault, directly or through other vars: var -> the vault var it came from.

    A renderer reads vars through this to know a file or value is derived from a secret even
    when its text no longer contains the secret (`{{ token|upper }}`, a slice, a hash)."""
    outer = getattr(_LOCAL, "reads", None)
    found: dict[str, str] = {}
    _LOCAL.reads = found
    try:
        yield found
    finally:
        _LOCAL.reads = outer
        if outer is not None:    # a reader inside another: what it saw was read for the outer one too
            for var, source in found.items():
                outer.setdefault(var, source)


def reading_secret() -> tuple[str, str] | None:
    """The first (var, vault var) the innermost secret_reads() collected so far, None if none: an
    error raised while computing a value must not quote it, nor the exception's text, once the
    computation read a secret (masking the output finds only a secret's exact text)."""
    reads = getattr(_LOCAL, "reads", None)
    return min(reads.items()) if reads else None


def unless_secret(reason: str) -> str:
    """`reason`, unless the failing computation read a vault var (see reading_secret): then which
    one, and not the reason, which may quote a value computed from it."""
    read = reading_secret()
    return reason if read is None else not_quoted(*read)


def not_quoted(var: str, source: str) -> str:
    return (f"this fails after reading {secret_read(var, source)}; the error is not shown, as it may quote the "
            "secret or a value computed from it (check the value with `rosdeploy vault view`)")


def shown_unless_secret(value: Any, read: Mapping[str, str]) -> str:
    """A value for a message (`read`: what secret_reads() collected while computing it): never one
    computed from a vault var, in any form."""
    if not read:
        return shown(value)
    return f"'********' (computed from vault var {shown(min(read.items())[1])}: a secret is never shown)"


def secret_read(var: str, source: str) -> str:
    """How a secret var was read, for messages: `vault var 'token'`, or `var 'p' (computed from
    vault var 'token')`."""
    return f"vault var {shown(var)}" if var == source else f"var {shown(var)} (computed from vault var {shown(source)})"


def is_template(value: Any) -> bool:
    return isinstance(value, str) and not isinstance(value, Unsafe) and any(m in value for m in _MARKERS)


class HostVars(Mapping[str, Any]):
    """One host's merged vars, each templated on first read (then cached).

    `magic` holds inventory_hostname & co; `hostvars` is filled in once every host
    exists, so templates may look at other hosts as in Ansible.
    """

    def __init__(self, name: str, raw: Mapping[str, Any], origins: Mapping[str, Origin],
                 magic: Mapping[str, Any]) -> None:
        self._name = name
        self._raw = dict(raw)
        self._origins = origins
        self._magic = dict(magic)
        self._done: dict[str, Any] = {}
        self._too_deep: dict[str, TemplateFailed] = {}
        self._overrides: dict[str, Any] = {}
        # var -> the vault var its value came from: the vault vars themselves, then every var
        # whose template read one (marked as it is templated, see _note)
        self._secret_from = {key: key for key in self._raw if _from_vault(self._raw[key], origins.get(key))}
        self._sources_read: set[str] = set()    # vault vars whose value (or one computed from it) was read

    # A template reaches this object (`host.vars`, `hostvars[name]`): every member that reads a
    # value past value()'s tracking (the raw values, the secret texts, an Origin's
    # inline_secrets) or changes one (override) is refused to it. The sandbox refuses `_` names;
    # the public ones rosdeploy calls from modules owned elsewhere are marked unsafe, which
    # the sandbox refuses to call.
    @unsafe
    def override(self, key: str, value: Any) -> None:
        """A value rosdeploy normalised (an absolute path): what every reader then sees."""
        self._overrides[key] = value

    @unsafe
    def origin(self, key: str) -> Origin | None:
        """Where the value in effect was set (the file and key that won the precedence merge)."""
        return self._origins.get(key)

    @unsafe
    def secret_source(self, key: str) -> str | None:
        """The vault var that `key`'s value came from, once `key` was read; None if none."""
        return self._secret_from.get(key)

    @unsafe
    def secret_texts(self) -> frozenset[str]:
        """Every text known to be secret now: the vault vars' values, and the values computed from
        them so far (as text, and every string inside)."""
        texts: set[str] = set()
        for var, source in self._secret_from.items():
            if var == source:
                texts.update(text for _, text in strings(self._raw[var], ()))
            if var in self._done:
                texts.update(text for _, text in strings(self._done[var], ()))
                texts.add(str(self._done[var]))
        return frozenset(texts)

    @unsafe
    def secret_texts_read(self) -> frozenset[str]:
        """The texts of this robot's vault vars that anything has read so far (directly or through
        other vars): only these can be in what was rendered, so only these are searched for
        there. A vault value nothing reads (`ansible_become_password: robot`) cannot leak, and
        searching for it would only find innocent text."""
        return frozenset(text for var in self._sources_read if self._secret_from.get(var) == var
                         for _, text in strings(self._raw[var], ()))

    def __getitem__(self, key: str) -> Any:
        if getattr(_LOCAL, "stack", None):   # inside another var's template: let it report
            return self.value(key)
        try:
            return self.value(key)
        except TemplateFailed as failed:
            origin = self._origins.get(failed.key) or self._origins[key]
            problem = origin.problem((failed.key,), f"robot {shown(self._name)}: {failed.message}")
            # Jinja raises exc(hint) where the value is used: UnresolvedVar takes the Problem itself
            kind = Unresolved if failed.undefined else Broken
            return kind(hint=problem, name=key, exc=UnresolvedVar)  # type: ignore[arg-type]

    @unsafe
    def value(self, key: str) -> Any:
        """The templated value; TemplateFailed (naming the var) if it cannot be templated."""
        result = self._value(key)
        source = self._secret_from.get(key)
        if source is not None:
            self._sources_read.add(source)
            _note(key, source)
        return result

    def _value(self, key: str) -> Any:
        if key in self._overrides:
            return self._overrides[key]
        if key in self._done:
            return self._done[key]
        if key in self._too_deep:
            raise self._too_deep[key]
        try:
            value = self._template(key, self._raw[key])
        except TemplateFailed as failed:
            if failed.deep:    # kept: reading it again would only climb down the same chain again
                self._too_deep[key] = failed
            raise
        self._done[key] = value
        return value

    def __contains__(self, key: object) -> bool:
        return key in self._raw      # Mapping's own would template the value (and count a read)

    def __iter__(self) -> Iterator[str]:
        return iter(self._raw)

    def __len__(self) -> int:
        return len(self._raw)

    def __repr__(self) -> str:
        return f"HostVars({self._name!r}, {len(self._raw)} vars)"

    def _template(self, key: str, value: Any) -> Any:
        stack: list[tuple[HostVars, str]] = getattr(_LOCAL, "stack", None) or []
        if any(host is self and name == key for host, name in stack):   # `is`: == would read every var
            raise TemplateFailed(key, f"recursive loop: {' -> '.join([*(k for _, k in stack), key])}")
        _LOCAL.stack = [*stack, (self, key)]
        try:
            result = _render(value, _Scope(self), key)
            # a YAML list or dict of templates: each item is weighed alone (_sized), not all together
            return _sized(key, result) if result is not value else result
        finally:
            _LOCAL.stack = stack

    def _lookup(self, name: str) -> Any:
        """What a template sees for `name`: the magic vars first, then the host's vars."""
        if name in self._magic:
            return self._magic[name]
        return self.value(name)

    def _knows(self, name: str) -> bool:
        return name in self._magic or name in self._raw


def raw_vars(hostvars: HostVars) -> Mapping[str, Any]:
    """The merged vars as written, none templated (what `ansible-inventory --list` prints): for
    Python callers only, as a function, since a template reaches a HostVars but no module."""
    return hostvars._raw


def _from_vault(value: Any, origin: Origin | None) -> bool:
    if origin is None:
        return False
    if origin.secret:      # a vault-encrypted vars file: every value in it
        return True
    return bool(origin.inline_secrets) and any(text in origin.inline_secrets for _, text in strings(value, ()))


def _note(key: str, source: str) -> None:
    """A var from a vault was read: the var whose template read it is secret too, or, at the
    top, the reader that collects secret_reads() learns of it."""
    stack = getattr(_LOCAL, "stack", None)
    if stack:
        reader, name = stack[-1]
        reader._secret_from.setdefault(name, source)
        return
    reads = getattr(_LOCAL, "reads", None)
    if reads is not None:
        reads.setdefault(key, source)


class _Scope(dict):
    """Jinja2 reads names through this: each var is templated only if a template uses it."""

    def __init__(self, host: HostVars) -> None:
        super().__init__()
        self._host = host

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and (self._host._knows(name) or name in _ENV.globals)

    def __getitem__(self, name: str) -> Any:
        if self._host._knows(name):
            return self._host._lookup(name)
        # a shared context gets no globals from Jinja: `range` and `dict` are looked up here
        return _ENV.globals[name]

    def get(self, name: str, default: Any = None) -> Any:
        return self[name] if name in self else default


def _render(value: Any, scope: _Scope, key: str) -> Any:
    if isinstance(value, dict):
        return {k: _render(v, scope, key) for k, v in value.items()}
    if isinstance(value, list):
        return [_render(v, scope, key) for v in value]
    if not is_template(value):
        return value
    try:
        whole = _WHOLE.match(value)
        if whole and "{{" not in whole["expr"] and "}}" not in whole["expr"]:
            return _checked(key, _sized(key, _expression(whole["expr"], scope)))
        template = _compiled(value)
        context = template.new_context(scope, shared=True)
        text = _ENV.concat(template.root_render_func(context))
        if len(text) > MAX_LENGTH:    # `d2: "{{ d1 }}{{ d1 }}"` doubling on: no operator to bound
            raise TemplateFailed(key, f"the value of {key} would be longer than {MAX_LENGTH:,} characters")
        return _checked(key, text)
    except TemplateFailed:
        raise
    except jinja2.TemplateError as exc:
        raise _failed(scope, key, value, _reason(exc), undefined=isinstance(exc, jinja2.UndefinedError)) from None
    except RecursionError:
        raise _failed(scope, key, value, "the templates refer to each other without end, or nest too deeply",
                      deep=True, fixed=True) from None
    except (TypeError, ValueError, ArithmeticError, LookupError, AttributeError) as exc:
        raise _failed(scope, key, value, str(exc)) from None


def _sized(key: str, result: Any) -> Any:
    """A var's templated list or dict, refused here (at the var) when written out it would be longer
    than MAX_LENGTH: `[v1, v1, ...]` sixteen times, ten vars deep, is a few KB in memory but 2**40
    items to every reader (weight counts a list held many times over each time, memoised)."""
    if isinstance(result, (list, tuple, dict, set, frozenset)) and weight(result) > MAX_LENGTH:
        raise TemplateFailed(key, f"the value of {key} would be longer than {MAX_LENGTH:,} characters or items "
                             "written out (a list or dict that holds other vars' lists many times over)")
    return result


def _checked(key: str, result: Any) -> Any:
    """A templated value every file can hold, refused here (so at the var's file and line) when not:
    a lone surrogate or a noncharacter (`{{ "\\ud800" }}`: Jinja reads escapes), or a number that is
    not finite (`{{ x * 1e308 }}`). The reason names neither the value nor what it read."""
    why = not_text(result)
    if why is None and isinstance(result, float) and not math.isfinite(result):
        why = f"is {str(result).lstrip('-')}, not a finite number: compute a finite one"
    if why is not None:
        raise TemplateFailed(key, f"the templated value of {key} {why}")
    return result


def _failed(scope: _Scope, key: str, value: str, reason: str, deep: bool = False, undefined: bool = False,
            fixed: bool = False) -> TemplateFailed:
    """Why `key` could not be templated. Neither a vault value (its `{{` made it a template) nor a
    reason computed while reading one is quoted, whole, cut short or escaped: masking the output
    finds a secret's exact text only. `fixed`: the reason is rosdeploy's own words."""
    source = scope._host._secret_from.get(key)
    if source == key:
        what = f"cannot template the value of vault var {shown(key)} (not shown: it is secret)"
    elif source is not None:
        what = f"cannot template {shown(value)}, which reads {secret_read(source, source)}"
    else:
        return TemplateFailed(key, f"cannot template {shown(value)}: {reason}", deep=deep, undefined=undefined)
    why = reason if fixed else "the error is not shown, as it may quote the secret or a value computed from it"
    return TemplateFailed(key, f"{what}: {why}", deep=deep, undefined=undefined)


def _expression(expr: str, scope: _Scope) -> Any:
    """`{{ expr }}` alone: the expression's own value, not its text (so a number stays a number)."""
    template = _compiled_expression(expr)
    context = template.new_context(scope, shared=True)
    with metered():     # its work counts toward the command's budget too, as a text's does (concat)
        for _ in template.root_render_func(context):
            pass
    result = context.vars["result"]
    if isinstance(result, jinja2.Undefined):
        result._fail_with_undefined_error()
    return result


# One compile per distinct text: the same group_vars value is templated for every robot
# (500 hosts, one compile), and a var read again after a failure compiles nothing again.
@functools.lru_cache(maxsize=4096)
def _compiled(value: str) -> jinja2.Template:
    return _ENV.from_string(value)


@functools.lru_cache(maxsize=4096)
def _compiled_expression(expr: str) -> jinja2.Template:
    return _ENV.compile_expression(expr, undefined_to_none=False)._template


def _reason(exc: jinja2.TemplateError) -> str:
    if isinstance(exc, NotText):
        return exc.message or ""
    if isinstance(exc, jinja2.sandbox.SecurityError):
        return f"refused by the template sandbox ({exc.message}): inventory templates may read vars only"
    message = exc.message or type(exc).__name__
    if message.startswith("No filter named"):     # one of Ansible's (to_yaml, b64decode, hash…)
        return (f"{message} (an inventory template has Jinja2's filters and basename, dirname, bool, "
                "regex_replace, ternary; write the value itself)")
    return message
