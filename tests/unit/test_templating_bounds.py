"""Inventory templates a hostile or careless vars file can write: bounded in time and size (issue 18)."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from rosdeploy.cli import main
from rosdeploy.inventory.templating import HostVars

import test_sandbox_bounds

lab = test_sandbox_bounds.lab     # the fixture: the example fleet copied, the vault variables unset
LITTLE_MEMORY, QUICK = test_sandbox_bounds.LITTLE_MEMORY, test_sandbox_bounds.QUICK


def validate(capsys: pytest.CaptureFixture, lab: Path) -> tuple[int, str, float]:
    began = time.monotonic()
    password = str(lab / "inventory" / ".vault-password")
    code = main(["validate", str(lab / "fleet.yml"), "--vault-password-file", password])
    out = capsys.readouterr()
    return code, out.out + out.err, time.monotonic() - began


def vars_file(lab: Path, lines: list[str]) -> None:
    (lab / "inventory" / "group_vars" / "all" / "extra.yml").write_text("\n".join(lines) + "\n")


def test_a_long_chain_of_unused_vars_costs_one_compile_per_value(capsys: pytest.CaptureFixture, lab: Path) -> None:
    # Each top-level read climbed the chain until Python's stack ran out, and compiled every
    # value again on the way: 2,000 links took minutes.
    vars_file(lab, [f"v{i}: '{{{{ v{i + 1} }}}}'" for i in range(2000)] + ["v2000: end"])
    code, text, took = validate(capsys, lab)
    assert code == 0 and "Traceback" not in text, text
    assert took < 20, took


def test_a_doubling_chain_is_refused_where_it_is_used(capsys: pytest.CaptureFixture, lab: Path) -> None:
    vars_file(lab, ["d0: ab"] + [f"d{i + 1}: '{{{{ d{i} }}}}{{{{ d{i} }}}}'" for i in range(60)])
    code, text, _ = validate(capsys, lab)
    assert code == 0, text      # nothing uses them: harmless, as in Ansible
    fleet = lab / "fleet.yml"
    data = yaml.safe_load(fleet.read_text())
    data["services"]["driver"].setdefault("environment", {})["X"] = "{{ d40 }}"
    fleet.write_text(yaml.safe_dump(data, sort_keys=False))
    code, text, took = validate(capsys, lab)     # 2**41 characters: memory, then MemoryError
    assert code == 2 and "d19: " in text and "longer than 1,000,000 characters" in text, text
    assert "Traceback" not in text and took < 20, (took, text)


def use_in_fleet(lab: Path, value: str) -> None:
    fleet = lab / "fleet.yml"
    data = yaml.safe_load(fleet.read_text())
    data["services"]["driver"].setdefault("environment", {})["X"] = value
    fleet.write_text(yaml.safe_dump(data, sort_keys=False))


@pytest.mark.parametrize("line, words", [
    # Python's re backtracks for ever on this, and cannot be interrupted outside the main thread
    ("""r: "{{ ('a' * 30 ~ '!')|regex_replace('^(a+)+$', 'x') }}\"""", "a repeat inside a repeat"),
    ("""r: "{{ ('a' * 30 ~ '!')|regex_replace('^(a|a)*$', 'x') }}\"""", "alternatives inside a repeat"),
    ("""r: "{{ ('a' * 9000)|regex_replace('.*a.*b', 'x') }}\"""", "could take too long"),
    # 400 million characters, built before anything weighed them
    ("""r: "{{ ('a' * 20000)|regex_replace('', 'b' * 20000) }}\"""", "longer than 1,000,000"),
])
def test_a_regex_replace_that_backtracks_or_grows_is_refused(lab: Path, line: str, words: str) -> None:
    vars_file(lab, [line])
    use_in_fleet(lab, "{{ vars.r }}")
    code, text = validate_in_little_memory(lab)
    assert code == 2 and "r: " in text and words in text, text
    assert "Traceback" not in text and "MemoryError" not in text, text


def validate_in_little_memory(lab: Path) -> tuple[int | str, str]:
    """`rosdeploy validate` in a child limited to LITTLE_MEMORY and QUICK * 2 seconds."""
    child = ("import resource, sys\n"
             f"resource.setrlimit(resource.RLIMIT_AS, ({LITTLE_MEMORY}, {LITTLE_MEMORY}))\n"
             "from rosdeploy.cli import main\n"
             "sys.exit(main(sys.argv[1:]))\n")
    password = str(lab / "inventory" / ".vault-password")
    try:
        done = subprocess.run([sys.executable, "-c", child, "validate", str(lab / "fleet.yml"),
                               "--vault-password-file", password], capture_output=True, text=True,
                              timeout=QUICK * 2, cwd=Path(__file__).parents[2])
    except subprocess.TimeoutExpired:
        return "TIMEOUT", ""
    return done.returncode, done.stdout + done.stderr


def test_regex_replace_still_replaces() -> None:
    from rosdeploy.sandbox import regex_replace
    assert regex_replace("/a/b/c", r"^(.*)/[^/]*$", r"\1") == "/a/b"
    assert regex_replace("amr-01.site", r"\.site$") == "amr-01"
    assert regex_replace("a-b", "(?P<x>-)", r"[\g<x>]") == "a[-]b"
    assert regex_replace(12, "1", "x") == "x2"


def test_squaring_a_huge_int_in_a_chain_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    """A value that is one `{{ }}` keeps its int: each link squared the last (gigabytes by a20)."""
    vars_file(lab, ["a0: '{{ 2 ** 2000 }}'"] + [f"a{i}: '{{{{ a{i - 1} * a{i - 1} }}}}'" for i in range(1, 21)])
    use_in_fleet(lab, "{{ vars.a20|string|length }}")
    code, text, took = validate(capsys, lab)
    assert code == 2 and "too large a number" in text, text
    assert "Traceback" not in text and "MemoryError" not in text and took < 10, (took, text)


def test_a_quadratic_inventory_expression_is_refused(lab: Path) -> None:
    """A var that is one `{{ }}` is evaluated for its value, never joined as text: its work is
    counted on its own template context."""
    vars_file(lab, ["""q: "{{ ('a' * 99999)|list|select('in', ('b' * 99999)|list)|list|length }}\""""])
    use_in_fleet(lab, "{{ vars.q }}")
    code, text = validate_in_little_memory(lab)
    assert code == 2 and "q: " in text and "loop steps" in text, text
    assert "Traceback" not in text, text


@pytest.mark.parametrize("value, expected", [("{{ range(3)|list }}", [0, 1, 2]), ("a{{ range(2)|list }}", "a[0, 1]"),
                                             ("{{ dict(a=1) }}", {"a": 1})])
def test_the_sandbox_globals_are_there_in_inventory_values(value: str, expected: object) -> None:
    """Jinja gives a shared context no globals: `range` and `dict` were undefined in host vars."""
    assert HostVars("r1", {"x": value}, {}, {}).value("x") == expected
