"""load_fleet: every key's validation, with file:line, key path and a fix in each message."""
from __future__ import annotations

import copy
import datetime
import random
import os
from pathlib import Path
from typing import Any

import pytest
import yaml

from rosdeploy.errors import FleetSpecError, Problem
from rosdeploy.fleet import compose_duration, load_fleet, parse_duration, problem_at, size_bytes
from rosdeploy.model import HealthCheck, Topic

DELETE = object()

BASE: dict[str, Any] = {
    "project": "warehouse",
    "inventory": "./inventory",
    "registry": "registry.local:5000",
    "version": "1.4.2",
    "services": {
        "driver": {
            "image": "acme/amr-driver",
            "healthcheck": {"test": ["CMD-SHELL", "test -f /run/ok"]},
            "topics": ["/joint_states"],
        },
        "navigation": {"image": "acme/amr-navigation", "depends_on": ["driver"]},
    },
}


def merge(base: dict, patch: dict) -> dict:
    out = copy.deepcopy(base)
    for key, value in patch.items():
        if value is DELETE:
            out.pop(key, None)
        elif isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


@pytest.fixture
def fleet_dir(tmp_path: Path) -> Path:
    (tmp_path / "inventory").mkdir()
    (tmp_path / "inventory" / "hosts.yml").write_text("all: {}\n")
    return tmp_path


def write(folder: Path, data: Any = None, text: str | None = None) -> Path:
    path = folder / "fleet.yml"
    path.write_text(text if text is not None else yaml.safe_dump(data, sort_keys=False))
    return path


def problems(folder: Path, patch: dict | None = None, text: str | None = None, **kw: Any) -> list[Problem]:
    with pytest.raises(FleetSpecError) as info:
        load_fleet(write(folder, merge(BASE, patch or {}), text), **kw)
    return list(info.value.problems)


def one(folder: Path, patch: dict, key: str, *words: str) -> Problem:
    """Exactly one problem, at `key`, whose message has every word."""
    found = problems(folder, patch)
    assert [p.key for p in found] == [key], found
    for word in words:
        assert word in found[0].message, found[0].message
    assert found[0].file.endswith("fleet.yml") and found[0].line, found[0]
    return found[0]


# ------------------------------------------------------------------ valid

def test_minimal_fleet_gets_documented_defaults(fleet_dir: Path) -> None:
    spec = load_fleet(write(fleet_dir, BASE))
    assert spec.project == "warehouse" and spec.version == "1.4.2"
    assert spec.inventory == str(fleet_dir / "inventory")
    driver, nav = spec.services
    assert (driver.name, driver.image, driver.tag, driver.restart) == (
        "driver", "acme/amr-driver", "1.4.2", "unless-stopped")
    assert driver.healthcheck == HealthCheck(("CMD-SHELL", "test -f /run/ok"))
    assert driver.topics == (Topic("/joint_states"),)
    assert nav.depends_on == ("driver",)
    assert spec.image_ref(driver) == "registry.local:5000/acme/amr-driver:1.4.2"
    assert (spec.rmw, spec.network_mode, spec.shm_size, spec.log_max_file) == ("fastdds", "host", "512m", 3)
    assert spec.rollback.keep_releases == 3 and spec.rollout.waves == ("100%",)
    assert spec.ssh_persist == 60.0


def full_fleet(fleet_dir: Path) -> dict:
    """BASE with every key set."""
    (fleet_dir / "templates").mkdir(exist_ok=True)
    (fleet_dir / "cfg").write_text("Host amr*\n  User robot\n")
    return merge(BASE, {
        "templates": "./templates", "deploy_root": "/opt/rosdeploy",
        "ssh": {"known_hosts": "~/kh", "config": "cfg", "connect_timeout": "5s", "command_timeout": "2m",
                "persist": 0},
        "ros": {"rmw": "cyclonedds", "network_mode": "bridge", "shm_size": "1g"},
        "logging": {"max_size": "20m", "max_file": 5}, "preflight": {"min_free_disk_mb": 0},
        "health": {"timeout": "2m", "stable": 5, "interval": "500ms", "topic_window": "3s", "probe_service": "driver"},
        "rollout": {"waves": [1, "10%", "100%"], "max_fail": "5%", "forks": 20, "order_by": "site_", "pause": "1m"},
        "rollback": {"auto": False, "fleet": False, "keep_releases": 5},
        "vars": {"dds_lease_duration": 20},
        "services": {"driver": {
            "tag": "1.4.1-3f9a2c1", "command": "ros2 launch 'amr driver' x.py", "environment": {"A": 1, "B": True},
            "secrets": {"TOKEN": "fleet_api_token"}, "devices": ["motor", "lidar"], "gpu": True, "restart": "always",
            "resources": {"memory": "512m", "cpus": 1.5},
            "healthcheck": {"test": "test -f /ok", "interval": 5, "timeout": "1500ms", "retries": 5,
                            "start_period": "1m"},
            "topics": [{"name": "/scan", "min_rate": 5}], "user": "1000:1000", "privileged": True,
            "allow_privileged": True, "compose": {"cap_add": ["SYS_NICE"]}},
            # profiled: nothing depends on it, and it is not the probe service (a deploy never starts it)
            "navigation": {"profiles": ["deploy"]}},
    })


