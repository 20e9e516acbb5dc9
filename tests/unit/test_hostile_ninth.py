"""Ninth hostile-input round (issue #18): each case was let through, refused late, or blamed the wrong place.

1. `links:` / `external_links:` on host networking passed validate, check and render; the robot's
   Docker refuses the container ("host type networking can't be used with links").
2. The links to a disk (/dev/disk/by-uuid/..., /dev/block/8:1, /dev/root) and raw flash (mtd*,
   ubi*) passed `device-root`, where /dev/sda itself is refused (its cases are in test_values_eighth.py).
"""
from __future__ import annotations

import io
from pathlib import Path

import pytest
import yaml

from rosdeploy import pending
from rosdeploy.cli import main, report
from rosdeploy.output import Output
from rosdeploy.results import FleetResult, HostResult
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


# ------------------------------------------------------------------ 6. the controller's paths in templates

def _template(lab: Path, text: str) -> None:
    (lab / "templates").mkdir(exist_ok=True)
    (lab / "templates" / "x.txt.j2").write_text(text)
    edit(lab, lambda d: d.update(templates="templates"))


def test_the_same_fleet_renders_the_same_release_from_any_folder(capsys: pytest.CaptureFixture, lab: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    # `{{ spec }}` wrote the fleet path as given on the command line: another folder, another
    # release id, and a redeploy of every robot; `known_hosts: /x/${VAR}` carried the environment
    monkeypatch.setenv("CANARY", "canary-5c1e")
    (lab / "kh-canary-5c1e").write_text("")
    _template(lab, "{{ spec }}\n{{ host }}\n")
    edit(lab, lambda d: d.update(ssh={"known_hosts": str(lab / "kh-${CANARY}")}))
    ids = []
    for folder, fleet in ((lab.parent, lab / "fleet.yml"), (lab, Path("fleet.yml"))):
        monkeypatch.chdir(folder)
        out = lab.parent / f"out-{len(ids)}"
        code = main(["render", str(fleet), "--vault-password-file", str(lab / "inventory" / ".vault-password"),
                     "--out", str(out), "--limit", "r1"])
        text = "".join(capsys.readouterr())
        assert code == 0, text
        written = (out / "r1" / "x.txt").read_text()
        assert "canary" not in written and str(lab) not in written and "FleetSpec(project='lab'" in written
        ids.append(text.split("r1", 1)[1].split()[0])
    assert ids[0] == ids[1], ids


@pytest.mark.parametrize("read", ["spec.path", "spec.inventory", "spec.known_hosts", "spec.templates",
                                  "host.source", "host.key_file", "spec|attr('ssh_config')"])
def test_a_template_reading_a_controller_path_is_refused(capsys: pytest.CaptureFixture, lab: Path, read: str) -> None:
    _template(lab, f"{{{{ {read} }}}}\n")
    refused_everywhere(capsys, lab, "x.txt.j2:1: robot 'r1': access to attribute")


# ------------------------------------------------------------------ 7. the run record's folder in the summary

def test_a_run_folder_with_a_newline_keeps_the_summary_on_one_line() -> None:
    # ROSDEPLOY_RUNS_DIR=$'/tmp/p/nl\nx' split "apply: 1 unreachable in 0.6s (record: /tmp/p/nl" in two
    stream = io.StringIO()
    result = FleetResult("apply", (HostResult("r1", "unreachable", reason="no route"),), seconds=0.6)
    report.summary(Output(stdout=stream, stderr=stream, color=False), result, Path("/tmp/p/nl\nx/20261125-1"))
    last = stream.getvalue().rstrip("\n").splitlines()[-1]
    assert last.startswith("apply: 1 unreachable in 0.6s") and "record: /tmp/p/nl\\nx/20261125-1)" in last, last


# ------------------------------------------------------------------ 8. deep recursion is not "without end"

@pytest.mark.parametrize("stop", ["n < 5000", "true"])
def test_deep_recursion_is_said_to_be_too_deep(capsys: pytest.CaptureFixture, lab: Path, stop: str) -> None:
    # a recursion 5,000 deep that ends was said to recurse "without end"
    macro = f"{{% macro m(n) %}}{{% if {stop} %}}{{{{ m(n + 1) }}}}{{% endif %}}{{% endmacro %}}"
    _template(lab, macro + "{{ m(0) }}\n")
    refused_everywhere(capsys, lab, "x.txt.j2:1: robot 'r1': the template recurses too deeply (past Python's limit")


# ------------------------------------------------------------------ 9. the robots apply picks up

def test_validate_and_check_with_limit_judge_the_pending_robots_apply_would_take(
        capsys: pytest.CaptureFixture, lab: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # `validate --limit r1` said OK; `apply --limit r1` also took r2, pending from a run before,
    # and refused it: validating first with the same options did not predict the apply
    monkeypatch.setenv("ROSDEPLOY_PENDING_DIR", str(lab.parent / "pending"))
    hosts = lab / "inventory" / "hosts.yml"
    hosts.write_text(hosts.read_text().replace("          ros_domain_id: 2\n", ""))
    assert cli(capsys, lab, "validate", "--limit", "r1")[0] == 0
    pending.save(str(lab / "fleet.yml"), pending.merged({}, [HostResult("r2", "unreachable", reason="no route")],
                                                          "1.0.0", "run1"))
    for command in ("validate", "check"):
        code, text = cli(capsys, lab, command, "--limit", "r1")
        assert code == 2 and "also validating 1 robot(s) pending for 1.0.0" in text and "r2 (unreachable)" in text
        assert "'r2' declares no ros_domain_id" in text, (command, text)


# ------------------------------------------------------------------ 10. compose keys with no fleet key to name

@pytest.mark.parametrize("key, value, words", [
    ("extends", {"file": "/opt/x.yml", "service": "x"}, "`extends` is refused: it brings in a service from a compose "
                                                        "file `check` never sees"),
    ("volumes_from", ["driver"], "`volumes_from` is refused: it mounts another container's folders"),
    ("container_name", "fixed", "`container_name` is refused: a fixed name cannot exist twice"),
    ("labels", {"a": "b"}, "`labels` is rendered by rosdeploy (the project, service and version labels"),
])
def test_a_refused_compose_key_says_why_in_plain_words(capsys: pytest.CaptureFixture, lab: Path, key: str,
                                                       value: object, words: str) -> None:
    # it said "set it with the fleet key `the service's own keys (what runs is what the fleet file says)`"
    edit(lab, lambda d: d["services"]["bridge"].update(compose={key: value}))
    refused_everywhere(capsys, lab, f"services.bridge.compose.{key}: {words}")
    assert "set it with the fleet key" not in cli(capsys, lab, "validate")[1]
