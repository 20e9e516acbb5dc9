"""The one Jinja2 environment kind that renders anything a user wrote: sandboxed and bounded.

A fleet file, an inventory written by another system, or a template folder is configuration,
not code: nothing in it may run a command, read the process environment (where
ROSDEPLOY_VAULT_PASSWORD lives) or reach Python internals. Jinja2's
ImmutableSandboxedEnvironment refuses every `_`-prefixed attribute (`lipsum.__globals__`,
`''.__class__.__mro__`, `self.__init__`, `|attr('__class__')`, `'{0.__class__}'.format`),
every mutation of a list or dict, and ranges over 100,000 items. On top of it:

- the globals a configuration value has no use for (`lipsum`, `cycler`, `joiner`,
  `namespace`) are gone, so they cannot be a stepping stone either;
- `*`, `**`, `%`, `+`, `~`, `str.format`, the str methods and filters that grow a string
  (`replace`, `join`, `center`, `ljust`, `rjust`, `zfill`, `expandtabs`, `translate`,
  `indent`, `wordwrap`, `batch`, `slice`) are bounded before they build their result:
  `'a' * 10**10`, `9**9**9`, `'%999999999s'`, `''|replace('', 'b' * 10000)` or
  `[[1] * 10**5] * 10**5` would otherwise take the controller's memory or CPU. A list counts
  by its nested size (its *weight*), not its length;
- a rendered value (and a rendered template file) may not exceed MAX_LENGTH characters, so a
  chain of vars that each double the last stops at the first one too long;
- a *value* (one string of a fleet file or inventory) may hold expressions and `if`, but no
  loop, macro, include or import: those belong in template files;
- a filter that gets a lazy sequence (`range(1000)|map('center', 999999)|list`) weighs its
  items as it takes them, so it stops before holding more than MAX_LENGTH characters;
- one render (a value, or a template file with what it includes) may take at most MAX_WORK
  units of work (loop items by the size of the loop body, calls, filter calls, items weighed,
  `in` searches, and the characters or items an operation reads or builds: a slice, `~`, a
  comparison, a filter or str method of a long string): nested loops, `range(99999)|select('in',
  big)` or `big[::-1]` in a loop stop within a second or two, not hours; and inside
  command_budget() (one CLI command) all renders together at most COMMAND_WORK, so a value
  costing most of MAX_WORK is not run for each of 5,000 robots;
- every string or list a filter, slice, operator, method call, literal or macro builds is at
  most MAX_LENGTH characters or items (checked as soon as it is built: `|tojson|tojson...`
  doubling its backslashes stops at the first one too long), and all those one render builds
  together at most MAX_BUILT bytes: 400 strings of 999,999 characters in one list, or a macro
  that recurses with a long argument, stop at 100 MB, not gigabytes;
- output is the same on every run: no `random` filter, and no object whose text is its
  address (`{{ range }}`), so the same inputs always give the same release.

Every refusal is a `jinja2.TemplateError` (SecurityError), so callers report it like any
other template error: a file:key problem, exit 2.
"""
from __future__ import annotations

import collections.abc
import contextlib
import itertools
import importlib
import math
import operator
import os
import re
import string
import sys
import threading
import types
import functools
from functools import update_wrapper
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping, MutableMapping, Sequence, cast

import jinja2
import jinja2.nodes
from jinja2.bccache import Bucket
from jinja2.compiler import CodeGenerator, Frame, operators, optimizeconst
from jinja2.runtime import LoopContext
from jinja2.sandbox import ImmutableSandboxedEnvironment, SandboxedEscapeFormatter, SandboxedFormatter, SecurityError
from markupsafe import Markup

from rosdeploy.budget import COMMAND, COMMAND_WORK, LOCK, command_budget  # noqa: F401 (command_budget: the API)
from rosdeploy.yamlsrc import not_text

MAX_NESTING = 64                 # levels of a template's syntax tree (see _PlainReads._generate)
TOO_DEEP = "brackets, parentheses or expressions nest too deeply: split it into smaller values"
MAX_LENGTH = 1_000_000          # characters or items one operation may produce
OBJECT_WEIGHT = 64               # what an object other than a string, number or container counts as
MAX_POWER_BITS = 4096           # `**` and int `*` results beyond this are a DoS, not a configuration value
MAX_WORK = 10_000_000           # units of work one render may take (about a second: see the costs below)
_SCAN_RATE = 8                  # items an `in` search scans (at C speed, ~16 ns each) per unit of MAX_WORK
_RECURSE_COST = 64              # a recursive loop's `loop(x)`, per item: a call, a new loop, its output
# MAX_WORK is in units of about 0.1 µs of work (an empty loop's iteration takes one); what costs more:
_NODE_COST = 4                  # an expression or statement in a loop body, per iteration
_FILTER_COST = 32               # a filter call (`map('int')` calls one per item, in no loop body)
_CALL_COST = 48                 # a call through the sandbox (`x.upper()`): checks, then the call
_WEIGH_COST = 5                 # an item weighed (a filter's list argument, each time)
_CHAR_SHIFT = 4                 # a character read or built at C speed (slice, `~`, compare): 1/16 unit
_ITEM_COST = 2                  # an item of a container walked in Python (to price a comparison)
MAX_BUILT = 100_000_000         # bytes of strings and containers one render may build in all
_ITEM_BYTES = 64                # what an item of a container a filter or method built may hold besides its slot
# A %-format or str.format width/precision of 5+ digits: pads to 10**4+ characters.
_BIG_FORMAT = re.compile(r"%[-#0 +]*(\d{5,}|\*)|%[-#0 +]*\d*\.\d{5,}|\{[^{}]*:[^{}]*\d{5,}[^{}]*\}")
_WIDTH_FILTERS = ("center", "indent", "wordwrap", "truncate", "batch", "slice")
_TOO_LONG = f"a value longer than {MAX_LENGTH:,} characters is not allowed"
_TOO_MUCH_WORK = (f"this template takes more than {MAX_WORK:,} loop steps or searches (loops inside loops, or `in` "
                  "a long list many times) and is not allowed: loop over less, or search a dict instead of a list")
_COMMAND_SPENT = (f"the templates of this command together take more than {COMMAND_WORK:,} loop steps or "
                  "searches (some value or template file does much work for every robot) and are not allowed: "
                  "find the values that loop or search the most and make them do less")
_TOO_MUCH_BUILT = (f"this template builds more than {MAX_BUILT // 1_000_000} MB of strings and lists in all (long "
                   "values copied in a loop, into a list or through a recursive macro) and is not allowed: build "
                   "fewer or shorter values")
_CONTAINERS = (list, tuple, dict, set, frozenset)
_TEXTS = (str, bytes)
_sizeof = sys.getsizeof
# What a single value may not contain (statements that loop, define code or read other files).
_VALUE_FORBIDDEN = (jinja2.nodes.For, jinja2.nodes.Macro, jinja2.nodes.CallBlock, jinja2.nodes.Include,
                    jinja2.nodes.Import, jinja2.nodes.FromImport, jinja2.nodes.Extends, jinja2.nodes.Block,
                    jinja2.nodes.FilterBlock)


# re's own parser (no stubs): a pattern's parse tree, to bound its backtracking before matching
_sre_parse: Any = importlib.import_module("re._parser")
# .budget: [work left, bytes left, work given] of the render under way in this thread, or None
_RENDER = threading.local()


def _bounded_concat(parts: Iterable[str]) -> str:
    """Template output, joined only when it is at most MAX_LENGTH characters, counted as it comes
    (a loop of long pieces stops at the first past the bound, before holding them all). Every
    render ends here, so the outermost call holds the render's MAX_WORK budget."""
    budget = getattr(_RENDER, "budget", None)
    if budget is not None:      # a macro, `{% set %}` block, inventory var: a string it holds on to
        return _built(_joined(parts), budget, "this block's output")
    with metered():
        text = _joined(parts)
    why = not_text(text)
    if why is not None:     # `{{ "\\ud800" }}`: Jinja reads escapes; writing the text would crash
        raise NotText(f"the rendered text {why}")
    return text


