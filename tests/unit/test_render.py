"""Rendering: (FleetSpec, Host) -> RenderedRelease, checked by parsing every file back."""
from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest
import yaml

from rosdeploy.errors import RenderError
from rosdeploy.model import FleetSpec, HealthCheck, Host, RenderedRelease, Service, UdevDevice
from rosdeploy.render import Renderer, env_value, render, yaml_str

NASTY = "a\": {}[]&*#<>'|%@`!,?-\\ $HOME ${X} $$ \t ü 😀 \u2028 \x85 end"

# Key names the schema of Compose v1 1.29.2 (compose/config/compose_spec.json) accepts;
# v1 refuses a file with any other key (e.g. a top-level `name:`), v2 accepts all of them.
V1_TOP_KEYS = {"version", "services", "networks", "volumes", "secrets", "configs"}
V1_SERVICE_KEYS = {
    "deploy", "build", "blkio_config", "cap_add", "cap_drop", "cgroup_parent", "command", "configs",
    "container_name", "cpu_count", "cpu_percent", "cpu_shares", "cpu_quota", "cpu_period", "cpu_rt_period",
    "cpu_rt_runtime", "cpus", "cpuset", "credential_spec", "depends_on", "device_cgroup_rules", "devices",
    "dns", "dns_opt", "dns_search", "domainname", "entrypoint", "env_file", "environment", "expose",
    "extends", "external_links", "extra_hosts", "group_add", "healthcheck", "hostname", "image", "init",
    "ipc", "isolation", "labels", "links", "logging", "mac_address", "mem_limit", "mem_reservation",
    "mem_swappiness", "memswap_limit", "network_mode", "networks", "oom_kill_disable", "oom_score_adj",
    "pid", "pids_limit", "platform", "ports", "privileged", "profiles", "pull_policy", "read_only",
    "restart", "runtime", "scale", "security_opt", "shm_size", "secrets", "sysctls", "stdin_open",
    "stop_grace_period", "stop_signal", "storage_opt", "tmpfs", "tty", "ulimits", "user", "userns_mode",
    "volumes", "volumes_from", "working_dir",
}


# ------------------------------------------------------------------ helpers

def make_service(name: str = "driver", **kw: Any) -> Service:
    base: dict[str, Any] = dict(
        image=f"demo/{name}", tag="1.0.0", command=("ros2", "run", "demo", name),
        healthcheck=HealthCheck(("CMD-SHELL", "test -f /tmp/healthy")), memory="256m", cpus=0.5)
    base.update(kw)
    return Service(name=name, **base)


def make_spec(*services: Service, **kw: Any) -> FleetSpec:
    base: dict[str, Any] = dict(
        path="/fleet/fleet.yml", project="demo", inventory="/fleet/inventory",
        registry="registry.local:5000", version="1.0.0")
    base.update(kw)
    return FleetSpec(services=services or (make_service(),), **base)


def make_host(name: str = "robot1", **kw: Any) -> Host:
    base: dict[str, Any] = dict(groups=("all",), vars={}, address="10.0.0.1", ros_domain_id=7,
                                source="/fleet/inventory/hosts.yml:4")
    base.update(kw)
    return Host(name=name, **base)


def files(release: RenderedRelease) -> dict[str, str]:
    return {f.name: f.content for f in release.files}


def compose(release: RenderedRelease) -> dict[str, Any]:
    return yaml.safe_load(release.file("compose.yml").content)


def uncompose(value: str) -> str:
    """What compose makes of a literal after interpolation: `$$` is one `$`."""
    return value.replace("$$", "$")


def dotenv(text: str) -> dict[str, str]:
    """The subset of .env both Compose v1 and v2 read alike: bare or single-quoted values."""
    out = {}
    for line in text.splitlines():
        if not line or line.startswith("#"):
            continue
        key, _, value = line.partition("=")
        out[key] = value[1:-1] if value.startswith("'") else value
    return out


def peers_fastdds(xml_text: str) -> set[str]:
    root = ET.fromstring(xml_text)
    return {e.text for e in root.iter() if e.tag.endswith("address")}


