"""Probe O (tenth round) items 1, 2 and 5: strings a YAML 1.2 reader takes for numbers.

1. The `compose:` pass-through writes every string that YAML 1.1 (Compose v1, PyYAML) or YAML 1.2
   (Compose v2, go-yaml v3) would read as a number, bool or null quoted: `hostname: "1e3"` was
   written `hostname: 1e3`, which Compose v2 refuses. yaml_key quotes the same words. A user's
   compose template that writes such a string bare is a compose-invalid error.
2. A `files: {var: ...}` mapping is written the same way (one helper, files.represent_text): ROS 2's
   parameter parser (strtol/strtod, YAML 1.1 bools) read `serial: 1e3` as a double.
5. check's messages quote service names as they quote robots: `service '1e3' sets no user:`.

The oracle is the readers' own rules, written out here: the YAML 1.2.2 core schema (section
10.3.2), go-yaml v3's resolve (it drops every `_`, and reads `0X1F`, `0B1`, `0O17`, `017` as
ints), YAML 1.1's bools, and C's strtol/strtod as rcl_yaml_param_parser uses them. Where the
docker CLI has the compose plugin, `docker compose config -q` reads the rendered file too (it
only parses; no daemon).
"""
from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml

from rosdeploy import files, render
from rosdeploy.checks import RULES, run_checks
from test_checks import fires, host, release, run, spec
from test_checks_ninth import user_template
import test_hostile
from test_hostile import cli, edit

lab = test_hostile.lab      # the fixture: the example fleet copied

# The YAML 1.2.2 core schema, section 10.3.2: a plain scalar matching one of these is not a string.
CORE_12 = re.compile(r"null|Null|NULL|~|true|True|TRUE|false|False|FALSE|[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+"
                     r"|[-+]?(\.[0-9]+|[0-9]+(\.[0-9]*)?)([eE][-+]?[0-9]+)?|[-+]?(\.inf|\.Inf|\.INF)|\.nan|\.NaN|\.NAN")
# go-yaml v3 (Compose v2): `_` dropped, then Go's ParseInt(s, 0, 64) and its yamlStyleFloat.
GO_INT = re.compile(r"[-+]?(0[xX][0-9a-fA-F]+|0[oO]?[0-7]+|0[bB][01]+|[0-9]+)")
GO_FLOAT = re.compile(r"[-+]?(\.[0-9]+|[0-9]+(\.[0-9]*)?)([eE][-+]?[0-9]+)?")
# YAML 1.1's bools (the spec's list: y and n too), and rcl_yaml_param_parser's (the same words).
BOOL_11 = re.compile(r"y|Y|yes|Yes|YES|n|N|no|No|NO|true|True|TRUE|false|False|FALSE|on|On|ON|off|Off|OFF")
RESOLVER = yaml.resolver.Resolver()     # YAML 1.1 as PyYAML (Compose v1) reads it: `1:20` is 80
NUMBER_TAGS = {f"tag:yaml.org,2002:{kind}" for kind in ("int", "float", "bool")}
# C's strtol (base 0) and strtod, which rcl_yaml_param_parser tries on every plain scalar.
STRTOL = re.compile(r"[-+]?(0[xX][0-9a-fA-F]+|0[0-7]*|[1-9][0-9]*)")
STRTOD = re.compile(r"[-+]?((\d+\.?\d*|\.\d+)([eE][-+]?\d+)?|0[xX]([0-9a-fA-F]+\.?[0-9a-fA-F]*|\.[0-9a-fA-F]+)"
                    r"([pP][-+]?\d+)?|inf|infinity|nan)", re.IGNORECASE)

# Strings that some reader takes for something else when written bare.
NOT_TEXT_SOMEWHERE = ["1e3", "0o17", "0e1", "1.0e3", ".5", "+1", "0x1F", "0X1F", "0O17", "0B1", "017", "1.",
                      "1e+3", "-1E-3", "+.5", "1_0", "1_e3", "0_x1", "-_1", ".inf", "-.Inf", "+.INF", ".NaN",
                      "1:20", "y", "Y", "n", "N", "on", "ON", "Off", "yes", "NO", "true", "False", "TRUE",
                      "~", "null", "Null", "NULL", "", "inf", "Infinity", "nan", "0x1p3", "-infinity"]
# Plain text everywhere: written bare as before.
TEXT_EVERYWHERE = ["r1", "ros:humble", "1.2.3.4", "/dev/ttyUSB0", "eth0", "yesterday", "onboard", "nano", "e3",
                   "x1e3", "1e3x", "10m", "host-gateway", "0.0.0.0:8080"]


