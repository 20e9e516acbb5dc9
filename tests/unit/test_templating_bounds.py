"""Inventory templates a hostile or careless vars file can write: bounded in time and size (issue 18)."""
from __future__ import annotations

import time
from pathlib import Path

import pytest
import yaml

from rosdeploy.cli import main

import test_sandbox_bounds

lab = test_sandbox_bounds.lab     # the fixture: the example fleet copied, the vault variables unset


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
