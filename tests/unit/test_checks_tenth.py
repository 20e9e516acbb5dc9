"""Probe Q (user templates): `check` judges what the robot's Compose v2 reads, not its own reading.

Each expectation below was taken from `docker compose config` (v2.40.3) on the same files:
its casts of string booleans, its .env parser (compose-go's dotenv), its interpolation grammar,
`extends`, a config's `file:`, and more than one YAML document.
"""
from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest
import yaml

from rosdeploy.checks import RULES, compose_bool, run_checks
from rosdeploy.compose_env import interpolate, parse_env, read_env
from test_checks import FASTDDS_PEERS, GOOD_SERVICE, host, release, spec
import test_hostile
from test_checks_ninth import user_template
from test_hostile import cli

lab = test_hostile.lab      # the fixture: the example fleet copied

ENV = "ROS_DOMAIN_ID=5\n"


def found(rule_id: str, service: dict | None = None, *, env: str = ENV, top: dict | None = None,
          files: dict[str, str] | None = None) -> list:
    """The findings of one rule on one robot whose (user) compose.yml holds service `driver`."""
    svc = {**copy.deepcopy(GOOD_SERVICE), **(service or {})}
    compose = yaml.safe_dump({"services": {"driver": svc}, **(top or {})})
    h = host()
    return run_checks(spec(), [h], [release(h, compose=compose, env=env, extra=files)], rules=[RULES[rule_id]])


def messages(rule_id: str, *args: Any, **kw: Any) -> str:
    return "\n".join(p.message for p in found(rule_id, *args, **kw))


# -------------------------------------------------- 4. string booleans

@pytest.mark.parametrize("value", ["true", "True", "yes", "YES", "y", "Y", "on", "${PRIV}"])
def test_a_string_compose_casts_to_true_is_privileged(value: str) -> None:
    assert "runs privileged" in messages("privileged", {"privileged": value}, env=ENV + "PRIV=yes\n")


@pytest.mark.parametrize("value", ["false", "off", "no", "n", False])
def test_a_string_compose_casts_to_false_is_not(value: Any) -> None:
    assert "runs privileged" not in messages("privileged", {"privileged": value})


@pytest.mark.parametrize("value", ["false", "off", "No", "n"])
def test_read_only_false_as_a_string_is_writable(value: str) -> None:
    volume = {"type": "bind", "source": "/etc", "target": "/e", "read_only": value}
    assert "mounts /etc writable" in messages("mount-system-writable", {"volumes": [volume]})
    volume["read_only"] = "yes"
    assert not found("mount-system-writable", {"volumes": [volume]})


@pytest.mark.parametrize("service", [{"privileged": "1"}, {"read_only": "t"}, {"init": ""},
                                     {"volumes": [{"type": "bind", "source": "/x", "target": "/x",
                                                   "read_only": "0"}]}])
def test_a_boolean_compose_refuses_is_compose_invalid(service: dict) -> None:
    assert "not a boolean Compose reads" in messages("compose-invalid", service)


@pytest.mark.parametrize("disable, fires", [("false", False), ("no", False), (False, False), ("on", True),
                                             (True, True)])
def test_healthcheck_disable_is_read_as_compose_casts_it(disable: Any, fires: bool) -> None:
    service = {"healthcheck": {"test": ["CMD", "true"], "disable": disable}}
    assert bool(found("healthcheck-missing", service)) == fires


def test_compose_bool() -> None:
    assert [compose_bool(v) for v in (True, "ON", "y", False, "Off", "N", "1", "", None, 1)] == \
        [True, True, True, False, False, False, None, None, None, None]


# ------------------------------------------------- 2. .env as compose reads it

def test_env_reads_like_compose_v2() -> None:
    text = ('A=1 # c\nB="b" # c\nC="multi\nline"\nexport D=d\nH=a#b\nI=${B}-x\nJ=\'${B}\'\nK = k\nEMPTY=\n'
            "# a comment\n\nL='a b'\nS='a\\b #c'\n")
    assert parse_env(text) == {"A": "1", "B": "b", "C": "multi\nline", "D": "d", "H": "a#b", "I": "b-x",
                               "J": "${B}", "K": "k", "EMPTY": "", "L": "a b", "S": "a\\b #c"}
    assert read_env(text)[1] == []


@pytest.mark.parametrize("line, words", [
    ("E='x\\'y'", "backslash"), ('F="x\\ty"', "backslash"), ("G: g", "Compose v1 does not read"),
    ("I=$$x", "Compose v1 reads otherwise"), ("M=$B", "Compose v1 reads otherwise"), ('N="open', "no closing quote"),
    ('O="a" b', "text after its closing quote"), ("P=${HOME}/x", "${HOME}"), ("INHERITED", "robot's environment"),
    ("B$D=1", "is not KEY=VALUE")])
def test_env_lines_v1_reads_otherwise_or_from_the_robot_are_refused(line: str, words: str) -> None:
    problems = read_env(f"B=1\n{line}\nZ=2\n")[1]
    assert problems and problems[0].startswith("line 2:") and words in problems[0], problems
    text = messages("compose-invalid", env=f"{ENV}B=1\n{line}\nZ=2\n")
    assert "the .env rendered for 'amr-1': line 3: " + problems[0].removeprefix("line 2: ") in text, text