def peers_cyclone(xml_text: str) -> set[str]:
    root = ET.fromstring(xml_text)
    return {e.get("address") for e in root.iter() if e.tag.endswith("Peer")}


FULL = make_spec(
    make_service("driver", restart="always", devices=("motor",), secret_env={"API_TOKEN": "vault_token"},
                 environment={"RATE": "50", "ROBOT": "{{ inventory_hostname }}"}),
    make_service("perception", gpu=True, depends_on=("driver",), devices=("camera",),
                 extra={"device_cgroup_rules": ["c 81:* rmw"]}),
    make_service("watchdog", image="demo/driver", healthcheck=None, profiles=("deploy",), user="1000:1000"),
)
FULL_HOST = make_host(
    vars={"vault_token": "t0k3n-$ecret"}, secret_values=frozenset({"t0k3n-$ecret"}), gpu=True,
    devices={"motor": "/dev/robot/motor", "camera": "/dev/video0"},
    udev=(UdevDevice("robot/motor", "tty", "0403", "6001"),))


# ------------------------------------------------------------ determinism

def test_same_inputs_give_identical_bytes_and_digest() -> None:
    a = Renderer(FULL).render(FULL_HOST)
    b = Renderer(FULL).render(FULL_HOST)
    assert files(a) == files(b)
    assert a.digest == b.digest and a.release_id == b.release_id
    assert a == render(FULL, FULL_HOST)


@pytest.mark.parametrize("change", [
    lambda s, h: (s, dataclasses.replace(h, ros_domain_id=8)),
    lambda s, h: (s, dataclasses.replace(h, vars={**h.vars, "vault_token": "other-secret"})),
    lambda s, h: (s, dataclasses.replace(h, name="robot2")),   # ROBOT env comes from the host name
    lambda s, h: (dataclasses.replace(s, version="1.0.1"), h),
    lambda s, h: (dataclasses.replace(s, log_max_size="20m"), h),
])
def test_digest_changes_with_any_input(change: Any) -> None:
    spec, host = change(FULL, FULL_HOST)
    assert render(spec, host).digest != render(FULL, FULL_HOST).digest


def test_files_sorted_and_images_sorted_unique() -> None:
    rel = render(FULL, FULL_HOST)
    names = [f.name for f in rel.files]
    assert names == sorted(names)
    assert [n for n in names if not n.startswith("store/")] == [".env", "99-rosdeploy.rules", "compose.yml",
                                                               "fastdds.xml", "logrotate.conf", "logrotate.cron"]
    assert [n.split("/")[-1] for n in names if n.startswith("store/")] == ["fastdds.xml"]
    assert rel.images == ("registry.local:5000/demo/driver:1.0.0", "registry.local:5000/demo/perception:1.0.0")


# ------------------------------------------------------------------ compose