@contextlib.contextmanager
def metered() -> Iterator[list[int]]:
    """The budget of the render under way in this thread; if none is, a new one for the render
    that starts here (MAX_WORK, or what is left of the command's budget if less), whose work is
    taken from the command's budget when it ends."""
    budget = getattr(_RENDER, "budget", None)
    if budget is not None:
        yield budget
        return
    command = COMMAND.left
    given = MAX_WORK if command is None else max(0, min(MAX_WORK, command[0]))
    budget = _RENDER.budget = [given, MAX_BUILT, given]
    try:
        yield budget
    finally:
        _RENDER.budget = None
        if command is not None:
            with LOCK:
                command[0] -= given - budget[0]


class NotText(SecurityError):
    """A render whose text no file can hold (yamlsrc.not_text): refused, never written."""


def _joined(parts: Iterable[str]) -> str:
    # counted a few pieces at a time, at C speed: one by one in Python was a tenth of a render's
    # time; a piece is at most MAX_LENGTH, so at most _JOIN_CHUNK of them are held past the bound
    pieces: list[str] = []
    total = 0
    parts = iter(parts)
    while chunk := list(itertools.islice(parts, _JOIN_CHUNK)):
        total += sum(map(len, chunk))
        pieces += chunk
        if total > MAX_LENGTH or len(pieces) > MAX_LENGTH:   # a million empty pieces: a loop that outputs nothing
            raise SecurityError(_TOO_LONG)
    return "".join(pieces)


_JOIN_CHUNK = 16


def _budget(context: Any = None) -> list[int]:
    """The work left to the render under way: the one of its outermost concat, or else (an
    expression evaluated for its value, never joined) the one of its template context."""
    budget = getattr(_RENDER, "budget", None)
    if budget is not None:
        return budget
    if context is None:
        return [MAX_WORK, MAX_BUILT]
    budget = getattr(context, "_work_left", None)
    if budget is None:
        budget = context._work_left = [MAX_WORK, MAX_BUILT]
    return budget


def charge(units: int, budget: list[int] | None = None) -> None:
    """Take `units` of work from the render's budget: SecurityError once it is spent."""
    budget = _budget() if budget is None else budget
    budget[0] -= units
    if budget[0] < 0:
        raise SecurityError(_out_of_work(budget))


def _out_of_work(budget: list[int]) -> str:
    """Why a render whose budget is spent is refused: its own bound, or the command's (a budget
    given less than MAX_WORK: what the renders before it had left)."""
    return _TOO_MUCH_WORK if len(budget) < 3 or budget[2] >= MAX_WORK else _COMMAND_SPENT


def _built(value: Any, budget: list[int], what: str = "this value", new_items: bool = False) -> Any:
    """`value`, just built by an operation of the render (a filter, slice, `~`, operator, method
    call, literal, block): refused when longer than MAX_LENGTH, and charged to the render's work
    (the characters or items built) and to the bytes it may build in all (MAX_BUILT).
    `new_items`: a container whose items may be new objects too (a filter's or method's result)."""
    if isinstance(value, _TEXTS):
        size = len(value)
        work = size >> _CHAR_SHIFT
        held = _sizeof(value)
    elif isinstance(value, _CONTAINERS):
        size = work = len(value)
        held = _sizeof(value) + (size * _ITEM_BYTES if new_items else 0)
    else:
        return value
    if size > MAX_LENGTH:
        raise SecurityError(f"{what} is longer than {MAX_LENGTH:,} characters or items, which is not allowed")
    budget[0] -= work
    budget[1] -= held
    if budget[0] < 0:
        raise SecurityError(_out_of_work(budget))
    if budget[1] < 0:
        raise SecurityError(_TOO_MUCH_BUILT)
    return value


def _touch_cost(value: Any, limit: int = MAX_WORK) -> int:
    """The work of reading all of `value` at C speed (comparing it, hashing it): a string 1/16
    unit a character; a container _ITEM_COST an item walked, plus its strings. A container is
    walked in Python, so the walk stops past `limit` (the caller is refused then anyway)."""
    if isinstance(value, _TEXTS):
        return len(value) >> _CHAR_SHIFT
    if not isinstance(value, _CONTAINERS) or not value:
        return 0
    cost = 0
    todo = [value]
    while todo and cost <= limit:
        item = todo.pop()
        if isinstance(item, _TEXTS):
            cost += _ITEM_COST + (len(item) >> _CHAR_SHIFT)
        elif isinstance(item, _CONTAINERS):
            # not memoised: comparing [big] * 9 to [big2] * 9 compares big nine times
            cost += _ITEM_COST
            todo.extend(itertools.chain.from_iterable(item.items()) if isinstance(item, dict) else item)
        else:
            cost += _ITEM_COST
    return cost


def _compare_cost(left: Any, right: Any) -> int:
    """What comparing left and right may read: the smaller of the two (it stops at the shorter)."""
    cost = _touch_cost(left)
    return min(cost, _touch_cost(right, cost)) if cost else 0


_COMPARE: dict[str, Callable[[Any, Any], Any]] = {
    "eq": operator.eq, "ne": operator.ne, "lt": operator.lt, "lteq": operator.le, "gt": operator.gt,
    "gteq": operator.ge}


def compared(op: str, left: Any, right: Any, context: Any) -> Any:
    """`left op right` (one comparison, not `in`), charged for the characters or items it reads:
    `big == big2` in a loop was as cheap as `1 == 1`."""
    cost = _compare_cost(left, right)
    if cost:
        charge(cost, _budget(context))
    return _COMPARE[op](left, right)


def touched(value: Any, context: Any) -> Any:
    """An operand of a chained comparison (`a < b < c`), charged for all of it."""
    cost = _touch_cost(value)
    if cost:
        charge(cost, _budget(context))
    return value


def contained(value: Any, container: Any, context: Any) -> bool:
    """`value in container`, charged as searched() plus, for a list or tuple, the needle's length
    for every item it may be compared with (a long string against many as long)."""
    cost = _search_cost(container)
    per_item = _touch_cost(value)
    if per_item:
        cost += per_item * (len(container) if isinstance(container, (list, tuple)) else 1)
    charge(cost, _budget(context))
    return value in container


def _search_cost(container: Any) -> int:
    scanned = len(container) if isinstance(container, (str, bytes, list, tuple, range)) else 0
    return 1 + scanned // _SCAN_RATE


def sliced(value: Any, context: Any) -> Any:
    """The result of `x[a:b]` (see _BoundedCodeGenerator): `big[::-1]` copies all of big."""
    return _built(value, _budget(context), "this slice")


def literal(value: Any, context: Any) -> Any:
    """A list, tuple or dict written in the template: at most MAX_LENGTH characters or items in
    its items together (one level: an item counts by its length), its slots charged to MAX_BUILT."""
    size = 0
    for item in itertools.chain.from_iterable(value.items()) if isinstance(value, dict) else value:
        size += len(item) if isinstance(item, (*_TEXTS, *_CONTAINERS)) else 1
    _refuse_longer(size, f"this {type(value).__name__}")
    return _built(value, _budget(context), f"this {type(value).__name__}")


def counted(iterable: Any, cost: int = 1, budget: list[int] | None = None) -> Any:
    """A `{% for %}` iterable (and a recursive loop's `loop(x)`), each item charged `cost` (the
    size of the loop's body): a sized one at once (a Jinja loop has no `break`, so it takes every
    item) and iterated at full speed; another item by item."""
    if isinstance(iterable, jinja2.Undefined):
        return iterable            # iterating it says what is undefined
    budget = _budget() if budget is None else budget
    try:
        size = len(iterable)
    except TypeError:
        return _counting(iter(iterable), cost, budget)
    charge(size * cost, budget)
    return iterable


def _counting(items: Iterator[Any], cost: int, budget: list[int]) -> Iterator[Any]:
    for item in items:
        charge(cost, budget)
        yield item