def test_an_inline_comment_does_not_hide_pid_host_or_a_writable_etc() -> None:
    env = ENV + 'P="host" # comment\nS=/etc # the config folder\n'
    assert "(pid: host)" in messages("privileged", {"pid": "${P}"}, env=env)
    assert "mounts /etc writable" in messages("mount-system-writable", {"volumes": ["${S}:/e"]}, env=env)


def test_a_multi_line_value_does_not_hide_the_domain_id() -> None:
    env = 'ROS_DOMAIN_ID=7\nX_PAD="\nROS_DOMAIN_ID=5\n"\n'
    assert "does not set ROS_DOMAIN_ID" in messages("domain-id-not-injected", env=env)


# --------------------------------------------------------- 3. interpolation

@pytest.mark.parametrize("text, expect", [
    ("${L:+alt}", "alt"), ("${NOPE:-${B}x}", "bx"), ("${NOPE+z}|${B+z}|${EMPTY:+z}|${EMPTY+z}", "|z||z"),
    ("$$B ${B}", "$B b"), ("${NOPE:-a}b}", "ab}"), ("${B:?err}", "b"), ("${EMPTY-d}${EMPTY:-d}", "d")])
def test_interpolation_reads_like_compose_v2(text: str, expect: str) -> None:
    assert interpolate(text, {"B": "b", "L": "1", "EMPTY": ""}) == expect


@pytest.mark.parametrize("volume, env", [("${S:+/var/run/docker.sock}:/s", "S=1"),
                                         ("${S:-x}:/s", "S=/var/run/docker.sock"),
                                         ("${A}/docker.sock:/s", "B=/var/run\nA=${B}")])
def test_the_socket_behind_interpolation_is_found(volume: str, env: str) -> None:
    assert "/var/run/docker.sock" in messages("docker-socket-mounted", {"volumes": [volume]}, env=f"{ENV}{env}\n")


@pytest.mark.parametrize("service", [{"volumes": ["${HOME}/.ssh:/s"]}, {"volumes": ["${HOME}:/h"]},
                                     {"privileged": "${PRIV:-false}"}, {"volumes": ["$USER:/u"]}])
def test_a_value_from_the_robot_environment_is_refused(service: dict) -> None:
    text = messages("compose-invalid", service)
    assert "comes from the robot's environment" in text and "write the value" in text, text


def test_the_robot_environment_in_an_unjudged_key_is_fine() -> None:
    assert not found("compose-invalid", {"environment": {"ROS_DOMAIN_ID": "${ROS_DOMAIN_ID}", "H": "${HOME}"}})


# ------------------------------------------------------------- 5. extends

@pytest.mark.parametrize("extends", [{"service": "other"}, "other"])
def test_extends_of_the_same_file_is_refused(extends: Any) -> None:
    text = messages("compose-invalid", {"extends": extends})
    assert "`extends`" in text and "'other'" in text and "write the service's own keys" in text, text


# ------------------------------------------------- 6. configs and secrets

@pytest.mark.parametrize("kind", ["configs", "secrets"])
def test_a_config_file_that_is_the_socket_is_refused(kind: str) -> None:
    service = {kind: [{"source": "c", "target": "/var/run/docker.sock"}]}
    text = messages("docker-socket-mounted", service, top={kind: {"c": {"file": "/var/run/docker.sock"}}})
    assert "mounts /var/run/docker.sock" in text
    # read-only like a config is: not a writable system folder, and an ordinary file is fine
    assert not found("mount-system-writable", service, top={kind: {"c": {"file": "/etc"}}})
    assert not found("docker-socket-mounted", {kind: ["c"]}, top={kind: {"c": {"file": "./app.yaml"}}})


# ------------------------------------------------------ 8. DDS profile XML

def test_a_malformed_dds_profile_on_host_networking_is_refused() -> None:
    assert "not valid XML" in messages("dds-peers-missing", files={"fastdds.xml": "<dds><profiles><unclosed></dds>"})
    assert not found("dds-peers-missing", files={"fastdds.xml": FASTDDS_PEERS})


# ---------------------------------------------- 9. more than one document

def test_a_second_yaml_document_is_named_whole() -> None:
    h = host()
    second = "---\nservices:\n  driver:\n    privileged: true\n"
    compose = yaml.safe_dump({"services": {"driver": GOOD_SERVICE}}) + second
    text = "\n".join(p.message for p in run_checks(spec(), [h], [release(h, compose=compose, env=ENV)],
                                                  rules=[RULES["compose-invalid"]]))
    assert "more than one YAML document" in text and "remove the `---`" in text, text


# ------------------------------------------------- through the commands

def test_a_user_template_with_home_in_a_mount_is_refused_by_validate(capsys: pytest.CaptureFixture,
                                                                      lab: Path) -> None:
    user_template(lab, volume="${HOME}/.ssh:/s")
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "${HOME}" in text and "robot's environment" in text, text


def test_a_user_template_unchanged_passes(capsys: pytest.CaptureFixture, lab: Path) -> None:
    user_template(lab)
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text
