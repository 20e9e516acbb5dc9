"""Ninth hostile-input round (issue #18): each case was let through, refused late, or blamed the wrong place.

1. `links:` / `external_links:` on host networking passed validate, check and render; the robot's
   Docker refuses the container ("host type networking can't be used with links").
2. The links to a disk (/dev/disk/by-uuid/..., /dev/block/8:1, /dev/root) and raw flash (mtd*,
   ubi*) passed `device-root`, where /dev/sda itself is refused (its cases are in test_values_eighth.py).
"""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

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


# ------------------------------------------------------------------ 4. names YAML reads as another type

ODD_NAMES = ["yes", "on", "true", "null", "off", "y"]


@pytest.mark.parametrize("name", ODD_NAMES)
def test_a_service_name_yaml_reads_as_a_bool_or_null_is_written_quoted(capsys: pytest.CaptureFixture, lab: Path,
                                                                      name: str) -> None:
    # `{{ svc.name }}:` wrote `yes:`: Compose v1 said "the services name True must be a quoted string",
    # v2 "non-string key in services"; check judged a data copy and found nothing
    def rename(d: dict) -> None:
        d["services"][name] = d["services"].pop("bridge")
    edit(lab, rename)
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    for robot in ("r1", "r2"):
        services = yaml.safe_load((lab / "out" / robot / "compose.yml").read_text())["services"]
        assert name in services and all(isinstance(key, str) for key in services), services.keys()


@pytest.mark.parametrize("name", ["yes", "null", "on"])
def test_a_secret_name_yaml_reads_as_a_bool_or_null_reaches_the_container_as_written(
        capsys: pytest.CaptureFixture, lab: Path, name: str) -> None:
    # v1 gave the container `True=<secret>`; v2 refused `<nil>` as a variable name
    def rename(d: dict) -> None:
        secrets = d["services"]["bridge"]["secrets"]
        secrets[name] = secrets.pop(next(iter(secrets)))
    edit(lab, rename)
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    environment = yaml.safe_load((lab / "out" / "r1" / "compose.yml").read_text())["services"]["bridge"]["environment"]
    assert name in environment and all(isinstance(key, str) for key in environment), environment.keys()


# ------------------------------------------------------------------ 5. ROS_LOG_DIR is rosdeploy's

@pytest.mark.parametrize("key", ["environment", "secrets"])
def test_ros_log_dir_is_refused_in_environment_and_secrets(capsys: pytest.CaptureFixture, lab: Path, key: str) -> None:
    # it moved the ROS logs out of /ros_log: the robot's logrotate never saw them
    def add(d: dict) -> None:
        value = "/tmp" if key == "environment" else "api_token"
        d["services"]["bridge"].setdefault(key, {})["ROS_LOG_DIR"] = value
    edit(lab, add)
    refused_everywhere(capsys, lab, f"services.bridge.{key}.ROS_LOG_DIR: ROS_LOG_DIR is /ros_log, set by rosdeploy")


@pytest.mark.parametrize("name", ["CYCLONEDDS_URI", "NVIDIA_VISIBLE_DEVICES"])
def test_a_secret_named_as_a_variable_rosdeploy_sets_is_refused(capsys: pytest.CaptureFixture, lab: Path,
                                                                name: str) -> None:
    def add(d: dict) -> None:
        secrets = d["services"]["bridge"]["secrets"]
        secrets[name] = secrets.pop(next(iter(secrets)))
    edit(lab, add)
    refused_everywhere(capsys, lab, f"services.bridge.secrets.{name}: {name} is set per robot by rosdeploy")