def _body_cost(node: jinja2.nodes.For | jinja2.nodes.Macro | jinja2.nodes.CallBlock) -> int:
    """What one iteration of a loop or one call of a macro costs, roughly: the nodes of its body
    (and a loop's test), not those of a loop inside it (charged by its own items)."""
    test = getattr(node, "test", None)
    todo: list[jinja2.nodes.Node] = [*node.body, *([test] if test else [])]
    cost = 1
    while todo:
        child = todo.pop()
        cost += _NODE_COST
        if not isinstance(child, jinja2.nodes.For):
            todo.extend(child.iter_child_nodes())
    return cost


def _charge_each_call(node: jinja2.nodes.Macro | jinja2.nodes.CallBlock) -> None:
    """A macro's body is charged by its size each time it runs: a call counts as one node where
    it is written, so a macro of 50,000 expressions called in a loop was nearly free."""
    if not getattr(node, "_counted", False):
        charged = jinja2.nodes.Call(jinja2.nodes.EnvironmentAttribute("charged"),
                                    [jinja2.nodes.Const(_body_cost(node))], [], None, None, lineno=node.lineno)
        node.body = [jinja2.nodes.ExprStmt(charged, lineno=node.lineno), *node.body]
        node._counted = True  # type: ignore[union-attr]  # visit_Macro may see the same node again


def charged(units: int) -> str:
    """charge() for a template: one call of a macro; writes nothing."""
    charge(units)
    return ""


def searched(container: Any, context: Any = None) -> Any:
    """The right side of `in` in a chained comparison, charged for the items it scans: a list,
    tuple, string or range its length / _SCAN_RATE; a dict or set one lookup (see contained())."""
    charge(_search_cost(container), _budget(context))
    return container


class _BoundedCodeGenerator(CodeGenerator):
    """`a ~ b` joins its strings inline, with no environment hook: check each operand as output is
    (see written()), and the result's length after (never longer than its operands together).
    Slices, comparisons and list, tuple and dict literals are inline Python too: each goes through
    an environment hook that charges what it reads or builds (sliced, compared, literal)."""

    @optimizeconst
    def visit_Concat(self, node: jinja2.nodes.Concat, frame: Frame) -> None:
        # CodeGenerator.visit_Concat, with each operand checked before str() and the result after
        if frame.eval_ctx.volatile:
            func_name = "(markup_join if context.eval_ctx.volatile else str_join)"
        elif frame.eval_ctx.autoescape:
            func_name = "markup_join"
        else:
            func_name = "str_join"
        self.write(f"environment.bounded_text({func_name}((")
        for arg in node.nodes:
            self.write("environment.finalize(")
            self.visit(arg, frame)
            self.write("), ")
        self.write(")), context)")

    def visit_Const(self, node: jinja2.nodes.Const, frame: Frame) -> None:
        # Jinja writes a float constant as str(): `1e400` (or `1e400 * 0`, folded) became the
        # name `inf` (`nan`) in the generated Python, a NameError when rendered
        self._finite(node.as_const(frame.eval_ctx), node.lineno)
        super().visit_Const(node, frame)

    def _output_child_to_const(self, node: jinja2.nodes.Expr, frame: Frame, finalize: Any) -> str:
        # `{{ 1e400 }}` alone is written at compile time, as the text "inf": refused as above
        const = super()._output_child_to_const(node, frame, finalize)   # Impossible: not a constant
        self._finite(node.as_const(frame.eval_ctx), node.lineno)
        return const

    def _finite(self, value: Any, lineno: int) -> None:
        found = _not_finite(value)
        if found is not None:
            self.fail(f"a number here is {found}, not a finite number (a literal past 1.8e308, or computed from "
                      "one): write a finite number", lineno)

    @optimizeconst
    def visit_Getitem(self, node: jinja2.nodes.Getitem, frame: Frame) -> None:
        if not isinstance(node.arg, jinja2.nodes.Slice):     # environment.getitem: one item, no copy
            super().visit_Getitem(node, frame)
            return
        self.write("environment.sliced(")
        super().visit_Getitem(node, frame)
        self.write(", context)")

    def visit_List(self, node: jinja2.nodes.List, frame: Frame) -> None:
        self.write("environment.literal(")
        super().visit_List(node, frame)
        self.write(", context)")

    def visit_Tuple(self, node: jinja2.nodes.Tuple, frame: Frame) -> None:
        if node.ctx != "load":          # `{% set a, b = ... %}`, `{% for k, v in ... %}`: names to assign
            super().visit_Tuple(node, frame)
            return
        self.write("environment.literal(")
        super().visit_Tuple(node, frame)
        self.write(", context)")

    def visit_Dict(self, node: jinja2.nodes.Dict, frame: Frame) -> None:
        self.write("environment.literal(")
        super().visit_Dict(node, frame)
        self.write(", context)")

    @optimizeconst
    def visit_Compare(self, node: jinja2.nodes.Compare, frame: Frame) -> None:
        # One comparison (nearly all): compared() or contained(), which see both sides. A constant
        # side is short (source text), and so is the comparison.
        if len(node.ops) == 1:
            op = node.ops[0]
            if op.op in ("in", "notin"):
                self.write("(" if op.op == "in" else "(not ")
                self.write("environment.contained(")
                self.visit(node.expr, frame)
                self.write(", ")
                self.visit(op.expr, frame)
                self.write(", context))")
                return
            if isinstance(node.expr, jinja2.nodes.Const) or isinstance(op.expr, jinja2.nodes.Const):
                self.write("(")
                self.visit(node.expr, frame)
                self.write(f" {operators[op.op]} ")
                self.visit(op.expr, frame)
                self.write(")")
                return
            self.write(f"environment.compared({op.op!r}, ")
            self.visit(node.expr, frame)
            self.write(", ")
            self.visit(op.expr, frame)
            self.write(", context)")
            return
        self.write("(")
        self._touched(node.expr, frame)
        for op in node.ops:
            self.visit(op, frame)
        self.write(")")

    def _touched(self, expr: jinja2.nodes.Expr, frame: Frame) -> None:
        if isinstance(expr, jinja2.nodes.Const):
            self.visit(expr, frame)
            return
        self.write("environment.touched(")
        self.visit(expr, frame)
        self.write(", context)")

    def visit_For(self, node: jinja2.nodes.For, frame: Frame) -> None:
        # every loop takes its items through counted(): nested loops share one budget per render
        if not getattr(node, "_counted", False):
            cost = jinja2.nodes.Const(_body_cost(node))
            node.iter = jinja2.nodes.Call(jinja2.nodes.EnvironmentAttribute("counted"), [node.iter, cost], [], None,
                                          None, lineno=node.iter.lineno)
            node._counted = True  # type: ignore[attr-defined]
        super().visit_For(node, frame)

    def visit_Macro(self, node: jinja2.nodes.Macro, frame: Frame) -> None:
        _charge_each_call(node)
        super().visit_Macro(node, frame)

    def visit_CallBlock(self, node: jinja2.nodes.CallBlock, frame: Frame) -> None:
        _charge_each_call(node)
        super().visit_CallBlock(node, frame)

    def visit_Operand(self, node: jinja2.nodes.Operand, frame: Frame) -> None:
        # in a chain (`a < b < c`, see visit_Compare): `x in big` inside a loop is a loop too,
        # charged by searched(); another operand by what comparing it reads
        if node.op not in ("in", "notin"):
            self.write(f" {operators[node.op]} ")
            self._touched(node.expr, frame)
            return
        self.write(f" {operators[node.op]} environment.searched(")
        self.visit(node.expr, frame)
        self.write(", context)")


def _not_finite(value: Any) -> str | None:
    """'inf' or 'nan' when `value` (a constant: a number, or a list, tuple or dict of them) holds one."""
    if isinstance(value, float):
        return None if math.isfinite(value) else str(value).lstrip("-")
    if isinstance(value, dict):
        value = [*value.keys(), *value.values()]
    if isinstance(value, (list, tuple)):
        return next((found for item in value if (found := _not_finite(item)) is not None), None)
    return None


# Attributes no template reads: `host.secret_values` holds every vault value of the robot as text,
# where reading a vault var is tracked (and refused outside .env).
HIDDEN = frozenset({"secret_values"})