def test_compose_parses_with_practices_on_every_service() -> None:
    rel = render(FULL, FULL_HOST)
    doc = compose(rel)
    assert set(doc) == {"x-ros-common", "services"}
    for name, svc in doc["services"].items():
        assert svc["logging"] == {"driver": "json-file", "options": {"max-size": "10m", "max-file": "3"}}
        assert svc["restart"] in ("always", "unless-stopped")
        assert svc["network_mode"] == "host" and svc["shm_size"] in ("512m", "1g")
        assert svc["environment"]["ROS_DOMAIN_ID"] == "${ROS_DOMAIN_ID:?ROS_DOMAIN_ID must be set in .env}"
        assert svc["environment"]["RMW_IMPLEMENTATION"].startswith("${RMW_IMPLEMENTATION:?")
        assert svc["environment"]["FASTRTPS_DEFAULT_PROFILES_FILE"] == "/fastdds.xml"
        assert svc["environment"]["ROS_LOG_DIR"] == "/ros_log"
        stored = next(f.name for f in rel.files if f.name.startswith("store/"))
        assert rel.file(stored).content == rel.file("fastdds.xml").content
        assert svc["volumes"] == [f"../../{stored}:/fastdds.xml:ro", "/dev/shm:/dev/shm", f"../../logs/{name}:/ros_log"]
        labels = dict(svc["labels"])
        assert len(labels.pop("io.rosdeploy.hash")) == 16
        assert labels == {"io.rosdeploy.project": "demo", "io.rosdeploy.service": name}
        assert svc["image"] in rel.images
        assert "privileged" not in svc
    assert {name for name, s in doc["services"].items() if "healthcheck" in s} == {"driver", "perception"}
    hc = doc["services"]["driver"]["healthcheck"]
    assert hc == {"test": ["CMD-SHELL", "test -f /tmp/healthy"], "interval": "5s", "timeout": "3s",
                  "retries": 3, "start_period": "10s"}
    driver = doc["services"]["driver"]
    assert driver["restart"] == "always" and driver["mem_limit"] == "256m" and driver["cpus"] == 0.5
    assert driver["command"] == ["ros2", "run", "demo", "driver"]
    assert driver["environment"]["ROBOT"] == "robot1"
    perception = doc["services"]["perception"]
    assert perception["depends_on"] == {"driver": {"condition": "service_healthy"}}
    assert perception["device_cgroup_rules"] == ["c 81:* rmw"]
    watchdog = doc["services"]["watchdog"]
    assert watchdog["profiles"] == ["deploy"] and watchdog["user"] == "1000:1000"
    assert "ROS_DOMAIN_ID=7" in rel.file(".env").content
    assert "ROS_DOMAIN_ID: 7" not in rel.file("compose.yml").content   # never hard-coded


def test_compose_uses_only_keys_compose_v1_accepts() -> None:
    for mode in ("host", "bridge"):
        doc = compose(render(dataclasses.replace(FULL, network_mode=mode), FULL_HOST))
        assert {k for k in doc if not k.startswith("x-")} <= V1_TOP_KEYS, "v1 rejects e.g. a top-level name:"
        for svc in doc["services"].values():
            assert set(svc) <= V1_SERVICE_KEYS


def test_privileged_only_when_set() -> None:
    spec = make_spec(make_service(privileged=True, allow_privileged=True))
    assert compose(render(spec, make_host()))["services"]["driver"]["privileged"] is True


def test_extra_may_not_repeat_rendered_keys() -> None:
    spec = make_spec(make_service(extra={"environment": {"A": "1"}, "restart": "no"}))
    with pytest.raises(RenderError, match="environment, restart are rendered by rosdeploy"):
        Renderer(spec)


# --------------------------------------------------------------- gpu, devices

@pytest.mark.parametrize("service_gpu,host_gpu,reserved", [(True, True, True), (True, False, False),
                                                          (False, True, False), (False, False, False)])
def test_gpu_reservation_only_when_service_and_robot_have_gpu(service_gpu: bool, host_gpu: bool,
                                                              reserved: bool) -> None:
    spec = make_spec(make_service("perception", gpu=service_gpu))
    svc = compose(render(spec, make_host(gpu=host_gpu)))["services"]["perception"]
    if reserved:
        assert svc["runtime"] == "nvidia" and "deploy" not in svc   # what preflight checks, v1 and v2 alike
        assert svc["environment"]["NVIDIA_VISIBLE_DEVICES"] == "all"
        assert svc["environment"]["NVIDIA_DRIVER_CAPABILITIES"] == "compute,utility,video"
        assert svc["shm_size"] == "1g"
    else:
        assert "runtime" not in svc and "NVIDIA_VISIBLE_DEVICES" not in svc["environment"]
        assert svc["shm_size"] == "512m"


