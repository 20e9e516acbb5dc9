"""Probe N (round 9), the fleet file's part: values Compose or Docker refuse, and names ignored where written.

5. `compose:` ports short syntax Compose v2 refuses (a reversed range, a bad IP, an unknown protocol),
   extra_hosts without an IP, expose past 65535, a cpuset that is no CPU list: all passed.
6. `ipc: service:X` / `pid: service:X` naming no service passed; both Compose versions refuse the file.
12. Two services publishing one host port (bridge) passed; the second container fails at `up`.
7. The fleet's `vars:` took rosdeploy's and Ansible's per-robot names, which are read from the inventory only.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from test_hostile import cli, edit, lab, refused_everywhere

__all__ = ["lab"]   # the fixture: tests/unit/data/fleet copied, its vault password in place


def bridge_with(**compose: Any) -> Any:
    """The lab on bridge networking, with `compose:` on the driver."""
    def change(d: dict) -> None:
        d.setdefault("ros", {})["network_mode"] = "bridge"
        d["services"]["driver"]["compose"] = compose
    return change


def validate(capsys: pytest.CaptureFixture, lab: Path) -> tuple[int, str]:
    return cli(capsys, lab, "validate")


# ------------------------------------------------------------------ 5. what Compose's parsers refuse

# each refused by `docker compose config` (v2.40.3) with the message in the comment
REFUSED_PORTS = {
    "9000-8000:80": "runs backwards",              # invalid hostPort: 9000-8000
    "8080:81-80": "runs backwards",                # invalid containerPort: 81-80
    "999.1.1.1:8080:80": "is not an IP address",   # invalid IP address: 999.1.1.1
    "01.2.3.4:80:80": "is not an IP address",
    "localhost:8080:80": "is not an IP address",
    "[fe80::1%eth0]:80:80": "is not an IP address",
    "8080:80/xyz": "is not a protocol",            # invalid proto: xyz
    "8080:80/tcp/udp": "is not a protocol",
    "abc:80": "is not a host port",                # invalid hostPort: abc
    "1.2.3.4:80": "is not a host port",
    "8000-8002:80-81": "ranges of different lengths",
    "8080:0": "container port is missing",         # is missing a target port
    "8080: 80": "is not a container port",         # invalid containerPort:  80 (Go trims no space)
    "8080:80/ udp": "is not a protocol",
}


@pytest.mark.parametrize("port", sorted(REFUSED_PORTS))
def test_a_port_compose_refuses_is_refused(capsys: pytest.CaptureFixture, lab: Path, port: str) -> None:
    edit(lab, bridge_with(ports=["80", port]))
    code, text = validate(capsys, lab)
    assert code == 2, text
    line = next(x for x in text.splitlines() if "services.driver.compose.ports[1]" in x)
    assert REFUSED_PORTS[port] in line and "Compose refuses it" in line, text


# each taken by `docker compose config` and `docker-compose config` (v1 1.29.2)
TAKEN_PORTS = ["8080:80", "8080:80/udp", "8080:80/sctp", "8000-8001:80-81", "8000-8001:80", "80-81",
               "[::1]:8080:80", "::1:8080:80", "[::1]:8080:80/udp", "1.2.3.4::80", "0.0.0.0:8080:80", "0:80",
               "8080-8080:80", "[1.2.3.4]:80:80"]


def test_the_ports_compose_takes_still_pass(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, bridge_with(ports=[*TAKEN_PORTS, 9000, {"target": 81, "published": 9001}]))
    code, text = validate(capsys, lab)
    assert code == 0, text


def test_a_bad_port_is_refused_by_check_and_render_too(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, bridge_with(ports=["9000-8000:80"]))
    refused_everywhere(capsys, lab, "services.driver.compose.ports[0]: '9000-8000:80': the host port range")


@pytest.mark.parametrize("hosts", [["foo"], ["foo:notanip"], ["foo:"], ["foo:999.1.1.1"], {"foo": "notanip"}])
def test_an_extra_host_without_an_ip_is_refused(capsys: pytest.CaptureFixture, lab: Path, hosts: Any) -> None:
    edit(lab, bridge_with(extra_hosts=hosts))
    code, text = validate(capsys, lab)
    at = "services.driver.compose.extra_hosts." + ("foo" if isinstance(hosts, dict) else "[0]").lstrip(".")
    at = at.replace(".[", "[")
    assert code == 2 and f"{at}: 'foo' maps to" in text and "no IP address" in text, text


def test_extra_hosts_docker_takes_pass(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, bridge_with(extra_hosts=["a:1.2.3.4", "b=1.2.3.4", "c:host-gateway", "d:::1", "e=[::1]"]))
    code, text = validate(capsys, lab)
    assert code == 0, text


@pytest.mark.parametrize("change, at, words", [
    ({"expose": ["80", "70000"]}, "expose[1]", "at most 65535"),
    ({"expose": ["81-80"]}, "expose[0]", "runs backwards"),
    ({"cpuset": "abc"}, "cpuset", "is not a list of CPUs"),
    ({"cpuset": "3-1"}, "cpuset", "is not a list of CPUs"),
])
def test_expose_and_cpuset_docker_refuses(capsys: pytest.CaptureFixture, lab: Path, change: dict, at: str,
                                          words: str) -> None:
    edit(lab, bridge_with(**change))
    code, text = validate(capsys, lab)
    assert code == 2 and f"services.driver.compose.{at}:" in text and words in text, text


def test_expose_and_cpuset_docker_takes_pass(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, bridge_with(expose=["80", 81, "80-81", "80/udp"], cpuset="0-1,3"))
    code, text = validate(capsys, lab)
    assert code == 0, text


# ------------------------------------------------------------------ 6. ipc/pid naming no service

@pytest.mark.parametrize("key", ["ipc", "pid"])
def test_sharing_the_namespace_of_no_service_is_refused(capsys: pytest.CaptureFixture, lab: Path, key: str) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(compose={key: "service:brigde"}))
    refused_everywhere(capsys, lab, f"services.driver.compose.{key}: no service is named `brigde`: "
                                    "did you mean `bridge`?")


@pytest.mark.parametrize("key", ["ipc", "pid"])
def test_sharing_its_own_namespace_is_refused_and_another_service_s_passes(capsys: pytest.CaptureFixture, lab: Path,
                                                                          key: str) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(compose={key: "service:driver"}))
    code, text = validate(capsys, lab)
    assert code == 2 and f"services.driver.compose.{key}: a service cannot share its own" in text, text
    edit(lab, lambda d: d["services"]["driver"].update(compose={key: "service:bridge"}))
    code, text = validate(capsys, lab)
    assert code == 0, text


# ------------------------------------------------------------------ 12. one host port, two services

def two_publish(first: Any, second: Any, network: str = "bridge") -> Any:
    def change(d: dict) -> None:
        d.setdefault("ros", {})["network_mode"] = network
        d["services"]["driver"]["compose"] = {"ports": ["9999:99", first]}
        d["services"]["bridge"]["compose"] = {"ports": [second]}
    return change


@pytest.mark.parametrize("first, second", [
    ("8080:80", "8080:80"), ("8080:80", "8080:81"), ("8000-8010:80-90", "8005:80"),
    ("127.0.0.1:8080:80", "8080:80"), ("0.0.0.0:8080:80", "127.0.0.1:8080:80"), ("[::]:8080:80", "[::1]:8080:80"),
    ("8080:80/udp", "8080:53/UDP"), ({"target": 80, "published": 8080}, "8080:80"),
    ("8080:80", {"target": 80, "published": 8080, "protocol": "TCP"}),
])
def test_two_services_on_one_host_port_are_refused(capsys: pytest.CaptureFixture, lab: Path, first: Any,
                                                   second: Any) -> None:
    edit(lab, two_publish(first, second))
    code, text = validate(capsys, lab)
    assert code == 2, text
    line = next(x for x in text.splitlines() if "services.bridge.compose.ports[0]" in x)
    assert "already published by service `driver` (its compose.ports[1])" in line, text


@pytest.mark.parametrize("first, second", [
    ("8080:80", "8081:80"), ("8080:80/tcp", "8080:80/udp"), ("127.0.0.1:8080:80", "127.0.0.2:8080:80"),
    ("0.0.0.0:8080:80", "[::1]:8080:80"), ("80", "80"), ("8000-8004:80-84", "8005:80"),
])
def test_different_host_ports_pass(capsys: pytest.CaptureFixture, lab: Path, first: Any, second: Any) -> None:
    edit(lab, two_publish(first, second))
    code, text = validate(capsys, lab)
    assert code == 0, text


def test_a_clash_is_refused_by_check_and_render_and_not_on_host_networking(capsys: pytest.CaptureFixture,
                                                                           lab: Path) -> None:
    edit(lab, two_publish("8080:80", "8080:80"))
    refused_everywhere(capsys, lab, "services.bridge.compose.ports[0]: host port 8080/tcp is already published")
    edit(lab, two_publish("8080:80", "8080:80", network="host"))    # not published on the host's network
    code, text = validate(capsys, lab)
    assert "already published" not in text, text


def test_a_service_with_profiles_never_clashes(capsys: pytest.CaptureFixture, lab: Path) -> None:
    def change(d: dict) -> None:
        two_publish("8080:80", "8080:80")(d)
        d["services"]["bridge"]["profiles"] = ["debug"]
    edit(lab, change)
    code, text = validate(capsys, lab)
    assert code == 0, text


# ------------------------------------------------------------------ 7. per-robot names in the fleet's vars

@pytest.mark.parametrize("name, value, words", [
    ("rosdeploy_deploy_root", "/opt/x", "top-level key `deploy_root:`"),
    ("rosdeploy_compose", "v9", "the inventory"),
    ("rosdeploy_known_hosts", "/dev/zero", "the inventory"),
    ("rosdeploy_ready", 5, "top-level key `ready:`"),
    ("ansible_port", 99999, "the inventory"),
    ("ansible_user", "ubuntu", "the inventory"),
    ("ros_domain_id", 7, "the inventory"),
    ("devices", {"motor": "/dev/ttyUSB0"}, "the inventory"),
    ("gpu", True, "the inventory"),
    ("udev", [], "the inventory"),
    ("window", {"start": "01:00"}, "top-level key `window:`"),
])
def test_a_per_robot_var_in_the_fleet_vars_is_refused(capsys: pytest.CaptureFixture, lab: Path, name: str,
                                                      value: Any, words: str) -> None:
    edit(lab, lambda d: d.update(vars={name: value}))
    code, text = validate(capsys, lab)
    line = next((x for x in text.splitlines() if f"vars.{name}:" in x), "")
    assert code == 2 and "per-robot variable, which" in line, text
    assert "from the inventory only, so here it would be ignored" in line, text
    assert words in line and "fleet.yml:" in line, text


def test_an_unknown_rosdeploy_var_gets_a_did_you_mean(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, lambda d: d.update(vars={"rosdeploy_deploy_rot": "/x"}))
    refused_everywhere(capsys, lab, "vars.rosdeploy_deploy_rot: unknown rosdeploy variable 'rosdeploy_deploy_rot': "
                                    "did you mean `rosdeploy_deploy_root`?")


def test_the_vars_rosdeploy_reads_from_the_fleet_still_work(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, lambda d: d.update(vars={"rosdeploy_home": "/home/robot", "logrotate_keep": 3, "dds_peers": [],
                                       "site_name": "north", "ros_network_name": "x"}))
    code, text = validate(capsys, lab)
    assert code == 0, text
    edit(lab, lambda d: d.update(vars={"rosdeploy_home": "relative"}))
    code, text = validate(capsys, lab)
    assert code == 2 and "vars.rosdeploy_home: must be the absolute path" in text, text
