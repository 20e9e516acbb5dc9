"""The one Jinja2 environment kind that renders anything a user wrote: sandboxed and bounded.

A fleet file, an inventory written by another system, or a template folder is configuration,
not code: nothing in it may run a command, read the process environment (where
ROSDEPLOY_VAULT_PASSWORD lives) or reach Python internals. Jinja2's
ImmutableSandboxedEnvironment refuses every `_`-prefixed attribute (`lipsum.__globals__`,
`''.__class__.__mro__`, `self.__init__`, `|attr('__class__')`, `'{0.__class__}'.format`),
every mutation of a list or dict, and ranges over 100,000 items. On top of it:

- the globals a configuration value has no use for (`lipsum`, `cycler`, `joiner`,
  `namespace`) are gone, so they cannot be a stepping stone either;
- `*`, `**` and `%` and the padding filters are bounded: `'a' * 10**10`, `9**9**9` or
  `'%999999999s'` would otherwise take the controller's memory or CPU;
- a *value* (one string of a fleet file or inventory) may hold expressions and `if`, but no
  loop, macro, include or import: those belong in template files.

Every refusal is a `jinja2.TemplateError` (SecurityError), so callers report it like any
other template error: a file:key problem, exit 2.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Callable, Mapping, MutableMapping

import jinja2
import jinja2.nodes
from jinja2.sandbox import ImmutableSandboxedEnvironment, SecurityError

MAX_LENGTH = 1_000_000          # characters or items one operation may produce
MAX_POWER_BITS = 4096           # `**` results beyond this are a DoS, not a configuration value
# A %-format or str.format width/precision of 5+ digits: pads to 10**4+ characters.
_BIG_FORMAT = re.compile(r"%[-#0 +]*(\d{5,}|\*)|%[-#0 +]*\d*\.\d{5,}|\{[^{}]*:[^{}]*\d{5,}[^{}]*\}")
_WIDTH_FILTERS = ("center", "indent", "wordwrap", "truncate")
# What a single value may not contain (statements that loop, define code or read other files).
_VALUE_FORBIDDEN = (jinja2.nodes.For, jinja2.nodes.Macro, jinja2.nodes.CallBlock, jinja2.nodes.Include,
                    jinja2.nodes.Import, jinja2.nodes.FromImport, jinja2.nodes.Extends, jinja2.nodes.Block,
                    jinja2.nodes.FilterBlock)


class Sandbox(ImmutableSandboxedEnvironment):
    """ImmutableSandboxedEnvironment with bounded operators and no stepping-stone globals."""

    intercepted_binops = frozenset({"*", "**", "%"})

    def __init__(self, plain_types: tuple[type, ...] = (), **kwargs: Any) -> None:
        """`plain_types`: frozen dataclasses of plain values whose public fields templates read in
        bulk; their attribute access skips the sandbox's per-access checks (half the render time
        of 5,000 robots), which could only ever allow a name without a leading `_` on them."""
        self.plain_types = frozenset(plain_types)
        kwargs.setdefault("undefined", jinja2.StrictUndefined)
        kwargs.setdefault("autoescape", False)
        super().__init__(**kwargs)
        for name in ("lipsum", "cycler", "joiner", "namespace"):
            self.globals.pop(name, None)
        for name in _WIDTH_FILTERS:
            self.filters[name] = _bounded_filter(self.filters[name])
        self.filters["format"] = _checked_format(self.filters["format"])

    def make_globals(self, d: MutableMapping[str, Any] | None) -> MutableMapping[str, Any]:
        """A plain dict, not Jinja's ChainMap: every render copies a template's globals twice, and
        iterating a ChainMap was 8% of rendering 500 robots. The same names and values, since
        nothing changes this environment's globals after __init__."""
        return {**self.globals, **(d or {})}

    def getattr(self, obj: Any, attribute: str) -> Any:
        if type(obj) in self.plain_types and not attribute.startswith("_"):
            try:
                return getattr(obj, attribute)
            except AttributeError:
                pass
        return super().getattr(obj, attribute)

    def call_binop(self, context: Any, operator_: str, left: Any, right: Any) -> Any:
        if operator_ == "*":
            _check_repeat(left, right)
        elif operator_ == "**":
            _check_power(left, right)
        elif operator_ == "%" and isinstance(left, str):
            _check_format(left)
        return self.binop_table[operator_](left, right)

    def wrap_str_format(self, value: Any) -> Callable[..., str] | None:
        wrapped = super().wrap_str_format(value)
        if wrapped is not None:
            _check_format(str(getattr(value, "__self__", "")))
        return wrapped