class _PlainReads(ImmutableSandboxedEnvironment):
    """Jinja's immutable sandbox, reading the public fields of `plain_types` without its
    per-access checks: frozen dataclasses of plain values, whose public fields templates read
    in bulk (half the render time of 5,000 robots); the check could only ever allow a name
    without a leading `_` on them."""

    plain_types: frozenset[type] = frozenset()
    # fields of a plain type no template reads (see HIDDEN), e.g. the controller's own paths: a
    # release must not depend on where rosdeploy runs, nor carry what the environment expanded
    hidden_of: Mapping[type, frozenset[str]] = {}

    def getattr(self, obj: Any, attribute: str) -> Any:
        # one dict lookup: templates read these fields 100,000 times for 500 robots
        hidden = self._hidden_in.get(type(obj))
        if hidden is not None and attribute not in hidden and not attribute.startswith("_"):
            try:
                return getattr(obj, attribute)
            except AttributeError:
                pass
        return super().getattr(obj, attribute)

    @functools.cached_property
    def _hidden_in(self) -> dict[type, frozenset[str]]:
        """Each plain type -> the fields templates do not read on it (HIDDEN and its hidden_of)."""
        return {t: HIDDEN | self.hidden_of.get(t, frozenset()) for t in self.plain_types}

    def is_safe_attribute(self, obj: Any, attr: str, value: Any) -> bool:
        return attr not in HIDDEN and attr not in self.hidden_of.get(type(obj), ()) and \
            super().is_safe_attribute(obj, attr, value)

    # Parsing, code generation and Python's compile() all recurse once per nesting level: a
    # value like `{{ [[[[...1]]]] }}` 1,000 deep is a syntax error of the value, not a crash.
    def _parse(self, source: str, name: str | None, filename: str | None) -> jinja2.nodes.Template:
        with _nesting_bounded(name, filename):
            return super()._parse(source, name, filename)

    def _generate(self, source: jinja2.nodes.Template, name: str | None, filename: str | None,
                  defer_init: bool = False) -> str:
        # Jinja's code generator takes time that grows faster than the square of the nesting
        # (`{{ x.y.y.y... }}` 300 deep: 4 s). Checked here, not in _parse: compile_expression
        # (an inventory value that is one expression) builds its tree without _parse.
        # rosdeploy's own templates nest 8 deep.
        deep = _deeper_than(source, MAX_NESTING)
        if deep is not None:
            raise jinja2.TemplateSyntaxError(f"{TOO_DEEP} (more than {MAX_NESTING} levels)", deep.lineno or 1,
                                             name, filename)
        with _nesting_bounded(name, filename):
            return super()._generate(source, name, filename, defer_init=defer_init)

    def _compile(self, source: str, filename: str) -> types.CodeType:
        with _nesting_bounded(None, filename):
            return super()._compile(source, filename)


def _deeper_than(tree: jinja2.nodes.Node, limit: int) -> jinja2.nodes.Node | None:
    """The first node found more than `limit` levels down, walked without recursion."""
    stack = [(tree, 1)]
    while stack:
        node, depth = stack.pop()
        if depth > limit:
            return node
        stack.extend((child, depth + 1) for child in node.iter_child_nodes())
    return None


@contextlib.contextmanager
def _nesting_bounded(name: str | None, filename: str | None) -> Iterator[None]:
    try:
        yield
    except (RecursionError, MemoryError) as exc:
        raise jinja2.TemplateSyntaxError(TOO_DEEP, 1, name, filename) from exc
    except SyntaxError as exc:   # Python's own limit: "too many nested parentheses"
        raise jinja2.TemplateSyntaxError(f"{TOO_DEEP} ({exc.msg})", 1, name, filename) from exc


class ShippedSandbox(_PlainReads):
    """For rosdeploy's own templates (rosdeploy/templates/): Jinja's sandbox, without the bounds
    below (work budget, output count, filter weighing). Their loops and output are bounded by
    their inputs, which the loaders bound, and those checks were a sixth of the render time."""

    def __init__(self, plain_types: tuple[type, ...] = (), hidden_of: Mapping[type, frozenset[str]] | None = None,
                 **kwargs: Any) -> None:
        self.plain_types = frozenset(plain_types)
        self.hidden_of = hidden_of or {}
        kwargs.setdefault("undefined", jinja2.StrictUndefined)
        kwargs.setdefault("autoescape", False)
        super().__init__(**kwargs)


class ShippedCache(jinja2.FileSystemBytecodeCache):
    """rosdeploy's own templates, compiled once per version of their source and kept between
    commands: compiling the six took ~22 ms of every command that renders. Only ShippedSandbox
    uses it. Sandbox compiles with its own code generator (the bounds), and code compiled for one
    must never run in the other. A damaged entry is compiled again; a cache that cannot be
    written is no cache, never an error."""

    def load_bytecode(self, bucket: Bucket) -> None:
        try:
            super().load_bytecode(bucket)
        except Exception:     # noqa: BLE001 - a damaged or truncated entry: compile again
            bucket.reset()

    def dump_bytecode(self, bucket: Bucket) -> None:
        try:
            super().dump_bytecode(bucket)
        except OSError:
            pass