def test_devices_resolved_with_groups() -> None:
    spec = make_spec(make_service(devices=("motor", "lidar", "camera", "cam2", "imu", "gpio")))
    host = make_host(
        devices={"motor": "/dev/robot/motor", "lidar": "/dev/ttyUSB0", "camera": "/dev/video0",
                 "cam2": "/dev/robot/cam2", "imu": "/dev/robot/imu", "gpio": "/dev/gpiochip0"},
        udev=(UdevDevice("robot/motor", "tty", "0403", "6001"),
              UdevDevice("robot/cam2", "video4linux", "046d", "0825"),
              UdevDevice("robot/imu", "tty", "10c4", "ea60", group="plugdev")))
    svc = compose(render(spec, host))["services"]["driver"]
    assert svc["devices"] == ["/dev/robot/motor:/dev/robot/motor", "/dev/ttyUSB0:/dev/ttyUSB0",
                              "/dev/video0:/dev/video0", "/dev/robot/cam2:/dev/robot/cam2",
                              "/dev/robot/imu:/dev/robot/imu", "/dev/gpiochip0:/dev/gpiochip0"]
    assert svc["group_add"] == ["dialout", "plugdev", "video"]


def test_bind_mounts_follow_the_ones_rosdeploy_makes() -> None:
    spec = make_spec(make_service(volumes=("/opt/maps:/maps:ro", "/var/lib/calib:/calib:rw")))
    svc = compose(render(spec, make_host()))["services"]["driver"]
    assert svc["volumes"][3:] == ["/opt/maps:/maps:ro", "/var/lib/calib:/calib:rw"]
    assert svc["volumes"][1:3] == ["/dev/shm:/dev/shm", "../../logs/driver:/ros_log"]


def test_missing_device_names_robot_service_and_device() -> None:
    spec = make_spec(make_service(devices=("lidar",)))
    with pytest.raises(RenderError) as err:
        render(spec, make_host(devices={}))
    problem = err.value.problems[0]
    assert problem.file == "/fleet/inventory/hosts.yml" and problem.line == 4
    assert "robot1" in str(problem) and "driver" in str(problem) and "'lidar'" in str(problem)


# ---------------------------------------------------------------------- DDS

def test_bridge_mode_lists_every_service_as_peer_in_both_dds_flavours() -> None:
    host = dataclasses.replace(FULL_HOST, vars={**FULL_HOST.vars, "dds_peers": ["10.0.0.2"]})
    fast = files(render(dataclasses.replace(FULL, network_mode="bridge"), host))
    root = ET.fromstring(fast["fastdds.xml"])
    assert peers_fastdds(fast["fastdds.xml"]) == {"driver", "perception", "watchdog", "10.0.0.2"}
    ports = {int(e.text) for e in root.iter() if e.tag.endswith("port")}
    assert ports == {7400 + 250 * 7 + 10 + 2 * p for p in range(4)}       # domain 7, participants 0..3
    assert root.find(".//{*}leaseDuration/{*}sec").text == "10"
    doc = yaml.safe_load(fast["compose.yml"])
    assert doc["networks"] == {"ros": {"driver": "bridge"}}
    assert all(s["networks"] == ["ros"] and "network_mode" not in s for s in doc["services"].values())

    cyc = files(render(dataclasses.replace(FULL, network_mode="bridge", rmw="cyclonedds"), host))
    root = ET.fromstring(cyc["cyclonedds.xml"])
    assert peers_cyclone(cyc["cyclonedds.xml"]) == {"driver", "perception", "watchdog", "10.0.0.2"}
    assert root.find(".//{*}General/{*}AllowMulticast").text == "false"
    assert root.find(".//{*}Discovery/{*}ParticipantIndex").text == "auto"
    assert root.find(".//{*}Discovery/{*}MaxAutoParticipantIndex").text == "120"
    assert root.find(".//{*}Internal/{*}SocketReceiveBufferSize").get("min") == "10MB"
    assert "fastdds.xml" not in cyc


