"""Values that grow past what one operator check sees: refused quickly as a TemplateError (exit 2, a
file:key problem), never a hang or an internal MemoryError; ordinary uses still work."""
from __future__ import annotations

import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Sequence

import jinja2
import pytest
import yaml

from rosdeploy.cli import main
from rosdeploy.sandbox import Layered, Sandbox, describe, render_value, value_template

DATA = Path(__file__).resolve().parent / "data" / "fleet"
QUICK = 5.0     # seconds: each of these took over 20 s, or 4 GB, before
OURS = ("is not allowed", "longer than 1,000,000 characters", "would exceed 1000000 items")  # the sandbox's words


@pytest.fixture
def lab(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    shutil.copytree(DATA, tmp_path / "lab")
    monkeypatch.delenv("ROSDEPLOY_VAULT_PASSWORD", raising=False)
    monkeypatch.delenv("ROSDEPLOY_VAULT_PASSWORD_FILE", raising=False)
    return tmp_path / "lab"


def cli(capsys: pytest.CaptureFixture, lab: Path, command: str) -> tuple[int, str, float]:
    began = time.monotonic()
    password = str(lab / "inventory" / ".vault-password")
    extra = ["--out", str(lab / "out")] if command == "render" else []
    code = main([command, str(lab / "fleet.yml"), "--vault-password-file", password, *extra])
    captured = capsys.readouterr()
    return code, captured.out + captured.err, time.monotonic() - began


def set_env(lab: Path, value: str) -> None:
    path = lab / "fleet.yml"
    data = yaml.safe_load(path.read_text())
    data["services"]["driver"].setdefault("environment", {})["X"] = value
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def refused_at_key(capsys: pytest.CaptureFixture, lab: Path, command: str, value: str,
                   words: Sequence[str]) -> float:
    """`value` in a fleet environment value: exit 2 at its file:key with one of `words`, no crash, nothing
    written; the seconds it took."""
    set_env(lab, value)
    code, text, took = cli(capsys, lab, command)
    assert code == 2, text
    assert "fleet.yml" in text and "services.driver.environment.X" in text, text
    assert any(w in text for w in words), text
    assert not any(crash in text for crash in ("Traceback", "internal error", "MemoryError", "RecursionError")), text
    assert not (lab / "out").exists()
    return took


def render(source: str, **variables: object) -> str:
    return render_value(value_template(Sandbox(), source), variables)


def refused(source: str, **variables: object) -> str:
    began = time.monotonic()
    with pytest.raises(jinja2.TemplateError) as caught:
        render(source, **variables)
    assert time.monotonic() - began < QUICK
    message = str(caught.value)
    assert any(words in message for words in OURS), message   # not a MemoryError that happened to be quick
    return message


AMPLIFIERS = [
    "{{ ('a'*100000)|replace('', 'b'*10000) }}",
    "{{ ('a'*100000).replace('', 'b'*10000) }}",
    "{{ ('a'*100000)|replace('a', 'b'*100000) }}",
    "{{ ('a'*100000)|list|join('b'*100000) }}",
    "{{ ('b'*100000).join(('a'*100000)|list) }}",
    "{{ [[1]*100000]*100000 }}",
    "{{ [('a'*1000,)*1000]*1000 }}",
    "{{ '{x:>{w}}'.format(x='a', w=999999999) }}",
    "{{ '{:>{}}'.format('a', 999999999) }}",
    "{{ '{x:>{w}}'.format_map({'x': 'a', 'w': 999999999}) }}",
    "{{ ('{0}' * 100000).format('a' * 100000) }}",
    "{{ ('%(a)s' * 100000) % {'a': 'x' * 100000} }}",
    "{{ ('%(a)s' * 100000)|format(a='x' * 100000) }}",
    "{{ 'a'.center(999999999) }}",
    "{{ 'a'.ljust(999999999) }}",
    "{{ 'a'.rjust(999999999) }}",
    "{{ 'a'.zfill(999999999) }}",
    "{{ ('\t'*1000000).expandtabs(1000000) }}",
    "{{ ('a'*1000000).translate({97: 'b'*1000000}) }}",
    "{{ ('\n'*1000000)|indent('b'*1000000, blank=True) }}",
    "{{ ('\n'*1000000)|indent(1000000, blank=True) }}",
    "{{ ('a '*500000)|wordwrap(1, wrapstring='b'*1000000) }}",
    "{{ [1]|batch(999999999, 0)|list }}",
    "{{ [1]|slice(999999999)|list }}",
    "{{ ('a'.encode() * 1000000) * 1000 }}",
    "{% set a = [1, 1] %}" + "{% set a = [a, a] %}" * 60 + "{{ a }}",
    "{% set a = [1, 1] %}" + "{% set a = [a, a] %}" * 60 + "{{ 'x' ~ a }}",
    "{% set a = [1, 1] %}" + "{% set a = [a, a] %}" * 60 + "{{ '{}'.format(a) }}",
    "{% set a = 'ab' %}" + "{% set a = a ~ a %}" * 60 + "{{ a }}",
    "{% set a = 'ab' %}" + "{% set a = a + a %}" * 60 + "{{ a }}",
    "{% set a = ['ab'] %}" + "{% set a = a + a %}" * 60 + "{{ a }}",
    # a filter writes its value out itself, past every operator (hung before)
    "{% set a = [1, 1] %}" + "{% set a = [a, a] %}" * 60 + "{{ a|tojson }}",
    "{% set a = [1, 1] %}" + "{% set a = [a, a] %}" * 60 + "{{ a|string|length }}",
    "{% set a = [1, 1] %}" + "{% set a = [a, a] %}" * 60 + "{{ a|pprint }}",
    "{{ ([range(1)] * 1000000)|string|length }}",     # an object writes out longer than 1 character
]


@pytest.mark.parametrize("source", AMPLIFIERS)
def test_an_amplifying_value_is_refused_quickly(source: str) -> None:
    refused(source)


def test_a_long_output_is_refused_as_too_long() -> None:
    assert "a value longer than 1,000,000 characters" in refused("{{ a }}{{ a }}", a="x" * 600_000)


@pytest.mark.parametrize("source, expect", [
    ("{{ 'a-b'|replace('-', '_') }}", "a_b"),
    ("{{ 'a-b'.replace('-', '_') }}", "a_b"),
    ("{{ 'aaa'|replace('a', 'b', 2) }}", "bba"),
    ("{{ [1, 2]|join(',') }}", "1,2"),
    ("{{ ','.join(['a', 'b']) }}", "a,b"),
    ("{{ [{'n': 'a'}, {'n': 'b'}]|join('-', attribute='n') }}", "a-b"),
    ("{{ '{:>5}'.format('x') }}", "    x"),
    ("{{ '{0}-{x}'.format(1, x=2) }}", "1-2"),
    ("{{ '{x}'.format_map({'x': 3}) }}", "3"),
    ("{{ [0]*3 }}", "[0, 0, 0]"),
    ("{{ ([0]*1000000)|length }}", "1000000"),
    ("{{ 'ab' * 3 }}", "ababab"),
    ("{{ 1 + 2 }}", "3"),
    ("{{ 'a' + 'b' }}", "ab"),
    ("{{ [1] + [2] }}", "[1, 2]"),
    ("{{ 'a' ~ 1 ~ [2] }}", "a1[2]"),
    ("{{ '%s-%05d' % ('a', 3) }}", "a-00003"),
    ("{{ '%(a)s' % {'a': 1} }}", "1"),
    ("{{ '%-4s|'|format('x') }}", "x   |"),
    ("{{ 'x'.center(5) ~ 'x'.ljust(2) ~ 'x'.rjust(2) ~ '7'.zfill(3) }}", "  x  x  x007"),
    ("{{ 'a\tb'.expandtabs(4) }}", "a   b"),
    ("{{ 'ab'.translate({97: 'xy'}) }}", "xyb"),
    ("{{ 'a\nb'|indent(2, first=True) }}", "  a\n  b"),
    ("{{ 'a b c'|wordwrap(2) }}", "a\nb\nc"),
    ("{{ [1, 2, 3]|batch(2, 0)|list }}", "[[1, 2], [3, 0]]"),
    ("{{ [1, 2, 3]|slice(2)|list }}", "[[1, 2], [3]]"),
    ("{% set a = [1] %}{% set a = [a, a] %}{{ a }}", "[[1], [1]]"),
    ("{{ [1, 2]|sum }}", "3"),
    ("{{ [[1], [2, 3]]|sum(start=[]) }}", "[1, 2, 3]"),
    ("{{ [(1,), (2,)]|sum(start=(0,)) }}", "(0, 1, 2)"),
    ("{{ [{'a': [1]}, {'a': [2]}]|sum('a', []) }}", "[1, 2]"),
])
def test_ordinary_uses_still_work(source: str, expect: str) -> None:
    assert render(source) == expect


def test_a_sum_of_lists_is_refused_before_it_is_built() -> None:
    """The start is not the filter's input, so nothing weighed it: the sum was built, then refused
    only where written (and `|length` of it passed)."""
    assert "this sum would be longer" in refused("{{ [[1]*600000]|sum(start=[1]*600000)|length }}")
    with pytest.raises(jinja2.TemplateError, match=r'can only concatenate list \(not "tuple"\)'):
        render("{{ [[1], (2,)]|sum(start=[]) }}")     # as Python's sum says it


def test_a_sum_of_many_lists_takes_linear_time() -> None:
    """Python's sum copies the total at each `+`: 200,000 one-item lists took 40 s."""
    began = time.monotonic()
    assert render("{{ ([[1]]*200000)|sum(start=[])|length }}") == "200000"
    assert time.monotonic() - began < 2


def test_a_long_value_within_the_bound_renders() -> None:
    assert len(render("{{ a }}{{ a }}", a="x" * 400_000)) == 800_000
    assert len(render("{{ a|replace('x', 'yy') }}", a="x" * 400_000)) == 800_000


# ------------------------------------------------------------------ via the CLI

@pytest.mark.parametrize("payload", [
    "{{ ('a'*100000)|replace('', 'b'*10000) }}",
    "{{ ('a'*100000)|list|join('b'*100000) }}",
    "{{ [[1]*100000]*100000 }}",
    "{{ '{x:>{w}}'.format(x='a', w=999999999) }}",
])
@pytest.mark.parametrize("command", ["validate", "check", "render"])
def test_a_fleet_value_that_amplifies_is_a_clean_problem(capsys: pytest.CaptureFixture, lab: Path,
                                                         payload: str, command: str) -> None:
    took = refused_at_key(capsys, lab, command, payload, OURS)
    assert took < QUICK * 2, took
    assert not (lab / "out").exists()


@pytest.mark.parametrize("link", [
    # (`'{{ d }}{{ d }}'`, text, is bounded where inventory/templating.py renders text: test_templating_bounds.py)
    "'{{{{ {p} ~ {p} }}}}'",                     # one expression: kept as its value, not rendered text
    "'{{{{ {p} + {p} }}}}'",
    "'{{{{ [{p}, {p}] }}}}'",                    # a list holding the previous one twice
    "\"{{{{ '{{}}{{}}'.format({p}, {p}) }}}}\"",
    "\"{{{{ '%s%s' % ({p}, {p}) }}}}\"",
])
def test_an_inventory_doubling_chain_fails_fast(capsys: pytest.CaptureFixture, lab: Path, link: str) -> None:
    lines = ["d0: ab"] + [f"d{i}: " + link.format(p=f"d{i - 1}") for i in range(1, 61)]
    (lab / "inventory" / "host_vars" / "r2.yml").write_text("\n".join(lines) + "\n")
    set_env(lab, "{{ vars.d60 if inventory_hostname == 'r2' else 'x' }}")
    code, text, took = cli(capsys, lab, "validate")
    assert code == 2, text
    assert "services.driver.environment.X" in text and "1,000,000 characters" in text, text
    assert "Traceback" not in text and "internal error" not in text and "MemoryError" not in text, text
    assert took < QUICK * 2, took


# ------------------------------------------------------------------ issue 18, second round: in a subprocess
# with little memory and a deadline, so a fix that regresses fails here instead of hanging or swapping

LITTLE_MEMORY = 600 * 2**20     # bytes of address space: Python and Jinja take about 150 MB of it
_CHILD = """
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, ({limit}, {limit}))
from rosdeploy.render import FILTERS
from rosdeploy.sandbox import Layered, Sandbox, describe, render_value, value_template
env = Sandbox()
env.add_filters(FILTERS)     # the sandbox as the renderer makes it (xml, yaml_str...)
source = sys.stdin.read()
try:
    if sys.argv[1] == "file":
        print("OK", len(env.from_string(source).render(big=list(range(99999)))))
    else:
        print("OK", len(render_value(value_template(env, source), {{}})))
except MemoryError:
    print("MemoryError")
except Exception as exc:
    print(type(exc).__name__, exc)
"""


def bounded_outcome(source: str, kind: str = "value") -> str:
    """What rendering `source` says in a child process limited to LITTLE_MEMORY and QUICK seconds."""
    try:
        done = subprocess.run([sys.executable, "-c", _CHILD.format(limit=LITTLE_MEMORY), kind], input=source,
                              capture_output=True, text=True, timeout=QUICK, cwd=Path(__file__).parents[2])
    except subprocess.TimeoutExpired:
        return "TIMEOUT"
    return done.stdout + done.stderr


LAZY_AMPLIFIERS = [
    "{{ range(1000)|map('string')|map('center', 999999)|list|length }}",
    "{{ range(3000)|map('string')|map('center', 999999)|list|length }}",
    "{{ range(3000)|map('string')|map('center', 999999)|join|length }}",
    "{{ range(3000)|map('string')|map('center', 999999)|unique|list|length }}",
    "{{ range(3000)|map('string')|map('center', 999999)|sort|length }}",
    "{{ ''.join(range(3000)|map('string')|map('center', 999999))|length }}",
]


@pytest.mark.parametrize("source", LAZY_AMPLIFIERS)
def test_a_lazy_sequence_is_weighed_as_it_is_taken(source: str) -> None:
    """`list`, `unique`, `join`... built the whole list (1 GB, or MemoryError) before anything weighed it."""
    said = bounded_outcome(source)
    assert "SecurityError" in said and "longer than 1,000,000" in said, said


def test_template_output_is_counted_as_it_comes() -> None:
    """_bounded_concat held every piece (1 GB here) before adding up their lengths."""
    said = bounded_outcome('{% for i in range(1000) %}{{ "x" * 999999 }}{% endfor %}', "file")
    assert "SecurityError" in said and "longer than 1,000,000" in said, said


@pytest.mark.parametrize("source", [
    "{% for i in range(99999) %}{% for j in range(99999) %}{% endfor %}{% endfor %}x",
    "{% for i in range(99999) %}{% for j in range(99999) if j < 0 %}{% endfor %}{% endfor %}x",
    "{% for i in range(99999) %}{% for j in range(99999)|map('int') %}{% endfor %}{% endfor %}x",
    "{% for i in range(99999) %}{% if i in big %}{% endif %}{% endfor %}x",
    "{% for i in range(99999) %}{% if i not in big %}{% endif %}{% endfor %}x",
    "{% for i in range(99999) %}{{ big|length }}{% endfor %}x",
    "{% for i in range(2) recursive %}{% if loop.depth < 40 %}{{ loop(range(2)) }}{% endif %}{% endfor %}",
    "{{ range(99999)|select('in', big)|list|length }}",
    "{{ range(99999)|reject('in', big)|list|length }}",
    # a macro's body is charged each call: written once, called 100,000 times
    "{% macro m(x) %}" + "{{ x }}" * 5000 + "{% endmacro %}{% for i in range(100000) %}{{ m(i)|length }}{% endfor %}",
    "{% macro m() %}{{ caller() }}{% endmacro %}{% for i in range(100000) %}{% call m() %}" + "{{ i }}" * 5000
    + "{% endcall %}{{ '' }}{% endfor %}",
])
def test_a_template_file_that_loops_too_long_is_refused(source: str) -> None:
    """No output, so no output bound: these ran for hours (or forever)."""
    said = bounded_outcome(source, "file")
    assert "SecurityError" in said and "loop steps" in said, said


def test_a_quadratic_in_test_in_one_value_is_refused() -> None:
    said = bounded_outcome("{{ range(99999)|select('in', range(99999)|list)|list|length }}")
    assert "SecurityError" in said and "loop steps" in said, said


@pytest.mark.parametrize("source, expect", [
    ("{% for i in range(1000) %}{% for j in range(1000) %}{% endfor %}{% endfor %}x", "x"),
    ("{% for i in range(3) if i != 1 %}{{ i }}{% endfor %}", "02"),
    ("{% for i in [1, [2, [3]]] recursive %}{% if i is iterable %}{{ loop(i) }}{% else %}{{ i }}{% endif %}"
     "{% endfor %}", "123"),
    ("{{ 2 in [1, 2] }}{{ 'b' not in 'abc' }}{{ 'k' in {'k': 1} }}", "TrueFalseTrue"),
    ("{{ [1, 2, 3]|select('in', [1, 3])|list }}", "[1, 3]"),
    ("{{ range(3)|map('string')|join('-') }}", "0-1-2"),
    ("{{ range(3)|map('string')|unique|list }}", "['0', '1', '2']"),
    ("{{ ''.join(range(3)|map('string')) }}", "012"),
    ("{{ dict([('a', 1)]) }}", "{'a': 1}"),
    ("{{ (2 ** 2000 * 2 ** 2000)|string|length }}", "1205"),
    ("{{ [1, 'a', none, 1.5, true, (2,), {'k': [3]}] }}", "[1, 'a', None, 1.5, True, (2,), {'k': [3]}]"),
    ("{% macro m(x) %}[{{ x }}]{% endmacro %}{% for i in range(3) %}{{ m(i) }}{% endfor %}", "[0][1][2]"),
    ("{% macro m(x) %}[{{ x }}{{ caller() }}]{% endmacro %}{% call m(2) %}in{% endcall %}", "[2in]"),
])
def test_ordinary_loops_and_sequences_still_work(source: str, expect: str) -> None:
    assert jinja2_file(source) == expect


def jinja2_file(source: str) -> str:
    return Sandbox().from_string(source).render()


@pytest.mark.parametrize("source", [
    "{{ (2 ** 2000) * (2 ** 2000) * (2 ** 2000) }}",
    "{{ (2 ** 2040) * (2 ** 2040) * (2 ** 100) }}",
])
def test_a_product_of_huge_ints_is_refused(source: str) -> None:
    with pytest.raises(jinja2.TemplateError, match="too large a number"):
        render(source)


@pytest.mark.parametrize("source", [
    "{{ range }}", "{{ ''.upper }}", "{{ [range] }}", "{{ {'f': range} }}", "{{ range(3)|map('string') }}",
    "{{ 'x' ~ range }}", "{{ '{}'.format(range) }}", "{{ [1, 2]|random }}", "{{ dict }}",
])
def test_an_output_that_differs_on_every_run_is_refused(source: str) -> None:
    """`<function safe_range at 0x7fd...>` and `|random` changed the release digest on every run."""
    with pytest.raises(jinja2.TemplateError) as caught:
        render(source)
    assert "memory address" in str(caught.value) or "random filter is not allowed" in str(caught.value)


def test_objects_that_write_the_same_text_every_run_still_write() -> None:
    assert render("{{ vars }}|{{ range(2) }}", vars=Layered({"a": 1})) == "<1 vars>|range(0, 2)"


def test_a_memory_error_says_what_to_do() -> None:
    text = describe(MemoryError())
    assert "memory" in text and "smaller" in text and "()" not in text, text


DEEP = 3000    # levels: Jinja's parser takes ~12 frames a level, Python's stack 1,000 frames


@pytest.mark.parametrize("source", [
    "{{ " + "[" * DEEP + "1" + "]" * DEEP + " }}",
    "{{ " + "(" * DEEP + "1" + ")" * DEEP + " }}",
    "{{ " + "-" * DEEP + "1 }}",
    "{{ " + " + ".join(["1"] * DEEP) + " }}",
    "{{ 1" + "|string" * DEEP + " }}",
    "{% if 1 %}" * DEEP + "x" + "{% endif %}" * DEEP,
    "{{ x" + ".y" * 300 + " }}",     # within Python's stack, but Jinja took 4 s to compile it
], ids=["lists", "parentheses", "minus-signs", "a-long-sum", "filters", "ifs", "attributes"])
@pytest.mark.parametrize("command", ["validate", "render"])
def test_a_fleet_value_that_nests_too_deeply_is_a_syntax_error(capsys: pytest.CaptureFixture, lab: Path,
                                                                source: str, command: str) -> None:
    took = refused_at_key(capsys, lab, command, source, ("nest too deeply",))
    assert took < QUICK / 2, took     # the attribute chain: 4 s before the nesting bound


def test_a_template_file_that_nests_too_deeply_names_the_file(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "templates").mkdir()
    (lab / "templates" / "compose.yml.j2").write_text("x: {{ " + "(" * DEEP + "1" + ")" * DEEP + " }}\n")
    (lab / "fleet.yml").write_text((lab / "fleet.yml").read_text() + "templates: templates\n")
    code, text, _ = cli(capsys, lab, "render")
    assert code == 2, text
    assert "compose.yml.j2:1:" in text and "nest too deeply" in text, text
    assert "Traceback" not in text and "internal error" not in text, text
    assert not (lab / "out").exists()


@pytest.mark.parametrize("nested", ["[" * DEEP + "1" + "]" * DEEP, "x" + ".y" * 300],
                         ids=["lists", "attributes"])
def test_an_inventory_var_that_nests_too_deeply_is_refused_where_it_is_used(capsys: pytest.CaptureFixture,
                                                                             lab: Path, nested: str) -> None:
    # one whole expression: inventory values compile it with compile_expression, which has no _parse
    (lab / "inventory" / "host_vars" / "r2.yml").write_text(f"deep: '{{{{ {nested} }}}}'\n")
    set_env(lab, "{{ deep | default('x') if inventory_hostname == 'r2' else 'x' }}")
    code, text, took = cli(capsys, lab, "validate")
    assert code == 2, text
    assert "r2.yml:1: deep:" in text and "robot 'r2'" in text and "nest too deeply" in text, text
    assert "Traceback" not in text and "internal error" not in text, text
    assert took < QUICK / 2, took      # the attribute chain: 4 s per robot before the nesting bound