def misread(text: str) -> list[str]:
    """The readers that take `text`, written as a plain scalar, for something other than a string."""
    bare = text.replace("_", "")
    judged = {"YAML 1.2 core": CORE_12.fullmatch(text) or not text,
              "go-yaml v3": text[:1] in "0123456789+-." and (GO_INT.fullmatch(bare) or GO_FLOAT.fullmatch(bare)),
              "YAML 1.1 bool": BOOL_11.fullmatch(text),
              "PyYAML": RESOLVER.resolve(yaml.ScalarNode, text, (True, False)) != "tag:yaml.org,2002:str",
              "rcl strtol/strtod": STRTOL.fullmatch(text) or STRTOD.fullmatch(text)}
    return [reader for reader, hit in judged.items() if hit]


def bare_misread(text: str) -> list[tuple[str, list[str]]]:
    """Each plain (unquoted, untagged) scalar of a YAML text that some reader takes for a non-string,
    though PyYAML reads it as one (a number or bool written as such is no finding)."""
    return [(e.value, misread(e.value)) for e in yaml.parse(text) if isinstance(e, yaml.ScalarEvent)
            and e.implicit[0] and misread(e.value) and e.value != "<<"
            and RESOLVER.resolve(yaml.ScalarNode, e.value, (True, False)) not in NUMBER_TAGS]


def test_the_oracle_judges_the_probes_cases() -> None:
    assert all(misread(text) for text in NOT_TEXT_SOMEWHERE), [t for t in NOT_TEXT_SOMEWHERE if not misread(t)]
    assert not any(misread(text) for text in TEXT_EVERYWHERE), [t for t in TEXT_EVERYWHERE if misread(t)]


# ------------------------------------------------------ 1. the compose pass-through

@pytest.mark.parametrize("text", NOT_TEXT_SOMEWHERE)
def test_a_string_some_reader_takes_for_a_number_is_quoted_in_the_pass_through(text: str) -> None:
    data = {"hostname": text, "dns_search": [text], "extra_hosts": {text or "x": "1.2.3.4"}}
    written = render._dumped(data)
    assert not bare_misread(written), written
    assert yaml.safe_load(written) == data


def test_plain_words_stay_bare_and_numbers_stay_numbers_in_the_pass_through() -> None:
    data = {"dns_search": TEXT_EVERYWHERE, "cpu_shares": 512, "cpus": 1.5, "read_only": True, "init": False}
    written = render._dumped(data)
    assert yaml.safe_load(written) == data
    assert "cpu_shares: 512\n" in written and "cpus: 1.5\n" in written and "read_only: true\n" in written
    assert "- 1.2.3.4\n" in written and "- ros:humble\n" in written, written


@pytest.mark.parametrize("text", ["inf", "Infinity", "NaN", "YES", "n", "Off", "NULL"])
def test_yaml_key_quotes_every_word_some_reader_takes_for_another_type(text: str) -> None:
    assert render.yaml_key(text) == f'"{text}"'


def test_yaml_key_keeps_plain_names_bare() -> None:
    assert [render.yaml_key(k) for k in ("driver", "ROS_DOMAIN_ID", "nano", "yes_no")] == \
        ["driver", "ROS_DOMAIN_ID", "nano", "yes_no"]


PASS_THROUGH = {"hostname": "1e3", "domainname": "0o17", "entrypoint": ["1e3"], "dns_search": ["0e1"],
                "dns_opt": [".5"], "extra_hosts": {"1e3": "1.2.3.4"}, "read_only": True}


def rendered_compose(capsys: pytest.CaptureFixture, lab: Path) -> str:
    edit(lab, lambda d: d["services"]["driver"].update(compose=PASS_THROUGH))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    return (lab / "out" / "r1" / "compose.yml").read_text()


def test_the_probes_pass_through_reaches_compose_yml_quoted(capsys: pytest.CaptureFixture, lab: Path) -> None:
    written = rendered_compose(capsys, lab)
    assert not bare_misread(written), bare_misread(written)
    driver = yaml.safe_load(written)["services"]["driver"]
    assert {key: driver[key] for key in PASS_THROUGH} == PASS_THROUGH
    assert "    hostname: '1e3'\n" in written and "    read_only: true\n" in written


@pytest.mark.skipif(subprocess.run(["sh", "-c", "docker compose version"], capture_output=True).returncode != 0
                    if shutil.which("docker") else True, reason="no docker CLI with the compose plugin")
def test_compose_v2_reads_the_rendered_pass_through(capsys: pytest.CaptureFixture, lab: Path) -> None:
    rendered_compose(capsys, lab)
    # `config -q` only parses and validates the file (with its .env beside it): no daemon.
    run = subprocess.run(["docker", "compose", "-p", "t", "config", "-q"], cwd=lab / "out" / "r1",
                         capture_output=True, text=True, timeout=20)
    assert run.returncode == 0, run.stderr