def test_host_mode_has_no_peers() -> None:
    fast = files(render(FULL, FULL_HOST))
    assert peers_fastdds(fast["fastdds.xml"]) == set()
    cyc = files(render(dataclasses.replace(FULL, rmw="cyclonedds"), FULL_HOST))
    assert peers_cyclone(cyc["cyclonedds.xml"]) == set()
    assert ET.fromstring(cyc["cyclonedds.xml"]).find(".//{*}AllowMulticast") is None
    env = dotenv(cyc[".env"])
    assert env["RMW_IMPLEMENTATION"] == "rmw_cyclonedds_cpp"
    svc = yaml.safe_load(cyc["compose.yml"])["services"]["driver"]
    assert svc["environment"]["CYCLONEDDS_URI"] == "file:///cyclonedds.xml"
    assert svc["volumes"][0].startswith("../../store/")
    assert svc["volumes"][0].endswith("/cyclonedds.xml:/cyclonedds.xml:ro")


def test_host_mode_with_inventory_peers_keeps_multicast() -> None:
    host = dataclasses.replace(FULL_HOST, vars={**FULL_HOST.vars, "dds_peers": "robot2.lan"})
    fast = render(FULL, host).file("fastdds.xml").content
    assert peers_fastdds(fast) == {"239.255.0.1", "robot2.lan"}


def test_bad_dds_peers_is_an_error() -> None:
    with pytest.raises(RenderError, match="dds_peers must be a list"):
        render(FULL, dataclasses.replace(FULL_HOST, vars={**FULL_HOST.vars, "dds_peers": [1]}))


# ------------------------------------------------------------------ secrets

def test_secrets_only_in_env_file() -> None:
    rel = render(FULL, FULL_HOST)
    env_file = rel.file(".env")
    assert env_file.mode == 0o600 and env_file.secret
    assert dotenv(env_file.content)["API_TOKEN"] == "t0k3n-$ecret"
    assert rel.secret_values == frozenset({"t0k3n-$ecret"})
    for f in rel.files:
        if f.name != ".env":
            assert "t0k3n" not in f.content and not f.secret and f.mode == 0o644
    svc = compose(rel)["services"]["driver"]
    assert svc["environment"]["API_TOKEN"] == "${API_TOKEN:?API_TOKEN must be set in .env}"


def test_env_file_without_secrets_is_not_secret_but_still_0600() -> None:
    rel = render(make_spec(), make_host())
    assert rel.file(".env").mode == 0o600 and not rel.file(".env").secret and rel.secret_values == frozenset()
    assert dotenv(rel.file(".env").content) == {
        "COMPOSE_PROJECT_NAME": "demo", "ROS_DOMAIN_ID": "7", "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp",
        "ROSDEPLOY_PROJECT": "demo", "ROSDEPLOY_VERSION": "1.0.0",
        "DRIVER_IMAGE": "registry.local:5000/demo/driver:1.0.0"}


@pytest.mark.parametrize("value", ["two\nlines", "it's", "back\\\\slash", "trailing\\"])
def test_secret_values_env_cannot_carry_are_refused(value: str) -> None:
    host = dataclasses.replace(FULL_HOST, vars={"vault_token": value}, secret_values=frozenset({value}))
    with pytest.raises(RenderError, match="secret API_TOKEN"):
        render(FULL, host)


def test_missing_secret_var_is_named() -> None:
    with pytest.raises(RenderError, match="reads secret API_TOKEN from var 'vault_token'"):
        render(FULL, dataclasses.replace(FULL_HOST, vars={}))


def test_secret_leaking_into_compose_is_refused() -> None:
    spec = make_spec(make_service(environment={"TOKEN": "{{ vault_token }}"}))
    host = make_host(vars={"vault_token": "hunter22"}, secret_values=frozenset({"hunter22"}))
    with pytest.raises(RenderError, match="copies a vault secret into compose.yml") as caught:
        render(spec, host)
    # reported at the fleet key that copies it, not where the robot is declared
    assert [p.key for p in caught.value.problems] == ["services.driver.environment.TOKEN"]
    assert "hunter22" not in str(caught.value)


# ------------------------------------------------------------ metacharacters

@pytest.mark.parametrize("value", [NASTY, "", "yes", "null", "0o17", "1e3", "- x", "~", "#x", "&a *b", "\x01\x7f"])
def test_yaml_str_round_trips(value: str) -> None:
    assert yaml.safe_load(f"k: {yaml_str(value)}") == {"k": value}