def shipped_cache() -> ShippedCache | None:
    """The cache in ~/.cache/rosdeploy/templates ($XDG_CACHE_HOME), or None where that folder
    cannot be made, or is not this user's alone: its entries are code this process will run."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    folder = os.path.join(base, "rosdeploy", "templates")
    if not os.path.isabs(folder):          # no HOME: not a folder relative to wherever this runs
        return None
    try:
        os.makedirs(folder, mode=0o700, exist_ok=True)
        info = os.stat(folder)
    except OSError:
        return None
    if info.st_uid != os.getuid() or info.st_mode & 0o077:
        return None
    return ShippedCache(folder)


class Sandbox(_PlainReads):
    """ImmutableSandboxedEnvironment with bounded operators and no stepping-stone globals."""

    intercepted_binops = frozenset({"*", "**", "%", "+"})
    code_generator_class = _BoundedCodeGenerator
    concat = staticmethod(_bounded_concat)
    counted = staticmethod(counted)
    searched = staticmethod(searched)
    charged = staticmethod(charged)
    contained = staticmethod(contained)
    compared = staticmethod(compared)
    touched = staticmethod(touched)
    sliced = staticmethod(sliced)
    literal = staticmethod(literal)

    def __init__(self, plain_types: tuple[type, ...] = (), hidden_of: Mapping[type, frozenset[str]] | None = None,
                 **kwargs: Any) -> None:
        """`plain_types`, `hidden_of`: see _PlainReads."""
        self.plain_types = frozenset(plain_types)
        self.hidden_of = hidden_of or {}
        kwargs.setdefault("undefined", jinja2.StrictUndefined)
        kwargs.setdefault("finalize", written)
        kwargs.setdefault("autoescape", False)
        super().__init__(**kwargs)
        for name in ("lipsum", "cycler", "joiner", "namespace"):
            self.globals.pop(name, None)
        for name in _WIDTH_FILTERS:
            self.filters[name] = _bounded_filter(self.filters[name])
        self.filters["format"] = _checked_format(self.filters["format"])
        for name, bound in _FILTER_BOUNDS.items():
            self.filters[name] = bound(self.filters[name])
        self.filters["random"] = _no_random
        self.tests["in"] = _test_in
        for name, rate in _READING_TESTS.items():
            self.tests[name] = _charged_test(cast(Callable[..., Any], self.tests[name]), rate)
        for name in ("default", "d"):
            self.filters[name] = _failing_refused(self.filters[name])
        for name in ("defined", "undefined"):
            self.tests[name] = _failing_refused(cast(Callable[..., Any], self.tests[name]))
        self.add_filters({})

    def add_filters(self, filters: Mapping[str, Callable[..., Any]]) -> None:
        """Add `filters`, and weigh the value every filter gets: `tojson`, `string`, `pprint` and
        a rosdeploy filter turn a list holding one list many times over (`{% set a = [a, a] %}`)
        into 2**60 characters without an operator to stop it."""
        self.filters.update(filters)
        for name, func in self.filters.items():
            if not getattr(func, "_weighed", False):
                self.filters[name] = _weighed_filter(func, name)

    def make_globals(self, d: MutableMapping[str, Any] | None) -> MutableMapping[str, Any]:
        """A plain dict, not Jinja's ChainMap: every render copies a template's globals twice, and
        iterating a ChainMap was 8% of rendering 500 robots. The same names and values, since
        nothing changes this environment's globals after __init__."""
        return {**self.globals, **(d or {})}

    def call_binop(self, context: Any, operator_: str, left: Any, right: Any) -> Any:
        if operator_ == "+":
            _check_add(left, right)
        elif operator_ == "*":
            _check_repeat(left, right)
            _check_product(left, right)
        elif operator_ == "**":
            _check_power(left, right)
        elif operator_ == "%" and isinstance(left, (str, bytes)):
            _check_percent(left, right)
        result = self.binop_table[operator_](left, right)
        if isinstance(result, (*_TEXTS, list, tuple)):      # a new string or list, as long as it came out
            _built(result, _budget(context), f"the result of {operator_}")
        return result

    def call(self, context: Any, obj: Any, /, *args: Any, **kwargs: Any) -> Any:
        """Every call a template makes: the str/bytes methods that grow a string are checked
        first (one dict lookup for any other call); each call is charged to the render's work."""
        budget = _budget(context)
        charge(_CALL_COST, budget)
        if obj is counted:                              # a `{% for %}` (see _BoundedCodeGenerator)
            return counted(*args, budget=budget)
        owner = getattr(obj, "__self__", None)
        if isinstance(owner, _TEXTS):                   # a str method: reads all of it, may build a new one
            _charge_method(owner, args, budget)
            check = _METHOD_BOUNDS.get(obj.__name__)
            if check is not None:
                args = check(owner, args, kwargs)
        elif isinstance(obj, LoopContext) and args:     # a recursive loop's `loop(children)`
            args = (counted(args[0], _RECURSE_COST, budget), *args[1:])
        elif obj is dict and args:                      # dict(lazy pairs) holds them all
            args = (_lazy_weighed(args[0]), *args[1:])
        result = super().call(context, obj, *args, **kwargs)
        if result is owner or result is None:
            return result
        if isinstance(owner, _TEXTS) or obj is dict or getattr(obj, "_builds", False) \
                or (isinstance(owner, _CONTAINERS) and isinstance(result, _CONTAINERS)):   # `l.copy()`
            _built(result, budget, "the result of this call", new_items=True)
        return result

    @staticmethod
    def bounded_text(text: str, context: Any = None) -> str:
        """The result of `~` (see _BoundedCodeGenerator)."""
        if len(text) > MAX_LENGTH:
            raise SecurityError(_TOO_LONG)
        return _built(text, _budget(context), "the result of ~")

    def wrap_str_format(self, value: Any) -> Callable[..., str] | None:
        """Jinja's own wrapper (called on every attribute read), with a formatter that stops at
        MAX_LENGTH characters, and no width over 9999 or nested field (`{x:>{w}}`) in a spec."""
        if not isinstance(value, (types.MethodType, types.BuiltinMethodType)) \
                or value.__name__ not in ("format", "format_map"):
            return None
        f_self: Any = value.__self__
        if not isinstance(f_self, str):
            return None
        _check_str_format(f_self)
        str_type: type[str] = type(f_self)
        is_format_map = value.__name__ == "format_map"
        formatter = (_BoundedEscapeFormatter(self, escape=f_self.escape) if isinstance(f_self, Markup)
                     else _BoundedFormatter(self))

        def wrapper(*args: Any, **kwargs: Any) -> str:
            if is_format_map:
                if kwargs:
                    raise TypeError("format_map() takes no keyword arguments")
                if len(args) != 1:
                    raise TypeError(f"format_map() takes exactly one argument ({len(args)} given)")
                kwargs = args[0]
                args = ()
            return str_type(formatter.vformat(f_self, args, kwargs))

        wrapped = update_wrapper(wrapper, value)
        wrapped._builds = True  # type: ignore[attr-defined]  # Sandbox.call charges what it built
        return wrapped


class _BoundedFormatter(SandboxedFormatter):
    """Counts the characters it produced: `('{0}' * 10**5).format('a' * 10**5)` stops after the
    first fields past MAX_LENGTH, not at 10**10 characters."""

    produced = 0

    def vformat(self, format_string: str, args: Sequence[Any], kwargs: Mapping[str, Any]) -> str:
        self.produced = len(format_string)
        return super().vformat(format_string, args, kwargs)

    def format_field(self, value: Any, format_spec: str) -> Any:
        text = super().format_field(written(value), format_spec)
        self.produced += len(text)
        if self.produced > MAX_LENGTH:
            raise SecurityError(_TOO_LONG)
        return text


class _BoundedEscapeFormatter(_BoundedFormatter, SandboxedEscapeFormatter):
    """The same for Markup.format."""


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
    with _nesting_bounded(None, None):     # find_all recurses too
        found = next(iter(tree.find_all(_VALUE_FORBIDDEN)), None)
    if found is not None:
        kind = type(found).__name__.lower()
        raise jinja2.TemplateSyntaxError(
            f"a value may hold {{{{ expressions }}}} and {{% if %}} only, not {{% {kind} %}}: "
            "put loops, macros and includes in a template file", getattr(found, "lineno", 1))
    return env.from_string(tree)


class Layered(Mapping[str, Any]):
    """Mappings seen as one, the first that has a name wins, read one name at a time: nothing is
    copied, so an inventory var (templated when read) is templated only if something reads it,
    and a reader that watches which vars are read (inventory.templating.secret_reads) sees it."""

    def __init__(self, *layers: Mapping[str, Any]) -> None:
        self._layers = layers

    def __getitem__(self, name: str) -> Any:
        for layer in self._layers:
            if name in layer:
                return layer[name]
        raise KeyError(name)

    def __contains__(self, name: object) -> bool:
        return any(name in layer for layer in self._layers)

    def __iter__(self) -> Iterator[str]:
        return iter(dict.fromkeys(itertools.chain.from_iterable(reversed(self._layers))))

    def __len__(self) -> int:
        return sum(1 for _ in self)

    def __repr__(self) -> str:     # `{{ vars }}`: the same text on every run (no object address)
        return f"<{len(self)} vars>"


class _Names(dict):
    """A template's names, looked up in a Layered when used: Jinja reads a shared parent context
    with `in` and `[]` only, where Template.render would copy every var into a dict first."""

    def __init__(self, names: Layered) -> None:
        super().__init__()
        self._names = names

    def __contains__(self, name: object) -> bool:
        return name in self._names

    def __getitem__(self, name: str) -> Any:
        return self._names[name]

    def get(self, name: str, default: Any = None) -> Any:
        return self._names.get(name, default)


def render_value(template: jinja2.Template, *layers: Mapping[str, Any]) -> str:
    """Render one value with the names of `layers` (the first that has a name wins), each read
    only if used; any failure inside (a blocked access, 1/0, recursion) is a TemplateError."""
    context = template.new_context(_Names(Layered(*layers, template.globals)), shared=True)
    try:
        return template.environment.concat(template.root_render_func(context))
    except jinja2.TemplateError:
        raise
    except Exception as exc:   # user code failing is a user error, never an internal one
        raise jinja2.TemplateRuntimeError(describe(exc)) from exc


def describe(exc: BaseException) -> str:
    """A one-line reason for a failure inside a template, without the value that failed."""
    if isinstance(exc, RecursionError):
        # Python's limit stops it, whether or not it would end: the depth is the fault either way
        return (f"the template recurses too deeply (past Python's limit of {sys.getrecursionlimit()} calls, "
                "a macro or include calling itself without end, or nearly): make it shallower, e.g. a loop")
    if isinstance(exc, MemoryError):
        return ("a value grows larger than this computer's memory (MemoryError): build smaller values, "
                "e.g. fewer or shorter items in a list or loop")
    if isinstance(exc, OverflowError):
        return f"a value is too large ({type(exc).__name__}: {str(exc)[:200]})"
    return f"{type(exc).__name__}: {str(exc)[:200]}"