class ContainedLoader(jinja2.FileSystemLoader):
    """A template folder whose files must stay inside it: a symlink to ~/.ssh/id_ed25519 or
    /etc/shadow in a checked-out template folder would otherwise be rendered into a release
    and uploaded to every robot. Files must be UTF-8 (a TemplateError otherwise, not a crash)."""

    def get_source(self, environment: jinja2.Environment, template: str) -> tuple[str, str, Callable[[], bool]]:
        source, filename, uptodate = _decoded(lambda: super(ContainedLoader, self).get_source(environment, template),
                                              template)
        roots = [Path(p).resolve() for p in self.searchpath]
        if not any(Path(filename).resolve().is_relative_to(root) for root in roots):
            # not TemplateNotFound: a ChoiceLoader would quietly fall back to the next folder
            raise SecurityError(f"template {template} is a link to a file outside the template folder: copy the "
                                "file into the folder instead")
        return source, filename, uptodate


def _decoded(get: Callable[[], Any], template: str) -> Any:
    try:
        return get()
    except UnicodeDecodeError as exc:
        raise jinja2.TemplateSyntaxError(f"byte 0x{exc.object[exc.start]:02x} is not UTF-8: save the template "
                                         "as UTF-8", exc.object[:exc.start].count(b"\n") + 1, template) from None


def value_template(env: jinja2.Environment, source: str) -> jinja2.Template:
    """Compile one configuration value: expressions and `if` only (TemplateSyntaxError otherwise)."""
    tree = env.parse(source)
    found = next(iter(tree.find_all(_VALUE_FORBIDDEN)), None)
    if found is not None:
        kind = type(found).__name__.lower()
        raise jinja2.TemplateSyntaxError(
            f"a value may hold {{{{ expressions }}}} and {{% if %}} only, not {{% {kind} %}}: "
            "put loops, macros and includes in a template file", getattr(found, "lineno", 1))
    return env.from_string(tree)


def render_value(template: jinja2.Template, variables: Mapping[str, Any]) -> str:
    """Render one value; any failure inside (a blocked access, 1/0, recursion) is a TemplateError."""
    try:
        return template.render(variables)
    except jinja2.TemplateError:
        raise
    except Exception as exc:   # user code failing is a user error, never an internal one
        raise jinja2.TemplateRuntimeError(describe(exc)) from exc


def describe(exc: BaseException) -> str:
    """A one-line reason for a failure inside a template, without the value that failed."""
    if isinstance(exc, RecursionError):
        return "the template recurses without end"
    if isinstance(exc, (OverflowError, MemoryError)):
        return f"a value is too large ({type(exc).__name__}: {str(exc)[:200]})"
    return f"{type(exc).__name__}: {str(exc)[:200]}"


def _check_repeat(left: Any, right: Any) -> None:
    for seq, count in ((left, right), (right, left)):
        if isinstance(seq, (str, list, tuple)) and isinstance(count, int) and len(seq) * count > MAX_LENGTH:
            raise SecurityError(f"repeating a value {count} times would exceed {MAX_LENGTH} items")


def _check_power(left: Any, right: Any) -> None:
    if isinstance(left, int) and isinstance(right, int) and right > 0:
        if max(abs(left), 2).bit_length() * right > MAX_POWER_BITS:
            raise SecurityError(f"{left} ** {right} is too large a number")


def _check_format(text: str) -> None:
    if _BIG_FORMAT.search(text):
        raise SecurityError("a format width or precision over 9999 is not allowed")


def _bounded_filter(func: Callable[..., Any]) -> Callable[..., Any]:
    def bounded(*args: Any, **kwargs: Any) -> Any:
        for arg in [*args[1:], *kwargs.values()]:
            if isinstance(arg, int) and not isinstance(arg, bool) and abs(arg) > MAX_LENGTH:
                raise SecurityError(f"a width of {arg} is not allowed")
        return func(*args, **kwargs)
    _copy_markers(func, bounded)
    return bounded


def _checked_format(func: Callable[..., Any]) -> Callable[..., Any]:
    def checked(value: Any, *args: Any, **kwargs: Any) -> Any:
        _check_format(str(value))
        return func(value, *args, **kwargs)
    _copy_markers(func, checked)
    return checked


def _copy_markers(src: Callable[..., Any], dst: Callable[..., Any]) -> None:
    """Keep Jinja's pass_context/pass_environment markers: the filter is called the same way."""
    for attr in ("jinja_pass_arg",):
        if hasattr(src, attr):
            setattr(dst, attr, getattr(src, attr))