def test_inventory_values_with_metacharacters_parse_back() -> None:
    spec = make_spec(make_service(environment={"LABEL": "{{ label }}"}, devices=("motor",),
                                  healthcheck=HealthCheck(("CMD-SHELL", NASTY))),
                     network_mode="bridge")
    # dds_peers must be addresses now (a hostile one is refused: tests/unit/test_hostile.py)
    host = make_host(name="odd\nname: {x}", vars={"label": NASTY, "dds_peers": ["amr-2.local", "fe80::1"]},
                     devices={"motor": "/dev/robot/m&*<>#[]{}"})
    rel = render(spec, host)
    svc = compose(rel)["services"]["driver"]
    assert uncompose(svc["environment"]["LABEL"]) == NASTY
    assert uncompose(svc["healthcheck"]["test"][1]) == NASTY
    assert svc["devices"] == ["/dev/robot/m&*<>#[]{}:/dev/robot/m&*<>#[]{}"]
    assert {"amr-2.local", "fe80::1"} <= peers_fastdds(rel.file("fastdds.xml").content)
    # CycloneDDS talks IPv4 or IPv6 in a domain, not both: its peers here are names (test_hostile_sixth.py)
    host = dataclasses.replace(host, vars={**host.vars, "dds_peers": ["amr-2.local"]})
    cyc = render(dataclasses.replace(spec, rmw="cyclonedds"), host).file("cyclonedds.xml").content
    assert {"amr-2.local"} <= peers_cyclone(cyc)


def test_env_value_quoting() -> None:
    assert env_value("registry.local:5000/demo/x:1.0.0") == "registry.local:5000/demo/x:1.0.0"
    assert env_value("a b$c#d {x}") == "'a b$c#d {x}'"


def test_values_no_quoting_can_carry_are_refused() -> None:
    host = make_host(udev=(UdevDevice('robot/x"y', "tty", "0403", "6001"),))
    with pytest.raises(RenderError, match="invalid symlink"):
        render(make_spec(), host)
    with pytest.raises(RenderError, match="must be absolute"):
        render(make_spec(make_service(devices=("m",))), make_host(devices={"m": "/dev/a:/etc"}))
    with pytest.raises(RenderError, match="cannot go into a udev rule"):
        render(make_spec(), make_host(udev=(UdevDevice("robot/x", 'tty"', "0403", "6001"),)))


# -------------------------------------------------------------- udev, logs

def test_udev_rules_from_inventory() -> None:
    rules = render(FULL, FULL_HOST).file("99-rosdeploy.rules").content
    assert ('SUBSYSTEM=="tty", ATTRS{idVendor}=="0403", ATTRS{idProduct}=="6001", '
            'SYMLINK+="robot/motor", GROUP="dialout", MODE="0660"') in rules.splitlines()
    assert "installs it as" in rules
    empty = render(make_spec(), make_host()).file("99-rosdeploy.rules").content
    assert all(line.startswith("#") for line in empty.splitlines())


@pytest.mark.parametrize("root,user,expected", [
    ("~/rosdeploy", None, "/root/rosdeploy/demo/logs/*/*.log"),
    ("~/rosdeploy", "ops", "/home/ops/rosdeploy/demo/logs/*/*.log"),
    ("/srv/ros", "ops", "/srv/ros/demo/logs/*/*.log"),
])
def test_logrotate_covers_the_log_dirs(root: str, user: str | None, expected: str) -> None:
    conf = render(make_spec(deploy_root=root), make_host(user=user)).file("logrotate.conf").content
    assert f"{expected} {{" in conf
    for directive in ("size 50M", "rotate 5", "copytruncate", "compress", "missingok"):
        assert f"    {directive}\n" in conf


@pytest.mark.parametrize("name,value", [("dds_lease_duration", "10s"), ("logrotate_keep", True),
                                        ("logrotate_size", "50 MB"), ("dds_socket_buffer", "lots")])