def weight(value: Any, limit: int = MAX_LENGTH) -> int:
    """How big `value` is once written out, roughly: a string its length, a list, tuple, set or
    dict the weights of its items together (at least 1), a number 1, another object OBJECT_WEIGHT.
    Counting stops soon after `limit`; a list the value holds many times over is counted once
    (memoised by id), so `[[1] * 10**5] * 10**5` is 10**10 at once, not after 10**10 steps."""
    return _weigh(value, limit, {})


def _scalar_weight(value: Any) -> int:
    """A number or None writes out short; any other object (a robot, a service) as its repr, which
    is not computed here: OBJECT_WEIGHT, so `[host] * 10**6` is not a million characters."""
    return 1 if value is None or isinstance(value, (int, float)) else OBJECT_WEIGHT


def _weigh(value: Any, limit: int, seen: dict[int, int]) -> int:
    if isinstance(value, (str, bytes)):
        return len(value)
    if not isinstance(value, _CONTAINERS):
        return _scalar_weight(value)
    known = seen.get(id(value))
    if known is not None:
        return known
    seen[id(value)] = limit + 1       # while counting: a container inside itself is too big
    total = 0
    for item in itertools.chain.from_iterable(value.items()) if isinstance(value, dict) else value:
        total += _weigh(item, limit, seen)
        if total > limit:
            break
    total = max(total, 1)
    seen[id(value)] = total
    return total


def written(value: Any) -> Any:
    """Every `{{ value }}` and `~` operand before str(): a list holding the same list many times
    over (`{% set a = [a, a] %}` 60 times) is small in memory, but 2**60 characters written out;
    and an object written as its address (`{{ range }}`) is different text on every run.
    None (a null var) writes as nothing, as Ansible's templar finalizes it, not as `None`."""
    if isinstance(value, (str, int, float)):     # most output; Markup is a str, bool an int
        return value
    if value is None:
        return ""
    if isinstance(value, _CONTAINERS) and weight(value) > MAX_LENGTH:
        raise SecurityError(_TOO_LONG)
    _refuse_addressed(value, set())
    return value


# Written out, these show where they are in memory (`<function safe_range at 0x7fd...>`)
_ADDRESSED = (types.FunctionType, types.BuiltinFunctionType, types.MethodType, types.BuiltinMethodType,
              types.MethodWrapperType, types.WrapperDescriptorType, types.MethodDescriptorType,
              types.ClassMethodDescriptorType, types.GetSetDescriptorType, types.MemberDescriptorType,
              types.GeneratorType, types.CoroutineType, types.AsyncGeneratorType, types.ModuleType, type,
              collections.abc.Iterator)


def _refuse_addressed(value: Any, seen: set[int]) -> None:
    """SecurityError if `value`, or an item of it, writes out as its memory address: the same inputs
    must give the same text (and release digest) on every run. A container is walked once (by id)."""
    if isinstance(value, _CONTAINERS):
        if id(value) in seen:
            return
        seen.add(id(value))
        for item in itertools.chain.from_iterable(value.items()) if isinstance(value, dict) else value:
            if not isinstance(item, (str, int, float)) and item is not None:
                _refuse_addressed(item, seen)
        return
    if isinstance(value, (str, int, float)) or value is None:
        return
    kind = type(value)
    if isinstance(value, _ADDRESSED) or (kind.__repr__ is object.__repr__ and kind.__str__ is object.__str__):
        raise SecurityError(f"a {kind.__name__} object is not a value to write out (its text is its memory "
                            "address, different on every run): call it, or write one of its attributes")


def _refuse_longer(size: int, what: str) -> None:
    if size > MAX_LENGTH:
        raise SecurityError(f"{what} would be longer than {MAX_LENGTH:,} characters or items")


