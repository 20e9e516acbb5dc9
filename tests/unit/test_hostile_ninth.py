"""Ninth hostile-input round (issue #18): each case was let through, refused late, or blamed the wrong place.

1. `links:` / `external_links:` on host networking passed validate, check and render; the robot's
   Docker refuses the container ("host type networking can't be used with links").
2. The links to a disk (/dev/disk/by-uuid/..., /dev/block/8:1, /dev/root) and raw flash (mtd*,
   ubi*) passed `device-root`, where /dev/sda itself is refused (its cases are in test_values_eighth.py).
"""
from __future__ import annotations

from pathlib import Path

import pytest

from test_hostile import cli, edit, lab, refused_everywhere

__all__ = ["lab"]   # the fixture: tests/unit/data/fleet copied, its vault password in place


# ------------------------------------------------------------------ 1. links on host networking

@pytest.mark.parametrize("key", ["links", "external_links"])
def test_links_on_host_networking_are_refused_everywhere(capsys: pytest.CaptureFixture, lab: Path, key: str) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(compose={key: ["bridge"]}))
    refused_everywhere(capsys, lab, f"services.driver.compose.{key}: Docker refuses links on host networking",
                       "localhost")


def test_links_on_bridge_networking_are_still_checked_by_name(capsys: pytest.CaptureFixture, lab: Path) -> None:
    def bridge(d: dict) -> None:
        d.setdefault("ros", {})["network_mode"] = "bridge"
        d["services"]["driver"]["compose"] = {"links": ["bridge"]}
    edit(lab, bridge)
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text
    edit(lab, lambda d: d["services"]["driver"].update(compose={"links": ["brigde"]}))
    refused_everywhere(capsys, lab, "services.driver.compose.links[0]: no service is named `brigde`")
    edit(lab, lambda d: d["services"]["driver"].update(compose={"links": ["driver:alias"]}))
    refused_everywhere(capsys, lab, "services.driver.compose.links[0]: a service cannot link to itself")


# ------------------------------------------------------------------ 3. a templated ansible_connection

def _group_vars(lab: Path, text: str) -> Path:
    path = lab / "inventory" / "group_vars" / "lab.yml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("template", ["\"{{ 'lo' ~ 'cal' }}\"", "\"{{ 'docker' if true else 'ssh' }}\""])
def test_a_templated_connection_is_judged_by_what_it_gives(capsys: pytest.CaptureFixture, lab: Path,
                                                           template: str) -> None:
    # `ansible_connection: local` is said to be ignored; the same through a template was not
    _group_vars(lab, f"ansible_connection: {template}\n")
    code, text = cli(capsys, lab, "validate")
    warnings = [line for line in text.splitlines() if "ansible_connection" in line]
    assert code == 0 and len(warnings) == 1, text            # one line for both robots
    assert "lab.yml:1: ansible_connection:" in warnings[0] and "is ignored: rosdeploy reaches every robot over SSH" \
        in warnings[0], text


def test_a_templated_ssh_connection_says_nothing(capsys: pytest.CaptureFixture, lab: Path) -> None:
    _group_vars(lab, "ansible_connection: \"{{ 'ss' ~ 'h' }}\"\n")
    code, text = cli(capsys, lab, "validate")
    assert code == 0 and "ansible_connection" not in text, text