def test_bad_tunable_vars_are_named(name: str, value: Any) -> None:
    with pytest.raises(RenderError, match=f"robot 'robot1': {name} must be"):
        render(make_spec(), make_host(vars={name: value}))


def test_services_whose_image_vars_collide_are_refused() -> None:
    with pytest.raises(RenderError, match="both map to A_B_IMAGE"):
        Renderer(make_spec(make_service("a-b"), make_service("a_b")))


# ---------------------------------------------------------------- templates

def test_template_override_dir_wins(tmp_path: Path) -> None:
    (tmp_path / "logrotate.conf.j2").write_text("# mine for {{ host.name }}\n")
    (tmp_path / "notes.txt.j2").write_text("{{ project }} {{ version }}\n")
    (tmp_path / "_partial.j2").write_text("not rendered on its own\n")
    rel = render(make_spec(templates=str(tmp_path)), make_host())
    assert rel.file("logrotate.conf").content == "# mine for robot1\n"
    assert rel.file("notes.txt").content == "demo 1.0.0\n"
    assert "_partial" not in files(rel) and "compose.yml" in files(rel)


def test_every_template_renders_sandboxed_and_an_override_in_the_bounded_sandbox(tmp_path: Path) -> None:
    from jinja2.sandbox import SandboxedEnvironment

    from rosdeploy.sandbox import Sandbox
    (tmp_path / "logrotate.conf.j2").write_text("{{ (host.name ~ ' ') * 10**6 }}\n")
    renderer = Renderer(make_spec(templates=str(tmp_path)))
    for out, template in renderer.templates.items():
        assert isinstance(template.environment, SandboxedEnvironment), out
        assert isinstance(template.environment, Sandbox) == (out == "logrotate.conf"), out
    with pytest.raises(RenderError, match="would exceed"):     # the bounds hold in the override
        renderer.render(make_host())


def test_relative_template_dir_is_relative_to_fleet_file(tmp_path: Path) -> None:
    (tmp_path / "tpl").mkdir()
    (tmp_path / "tpl" / "logrotate.conf.j2").write_text("x\n")
    rel = render(make_spec(path=str(tmp_path / "fleet.yml"), templates="tpl"), make_host())
    assert rel.file("logrotate.conf").content == "x\n"


def test_missing_template_dir_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(RenderError, match="does not exist"):
        Renderer(make_spec(templates=str(tmp_path / "nope")))


def test_template_syntax_error_names_file_and_line(tmp_path: Path) -> None:
    (tmp_path / "compose.yml.j2").write_text("a: 1\nb: {{ oops\n")
    with pytest.raises(RenderError) as err:
        Renderer(make_spec(templates=str(tmp_path)))
    problem = err.value.problems[0]
    assert problem.file == str(tmp_path / "compose.yml.j2") and problem.line == 2
    assert "syntax error" in problem.message


def test_undefined_variable_names_template_line_robot_and_name(tmp_path: Path) -> None:
    (tmp_path / "env.j2").write_text("A=1\nB={{ host.name }}\nC={{ no_such_var }}\n")
    with pytest.raises(RenderError) as err:
        render(make_spec(templates=str(tmp_path)), make_host())
    problem = err.value.problems[0]
    assert problem.file == str(tmp_path / "env.j2") and problem.line == 3
    assert "robot1" in problem.message and "'no_such_var'" in problem.message


def test_undefined_variable_in_fleet_env_template() -> None:
    spec = make_spec(make_service(environment={"X": "{{ missing_var }}"}))
    with pytest.raises(RenderError, match="robot 'robot1': 'missing_var' is undefined"):
        render(spec, make_host())


# ------------------------------------------------------------ real compose

def _compose_commands() -> list[list[str]]:
    found = []
    if shutil.which("docker") and subprocess.run(["docker", "compose", "version"], capture_output=True).returncode == 0:
        found.append(["docker", "compose"])
    if shutil.which("docker-compose"):
        found.append(["docker-compose"])
    return found