def _check_repeat(left: Any, right: Any) -> None:
    for seq, count in ((left, right), (right, left)):
        if isinstance(seq, (str, bytes, list, tuple)) and isinstance(count, int) and count > 0:
            if len(seq) * count > MAX_LENGTH or weight(seq, MAX_LENGTH // count) * count > MAX_LENGTH:
                raise SecurityError(f"repeating a value {count} times would exceed {MAX_LENGTH} items")


def _check_add(left: Any, right: Any) -> None:
    if isinstance(left, (str, bytes)) and isinstance(right, (str, bytes)):
        _refuse_longer(len(left) + len(right), "adding these strings")
    elif isinstance(left, (list, tuple)) and isinstance(right, (list, tuple)):
        _refuse_longer(len(left) + len(right), "adding these lists")
        _refuse_longer(weight(left) + weight(right), "adding these lists")


def _check_power(left: Any, right: Any) -> None:
    if isinstance(left, int) and isinstance(right, int) and right > 0:
        if max(abs(left), 2).bit_length() * right > MAX_POWER_BITS:
            raise SecurityError(f"{left} ** {right} is too large a number")


def _check_format(text: str) -> None:
    if _BIG_FORMAT.search(text):
        raise SecurityError("a format width or precision over 9999 is not allowed")


def _check_str_format(text: str) -> None:
    """A str.format string: widths as in _check_format, and no replacement field inside a format
    spec, where `'{x:>{w}}'.format(x='a', w=999999999)` would bring in any width."""
    _check_format(text)
    try:
        nested = any(spec and "{" in spec for _, _, spec, _ in _FORMATTER.parse(text))
    except ValueError:          # malformed: str.format itself says so
        return
    if nested:
        raise SecurityError("a replacement field inside a format spec ('{x:>{w}}') is not allowed")


def _check_percent(text: str | bytes, args: Any) -> None:
    """`text % args` (and the `format` filter): no width over 9999, and at most MAX_LENGTH
    characters however often a field repeats a long argument (`'%(a)s' * 10**5 % {'a': long}`)."""
    if isinstance(text, bytes):
        text = text.decode("latin-1")
    _check_format(text)
    fields = [m for m in _PERCENT_FIELD.finditer(text) if m["kind"] != "%"]
    if not fields:
        return
    positional = max(map(weight, args), default=0) if isinstance(args, tuple) else weight(args)
    size = len(text)
    for field in fields:
        if field["key"] is not None:
            try:
                item = weight(args[field["key"]])
            except Exception:     # not a mapping, or no such key: `%` itself says so
                item = 0
        else:
            item = positional
        # a number's digits: a float's %f runs to 309 of them before the precision
        size += item + int(field["width"] or 0) + int(field["precision"] or 0) + 330
        _refuse_longer(size, "this %-format")


def _method_replace(text: str | bytes, args: tuple[Any, ...], kwargs: dict[str, Any]) -> tuple[Any, ...]:
    if len(args) >= 2:
        count = args[2] if len(args) > 2 else kwargs.get("count", -1)
        _refuse_longer(_replaced_size(text, args[0], args[1], count), "this replace")
    return args


def _replaced_size(text: Any, old: Any, new: Any, count: Any) -> int:
    """The length of text.replace(old, new, count), worked out before replacing."""
    if not isinstance(text, (str, bytes)) or not isinstance(old, (str, bytes)) \
            or not isinstance(new, (str, bytes)) or len(new) <= len(old):
        return 0
    found = len(text) + 1 if not old else text.count(old)   # type: ignore[arg-type]
    if isinstance(count, int) and count >= 0:
        found = min(found, count)
    return len(text) + found * (len(new) - len(old))


def _method_join(sep: str | bytes, args: tuple[Any, ...], kwargs: dict[str, Any]) -> tuple[Any, ...]:
    if len(args) == 1 and not kwargs:
        items = list(_lazy_weighed(args[0]))
        _refuse_longer(_joined_size(items, len(sep)), "this join")
        return (items,)
    return args


def _joined_size(items: list[Any], sep: int) -> int:
    size = max(len(items) - 1, 0) * sep
    for item in items:
        size += weight(item)
        if size > MAX_LENGTH:
            break
    return size


def _method_width(text: str | bytes, args: tuple[Any, ...], kwargs: dict[str, Any]) -> tuple[Any, ...]:
    width = args[0] if args else kwargs.get("width")
    if isinstance(width, int):
        _refuse_longer(width, "this padding")
    return args


def _method_expandtabs(text: str | bytes, args: tuple[Any, ...], kwargs: dict[str, Any]) -> tuple[Any, ...]:
    size = args[0] if args else kwargs.get("tabsize", 8)
    if isinstance(size, int) and size > 1:
        tab = "\t" if isinstance(text, str) else b"\t"
        _refuse_longer(len(text) + text.count(tab) * size, "expanding these tabs")   # type: ignore[arg-type]
    return args


def _method_translate(text: str | bytes, args: tuple[Any, ...], kwargs: dict[str, Any]) -> tuple[Any, ...]:
    table = args[0] if args else None
    values = table.values() if isinstance(table, dict) else table if isinstance(table, (list, tuple)) else ()
    longest = max((len(v) for v in values if isinstance(v, str)), default=1)
    if longest > 1:
        _refuse_longer(len(text) * longest, "this translate")
    return args


_FORMATTER = string.Formatter()
_PERCENT_FIELD = re.compile(r"%(?:\((?P<key>[^()]*)\))?[-#0 +]*(?P<width>\d*)(?:\.(?P<precision>\d*))?[hlL]?"
                            r"(?P<kind>.)", re.S)
_METHOD_BOUNDS: dict[str | None, Callable[[Any, tuple[Any, ...], dict[str, Any]], tuple[Any, ...]]] = {
    "replace": _method_replace, "join": _method_join, "center": _method_width, "ljust": _method_width,
    "rjust": _method_width, "zfill": _method_width, "expandtabs": _method_expandtabs,
    "translate": _method_translate,
}


class Failing(jinja2.StrictUndefined):
    """An undefined that stands for an error, not an absence (an inventory var whose template is
    broken, rosdeploy.inventory.templating.Broken): `default` and `is defined` raise its error
    instead of quietly standing in for the value the user meant."""


def _failing_refused(func: Callable[..., Any]) -> Callable[..., Any]:
    def refusing(value: Any, *args: Any, **kwargs: Any) -> Any:
        if isinstance(value, Failing):
            value._fail_with_undefined_error()
        return func(value, *args, **kwargs)
    _copy_markers(func, refusing)
    return refusing


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
        _check_percent(str(value), kwargs or args)
        return func(value, *args, **kwargs)
    _copy_markers(func, checked)
    return checked


def _bounded_replace(func: Callable[..., Any]) -> Callable[..., Any]:
    def replace(eval_ctx: Any, s: Any, old: Any, new: Any, count: Any = None) -> Any:
        _refuse_longer(_replaced_size(str(s), str(old), str(new), count), "this replace")
        return func(eval_ctx, s, old, new, count)
    _copy_markers(func, replace)
    return replace


def _bounded_join_filter(func: Callable[..., Any]) -> Callable[..., Any]:
    def join(eval_ctx: Any, value: Any, d: Any = "", attribute: Any = None) -> Any:
        items = list(value)
        if attribute is not None:
            items = list(map(jinja2.filters.make_attrgetter(eval_ctx.environment, attribute), items))
        _refuse_longer(_joined_size(items, len(str(d))), "this join")
        return func(eval_ctx, items, d)
    _copy_markers(func, join)
    return join


def _bounded_indent(func: Callable[..., Any]) -> Callable[..., Any]:
    def indent(s: Any, *args: Any, **kwargs: Any) -> Any:
        width = args[0] if args else kwargs.get("width", 4)
        pad = len(width) if isinstance(width, str) else width if isinstance(width, int) else 0
        if pad > 0 and isinstance(s, str):
            _refuse_longer(len(s) + (len(s.splitlines()) + 2) * pad, "this indent")
        return func(s, *args, **kwargs)
    _copy_markers(func, indent)
    return indent


def _bounded_wordwrap(func: Callable[..., Any]) -> Callable[..., Any]:
    def wordwrap(environment: jinja2.Environment, s: Any, *args: Any, **kwargs: Any) -> Any:
        width = args[0] if args else kwargs.get("width", 79)
        wrap = args[2] if len(args) > 2 else kwargs.get("wrapstring")
        wrap = environment.newline_sequence if wrap is None else wrap
        if isinstance(s, str) and isinstance(wrap, str) and isinstance(width, int) and width > 0:
            # each line and the next hold more than `width` characters of s together
            lines = len(s.splitlines()) + 2 * len(s) // width + 1
            _refuse_longer(len(s) + lines * len(wrap), "this wordwrap")
        return func(environment, s, *args, **kwargs)
    _copy_markers(func, wordwrap)
    return wordwrap


def _bounded_sum(func: Callable[..., Any]) -> Callable[..., Any]:
    """`lists|sum(start=[])` is Python's sum: each `+` copies the total so far, so 10**5 one-item
    lists took 10 s (quadratic), and the result was weighed only once written. A list or tuple
    start is weighed with the items first, then joined in one pass; any other start is func's."""
    def sum_(environment: jinja2.Environment, iterable: Any, attribute: Any = None, start: Any = 0) -> Any:
        if not isinstance(start, (list, tuple)):
            return func(environment, iterable, attribute, start)
        items = list(itertools.islice(iterable, MAX_LENGTH + 1))
        _refuse_longer(len(items), "this sum")
        if attribute is not None:
            items = list(map(jinja2.filters.make_attrgetter(environment, attribute), items))
        return _concatenated(start, items)
    _copy_markers(func, sum_)
    return sum_


def _concatenated(start: list[Any] | tuple[Any, ...], items: list[Any]) -> list[Any] | tuple[Any, ...]:
    """What sum(items, start) gives for sequences (a TypeError for a mixed one, as `[] + ()` is),
    refused before anything is copied when it would exceed MAX_LENGTH items or characters."""
    kind = list if isinstance(start, list) else tuple
    name = kind.__name__
    for item in items:
        if not isinstance(item, kind):
            raise TypeError(f'can only concatenate {name} (not "{type(item).__name__}") to {name}')
    _refuse_longer(len(start) + sum(map(len, items)), "this sum")
    elements = itertools.chain(start, itertools.chain.from_iterable(items))
    _refuse_longer(_weigh_each(elements), "this sum")
    return kind(itertools.chain(start, itertools.chain.from_iterable(items)))


def _weigh_each(values: Iterable[Any]) -> int:
    """The weight of a list of `values` without building it (and without the 1 an empty list adds)."""
    seen: dict[int, int] = {}
    total = 0
    for value in values:
        total += _weigh(value, MAX_LENGTH, seen)
        if total > MAX_LENGTH:
            break
    return total


def _lazy_weighed(value: Any) -> Any:
    """`value`, or if it is a lazy sequence (a generator, `map`), the same items weighed as they
    are taken: whatever collects them stops past MAX_LENGTH, before holding them all."""
    if isinstance(value, (str, bytes, *_CONTAINERS)) or not isinstance(value, collections.abc.Iterator):
        return value
    return _weighed_items(value)


def _weighed_items(items: Iterator[Any]) -> Iterator[Any]:
    total = 0
    for item in items:
        total += _weigh(item, MAX_LENGTH - total, {})     # a fresh memo: ids of freed items are reused
        if total > MAX_LENGTH:
            raise SecurityError(f"a sequence longer than {MAX_LENGTH:,} characters or items is not allowed")
        yield item


def _check_product(left: Any, right: Any) -> None:
    """`a * b` of ints: as many bits as both together, so squaring a 2**2000 twenty times over
    (a chain of inventory vars) would take gigabytes."""
    if isinstance(left, int) and isinstance(right, int) and left and right:
        if left.bit_length() + right.bit_length() > MAX_POWER_BITS + 1:
            raise SecurityError(f"a product of more than {MAX_POWER_BITS} bits is too large a number")


def _no_random(*args: Any, **kwargs: Any) -> Any:
    raise SecurityError("the random filter is not allowed: a release must render the same on every run (or "
                        "every plan would show a change): choose the value, e.g. by the robot's name")


@jinja2.pass_context
def _test_in(context: Any, value: Any, seq: Any) -> bool:
    """Jinja's `in` test, charged like the operator: `select('in', big)` is a loop too."""
    return contained(value, seq, context)


# Tests that read all of a long string or list: a comparison (charged like the operator), or
# islower/isupper (about 25 ns a character of a 4-byte string: 1/4 unit, 4 times a compare's).
_READING_TESTS = {name: 1 for name in ("==", "eq", "equalto", "!=", "ne", ">", "gt", "greaterthan", ">=", "ge",
                                       "<", "lt", "lessthan", "<=", "le")} | {"lower": 4, "upper": 4}


def _charged_test(func: Callable[..., Any], rate: int) -> Callable[..., Any]:
    @jinja2.pass_context
    def test(context: Any, value: Any, *args: Any) -> Any:
        cost = _compare_cost(value, args[0]) if args else _touch_cost(value)
        if cost:
            charge(cost * rate, _budget(context))
        return func(value, *args)
    return test


def _charge_method(text: str | bytes, args: tuple[Any, ...], budget: list[int]) -> None:
    """A str method reads its string (upper, replace, count, find...: up to ~25 ns a character,
    1/4 unit) and its arguments (a list to join: each item weighed in Python first)."""
    cost = len(text) >> _METHOD_SHIFT
    for arg in args:
        if isinstance(arg, _TEXTS):
            cost += len(arg) >> _CHAR_SHIFT
        elif isinstance(arg, _CONTAINERS):
            cost += len(arg) * _ITEM_COST
    if cost:
        charge(cost, budget)


_METHOD_SHIFT = 2


def regex_replace(value: Any, pattern: str, replacement: str = "") -> str:
    """Ansible's regex_replace, bounded: Python's `re` cannot be interrupted outside the main thread
    (inventories are templated in worker threads too), so a pattern that could backtrack for long
    on this value is refused before matching (_REGEX_STEPS), and the result is counted as it is built."""
    text = str(value)
    compiled = re.compile(pattern)
    if len(text) * _backtracking(_sre_parse.parse(pattern), len(text), False) > _REGEX_STEPS:
        raise SecurityError(f"regex_replace pattern {pattern!r} could take too long on a value of {len(text):,} "
                            "characters (nested or many repeats, like `(a+)+` or `.*x.*`): simplify the pattern")
    # matches do not overlap, so all of a group's copies together are at most the text once per reference
    matches = sum(1 for _ in compiled.finditer(text))
    refs = len(_GROUP_REF.findall(replacement))
    _refuse_longer(len(text) + matches * len(replacement) + refs * len(text), "this regex_replace")
    return compiled.sub(replacement, text)


_GROUP_REF = re.compile(r"\\(?:\d|g<)")
_REPEATS = (_sre_parse.MAX_REPEAT, _sre_parse.MIN_REPEAT, _sre_parse.POSSESSIVE_REPEAT)
_REGEX_STEPS = 10**8      # matching steps a pattern may take, at worst: about a second


def _backtracking(items: Any, n: int, repeated: bool) -> int:
    """How many ways, at most, `items` (a parsed pattern) can match at one position of an n-character
    text: each repeat multiplies by its choices, alternatives add. Refused where this does not hold:
    a repeat or `|` inside a repeat ((a+)+, (a|a)*: exponential), a backreference in one."""
    ways = 1
    for op, av in items:
        if op in _REPEATS:
            low, high, sub = av
            many = high > 1
            if repeated and many:
                raise SecurityError("a repeat inside a repeat (like `(a+)+`) is not allowed in regex_replace")
            ways *= (min(high, n) + 1) * _backtracking(sub, n, repeated or many)
        elif op is _sre_parse.BRANCH:
            if repeated:
                raise SecurityError("alternatives inside a repeat (like `(a|ab)*`) are not allowed in regex_replace")
            ways *= sum(_backtracking(alt, n, repeated) for alt in av[1])
        elif op in (_sre_parse.SUBPATTERN, _sre_parse.ASSERT, _sre_parse.ASSERT_NOT, _sre_parse.ATOMIC_GROUP):
            ways *= _backtracking(av if op is _sre_parse.ATOMIC_GROUP else av[-1], n, repeated)
        elif op is _sre_parse.GROUPREF_EXISTS:
            ways *= sum(_backtracking(alt, n, repeated) for alt in av[1:] if alt is not None)
        elif op is _sre_parse.GROUPREF and repeated:
            raise SecurityError("a backreference inside a repeat is not allowed in regex_replace")
        ways = min(ways, _REGEX_STEPS + 1)
    return ways


# applied after the width check of _WIDTH_FILTERS
_FILTER_BOUNDS = {"replace": _bounded_replace, "join": _bounded_join_filter, "indent": _bounded_indent,
                  "wordwrap": _bounded_wordwrap, "sum": _bounded_sum}


# Filters that take longer than 1/4 unit (25 ns) a character of a string, in units per 4
# characters (measured on 4-byte and escaped text, about twice over): most iterate the string
# in Python, a character at a time. Any other filter is charged 1 (a quarter unit a character).
_SLOW_FILTERS = {
    **dict.fromkeys(("urlize", "compose_list"), 160),
    **dict.fromkeys(("map", "select", "reject", "selectattr", "rejectattr"), 96),
    **dict.fromkeys(("sort", "unique", "groupby", "dictsort", "sum"), 64),
    **dict.fromkeys(("min", "max", "wordwrap"), 32),
    **dict.fromkeys(("batch", "slice", "urlencode", "title", "striptags", "wordcount", "pprint"), 16),
    "join": 8,
    **dict.fromkeys(("list", "tojson", "xml", "logrotate_path", "yaml_key", "regex_replace"), 4),
    # and those that read a string's length or an end of it, not all of it: a filter call
    **dict.fromkeys(("length", "count", "first", "last", "default", "d", "string"), 0),
}
# Filters whose result is their value or one of its items, not something new: not charged as built
_PICKING = frozenset({"first", "last", "min", "max", "attr", "default", "d", "string", "random"})


def _weighed_filter(func: Callable[..., Any], name: str = "filter") -> Callable[..., Any]:
    """`func`, its value weighed and its call charged to the render's work first (a string by its
    length, at the filter's rate), and its result checked and charged as built (_built). It takes
    the template context (to find the render's budget) and passes `func` what its marker asks for."""
    first = _FIRST_ARG.get(getattr(func, "jinja_pass_arg", None), None)
    rate = _SLOW_FILTERS.get(name, 1)
    what = f"the result of |{name}"
    picking = name in _PICKING

    @jinja2.pass_context
    def weighed(context: Any, *args: Any, **kwargs: Any) -> Any:
        budget = _budget(context)
        value = None
        if args:
            value = args[0]
            if isinstance(value, _TEXTS):   # most calls (the built-in templates' quoting filters)
                size = len(value)
                if size > MAX_LENGTH:
                    raise SecurityError(_TOO_LONG)
                charge(_FILTER_COST + (size * rate >> 2), budget)
            elif isinstance(value, _CONTAINERS):
                size = weight(value)
                if size > MAX_LENGTH:
                    raise SecurityError(_TOO_LONG)
                charge(size * _WEIGH_COST, budget)      # so `big|length` in a loop is a loop over big
            else:
                charge(_FILTER_COST, budget)
                args = (_lazy_weighed(value), *args[1:])
        result = func(*args, **kwargs) if first is None else func(first(context), *args, **kwargs)
        if result is not value and not picking and isinstance(result, (*_TEXTS, *_CONTAINERS)):
            _built(result, budget, what, new_items=True)
        return result
    weighed._weighed = True  # type: ignore[attr-defined]
    return weighed


# What a filter marked pass_context / pass_eval_context / pass_environment gets first
_FIRST_ARG: dict[Any, Callable[[Any], Any]] = {
    jinja2.utils._PassArg.context: lambda context: context,
    jinja2.utils._PassArg.eval_context: lambda context: context.eval_ctx,
    jinja2.utils._PassArg.environment: lambda context: context.environment,
}


def _copy_markers(src: Callable[..., Any], dst: Callable[..., Any]) -> None:
    """Keep Jinja's pass_context/pass_environment markers: the filter is called the same way."""
    for attr in ("jinja_pass_arg",):
        if hasattr(src, attr):
            setattr(dst, attr, getattr(src, attr))