def test_every_key_is_read(fleet_dir: Path) -> None:
    full = full_fleet(fleet_dir)
    spec = load_fleet(write(fleet_dir, full))
    d = spec.service("driver")
    assert d.tag == "1.4.1-3f9a2c1" and spec.service("navigation").tag == "1.4.2"
    assert d.command == ("ros2", "launch", "amr driver", "x.py")
    assert dict(d.environment) == {"A": "1", "B": "true"} and dict(d.secret_env) == {"TOKEN": "fleet_api_token"}
    assert d.devices == ("motor", "lidar") and d.gpu and d.restart == "always"
    assert (d.memory, d.cpus, d.user, spec.service("navigation").profiles) == ("512m", 1.5, "1000:1000", ("deploy",))
    assert d.healthcheck == HealthCheck(("CMD-SHELL", "test -f /ok"), "5s", "1500ms", 5, "60s")
    assert d.topics == (Topic("/scan", 5.0),) and d.privileged and d.allow_privileged
    assert dict(d.extra) == {"cap_add": ["SYS_NICE"]}
    assert spec.templates == str(fleet_dir / "templates") and spec.deploy_root == "/opt/rosdeploy"
    assert spec.known_hosts == os.path.expanduser("~/kh") and spec.ssh_config == str(fleet_dir / "cfg")
    assert (spec.connect_timeout, spec.command_timeout, spec.ssh_persist) == (5.0, 120.0, 0.0)
    assert (spec.rmw, spec.network_mode, spec.shm_size) == ("cyclonedds", "bridge", "1g")
    assert (spec.log_max_size, spec.log_max_file, spec.min_free_disk_mb) == ("20m", 5, 0)
    assert spec.health.timeout == 120 and spec.health.interval == 0.5 and spec.health.probe_service == "driver"
    assert spec.rollout.waves == (1, "10%", "100%") and spec.rollout.max_fail == "5%" and spec.rollout.pause == 60
    assert spec.rollback.auto is False and spec.rollback.keep_releases == 5
    assert dict(spec.vars) == {"dds_lease_duration": 20}


def test_healthcheck_image_trusts_the_image(fleet_dir: Path) -> None:
    spec = load_fleet(write(fleet_dir, merge(BASE, {"services": {"navigation": {"healthcheck": "image"}}})))
    nav = spec.service("navigation")
    assert nav.healthcheck is None and nav.healthcheck_from_image


def test_images_fully_qualified_without_registry(fleet_dir: Path) -> None:
    data = merge(BASE, {"registry": DELETE, "services": {"driver": {"image": "ghcr.io/acme/amr-driver"},
                                                         "navigation": {"image": "localhost:5000/nav"}}})
    spec = load_fleet(write(fleet_dir, data))
    assert spec.image_ref(spec.service("driver")) == "ghcr.io/acme/amr-driver:1.4.2"


# -------------------------------------------------------------- overrides

def test_version_override_keeps_pinned_tags(fleet_dir: Path) -> None:
    data = merge(BASE, {"services": {"navigation": {"tag": "0.9.0"}}})
    spec = load_fleet(write(fleet_dir, data), version="2.0.0")
    assert spec.version == "2.0.0" and spec.service("driver").tag == "2.0.0"
    assert spec.service("navigation").tag == "0.9.0"


