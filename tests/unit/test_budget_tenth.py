"""Bounded values, messages and template work (probe P items 1 and 2, probe O item 4).

1. A list literal naming another var's list 16 times, ten vars deep, is 2**40 items written out
   but a few KB in memory: the var is refused where it is templated (its expanded weight), and a
   message quoting such a value builds only its head (errors.shown), never its whole repr().
2. MAX_WORK bounds one render; sandbox.command_budget bounds all the renders of one command, so a
   value costing most of MAX_WORK for every robot stops after a few seconds, not hours.
3. A null var renders as nothing, as Ansible's templar finalizes None, not as the text `None`.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tracemalloc
from pathlib import Path
from typing import Any

import pytest
import yaml

import test_hostile
from rosdeploy import sandbox
from rosdeploy.errors import shown
from rosdeploy.inventory.templating import HostVars, TemplateFailed
from rosdeploy.sandbox import MAX_WORK, Sandbox, render_value, value_template
from test_hostile import cli, edit, set_env
from test_vault_taint import group_vars

lab = test_hostile.lab      # the fixture: the example fleet copied
ROOT = Path(__file__).resolve().parents[2]


def shared(levels: int, fan: int = 16) -> Any:
    """A list holding one list `fan` times, `levels` deep: fan**levels ones written out."""
    value: Any = 1
    for _ in range(levels):
        value = [value] * fan
    return value


def dag_vars(levels: int) -> dict[str, str | int]:
    """v0 .. v{levels}: each var a list literal naming the next var 16 times."""
    names = {f"v{i}": "{{ [" + ",".join([f"v{i + 1}"] * 16) + "] }}" for i in range(levels)}
    return {**names, f"v{levels}": 1}


# ------------------------------------------------------------------ 1. shared lists

def test_shown_cuts_a_list_held_many_times_over_without_writing_it_out() -> None:
    value = shared(5)      # 3 MB written out
    tracemalloc.start()
    try:
        text = shown(value)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert text.startswith("[[[[[1, 1, 1") and text.endswith(f"... ({len(repr(value))} characters)")
    assert len(text) < 150 and peak < 200_000, peak


def test_shown_of_a_2_to_the_40_list_is_immediate() -> None:
    """In a child under a 1 GB address-space limit: repr() of it would take all memory."""
    length = 1          # `1`; then `[` 16 of the level below, 15 `, ` and `]`
    for _ in range(10):
        length = 16 * length + 32
    code = ("import resource, sys; resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30)); "
            "from rosdeploy.errors import shown\nv = 1\nfor _ in range(10): v = [v] * 16\nprint(shown(v))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == 0 and done.stdout.strip().endswith(f"... ({length} characters)"), done.stderr[-500:]
    assert shown(shared(3), 10**6) == repr(shared(3))


@pytest.mark.parametrize("value", [None, 1, [1, 2], (1,), (), {}, set(), frozenset(), {1: [2, (3,)], "a": "b"},
                                   {1}, frozenset({2}), [[]], [1.5, True, None, "a\n"], list(range(30))])
def test_shown_writes_a_short_container_as_repr_does(value: Any) -> None:
    assert shown(value, 1000) == repr(value)


def test_shown_of_a_list_inside_itself() -> None:
    value: list[Any] = []
    value.append(value)
    assert shown(value) == "[[...]]"


def test_an_inventory_var_holding_another_vars_list_many_times_over_is_refused_at_its_var() -> None:
    hostvars = HostVars("r1", dag_vars(10), {}, {"inventory_hostname": "r1"})
    with pytest.raises(TemplateFailed) as failed:
        hostvars.value("v0")
    # v5 is 16**5 = 1,048,576 items: the first var on the way down past MAX_LENGTH
    assert failed.value.key == "v5" and "would be longer than 1,000,000 characters or items" in failed.value.message


def test_a_yaml_list_of_templates_is_weighed_whole() -> None:
    raw = {"big": "{{ 'x' * 600000 }}", "both": ["{{ big }}", "{{ big }}"]}
    with pytest.raises(TemplateFailed, match="would be longer than 1,000,000"):
        HostVars("r1", raw, {}, {}).value("both")


def test_the_probes_dag_is_a_clean_error_at_the_cli(capsys: pytest.CaptureFixture, lab: Path) -> None:
    group_vars(lab, rosdeploy_home="{{ v0 }}", **dag_vars(5))
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "rosdeploy_home" in text and "v0: the value of v0 would be longer than 1,000,000" in text
    assert len(text) < 3000, text[:3000]


# ------------------------------------------------------------------ 2. one budget per command

LOOP = "{{ range(20000)|map('string')|join|length }}"     # about a fifteenth of MAX_WORK a render


def test_renders_under_a_command_budget_stop_when_it_is_spent() -> None:
    template = value_template(Sandbox(), LOOP)
    rendered = 0
    with sandbox.command_budget(MAX_WORK // 4), pytest.raises(Exception) as refused:
        for _ in range(50):
            render_value(template, {})
            rendered += 1
    assert 2 <= rendered <= 5, rendered     # about 0.7 million units each
    assert "the templates of this command together take more than" in str(refused.value)
    assert render_value(template, {}) == "88890"     # outside the block: MAX_WORK a render, as before


def test_a_render_still_gets_at_most_max_work_under_a_larger_command_budget() -> None:
    template = value_template(Sandbox(), "{{ " + " + ".join(["(range(99999)|map('string')|join|length)"] * 5) + " }}")
    with sandbox.command_budget(100 * MAX_WORK), pytest.raises(Exception) as refused:
        render_value(template, {})
    assert f"takes more than {MAX_WORK:,}" in str(refused.value)


def test_inventory_templating_takes_from_the_command_budget() -> None:
    raw = {f"x{i}": LOOP for i in range(30)}
    hostvars = HostVars("r1", raw, {}, {"inventory_hostname": "r1"})
    with sandbox.command_budget(MAX_WORK // 4), pytest.raises(TemplateFailed) as failed:
        for name in raw:
            assert hostvars.value(name) == 88890
    assert "the templates of this command together" in failed.value.message


# ------------------------------------------------------------------ 3. null renders as nothing

def test_a_null_renders_as_nothing_in_a_fleet_value() -> None:
    env = Sandbox()
    assert render_value(value_template(env, "{{ x }}"), {"x": None}) == ""
    assert render_value(value_template(env, "a{{ x }}b"), {"x": None}) == "ab"
    assert render_value(value_template(env, "{{ x is none }}"), {"x": None}) == "True"


def test_a_null_renders_as_nothing_in_inventory_text_but_stays_null_alone() -> None:
    hostvars = HostVars("r1", {"site": None, "text": "s-{{ site }}", "alone": "{{ site }}"}, {}, {})
    assert hostvars.value("text") == "s-" and hostvars.value("alone") is None


def test_a_null_inventory_var_reaches_the_container_as_an_empty_value(capsys: pytest.CaptureFixture,
                                                                       lab: Path) -> None:
    group_vars(lab, site=None)
    edit(lab, set_env("{{ site }}"))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    found = [f for f in (lab / "out").rglob("*") if f.is_file() and "X" in f.read_text()]
    environments = [yaml.safe_load(f.read_text())["services"]["driver"]["environment"]
                    for f in found if f.name == "compose.yml"]
    assert environments and all(env["X"] == "" for env in environments), environments


def test_the_command_budget_is_five_renders() -> None:
    from rosdeploy import budget
    assert budget.COMMAND_WORK == 5 * MAX_WORK


def test_the_cli_runs_every_command_in_one_budget(capsys: pytest.CaptureFixture, lab: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """Each robot's value fits a render's budget; the two robots' together pass the command's."""
    from rosdeploy import budget
    test_hostile.edit(lab, lambda d: d["services"]["driver"].update(
        environment={"W": "{{ range(3000)|list|sort|length }}"}))
    code, text = test_hostile.cli(capsys, lab, "validate")
    assert code == 0, text
    monkeypatch.setattr(budget, "COMMAND_WORK", 10_000)
    code, text = test_hostile.cli(capsys, lab, "validate")
    assert code == 2 and "the templates of this command together take more than" in text, text