def _check_with_real_compose(tmp_path: Path, rel: RenderedRelease) -> None:
    release = tmp_path / rel.host / rel.project / "releases" / rel.release_id
    release.mkdir(parents=True)
    for f in rel.files:
        (release / f.name).parent.mkdir(parents=True, exist_ok=True)
        (release / f.name).write_text(f.content)
    if os.environ.get("CI"):   # CI installs both (scripts/host-setup): this must never be a skip there
        assert len(_compose_commands()) == 2, "CI needs Compose v2 and v1 on the host"
    for cmd in _compose_commands():
        done = subprocess.run([*cmd, "-f", "compose.yml", "config", "-q"], cwd=release,
                              capture_output=True, text=True)
        assert done.returncode == 0, f"{' '.join(cmd)} on {rel.host}: {done.stderr}"


NO_COMPOSE = ("neither `docker compose` (v2) nor `docker-compose` (v1) is installed; "
              "the integration suite runs real compose")


@pytest.mark.skipif(not _compose_commands() and not os.environ.get("CI"), reason=NO_COMPOSE)
@pytest.mark.parametrize("mode", ["host", "bridge"])
def test_real_compose_accepts_the_file(tmp_path: Path, mode: str) -> None:
    _check_with_real_compose(tmp_path, render(dataclasses.replace(FULL, network_mode=mode), FULL_HOST))


# ------------------------------------------------- golden: the example fleet

REPO = Path(__file__).resolve().parents[2]
GOLDEN = Path(__file__).resolve().parent / "golden" / "warehouse"
WAREHOUSE = REPO / "playbooks" / "warehouse.yml"
MASK = "<secret>"


def _warehouse_releases() -> dict[str, RenderedRelease]:
    from rosdeploy.project import load_project
    project = load_project(str(WAREHOUSE),
                           vault_password_file=str(REPO / "inventory" / "warehouse" / ".vault-password-example"))
    renderer = Renderer(project.spec)
    return {host.name: renderer.render(host) for host in project.targets()}


def _masked(release: RenderedRelease, content: str) -> str:
    """Golden files never hold a secret, even the demo vault's."""
    for value in sorted(release.secret_values, key=len, reverse=True):
        content = content.replace(value, MASK)
    return content


def test_warehouse_example_matches_golden_files() -> None:
    """Set ROSDEPLOY_UPDATE_GOLDEN=1 to rewrite tests/unit/golden/ after an intended change, then review the diff."""
    import os
    releases = _warehouse_releases()
    update = os.environ.get("ROSDEPLOY_UPDATE_GOLDEN") == "1"
    expected_hosts = sorted(p.name for p in GOLDEN.iterdir()) if GOLDEN.exists() else []
    assert update or sorted(releases) == expected_hosts
    for host, release in releases.items():
        assert release.secret_values, "the example's fleet-bridge reads a vault secret"
        for f in release.files:
            golden = GOLDEN / host / f.name
            text = _masked(release, f.content)
            if update:
                golden.parent.mkdir(parents=True, exist_ok=True)
                golden.write_text(text)
            assert golden.read_text() == text, f"{host}/{f.name} differs from {golden}"
        assert sorted(str(p.relative_to(GOLDEN / host)) for p in (GOLDEN / host).rglob("*") if p.is_file()) == \
            [f.name for f in release.files]


def test_warehouse_example_gpu_only_on_the_jetson_robot() -> None:
    releases = _warehouse_releases()
    gpu = {host for host, rel in releases.items() if compose(rel)["services"]["perception"].get("runtime") == "nvidia"}
    assert gpu == {"amr-n1"}
    assert compose(releases["amr-n2"])["services"]["perception"]["environment"]["PERCEPTION_MODEL"] == "yolov8n-cpu"


@pytest.mark.skipif(not _compose_commands() and not os.environ.get("CI"), reason=NO_COMPOSE)
def test_warehouse_example_accepted_by_real_compose(tmp_path: Path) -> None:
    for release in _warehouse_releases().values():
        _check_with_real_compose(tmp_path, release)