def test_overrides_make_the_keys_optional(fleet_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(fleet_dir)
    spec = load_fleet(write(fleet_dir, merge(BASE, {"inventory": DELETE, "version": DELETE})),
                      inventory="inventory/hosts.yml", version="3.0.0")
    assert spec.inventory == str(fleet_dir / "inventory" / "hosts.yml") and spec.version == "3.0.0"


def test_inventory_override_replaces_a_broken_key(fleet_dir: Path) -> None:
    spec = load_fleet(write(fleet_dir, merge(BASE, {"inventory": "./nowhere"})),
                      inventory=str(fleet_dir / "inventory"))
    assert spec.inventory == str(fleet_dir / "inventory")


def test_bad_overrides_are_located_on_the_command_line(fleet_dir: Path) -> None:
    found = problems(fleet_dir, inventory="/no/such/inventory", version="latest")
    assert {(p.file, p.key) for p in found} == {("--inventory", ""), ("--version", "version")}


def test_inventory_expands_home_and_variables(fleet_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FLEET_HOME", str(fleet_dir))
    monkeypatch.setenv("HOME", str(fleet_dir))
    assert load_fleet(write(fleet_dir, merge(BASE, {"inventory": "$FLEET_HOME/inventory"}))).inventory \
        == str(fleet_dir / "inventory")
    assert load_fleet(write(fleet_dir, merge(BASE, {"inventory": "~/inventory"}))).inventory \
        == str(fleet_dir / "inventory")


# -------------------------------------------------------- top-level errors

@pytest.mark.parametrize("patch, key, words", [
    ({"project": "Ware House"}, "project", ["not a valid project name", "lower-case"]),
    ({"project": "a;reboot"}, "project", ["not a valid project name"]),
    ({"project": 7}, "project", ["must be a string"]),
    ({"inventory": "./missing"}, "inventory", ["does not exist", "pass -i"]),
    ({"inventory": "$ROSDEPLOY_TEST_UNSET/x"}, "inventory", ["$ROSDEPLOY_TEST_UNSET is not set"]),
    ({"registry": "https://registry.local"}, "registry", ["without a scheme"]),
    ({"version": "latest"}, "version", ["not a release version"]),
    ({"version": ""}, "version", ["not a release version"]),
    ({"version": 1.4}, "version", ["quote it"]),
    ({"version": datetime.date(2024, 1, 1)}, "version", ["a date (2024-01-01; quote it"]),      # `version: 2024-01-01`
    ({"version": "1.0;reboot"}, "version", ["not a valid image tag"]),
    ({"version": "$(reboot)"}, "version", ["not a valid image tag"]),
    ({"templates": "./no-templates"}, "templates", ["is not a directory"]),
    ({"deploy_root": "~/r; rm -rf /"}, "deploy_root", ["path on the robot"]),
    ({"deploy_root": "relative/dir"}, "deploy_root", ["absolute path or one under ~"]),
    ({"ssh": {"connect_timeout": "soon"}}, "ssh.connect_timeout", ["duration like 90, 90s, 2m"]),
    ({"ssh": "fast"}, "ssh", ["must be a mapping"]),
    ({"ros": {"rmw": "zenoh"}}, "ros.rmw", ["one of fastdds, cyclonedds"]),
    ({"ros": {"network_mode": "macvlan"}}, "ros.network_mode", ["one of host, bridge"]),
    ({"ros": {"shm_size": 512}}, "ros.shm_size", ["with a unit like 512m"]),
    ({"logging": {"max_file": 0}}, "logging.max_file", ["whole number >= 1"]),
    ({"logging": {"max_size": "lots"}}, "logging.max_size", ["size with a unit"]),
    ({"preflight": {"min_free_disk_mb": -1}}, "preflight.min_free_disk_mb", ["whole number >= 0"]),
    ({"health": {"timeout": "-5s"}}, "health.timeout", ["duration"]),
    ({"health": {"probe_service": "drivr"}}, "health.probe_service", ["did you mean `driver`"]),
    ({"rollout": {"waves": [1, "150%"]}}, "rollout.waves[1]", ["percentage of the targets"]),
    ({"rollout": {"waves": "10%"}}, "rollout.waves", ["must be a list"]),
    ({"rollout": {"waves": [True]}}, "rollout.waves[0]", ["robot count"]),
    ({"rollout": {"max_fail": -1}}, "rollout.max_fail", ["robot count"]),
    ({"rollout": {"forks": 0}}, "rollout.forks", [">= 1"]),
    ({"rollout": {"order_by": "site north"}}, "rollout.order_by", ["not a valid group prefix"]),
    ({"rollout": {"pause": "a while"}}, "rollout.pause", ["duration"]),
    ({"rollout": {"pause": 10**400}}, "rollout.pause", ["at most 8784h"]),     # was an OverflowError
    ({"rollout": {"waves": []}}, "rollout.waves", ["at least one wave"]),
    ({"rollout": {"waves": [2, 1]}}, "rollout.waves", ["never shrink"]),
    ({"rollout": {"waves": [1, "50%", "10%"]}}, "rollout.waves", ["never shrink"]),
    ({"ssh": {"connect_timeout": 0}}, "ssh.connect_timeout", ["above 0"]),
    ({"health": {"topic_window": "0s"}}, "health.topic_window", ["above 0"]),
    ({"logging": {"max_size": "0m"}}, "logging.max_size", ["above 0"]),
    ({"registry": "registry.local:99999"}, "registry", ["not a TCP port"]),
    ({"health": {"timeout": float("nan")}}, "health.timeout", ["at most 8784h"]),
    ({"rollback": {"keep_releases": 1}}, "rollback.keep_releases", [">= 2"]),
    ({"rollback": {"auto": "yes"}}, "rollback.auto", ["true or false"]),
    ({"vars": {"bad-name": 1}}, "vars.bad-name", ["not a valid template variable name"]),
    ({"services": ["driver"]}, "services", ["must be a mapping of service names"]),
    # fifth hostile-input round (issue #18): each was accepted
    ({"registry": "myregistry"}, "registry", ["Docker Hub account", "e.g. myregistry.local or myregistry:5000"]),
    ({"registry": "myregistry/team"}, "registry", ["'myregistry' has no `.` or port"]),
    ({"images": {"controller_registry": "htps://registry.example.com"}}, "images.controller_registry",
     ["not a registry address", "http:// or https://"]),
    ({"images": {"max_rate": float("nan")}}, "images.max_rate", ["not a rate", "from 1kB/s up"]),
    ({"images": {"total_rate": float("inf")}}, "images.total_rate", ["not a rate"]),
    ({"images": {"max_rate": "0.0000001B/s"}}, "images.max_rate", ["not a rate"]),
    ({"images": {"max_rate": "2Mbps"}}, "images.max_rate", ["it is bits per second", "e.g. 2MB/s"]),
    ({"health": {"timeout": "5s", "stable": "1h"}}, "health.stable",
     ["health.stable (3600 s) is not shorter than health.timeout (5 s)", "no release could pass the gate"]),
    ({"health": {"stable": "90s"}}, "health.stable", ["not shorter than health.timeout (90 s)"]),   # the default
    ({"health": {"timeout": "5s"}}, "health.timeout", ["health.stable (5 s) is not shorter"]),        # the default
    ({"rollout": {"waves": [1, 1]}}, "rollout.waves[1]", ["1 is listed twice"]),
])
def test_top_level_values_are_checked(fleet_dir: Path, patch: dict, key: str, words: list[str]) -> None:
    one(fleet_dir, patch, key, *words)


def test_services_must_not_be_empty(fleet_dir: Path) -> None:
    found = problems(fleet_dir, text=yaml.safe_dump({**BASE, "services": {}}))
    assert [p.key for p in found] == ["services"] and "declares no service" in found[0].message


@pytest.mark.parametrize("missing", ["project", "inventory", "version", "services"])
def test_required_keys(fleet_dir: Path, missing: str) -> None:
    one(fleet_dir, {missing: DELETE}, missing, "required key missing")


# --------------------------------------------------------- service errors

def svc(patch: dict) -> dict:
    return {"services": {"driver": patch}}


@pytest.mark.parametrize("patch, key, words", [
    ({"image": "acme/amr-driver:1.2"}, "image", ["must not carry a tag", 'tag: "1.2"', "version"]),
    ({"image": "registry.local:5000/acme/amr-driver:latest"}, "image", ["must not carry a tag"]),
    ({"image": "acme/amr-driver@sha256:abc"}, "image", ["digest", "tag:"]),
    ({"image": "ghcr.io/acme/amr-driver"}, "image", ["names its own registry (ghcr.io)"]),
    ({"image": "Acme/Driver"}, "image", ["not a valid image repository"]),
    ({"image": "acme/driver;reboot"}, "image", ["not a valid image repository"]),
    ({"image": None}, "image", ["must be a string"]),
    ({"image": "acme/" + "a" * 4091}, "image", ["'acme/aaaa", "is 4096 characters long", "over 255"]),
    ({"image": "acme/" + "a" * 4091 + "@sha256:" + "0" * 64}, "image", ["is 4096 characters long"]),
    ({"image": "acme/" + "a" * 246}, "image", ["'registry.local:5000/acme/a", "is 271 characters long"]),
    ({"tag": "latest"}, "tag", ["not a release version"]),
    ({"tag": " "}, "tag", ["not a release version"]),
    ({"command": "ros2 launch 'unbalanced"}, "command", ["cannot split", "as a list"]),
    ({"command": []}, "command", ["non-empty list"]),
    ({"command": [["nested"]]}, "command[0]", ["string, number"]),
    ({"environment": {"ROS_DOMAIN_ID": 3}}, "environment.ROS_DOMAIN_ID", ["set per robot by rosdeploy"]),
    ({"environment": {"LIST": [1]}}, "environment.LIST", ["string, number or true/false"]),
    ({"environment": {"1BAD": "x"}}, "environment.1BAD", ["not a valid environment variable name"]),
    ({"environment": {"T": "x"}, "secrets": {"T": "tok"}}, "secrets.T", ["also in `environment`"]),
    ({"secrets": {"TOKEN": "fleet token"}}, "secrets.TOKEN", ["inventory variable name"]),
    ({"devices": ["motor", "motor"]}, "devices[1]", ["listed twice"]),
    ({"devices": ["../motor"]}, "devices[0]", ["device name"]),
    ({"devices": "motor"}, "devices", ["must be a list"]),
    ({"gpu": "yes"}, "gpu", ["true or false"]),
    ({"restart": False}, "restart", ["unless-stopped"]),
    ({"restart": "sometimes"}, "restart", ["one of always, unless-stopped, on-failure"]),
    ({"resources": {"memory": 512}}, "resources.memory", ["unit"]),
    ({"resources": {"cpus": 0}}, "resources.cpus", ["above 0"]),
    ({"resources": {"cpus": 1e300}}, "resources.cpus", ["up to 1024"]),
    ({"resources": {"memory": "99999999999999999999g"}}, "resources.memory", ["more than 1024g"]),
    ({"resources": {"gpus": 1}}, "resources.gpus", ["unknown key"]),
    ({"healthcheck": "yes"}, "healthcheck", ["`image` to trust"]),
    ({"healthcheck": {"test": DELETE, "interval": "5s"}}, "healthcheck.test", ["required key missing"]),
    ({"healthcheck": {"test": ["ros2", "topic", "list"]}}, "healthcheck.test", ["CMD or CMD-SHELL"]),
    ({"healthcheck": {"test": "x", "retries": 0}}, "healthcheck.retries", [">= 1"]),
    ({"healthcheck": {"test": "x", "timeout": "3 s"}}, "healthcheck.timeout", ["duration"]),
    ({"depends_on": ["navigaton"]}, "depends_on[0]", ["did you mean `navigation`"]),
    ({"depends_on": ["driver"]}, "depends_on[0]", ["cannot depend on itself"]),
    ({"topics": ["joint_states"]}, "topics[0].name", ["absolute"]),
    ({"topics": ["/a__b"]}, "topics[0].name", ["no `__`"]),      # ROS 2 refuses the name at run time
    ({"topics": [{"name": "/a", "min_rate": 0}]}, "topics[0].min_rate", ["above 0"]),
    ({"topics": [{"name": "/a", "rate": 5}]}, "topics[0].rate", ["did you mean `min_rate`"]),
    ({"user": 1000}, "user", ["quote it"]),
    ({"user": "root; reboot"}, "user", ["uid:gid"]),
    ({"privileged": "no"}, "privileged", ["true or false"]),
    ({"profiles": ["Deploy"]}, "profiles[0]", ["profile name"]),
    ({"compose": {"restart": "always"}}, "compose.restart", ["fleet key `restart`"]),
    ({"compose": {"group_add": ["dialout"]}}, "compose.group_add", ["devices"]),
    ({"compose": ["cap_add"]}, "compose", ["mapping of compose service keys"]),
])
def test_service_values_are_checked(fleet_dir: Path, patch: dict, key: str, words: list[str]) -> None:
    one(fleet_dir, svc(patch), f"services.driver.{key}", *words)


def test_service_name_must_be_an_identifier(fleet_dir: Path) -> None:
    one(fleet_dir, {"services": {"bad name; reboot": {"image": "acme/x"}}}, "services.bad name; reboot",
        "not a valid service name")


def test_image_is_required(fleet_dir: Path) -> None:
    one(fleet_dir, {"services": {"watchdog": {"restart": "always"}}}, "services.watchdog.image", "required key missing")


def test_no_registry_needs_fully_qualified_images(fleet_dir: Path) -> None:
    found = problems(fleet_dir, {"registry": DELETE})
    assert {p.key for p in found} == {"services.driver.image", "services.navigation.image"}
    assert "docker.io/acme/amr-driver" in found[0].message


def test_dependency_without_healthcheck_never_starts(fleet_dir: Path) -> None:
    data = {"services": {"driver": {"healthcheck": DELETE}}}
    one(fleet_dir, data, "services.navigation.depends_on[0]", "no healthcheck", "service_healthy")


def test_dependency_cycle(fleet_dir: Path) -> None:
    found = problems(fleet_dir, {"services": {"driver": {"depends_on": ["navigation"]},
                                              "navigation": {"healthcheck": "image"}}})
    assert len(found) == 1 and "dependency cycle driver -> navigation -> driver" in found[0].message


# ------------------------------------------------------------ did-you-mean

@pytest.mark.parametrize("patch, key, suggestion", [
    ({"servics": {}}, "servics", "services"),
    ({"registy": "r"}, "registy", "registry"),
    ({"rollout": {"wave": [1]}}, "rollout.wave", "waves"),
    ({"ros": {"shm": "1g"}}, "ros.shm", "shm_size"),
    ({"services": {"driver": {"enviroment": {}}}}, "services.driver.enviroment", "environment"),
    ({"services": {"driver": {"healthcheck": {"test": "x", "intervall": 5}}}},
     "services.driver.healthcheck.intervall", "interval"),
])
def test_unknown_keys_suggest_the_closest(fleet_dir: Path, patch: dict, key: str, suggestion: str) -> None:
    one(fleet_dir, patch, key, f"did you mean `{suggestion}`?")


def test_unknown_key_without_a_close_match_lists_the_keys(fleet_dir: Path) -> None:
    one(fleet_dir, {"zzz": 1}, "zzz", "the keys here are: project, inventory")


def test_misspelt_required_key_is_reported_once(fleet_dir: Path) -> None:
    data = merge(BASE, {})
    data["servics"] = data.pop("services")
    with pytest.raises(FleetSpecError) as info:
        load_fleet(write(fleet_dir, data))
    assert [p.key for p in info.value.problems] == ["servics"]


# ------------------------------------------- values that break files/shells

@pytest.mark.parametrize("patch, key", [
    ({"services": {"driver": {"environment": {"MOTD": "a\nb"}}}}, "services.driver.environment.MOTD"),
    ({"services": {"driver": {"command": ["echo", "a\0b"]}}}, "services.driver.command[1]"),
    ({"vars": {"note": "x\ry"}}, "vars.note"),
    ({"version": "1.0\n"}, "version"),
    ({"project": "ware\nhouse"}, "project"),
])
def test_control_characters_are_refused_once(fleet_dir: Path, patch: dict, key: str) -> None:
    one(fleet_dir, patch, key, "write it on one line")


def test_control_character_in_a_key(fleet_dir: Path) -> None:
    found = problems(fleet_dir, text=yaml.safe_dump(merge(BASE, {"vars": {"a\nb": 1}})))
    assert any(p.key == "vars.a\nb" and "key contains a newline" in p.message for p in found)


def test_shell_metacharacters_in_free_text_stay_data(fleet_dir: Path) -> None:
    env = {"services": {"driver": {"environment": {"CMD": "$(reboot); `x` | y"}}}}
    spec = load_fleet(write(fleet_dir, merge(BASE, env)))
    assert spec.service("driver").environment["CMD"] == "$(reboot); `x` | y"


# ------------------------------------------------------------ whole files

def test_malformed_yaml_names_file_and_line(fleet_dir: Path) -> None:
    found = problems(fleet_dir, text="project: warehouse\nservices: [unclosed\n")
    assert len(found) == 1 and found[0].line == 3 and "invalid YAML" in found[0].message


def test_duplicate_key(fleet_dir: Path) -> None:
    found = problems(fleet_dir, text="project: a\nproject: b\n")
    assert found[0].line == 2 and "duplicate key" in found[0].message


@pytest.mark.parametrize("text", ["", "- a\n- b\n", "just text\n"])
def test_not_a_mapping(fleet_dir: Path, text: str) -> None:
    found = problems(fleet_dir, text=text)
    assert len(found) == 1 and "must be a mapping" in found[0].message


def test_missing_file() -> None:
    with pytest.raises(FleetSpecError) as info:
        load_fleet("/no/such/fleet.yml")
    assert "cannot read file" in str(info.value)


def test_all_problems_are_collected_sorted_by_line(fleet_dir: Path) -> None:
    text = ("project: Bad\ninventory: ./inventory\nregistry: r.local\nversion: latest\n"
            "services:\n  driver:\n    image: acme/d:1\n    restart: no\n")
    found = problems(fleet_dir, text=text)
    assert [(p.line, p.key) for p in found] == [
        (1, "project"), (4, "version"), (7, "services.driver.image"), (8, "services.driver.restart")]
    assert str(found[0]).startswith(f"{fleet_dir / 'fleet.yml'}:1: project: 'Bad' is not a valid project name")


def test_spec_keeps_lines_for_later_checks(fleet_dir: Path) -> None:
    spec = load_fleet(write(fleet_dir, text="project: w\ninventory: ./inventory\nregistry: r.local\n"
                                            "version: '1'\nservices:\n  driver:\n    image: acme/d\n"))
    p = problem_at(spec, ("services", "driver", "restart"), "m")
    assert (p.line, p.key) == (6, "services.driver.restart")


# ---------------------------------------------------------------- values

@pytest.mark.parametrize("text, seconds", [
    (90, 90), (1.5, 1.5), ("90", 90), ("90s", 90), ("2m", 120), ("1m30s", 90), ("500ms", 0.5), ("1h", 3600)])
def test_durations(text: Any, seconds: float) -> None:
    assert parse_duration(text) == seconds


@pytest.mark.parametrize("text", ["", "s", "5x", "-1", -1, "1 m", True, None, "1m-5s", float("nan"), float("inf"),
                                  10**400, "99999999999999999999h", "8785h"])
def test_bad_durations(text: Any) -> None:
    with pytest.raises(ValueError):
        parse_duration(text)


def test_compose_durations() -> None:
    assert [compose_duration(s) for s in (5, 90.0, 1.5)] == ["5s", "90s", "1500ms"]


@pytest.mark.parametrize("text, size", [("512m", 512 << 20), ("1g", 1 << 30), ("256MB", 256 << 20),
                                        ("64k", 64 << 10), ("1024", 1024), (2048, 2048)])
def test_sizes(text: Any, size: int) -> None:
    assert size_bytes(text) == size


# ----------------------------------------------------------- no tracebacks

def _paths(value: Any, kp: tuple = ()) -> list[tuple]:
    out = [kp] if kp else []
    if isinstance(value, dict):
        for key, item in value.items():
            out += _paths(item, kp + (key,))
    elif isinstance(value, list):
        for i, item in enumerate(value):
            out += _paths(item, kp + (i,))
    return out


def _replace(data: Any, kp: tuple, value: Any) -> Any:
    data = copy.deepcopy(data)
    target = data
    for part in kp[:-1]:
        target = target[part]
    target[kp[-1]] = value
    return data


def test_any_wrong_value_anywhere_is_a_clean_error(fleet_dir: Path) -> None:
    """Every key, replaced by every kind of wrong value: FleetSpecError or a spec, never a crash."""
    example = full_fleet(fleet_dir)
    for kp in _paths(example):
        for wrong in (None, -1, "x", [], {"x": 1}, True):
            try:
                load_fleet(write(fleet_dir, _replace(example, kp, wrong)))
            except FleetSpecError as exc:
                assert exc.problems and all(p.file and p.message for p in exc.problems)


def test_volumes_are_bind_mounts_normalized_with_their_mode(fleet_dir: Path) -> None:
    spec = load_fleet(write(fleet_dir, merge(BASE, {"services": {"driver": {
        "volumes": ["/opt/maps:/maps:ro", "/var/lib/calib/:/calib", "/srv/a:/b:rw"]}}})))
    assert spec.services[0].volumes == ("/opt/maps:/maps:ro", "/var/lib/calib:/calib:rw", "/srv/a:/b:rw")


@pytest.mark.parametrize("volume,words", [
    ("maps:/maps", ["not a bind mount", "/path/on/robot:/path/in/container"]),
    ("/opt/maps:maps", ["not a bind mount"]),
    ("/opt/maps:/maps:rx", ["not a bind mount"]),
    ("/opt/../etc:/etc2", ["not a bind mount"]),
    ("/opt/..:/x", ["not a bind mount"]),
    ("/opt:/x/..", ["not a bind mount"]),
    ("/opt/m aps:/maps", ["not a bind mount"]),
    ("/opt/$HOME:/maps", ["not a bind mount"]),
    ("/opt/logs:/ros_log", ["where rosdeploy mounts /ros_log itself"]),
    ("/tmp/x:/dev/shm/x", ["where rosdeploy mounts /dev/shm itself"]),
    ("/etc/dds.xml:/fastdds.xml:ro", ["where rosdeploy mounts /fastdds.xml itself"]),
    (7, ["must be a string"]),
])
def test_bad_volumes_name_the_entry_and_the_fix(fleet_dir: Path, volume: Any, words: list[str]) -> None:
    one(fleet_dir, {"services": {"driver": {"volumes": [volume]}}}, "services.driver.volumes[0]", *words)


def test_a_file_without_target_is_a_problem_not_a_crash(fleet_dir: Path) -> None:
    found = problems(fleet_dir, {"files": {"params": {"template": "params.yaml"}}})
    assert [(p.key, "required key missing" in p.message) for p in found] == [("files.params.target", True)], found


@pytest.mark.parametrize("make, words", [
    (lambda p: None, "No such file or directory: give the path of an OpenSSH client config file"),
    (lambda p: p.mkdir(), "is not a regular file"),
    (lambda p: os.mkfifo(p), "is not a regular file"),                     # was silently nothing
    (lambda p: p.write_bytes(b"Host x\n\x8f\xff\n"), "is not UTF-8 text"),   # was an internal error
    (lambda p: p.write_bytes(b"#" * ((1 << 20) + 1)), "is larger than 1 MB"),   # a bigger one, a MemoryError
])
def test_an_ssh_config_that_cannot_be_one_is_refused(fleet_dir: Path, make: Any, words: str) -> None:
    make(fleet_dir / "cfg")
    one(fleet_dir, {"ssh": {"config": "cfg"}}, "ssh.config", words)


@pytest.mark.parametrize("target", ["/", "/.", "/etc/.", "/config//params.yaml", "/config/./params.yaml",
                                    "/config/params.yaml/"])
def test_a_file_target_is_written_plainly(fleet_dir: Path, target: str) -> None:
    # `/.` passed validate, and render failed on "--out: cannot write there (Is a directory)"
    one(fleet_dir, {"files": {"params": {"copy": "params.yaml", "target": target}}}, "files.params.target",
        "must be an absolute file path in the container, written without `.`, `..`, `//` or a trailing `/`")


def test_a_ready_condition_with_a_newline_is_a_problem_not_a_crash(fleet_dir: Path) -> None:
    """The control-character scan reports the value; the condition it belongs to must not reach later checks."""
    found = problems(fleet_dir, {"ready": {"when": [{"service": "a\nb", "command": ["true"]}]}})
    assert [p.key for p in found] == ["ready.when[0].service"], found
    assert "newline" in found[0].message


RICH: dict[str, Any] = merge(BASE, {
    "ros": {"rmw": "fastdds", "network_mode": "bridge"}, "health": {"probe_service": "driver"},
    "rollout": {"waves": [1, "50%"], "max_fail": 0},
    "files": {"params": {"template": "params/{{ inventory_hostname }}.yaml", "target": "/config/params.yaml"}},
    "ready": {"when": [{"topic": "/robot_mode", "field": "data", "is": "IDLE"},
                       {"service": "driver", "command": ["true"]}]},
    "services": {"driver": {"environment": {"RATE": 5}, "secrets": {"TOKEN": "fleet_token"}, "files": ["params"],
                            "resources": {"memory": "256m", "cpus": 0.5}, "volumes": ["/opt/maps:/maps:ro"]},
                 "navigation": {"compose": {"cap_add": ["SYS_NICE"]}, "healthcheck": "image"}},
})
ODD: list[Any] = [None, True, 0, -1, 2.5, "", "Bad Name", "latest", "driver", "nosuch", "a\nb", "ROS_DOMAIN_ID",
                  "TOKEN", "$NOPE/x", "../x", "/fastdds.xml", "0m", [], ["nosuch", "driver"], ["Bad!", "nosuch"],
                  ["driver", "driver"], [1, "x"], {}, {"a": 1}, {"test": "x"}, {"template": "a"}, ["CMD", 5],
                  {"cap_add": "X"}, {"ROS_DOMAIN_ID": "1"}, ["params", "nope"], "no"]


def _key_paths(data: Any, kp: tuple = ()) -> list[tuple]:
    inner = data.items() if isinstance(data, dict) else enumerate(data) if isinstance(data, list) else ()
    return [kp] + [p for key, value in inner for p in _key_paths(value, kp + (key,))]


def test_mutated_fleet_files_give_problems_never_a_crash(fleet_dir: Path) -> None:
    """Random odd values at random keys (how the two crashes above were found): a FleetSpec or a
    FleetSpecError, nothing else, for every file."""
    rng = random.Random(18)
    for _ in range(300):
        data = copy.deepcopy(RICH)
        for _ in range(rng.randrange(1, 4)):
            kp = rng.choice(_key_paths(data)[1:])
            parent = data
            for key in kp[:-1]:
                parent = parent[key]
            parent[kp[-1]] = copy.deepcopy(rng.choice(ODD))
        try:
            load_fleet(write(fleet_dir, data))
        except FleetSpecError as exc:
            assert exc.problems and all(p.file and p.message for p in exc.problems)


def test_topics_within_is_a_positive_duration(fleet_dir: Path) -> None:
    spec = load_fleet(write(fleet_dir, merge(BASE, {"health": {"topics_within": "45s"}})))
    assert spec.health.topics_within == 45.0
    assert load_fleet(write(fleet_dir, BASE)).health.topics_within == 10.0
    one(fleet_dir, {"health": {"topics_within": "0s"}}, "health.topics_within", "above 0")


# ------------------------------------------------- issue 18: hostile values refused at the key

NINES = "9" * 400


@pytest.mark.parametrize("patch, key", [
    ({"services": {"driver": {"resources": {"memory": NINES + "m"}}}}, "services.driver.resources.memory"),
    ({"logging": {"max_size": NINES + "m"}}, "logging.max_size"),
    ({"ros": {"shm_size": NINES + "m"}}, "ros.shm_size"),
    ({"ros": {"shm_size": "1025g"}}, "ros.shm_size"),
])
def test_a_size_past_a_terabyte_is_refused_at_its_key(fleet_dir: Path, patch: dict, key: str) -> None:
    # 400 nines overflowed float to inf: int(inf) raised OverflowError (exit 1).
    one(fleet_dir, patch, key, "more than 1024g")


def test_size_bytes_raises_value_error_on_overflow() -> None:
    with pytest.raises(ValueError):
        size_bytes(NINES + "m")


@pytest.mark.parametrize("cpus", [1e-7, 0.009])
def test_cpus_below_dockers_least_are_refused(fleet_dir: Path, cpus: float) -> None:
    one(fleet_dir, {"services": {"driver": {"resources": {"cpus": cpus}}}}, "services.driver.resources.cpus", "0.01")


@pytest.mark.parametrize("field, value, words", [
    ("interval", "0s", ["Docker reads 0"]), ("timeout", 0, ["Docker reads 0"]),
    ("interval", "0.0001s", ["1ms"]), ("start_period", "0.0004s", ["1ms"]),
])
def test_healthcheck_durations_docker_would_misread_are_refused(fleet_dir: Path, field: str, value: Any,
                                                               words: list[str]) -> None:
    patch = {"services": {"driver": {"healthcheck": {field: value}}}}
    one(fleet_dir, patch, f"services.driver.healthcheck.{field}", *words)


def test_a_healthcheck_start_period_of_0_means_none(fleet_dir: Path) -> None:
    spec = load_fleet(write(fleet_dir, merge(BASE, {"services": {"driver": {"healthcheck": {"start_period": 0}}}})))
    assert spec.services[0].healthcheck is not None


@pytest.mark.parametrize("volumes", [["/a:/b", "/c:/b"], ["/a:/b", "/c:/b/:ro"], ["/a:/b", "/c:/./b"]])
def test_two_volumes_at_one_container_path_are_refused(fleet_dir: Path, volumes: list[str]) -> None:
    one(fleet_dir, {"services": {"driver": {"volumes": volumes}}}, "services.driver.volumes[1]", "volumes[0]")


def test_a_volume_over_a_managed_mount_is_refused_however_written(fleet_dir: Path) -> None:
    one(fleet_dir, {"services": {"driver": {"volumes": ["/x:/dev/./shm"]}}}, "services.driver.volumes[0]",
        "rosdeploy mounts /dev/shm")


@pytest.mark.parametrize("tmpfs, key", [
    (["/dev/shm"], "services.driver.compose.tmpfs[0]"),
    (["/x", "/ros_log/sub:size=1m"], "services.driver.compose.tmpfs[1]"),
    ("/fastdds.xml", "services.driver.compose.tmpfs"),
])
def test_a_tmpfs_over_a_managed_mount_is_refused(fleet_dir: Path, tmpfs: Any, key: str) -> None:
    one(fleet_dir, {"services": {"driver": {"compose": {"tmpfs": tmpfs}}}}, key, "rosdeploy mounts")


@pytest.mark.parametrize("root", ["/.", "/./", "/./."])
def test_deploy_root_that_normalises_to_root_is_refused(fleet_dir: Path, root: str) -> None:
    one(fleet_dir, {"deploy_root": root}, "deploy_root", "root folder")
