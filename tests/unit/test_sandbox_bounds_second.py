"""Issue 18, third round: what a filter builds, what an operation reads, and what a render holds in all.

Each hostile case runs in a child process limited to LITTLE_MEMORY of address space and QUICK seconds:
before the fix, each one there took gigabytes (a MemoryError), or minutes (TIMEOUT), or passed."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

import test_sandbox_bounds
from rosdeploy.sandbox import MAX_BUILT, Sandbox, render_value, value_template

lab = test_sandbox_bounds.lab     # the fixture: the example fleet copied, the vault variables unset
LITTLE_MEMORY, QUICK = test_sandbox_bounds.LITTLE_MEMORY, test_sandbox_bounds.QUICK
TOO_LONG = "longer than 1,000,000 characters"
TOO_MUCH_WORK = "loop steps"
TOO_MUCH_BUILT = f"builds more than {MAX_BUILT // 1_000_000} MB"

outcome = test_sandbox_bounds.bounded_outcome   # in a child limited to LITTLE_MEMORY and QUICK seconds


def assert_refused(said: str, *words: str) -> None:
    assert "SecurityError" in said and any(w in said for w in words), said
    assert "MemoryError" not in said and "Traceback" not in said, said


def cli_in_little_memory(lab: Path, command: str = "validate") -> tuple[int | str, str, float]:
    """`rosdeploy COMMAND` on the lab fleet in a child limited to LITTLE_MEMORY and QUICK seconds."""
    child = ("import resource, sys\n"
             f"resource.setrlimit(resource.RLIMIT_AS, ({LITTLE_MEMORY}, {LITTLE_MEMORY}))\n"
             "from rosdeploy.cli import main\n"
             "sys.exit(main(sys.argv[1:]))\n")
    password = str(lab / "inventory" / ".vault-password")
    extra = ["--out", str(lab / "out")] if command == "render" else []
    began = time.monotonic()
    try:
        done = subprocess.run([sys.executable, "-c", child, command, str(lab / "fleet.yml"),
                               "--vault-password-file", password, *extra], capture_output=True, text=True,
                              timeout=QUICK, cwd=Path(__file__).parents[2])
    except subprocess.TimeoutExpired:
        return "TIMEOUT", "", QUICK
    return done.returncode, done.stdout + done.stderr, time.monotonic() - began


def set_env(lab: Path, value: str) -> None:
    test_sandbox_bounds.set_env(lab, value)


def render(source: str) -> str:
    return render_value(value_template(Sandbox(), source), {})


# ------------------------------------------------------------------ defect 8: what a filter builds

FILTER_AMPLIFIERS = [
    # each tojson doubles the backslashes: 662 MB after eight, more passes took all memory
    "{{ ('\\\\' * 999999)|tojson|tojson|tojson|tojson|tojson|tojson|tojson|tojson|length }}",
    "{{ ('\\\\' * 999999)|tojson|tojson|tojson|tojson|tojson|tojson|tojson|tojson|tojson|tojson|length }}",
    # twelve characters for one, then three for each: 22 s and 806 MB
    "{{ ('😀' * 999999)|urlencode|urlencode|urlencode|urlencode|urlencode|urlencode|urlencode|urlencode"
    "|urlencode|length }}",
    "{{ (\"'\" * 999999)|forceescape|forceescape|forceescape|forceescape|forceescape|length }}",
    "{{ (\"'\" * 999999)|e|string|e|string|e|string|e|string|e|length }}",
    "{{ ('‹' * 999999)|tojson|tojson|tojson|tojson|tojson|tojson|length }}",
    "{{ (\"'\" * 999999)|xml|xml|xml|xml|xml|length }}",
    "{{ ('\"' * 999999)|yaml_str|yaml_str|yaml_str|yaml_str|yaml_str|yaml_str|yaml_str|yaml_str|length }}",
]


@pytest.mark.parametrize("source", FILTER_AMPLIFIERS)
def test_a_filter_result_longer_than_the_bound_is_refused(source: str) -> None:
    said = outcome(source)
    assert_refused(said, TOO_LONG)
    assert "the result of |" in said, said       # says which filter


def test_a_chain_of_doubling_filters_is_a_clean_problem_at_its_key(capsys: pytest.CaptureFixture,
                                                                    lab: Path) -> None:
    took = test_sandbox_bounds.refused_at_key(capsys, lab, "validate", FILTER_AMPLIFIERS[0], (TOO_LONG,))
    assert took < QUICK, took
    set_env(lab, FILTER_AMPLIFIERS[2])
    code, text, took = cli_in_little_memory(lab, "render")
    assert code == 2 and "services.driver.environment.X" in text and TOO_LONG in text, text
    assert "Traceback" not in text and "MemoryError" not in text and took < QUICK, (took, text)
    assert not (lab / "out").exists()


def test_a_filter_that_reads_a_long_string_slowly_is_charged_before_it_runs() -> None:
    """compose_list iterates a string a character at a time (2.5 us each): 999,999 of them in one call."""
    said = outcome("{% set big = '😀' * 999999 %}{{ big|compose_list|length }}", "file")
    assert_refused(said, TOO_MUCH_WORK)


# ------------------------------------------------------------------ defect 9: work by the characters read

LONG_READS = [
    # 100,000 reversals of a million characters: ~300 s, under the budget
    "{% set big = '😀' * 999999 %}{% for i in range(100) %}{% for j in range(1000) %}{% set x = big[::-1] %}"
    "{% endfor %}{% endfor %}done",
    "{% set big = '😀' * 999999 %}{% for i in range(99999) %}{% set x = big[1:] %}{% endfor %}done",
    # reading, building nothing: comparisons, a test, a method, a filter
    "{% set a = '😀' * 999999 %}{% set b = '😀' * 999999 %}{% for i in range(99999) %}{% if a == b %}{% endif %}"
    "{% endfor %}done",
    "{% set a = '😀' * 999999 %}{% set b = '😀' * 999999 %}{% for i in range(99999) %}{% if a <= b %}{% endif %}"
    "{% endfor %}done",
    "{% set a = ['😀' * 99999] * 10 %}{% set b = ['😀' * 99999] * 10 %}{% for i in range(99999) %}"
    "{% if a == b %}{% endif %}{% endfor %}done",
    "{% set a = '😀' * 999999 %}{% set b = '😀' * 999999 %}{% for i in range(99999) %}{% if a is eq b %}{% endif %}"
    "{% endfor %}done",
    "{% set big = '😀' * 999999 %}{% for i in range(99999) %}{% if big is lower %}{% endif %}{% endfor %}done",
    "{% set big = '😀' * 999999 %}{% for i in range(99999) %}{% set n = big.count('x') %}{% endfor %}done",
    "{% set big = '😀' * 999999 %}{% for i in range(99999) %}{% set n = big|wordcount %}{% endfor %}done",
    "{% set a = '😀' * 99999 %}{% set l = [a ~ 1, a ~ 2, a ~ 3, a ~ 4, a ~ 5, a ~ 6, a ~ 7, a ~ 8, a ~ 9] %}"
    "{% set b = a ~ 0 %}{% for i in range(99999) %}{% if b in l %}{% endif %}{% endfor %}done",
]


@pytest.mark.parametrize("source", LONG_READS)
def test_an_operation_on_a_long_string_is_charged_by_its_length(source: str) -> None:
    assert_refused(outcome(source, "file"), TOO_MUCH_WORK, TOO_MUCH_BUILT)


def test_a_slow_inventory_template_is_refused_where_it_is_used(lab: Path) -> None:
    (lab / "inventory" / "group_vars" / "all" / "extra.yml").write_text(
        "slow: \"{% set big = '😀' * 999999 %}{% for i in range(100) %}{% for j in range(1000) %}"
        "{% set x = big[::-1] %}{% endfor %}{% endfor %}north\"\n")
    set_env(lab, "{{ slow }}")
    code, text, took = cli_in_little_memory(lab)
    assert code == 2 and "slow: " in text and "services.driver.environment.X" in text, text
    assert TOO_MUCH_WORK in text or TOO_MUCH_BUILT in text, text
    assert "Traceback" not in text and took < QUICK, (took, text)


# ------------------------------------------------------------------ defect 10: what one render builds in all

BIG = "'😀' * 999000"
MANY_LONG = [
    # 400 strings of a million characters in one list literal: 1.45 GB
    "{% set big = " + BIG + " %}{% set l = [" + ", ".join(f"big ~ '{i}'" for i in range(400)) + "] %}"
    "{% if l %}ok{% endif %}",
    "{% set big = " + BIG + " %}{% set t = (" + ", ".join(f"big ~ '{i}'" for i in range(400)) + ") %}"
    "{{ t|length }}",
    "{% set big = " + BIG + " %}{% set d = {" + ", ".join(f"'{i}': big[{i}:]" for i in range(400)) + "} %}"
    "{{ d|length }}",
    # a macro recursing with a long argument it builds: each level holds its own
    "{% macro m(s, n) %}{% if n %}{{ m(s ~ n, n - 1)|length }}{% endif %}{% endmacro %}{{ m(" + BIG + ", 150) }}",
    "{% macro m(s, n) %}{% if n %}{{ m(s.upper(), n - 1)|length }}{% endif %}{% endmacro %}{{ m(" + BIG + ", 150) }}",
    "{% macro m(s, n) %}{% if n %}{{ m(s|reverse, n - 1)|length }}{% endif %}{% endmacro %}{{ m(" + BIG + ", 150) }}",
    # a block's output held by each level
    "{% set big = " + BIG + " %}{% macro m(n) %}{% if n %}{% set x %}{{ big }}{% endset %}{{ m(n - 1) }}{% endif %}"
    "{% endmacro %}{{ m(150) }}",
]


@pytest.mark.parametrize("source", MANY_LONG)
def test_values_under_the_bound_cannot_add_up_to_gigabytes(source: str) -> None:
    assert_refused(outcome(source, "file"), TOO_MUCH_BUILT)


def test_a_literal_longer_than_the_bound_is_refused() -> None:
    said = outcome("{% set a = 'x' * 600000 %}{{ [a, a]|length }}")
    assert_refused(said, "this list would be longer than 1,000,000")


def test_a_fleet_value_that_builds_a_long_list_is_a_clean_problem(lab: Path) -> None:
    set_env(lab, "{% set big = " + BIG + " %}{{ [" + ", ".join(f"big ~ {i}" for i in range(150)) + "]|length }}")
    code, text, took = cli_in_little_memory(lab)
    assert code == 2 and "services.driver.environment.X" in text and TOO_MUCH_BUILT in text, text
    assert "Traceback" not in text and "MemoryError" not in text and took < QUICK, (took, text)


def test_an_inventory_list_of_long_strings_is_refused_where_it_is_used(lab: Path) -> None:
    items = ", ".join(f"big ~ {i}" for i in range(150))
    data = {"big": "{{ '😀' * 999000 }}", "many": "{{ [" + items + "] }}"}
    (lab / "inventory" / "group_vars" / "all" / "extra.yml").write_text(yaml.safe_dump(data))
    set_env(lab, "{{ many|length }}")
    code, text, took = cli_in_little_memory(lab)
    assert code == 2 and "many: " in text and TOO_MUCH_BUILT in text, text
    assert "Traceback" not in text and "MemoryError" not in text and took < QUICK, (took, text)


# ------------------------------------------------------------------ ordinary use is unchanged

@pytest.mark.parametrize("source, expect", [
    ("{{ 'abc'[::-1] }}{% set s = 'abcdef' %}{{ s[1:3] }}{{ s[::2] }}", "cbabcace"),
    ("{% set a = 'x' %}{{ a == 'x' }}{{ a != a }}{{ a < 'y' }}{{ 1 < 2 < 3 }}{{ a in 'xy' }}{{ a not in [a] }}",
     "TrueFalseTrueTrueTrueFalse"),
    ("{% set a, b = 1, 2 %}{{ a }}{{ b }}{{ [a, b] }}{{ (a,) }}{{ {'k': [a, (b,)]} }}", "12[1, 2](1,){'k': [1, (2,)]}"),
    ("{% set l = [1, 2] %}{{ l == [1, 2] }}{{ [l] == [[1, 2]] }}{{ l is eq [1, 2] }}{{ 'a' is lower }}",
     "TrueTrueTrueTrue"),
    ("{{ [1, 2, 3]|select('gt', 1)|list }}{{ [1, 2]|select('in', [2])|list }}", "[2, 3][2]"),
    ("{{ 'a b'.split() }}{{ 'ab'.upper() }}{{ '{}-{}'.format(1, 2) }}{{ 'x,y'|replace(',', ';') }}",
     "['a', 'b']AB1-2x;y"),
    ("{{ 'a\"'|tojson }}{{ 'a&b'|urlencode }}{{ '<'|e }}{{ ['b', 'a']|sort|join }}", '"a\\""a%26b&lt;ab'),
    ("{% macro m(s, n) %}{% if n %}{{ m(s ~ n, n - 1) }}{% else %}{{ s }}{% endif %}{% endmacro %}{{ m('x', 3) }}",
     "x321"),
])
def test_ordinary_uses_still_work(source: str, expect: str) -> None:
    assert Sandbox().from_string(source).render() == expect


def test_a_long_value_within_the_bounds_still_renders() -> None:
    """A 400,000-character value sliced, compared, escaped and joined a few times over is allowed."""
    source = ("{% set s = 'x' * 400000 %}{% for i in range(20) %}{% if s[1:] != s %}{{ '' }}{% endif %}"
              "{% set t = s|e ~ s.upper() %}{% endfor %}{{ (s ~ s)|length }}")
    began = time.monotonic()
    assert Sandbox().from_string(source).render() == "800000"
    assert time.monotonic() - began < 2
    assert len(render("{{ ('a' * 300000)|tojson|tojson|tojson }}")) == 300_014
