"""Round 11 (probe S): where a user template's errors point.

A compose.yml that a `compose.yml.j2` override renders and that does not parse back names the
template, the line of the rendered file only when every robot shares it, and the template's line
when the offending text is literal there; the robots are grouped. A `files:` template's include,
import or extends is refused at its line with a reason. A template whose name is not UTF-8 is
refused as such.
"""
from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import pytest

from rosdeploy import checks
from rosdeploy.errors import Problem
from test_hostile import CANARY, DATA, VAULT_CANARY, cli, edit

BUILTIN = Path(__file__).resolve().parents[2] / "rosdeploy" / "templates" / "compose.yml.j2"


@pytest.fixture
def lab(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """test_hostile's lab (imported, it would shadow every test's argument for ruff)."""
    shutil.copytree(DATA, tmp_path / "lab")
    monkeypatch.setenv("ROSDEPLOY_CANARY", CANARY)
    monkeypatch.setenv("ROSDEPLOY_VAULT_PASSWORD", VAULT_CANARY)
    monkeypatch.delenv("ROSDEPLOY_VAULT_PASSWORD_FILE", raising=False)
    return tmp_path / "lab"


def _override(lab: Path, before: str = "", after: str = "", name: str = "compose.yml.j2") -> Path:
    folder = lab / "templates"
    folder.mkdir(exist_ok=True)
    source = folder / name
    builtin = (BUILTIN.parent / name).read_text()
    source.write_text(before + builtin + after)
    edit(lab, lambda d: d.update(templates="./templates"))
    return source


def _errors(text: str, needle: str) -> list[str]:
    return [line for line in text.splitlines() if needle in line]


# ------------------------------------------------------------ defect 3: compose-invalid

def test_a_compose_error_whose_line_differs_by_robot_is_one_finding_naming_the_template_line(
        capsys: pytest.CaptureFixture, lab: Path) -> None:
    source = _override(lab, after="x-zz: !!python/object/apply:os.system ['true']\n")
    template_at = len(source.read_text().splitlines())
    code, text = cli(capsys, lab, "validate")
    assert code == 2, text
    found = _errors(text, "is not a valid compose file")
    assert len(found) == 1, text          # r1 and r2 render it at different lines: still one finding
    line = found[0]
    assert f"your template {source} renders for 'r1', 'r2'" in line, line
    assert f"written by line {template_at} of the template" in line, line
    assert "which line differs by robot" in line, line
    assert not re.search(r"\bline \d+ of the compose\.yml", line), line     # no one line claimed for both
    assert "unsupported YAML tag" in line, line


def test_a_compose_error_on_one_robot_gives_its_rendered_line(capsys: pytest.CaptureFixture, lab: Path) -> None:
    source = _override(lab, after="x-zz: !foo [a]\n")
    code, text = cli(capsys, lab, "validate", "--limit", "r1")
    assert code == 2, text
    (line,) = _errors(text, "is not a valid compose file")
    at = len(source.read_text().splitlines())
    assert re.search(rf"at line \d+ of the compose\.yml it renders, written by line {at} of the template", line), line


def test_a_compose_error_at_a_line_all_robots_share_is_said_once_with_that_line(
        capsys: pytest.CaptureFixture, lab: Path) -> None:
    _override(lab, before="x-zz: !foo [a]\n")
    code, text = cli(capsys, lab, "check")
    assert code == 2, text
    (line,) = _errors(text, "is not a valid compose file")
    # the built-in template's first tag strips the newline before it: rendered line 1 is no template line
    assert "'r1', 'r2'" in line and "at line 1 of the compose.yml it renders)" in line, line


def test_a_compose_error_a_value_wrote_names_no_template_line(capsys: pytest.CaptureFixture, lab: Path) -> None:
    _override(lab, after="x-zz: {{ '!foo' }} [a]\n")
    code, text = cli(capsys, lab, "validate")
    assert code == 2, text
    (line,) = _errors(text, "is not a valid compose file")
    assert "compose.yml.j2 renders for 'r1', 'r2'" in line and "written by line" not in line, line


def test_an_empty_compose_output_says_so(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "templates").mkdir()
    (lab / "templates" / "compose.yml.j2").write_text("{# nothing #}\n")
    edit(lab, lambda d: d.update(templates="./templates"))
    code, text = cli(capsys, lab, "validate")
    assert code == 2, text
    (line,) = _errors(text, "is not a valid compose file")
    assert "(it is empty)" in line and "'r1', 'r2'" in line, line


def test_an_env_template_line_compose_v1_reads_otherwise_names_the_template(
        capsys: pytest.CaptureFixture, lab: Path) -> None:
    source = _override(lab, after='ODD_ONE="a\\tb"\n', name="env.j2")
    code, text = cli(capsys, lab, "validate")
    assert code == 2, text
    (line,) = _errors(text, "backslash escape")
    at = len(source.read_text().splitlines())
    assert f"the .env your template {source} renders for 'r1', 'r2'" in line, line
    assert f"written by line {at} of the template" in line, line


def test_rendered_lines_are_kept_only_when_every_robot_shares_one() -> None:
    _lift_line, _with_robots, rendered_line = checks._lift_line, checks._with_robots, checks.rendered_line
    def problem(line: int | None) -> Problem:
        return Problem("fleet.yml", 4, "templates", f"for {{robots}}: bad ({rendered_line(line, 'compose.yml')})",
                       "error", "compose-invalid")
    (a, la), (b, lb), (c, lc) = _lift_line(problem(7)), _lift_line(problem(9)), _lift_line(problem(7))
    assert a == b == c and (la, lb, lc) == (7, 9, 7)
    assert "at" not in _with_robots(a, {"r1": 7, "r2": 9}).message.split("bad")[0]
    assert _with_robots(a, {"r1": 7, "r2": 9}).message == (
        "for 'r1', 'r2': bad (a line of the compose.yml it renders (which line differs by robot))")
    assert _with_robots(a, {"r1": 7, "r3": 7}).message == "for 'r1', 'r3': bad (line 7 of the compose.yml it renders)"


def test_the_template_line_is_given_only_for_literal_unique_text(tmp_path: Path) -> None:
    template_line = checks.template_line
    source = tmp_path / "t.j2"
    source.write_text("a: 1\nkey: {{ v }}\nx-zz: !foo [a]\nb: [\n]\nb: [\n")
    assert template_line(str(source), "a: 1\nkey: 2\nx-zz: !foo [a]\n", 3) == 3
    assert template_line(str(source), "a: 1\nkey: 2\n", 2) is None        # a value wrote it
    assert template_line(str(source), "b: [\n]\n", 1) is None             # on two lines of the template
    assert template_line(str(source), "b: [\n]\n", 2) is None             # too short to prove anything
    assert template_line(str(source), "a: 1\n", None) is None


# ------------------------------------------------ defect 2: files: templates include nothing

@pytest.mark.parametrize("tag, name", [
    ("{% include 'nope.j2' %}", "nope.j2"),
    ("{% extends 'base.j2' %}", "base.j2"),
    ("{% import 'm.j2' as m %}", "m.j2"),
    ("{% from 'f1.txt' import x %}", "f1.txt"),
    ("{% include 'f2.j2' %}", "f2.j2"),            # itself
])
def test_a_files_template_that_includes_is_refused_at_the_tag(capsys: pytest.CaptureFixture, lab: Path,
                                                              tag: str, name: str) -> None:
    (lab / "data").mkdir()
    (lab / "data" / "f2.j2").write_text(f"a: 1\n{{% if true %}}\n{tag}\n{{% endif %}}\n")

    def change(d: dict) -> None:
        d["files"] = {"f2": {"template": "data/f2.j2", "target": "/config/f2.txt"}}
        d["services"]["driver"]["files"] = ["f2"]
    edit(lab, change)
    code, text = cli(capsys, lab, "validate")
    assert code == 2, text
    (line,) = _errors(text, "cannot include")
    assert f"{lab / 'data' / 'f2.j2'}:3: files.f2.template: robot 'r1': {tag}: a files: template cannot include, " \
           f"import or extend other templates (here '{name}')" in line, line
    assert "(the same on 1 more robot(s))" in line, line


def test_a_files_template_cannot_take_a_partial_of_the_template_folder(capsys: pytest.CaptureFixture,
                                                                       lab: Path) -> None:
    """It did, from the renderer's loader, though the path reads as relative to the fleet file."""
    (lab / "templates").mkdir()
    (lab / "templates" / "_part.j2").write_text("from the folder\n")
    (lab / "data").mkdir()
    (lab / "data" / "f2.j2").write_text("{% include '_part.j2' %}\n")

    def change(d: dict) -> None:
        d.update(templates="./templates", files={"f2": {"template": "data/f2.j2", "target": "/config/f2.txt"}})
        d["services"]["driver"]["files"] = ["f2"]
    edit(lab, change)
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "f2.j2:1: files.f2.template" in text and "cannot include" in text, text


# ------------------------------------------------ defect 7: a template name that is not UTF-8

def test_a_template_name_that_is_not_utf8_is_refused_as_such(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "templates").mkdir()
    with open(os.path.join(os.fsencode(lab / "templates"), b"a\xffb.conf.j2"), "w") as handle:
        handle.write("x\n")
    edit(lab, lambda d: d.update(templates="./templates"))
    code, text = cli(capsys, lab, "render")
    assert code == 2, text
    assert "whose name is not UTF-8 (byte 0xff)" in text and "blank" not in text, text
    assert not (lab / "out").exists()