def test_a_user_template_that_writes_a_yaml12_number_bare_is_an_error(capsys: pytest.CaptureFixture,
                                                                      lab: Path) -> None:
    user_template(lab, after_image="    hostname: 1e3")
    code, text = cli(capsys, lab, "check")
    assert code == 2 and "error[compose-invalid]" in text and "'1e3' unquoted at line" in text, text
    assert "quote it in the compose template" in text
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "'1e3' unquoted at line" in text, text


@pytest.mark.parametrize("compose", [
    "services:\n  driver:\n    hostname: 1e3\n",
    "services:\n  driver:\n    extra_hosts:\n      0o17: 1.2.3.4\n",
    "services:\n  driver:\n    dns_search: [a, 1_0e3, .5]\n"])
def test_a_bare_yaml12_number_in_a_rendered_compose_file_is_found(compose: str) -> None:
    fires("compose-invalid", releases=[release(host(), compose=compose)])
    found = [p.message for p in run("compose-invalid", releases=[release(host(), compose=compose)])]
    assert any("unquoted at line" in m and "Compose v2" in m for m in found), found


@pytest.mark.parametrize("compose", [
    "services:\n  driver:\n    hostname: '1e3'\n    cpus: 1.5\n    mem_swappiness: 10\n",
    'services:\n  driver:\n    hostname: "1e3"\n    labels: {a: !!str 1e3}\n',
    "services:\n  driver:\n    hostname: r1e3\n    x-n: 1_000\n"])
def test_a_quoted_text_or_a_number_both_read_alike_is_fine(compose: str) -> None:
    h = host()
    found = run_checks(spec(), [h], [release(h, compose=compose)], rules=[RULES["compose-invalid"]])
    assert not found, found


# ------------------------------------------------------ 2. files: {var: ...}

CAMERA = '\ncamera:\n  serial: "1e3"\n  firmware: "1.5e3"\n  mode: "0o17"\n  flag: "y"\n  limit: "inf"\n' \
         '  "1e3": key\n  count: 12\n  gain: 1.5\n  on: true\n'


def test_a_var_file_writes_every_misread_string_quoted(capsys: pytest.CaptureFixture, lab: Path) -> None:
    with (lab / "inventory" / "host_vars" / "r1.yml").open("a") as handle:
        handle.write(CAMERA)
    with (lab / "inventory" / "group_vars" / "all" / "vars.yml").open("a") as handle:
        handle.write('\ncamera: {serial: "x"}\n')
    edit(lab, lambda d: (d.update(files={"cam": {"var": "camera", "target": "/config/camera.yaml"}}),
                         d["services"]["driver"].update(files=["cam"])))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    written = (lab / "out" / "r1" / "files" / "cam").read_text()
    assert not bare_misread(written), (bare_misread(written), written)
    assert yaml.safe_load(written) == {"serial": "1e3", "firmware": "1.5e3", "mode": "0o17", "flag": "y",
                                       "limit": "inf", "1e3": "key", "count": 12, "gain": 1.5, True: True}
    assert "count: 12\n" in written and "gain: 1.5\n" in written and "serial: '1e3'\n" in written, written


@pytest.mark.parametrize("value", [{"a": "0X1F", "b": ["1_0", "Infinity", "~"]}, ["N", "-.inf", "0x1p3"]])
def test_the_files_dumper_quotes_nested_strings(value: Any) -> None:
    written = yaml.dump(value, Dumper=files._Dumper, sort_keys=True, default_flow_style=False)
    assert not bare_misread(written) and yaml.safe_load(written) == value, written


# ------------------------------------------------------ 5. service names quoted

@pytest.mark.parametrize("rule_id, patch, words", [
    ("user-unset", {"user": None}, "service 'driver' sets no `user:`"),
    ("healthcheck-missing", {"healthcheck": None}, "service 'driver' has no health check"),
    ("resources-missing", {"mem_limit": None}, "service 'driver' has no memory limit"),
    ("restart-missing", {"restart": None}, "service 'driver' "),
    ("image-unversioned", {"image": "acme/driver:latest"}, "service 'driver' of 'amr-1' would run image")])
def test_check_messages_quote_the_service_name(rule_id: str, patch: dict, words: str) -> None:
    p = fires(rule_id, **patch)
    assert words in p.message, p.message


def test_a_service_named_like_a_number_is_quoted_in_checks_messages(capsys: pytest.CaptureFixture,
                                                                      lab: Path) -> None:
    def rename(d: dict) -> None:
        d["services"]["1e3"] = d["services"].pop("bridge")
        d["services"]["1e3"].pop("user")
    edit(lab, rename)
    code, text = cli(capsys, lab, "check")
    assert "service '1e3' sets no `user:`" in text and "service 1e3" not in text, text
