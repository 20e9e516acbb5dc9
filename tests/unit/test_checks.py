"""Every check rule: one case where it fires and one where it does not.

The releases are written by hand (a compose.yml as a user's template could render
it), so each rule is tested against exactly the compose shape it judges.
"""
from __future__ import annotations

import copy
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
import yaml

from rosdeploy import checks
from rosdeploy.checks import RULES, dds_peers, run_checks
from rosdeploy.compose_env import interpolate, parse_env
from rosdeploy.model import (FleetSpec, HealthCheck, Host, RenderedFile, RenderedRelease, RolloutPolicy, Service, Topic,
                             frozen_map)

GOOD_SERVICE: dict[str, Any] = {
    "image": "registry.local:5000/acme/driver:1.0",
    "environment": {"ROS_DOMAIN_ID": "${ROS_DOMAIN_ID:?set it}"},
    "network_mode": "host",
    "restart": "unless-stopped",
    "logging": {"driver": "json-file", "options": {"max-size": "10m", "max-file": "3"}},
    "shm_size": "512m",
    "mem_limit": "256m",
    "cpus": 1.0,
    "user": "1000:1000",
    "healthcheck": {"test": ["CMD", "true"]},
    "devices": ["/dev/robot/motor:/dev/robot/motor"],
}
FASTDDS_PEERS = """<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"><profiles><participant
 profile_name="p"><rtps><builtin><initialPeersList><locator><udpv4><address>driver</address>
 </udpv4></locator></initialPeersList></builtin></rtps></participant></profiles></dds>"""
CYCLONE_PEERS = """<CycloneDDS xmlns="https://cdds.io/config"><Domain><Discovery><Peers>
 <Peer address="driver"/></Peers></Discovery></Domain></CycloneDDS>"""
NO_PEERS = "<dds><profiles/></dds>"


def host(name: str = "amr-1", **kw: Any) -> Host:
    domain = kw.pop("ros_domain_id", 5)
    vars_ = {"ros_domain_id": domain, **kw.pop("vars", {})}
    base = dict(name=name, groups=("all",), vars=frozen_map(vars_), address="10.0.0.1", ros_domain_id=domain,
                devices=frozen_map({"motor": "/dev/robot/motor"}), source=f"inventory/hosts.yml:{len(name)}")
    return Host(**{**base, **kw})


def spec(**kw: Any) -> FleetSpec:
    driver = Service("driver", "acme/driver", "1.0", devices=("motor",), healthcheck=HealthCheck(("CMD", "true")),
                     **kw.pop("driver", {}))
    lines = {("services", "driver"): 7, ("ros",): 3, ("logging",): 4}
    return FleetSpec(path="fleet.yml", project="p", inventory="inventory", registry="registry.local:5000",
                     version="1.0", services=(driver,), lines=frozen_map(lines), **kw)


def release(h: Host, service: dict | None = None, *, compose: Any = None, env: str | None = None,
            extra: dict[str, str] | None = None) -> RenderedRelease:
    if compose is None:
        compose = yaml.safe_dump({"services": {"driver": service if service is not None else GOOD_SERVICE}})
    files = {"compose.yml": compose, ".env": f"ROS_DOMAIN_ID={h.ros_domain_id}\n" if env is None else env,
             "fastdds.xml": FASTDDS_PEERS, **(extra or {})}
    return RenderedRelease(h.name, "p", "1.0", tuple(RenderedFile(n, c) for n, c in sorted(files.items())), ())


def run(rule_id: str, *, fleet: FleetSpec | None = None, hosts: list[Host] | None = None,
        service: dict | None = None, releases: list[RenderedRelease] | None = None, **patch: Any) -> list:
    """The findings of one rule, over hosts (default one) each rendering `service` patched."""
    hosts = hosts or [host()]
    svc = copy.deepcopy(GOOD_SERVICE if service is None else service)
    for key, value in patch.items():
        if value is None:
            svc.pop(key, None)
        else:
            svc[key] = value
    rels = releases if releases is not None else [release(h, svc) for h in hosts]
    return run_checks(fleet or spec(), hosts, rels, rules=[RULES[rule_id]])


def fires(rule_id: str, **kw: Any) -> Any:
    found = run(rule_id, **kw)
    assert found, f"{rule_id} should fire"
    assert all(p.rule == rule_id and p.severity == RULES[rule_id].severity for p in found)
    return found[0]


def silent(rule_id: str, **kw: Any) -> None:
    found = run(rule_id, **kw)
    assert not found, found


# ------------------------------------------------------ robots and inventory

def test_domain_id_duplicate_on_one_network() -> None:
    a, b = host("amr-1", network="north"), host("amr-22", network="north")
    p = fires("domain-id-duplicate", hosts=[a, b])
    assert (p.file, p.line, p.key) == ("inventory/hosts.yml", 6, "ros_domain_id")
    assert "'amr-22' and 'amr-1' (inventory/hosts.yml:5) both use ros_domain_id 5 on network 'north'" in p.message
    silent("domain-id-duplicate", hosts=[a, replace(b, network="south")])
    silent("domain-id-duplicate", hosts=[a, host("amr-22", network="north", ros_domain_id=6)])


def test_domain_id_duplicate_counts_robots_outside_the_limit() -> None:
    a, b = host("amr-1"), host("amr-22")
    found = run_checks(spec(), [b], [release(b)], all_hosts=[a, b], rules=[RULES["domain-id-duplicate"]])
    assert len(found) == 1 and "amr-1" in found[0].message


def test_domain_id_missing() -> None:
    bare = replace(host(), vars=frozen_map({}))
    assert "declares no ros_domain_id" in fires("domain-id-missing", hosts=[bare]).message
    silent("domain-id-missing")
    # the environment variable's spelling, set where the robot's own var belongs (ninth round)
    shouted = replace(host(), vars=frozen_map({"ROS_DOMAIN_ID": 5}))
    p = fires("domain-id-missing", hosts=[shouted])
    assert "declares no ros_domain_id ('ROS_DOMAIN_ID' is set, but names are case-sensitive" in p.message, p.message
    assert p.key == "ROS_DOMAIN_ID"


def test_order_by_that_matches_no_group_of_the_targets() -> None:
    # `rollout.order_by: stie_` deployed every site in one order, silently (ninth round)
    sited = host(groups=("all", "site_north"))
    p = fires("order-by-unmatched", fleet=spec(rollout=RolloutPolicy(order_by="stie_")), hosts=[sited])
    assert p.key == "rollout.order_by" and "no group of the targeted robots starts with 'stie_'" in p.message
    silent("order-by-unmatched", fleet=spec(rollout=RolloutPolicy(order_by="site_")), hosts=[sited])
    silent("order-by-unmatched", hosts=[sited])


@pytest.mark.parametrize("domain", [-1, 233, 1000])
def test_domain_id_range(domain: int) -> None:
    assert "0-232" in fires("domain-id-range", hosts=[host(ros_domain_id=domain)]).message


def test_domain_id_range_and_unsafe_boundaries() -> None:
    for domain in (0, 101, 232):
        silent("domain-id-range", hosts=[host(ros_domain_id=domain)])
    for domain in (0, 101, 233):
        silent("domain-id-unsafe", hosts=[host(ros_domain_id=domain)])
    assert "ephemeral" in fires("domain-id-unsafe", hosts=[host(ros_domain_id=150)]).message


def test_device_undeclared_names_service_device_and_robots() -> None:
    lacking = [host("amr-1", devices=frozen_map()), host("amr-2", devices=frozen_map())]
    p = fires("device-undeclared", hosts=lacking)
    assert (p.file, p.key) == ("fleet.yml", "services.driver.devices[0]")
    assert "needs device `motor`" in p.message and "'amr-1', 'amr-2'" in p.message
    assert "`motor: /dev/robot/motor` under their `devices:`" in p.message
    silent("device-undeclared")


def test_secrets() -> None:
    fleet = spec(driver={"secret_env": frozen_map({"TOKEN": "api_token"})})
    fires("secret-undefined", fleet=fleet)
    plain = host(vars={"api_token": "s3cr3t-value"})
    vaulted = host(vars={"api_token": "s3cr3t-value"}, secret_values=frozenset({"s3cr3t-value"}))
    silent("secret-undefined", fleet=fleet, hosts=[plain])
    assert "not from a vault file" in fires("secret-not-vaulted", fleet=fleet, hosts=[plain]).message
    silent("secret-not-vaulted", fleet=fleet, hosts=[vaulted])
    short = host(vars={"api_token": "abc"}, secret_values=frozenset({"abc"}))
    assert "shorter than 8" in fires("secret-short", fleet=fleet, hosts=[short]).message
    assert "is empty" in fires("secret-empty", fleet=fleet, hosts=[host(vars={"api_token": ""})]).message
    silent("secret-empty", fleet=fleet, hosts=[vaulted])
    silent("secret-short", fleet=fleet, hosts=[vaulted])


def test_gpu_unavailable() -> None:
    fleet = spec(driver={"gpu": True})
    assert "without a GPU reservation" in fires("gpu-unavailable", fleet=fleet).message
    silent("gpu-unavailable", fleet=fleet, hosts=[host(gpu=True)], deploy={"resources": {"reservations": {
        "devices": [{"driver": "nvidia", "count": 1, "capabilities": ["gpu"]}]}}})


def test_host_changes_no_root() -> None:
    sudo_to_nobody = host(user="robot", vars={"ansible_become_user": "nobody"})
    found = fires("host-changes-no-root", hosts=[sudo_to_nobody])
    assert "ansible_become_user is 'nobody': host changes need root" in found.message
    silent("host-changes-no-root", hosts=[host(user="root", vars={"ansible_become": False})])
    silent("host-changes-no-root", hosts=[host(user="robot")])                 # sudo -n, as apply does
    silent("host-changes-no-root", hosts=[sudo_to_nobody], fleet=replace(spec(), log_rotate_every=None))


# --------------------------------------------------------- a robot's release

def test_compose_invalid() -> None:
    h = host()
    assert "line" in fires("compose-invalid", releases=[release(h, compose="services: [\n")]).message
    fires("compose-invalid", releases=[release(h, compose="version: '3'\n")])
    silent("compose-invalid")


def test_dds_peers_missing_on_bridge_networks() -> None:
    h = host()
    bridged = dict(GOOD_SERVICE, network_mode=None)
    bridged.pop("network_mode")
    p = fires("dds-peers-missing", releases=[release(h, bridged, extra={"fastdds.xml": NO_PEERS})])
    assert "no multicast" in p.message
    fires("dds-peers-missing", releases=[release(h, bridged, extra={"fastdds.xml": "<dds"})])
    silent("dds-peers-missing", releases=[release(h, bridged)])
    silent("dds-peers-missing", fleet=spec(rmw="cyclonedds"),
           releases=[release(h, bridged, extra={"cyclonedds.xml": CYCLONE_PEERS})])
    silent("dds-peers-missing", releases=[release(h, extra={"fastdds.xml": NO_PEERS})])   # host networking


def test_domain_id_not_injected() -> None:
    h = host()
    assert ".env" in fires("domain-id-not-injected", releases=[release(h, env="ROS_DOMAIN_ID=0\n")]).message
    hard = dict(GOOD_SERVICE, environment={"ROS_DOMAIN_ID": "5"})
    assert "hard-coded" in fires("domain-id-not-injected", releases=[release(h, hard)]).message
    listed = dict(GOOD_SERVICE, environment=["ROS_DOMAIN_ID=$ROS_DOMAIN_ID"])
    silent("domain-id-not-injected", releases=[release(h, listed)])
    silent("domain-id-not-injected")


# ------------------------------------------------- a service of a release

@pytest.mark.parametrize("image", ["registry.local:5000/acme/driver", "acme/driver:latest", "acme/driver:", ""])
def test_image_unversioned(image: str) -> None:
    fires("image-unversioned", image=image)


@pytest.mark.parametrize("image", ["registry.local:5000/acme/driver:1.0", "acme/driver@sha256:" + "a" * 64,
                                   "${DRIVER_IMAGE}"])
def test_image_versioned(image: str) -> None:
    h = host()
    env = "ROS_DOMAIN_ID=5\nDRIVER_IMAGE=r.local/acme/driver:2.0\n"
    silent("image-unversioned", releases=[release(h, dict(GOOD_SERVICE, image=image), env=env)])


@pytest.mark.parametrize("healthcheck", [None, {"disable": True}, {"test": ["NONE"]}])
def test_healthcheck_missing(healthcheck: Any) -> None:
    patch = {"healthcheck": healthcheck} if healthcheck else {"healthcheck": None}
    p = fires("healthcheck-missing", **patch)
    assert p.key == "services.driver.healthcheck" and p.line == 7


def test_healthcheck_from_image_is_trusted() -> None:
    silent("healthcheck-missing")
    silent("healthcheck-missing", fleet=spec(driver={"healthcheck_from_image": True}), healthcheck=None)


@pytest.mark.parametrize("restart", [None, "no"])
def test_restart_missing(restart: Any) -> None:
    fires("restart-missing", restart=restart)


@pytest.mark.parametrize("restart", ["always", "unless-stopped", "on-failure", "on-failure:3"])
def test_restart_present(restart: str) -> None:
    silent("restart-missing", restart=restart)


@pytest.mark.parametrize("kind, entry", [("secrets", "token"), ("configs", {"source": "params", "target": "/p"}),
                                         ("secrets", {"target": "/run/x"})])
def test_compose_ref_undefined(kind: str, entry: Any) -> None:
    """The built-in template defines no top-level secrets or configs: compose would refuse the file."""
    found = fires("compose-ref-undefined", **{kind: [entry]})
    assert found.key == f"services.driver.compose.{kind}[0]", found.key
    assert "does not define at the top level" in found.message and "fleet key" in found.message


def test_compose_ref_defined_by_a_user_template() -> None:
    h = host()
    svc = {**GOOD_SERVICE, "secrets": ["token", {"source": "token"}], "configs": [{"source": "params"}]}
    compose = yaml.safe_dump({"services": {"driver": svc}, "secrets": {"token": {"environment": "TOKEN"}},
                              "configs": {"params": {"file": "./params.yaml"}}})
    silent("compose-ref-undefined", releases=[release(h, compose=compose)])
    silent("compose-ref-undefined")


@pytest.mark.parametrize("logging", [None, {"driver": "json-file"},
                                     {"driver": "json-file", "options": {"max-size": "1m"}},
                                     {"driver": "syslog"}])
def test_log_rotation_missing(logging: Any) -> None:
    assert fires("log-rotation-missing", logging=logging).key == "logging"


@pytest.mark.parametrize("driver", ["local", "journald"])
def test_self_rotating_log_drivers(driver: str) -> None:
    silent("log-rotation-missing", logging={"driver": driver})
    silent("log-rotation-missing")


def test_docker_socket_mounted() -> None:
    mounts = ["./fastdds.xml:/fastdds.xml:ro", "/var/run/docker.sock:/var/run/docker.sock:rw"]
    assert "root on the robot" in fires("docker-socket-mounted", volumes=mounts).message
    assert fires("docker-socket-mounted", volumes=[{"type": "bind", "source": "/run/docker.sock",
                                                    "target": "/d.sock"}]).key == "services.driver.volumes"
    silent("docker-socket-mounted", volumes=mounts, fleet=spec(driver={"allow_privileged": True}))
    silent("docker-socket-mounted", volumes=["/opt/maps:/maps:ro"])


def test_privileged() -> None:
    assert "allow_privileged: true" in fires("privileged", privileged=True).message
    silent("privileged", privileged=True, fleet=spec(driver={"privileged": True, "allow_privileged": True}))
    silent("privileged")


@pytest.mark.parametrize("rule", ["a *:* rwm", "b *:* rwm", "b 8:* rwm", "b 8:0 r", "c *:* rwm", "c *:1 rw",
                                  "c 1:* rwm", "c 1:1 rw", "c 1:2 r", "c 10:* rwm", "c 10:237 rwm", "c 21:0 rw",
                                  "c 81 rwm", "x 1:1 r"])
def test_device_cgroup_rules_reaching_root_devices_are_privileged(rule: str) -> None:
    # Docker's default CAP_MKNOD makes any device the rule allows a node the container can open.
    found = fires("privileged", device_cgroup_rules=[rule])
    assert found.key == "services.driver.device_cgroup_rules" and rule in found.message
    silent("privileged", device_cgroup_rules=[rule], fleet=spec(driver={"allow_privileged": True}))


@pytest.mark.parametrize("rule", ["c 81:* rmw", "c 188:* rwm", "c 189:* rmw", "c 166:0 rw", "c 1:3 rw",
                                  "c 10:200 rwm"])
def test_device_cgroup_rules_for_robot_devices_are_not_privileged(rule: str) -> None:
    silent("privileged", device_cgroup_rules=[rule])


@pytest.mark.parametrize("shm", [None, "64m", "128m", "lots"])
def test_shm_too_small(shm: Any) -> None:
    assert fires("shm-too-small", shm_size=shm).key == "ros.shm_size"


@pytest.mark.parametrize("patch", [{"shm_size": "256m"}, {"shm_size": None, "ipc": "host"},
                                   {"shm_size": None, "volumes": ["/dev/shm:/dev/shm"]},
                                   {"shm_size": None, "volumes": [{"type": "bind", "source": "/dev/shm",
                                                                   "target": "/dev/shm"}]}])
def test_shm_big_enough_or_shared(patch: dict) -> None:
    silent("shm-too-small", **patch)


def test_shm_small_for_image_topics() -> None:
    cameras = spec(driver={"topics": (Topic("/camera/image_raw"),)})
    assert "/camera/image_raw" in fires("shm-small-for-images", fleet=cameras, shm_size="300m").message
    silent("shm-small-for-images", fleet=cameras)
    silent("shm-small-for-images", fleet=spec(driver={"topics": (Topic("/odom"),)}), shm_size="300m")


@pytest.mark.parametrize("device", ["/dev/ttyUSB0:/dev/ttyUSB0", "/dev/video0", {"source": "/dev/ttyACM0"}])
def test_device_unstable(device: Any) -> None:
    assert "udev" in fires("device-unstable", devices=[device]).message


@pytest.mark.parametrize("device", ["/dev/robot/lidar:/dev/ttyUSB0", "/dev/serial/by-id/usb-FTDI-if00",
                                    "/dev/v4l/by-id/usb-cam-video-index0"])
def test_device_stable(device: str) -> None:
    silent("device-unstable", devices=[device])


def test_resources_missing() -> None:
    assert "no memory or CPU limit" in fires("resources-missing", mem_limit=None, cpus=None).message
    assert "no CPU limit" in fires("resources-missing", cpus=None).message
    silent("resources-missing")
    silent("resources-missing", mem_limit=None, cpus=None,
           deploy={"resources": {"limits": {"memory": "1g", "cpus": "1"}}})


@pytest.mark.parametrize("user", ["root", "0", "0:0"])
def test_user_root(user: str) -> None:
    fires("user-root", user=user)


def test_user_non_root_and_unset() -> None:
    silent("user-root")
    silent("user-root", user=None)
    assert fires("user-unset", user=None).severity == "info"
    silent("user-unset")


def test_gpu_reservation() -> None:
    reserved = {"resources": {"reservations": {"devices": [{"driver": "nvidia", "capabilities": ["gpu"]}]}}}
    gpu_fleet = spec(driver={"gpu": True})
    assert "reserves no GPU" in fires("gpu-reservation", fleet=gpu_fleet, hosts=[host(gpu=True)]).message
    assert "does not have" in fires("gpu-reservation", deploy=reserved).message
    silent("gpu-reservation", fleet=gpu_fleet, hosts=[host(gpu=True)], deploy=reserved)
    silent("gpu-reservation", fleet=gpu_fleet)          # no GPU on the robot: rendered without one
    silent("gpu-reservation")


# --------------------------------------------------------------- machinery

def test_a_plain_sudo_password_fires_and_a_vaulted_one_does_not() -> None:
    plain = host(vars={"ansible_become_password": "sudo-pw-123"})
    vaulted = host(vars={"ansible_become_password": "sudo-pw-123"}, secret_values=frozenset({"sudo-pw-123"}))
    p = fires("become-password-not-vaulted", hosts=[plain])
    assert "ansible_become_password" in p.message and "sudo-pw-123" not in p.message
    silent("become-password-not-vaulted", hosts=[vaulted])


def test_devices_and_mounts_that_are_root() -> None:
    assert "/dev/mem" in fires("device-root", devices=["/dev/mem:/dev/mem"]).message
    silent("device-root")
    assert "/etc" in fires("mount-system-writable", volumes=["/etc:/etc"]).message
    silent("mount-system-writable", volumes=["/etc:/etc:ro"])
    base = spec()
    fleet = replace(base, services=(replace(base.services[0], devices=("motor", "lidar")),))
    two = host(devices=frozen_map({"motor": "/dev/robot/motor", "lidar": "/dev/robot/motor"}))
    assert "`motor` and `lidar`" in fires("device-duplicate", fleet=fleet, hosts=[two]).message
    silent("device-duplicate", fleet=fleet, hosts=[host(devices=frozen_map({"motor": "/a", "lidar": "/b"}))])



def test_fleet_octal_number_shows_what_the_file_read_found() -> None:
    from rosdeploy.errors import Problem
    found = Problem("fleet.yml", 9, "vars.port", "`017` is read as octal (15)")
    p = fires("fleet-octal-number", fleet=replace(spec(), warnings=(found,)))
    assert (p.file, p.line, p.key) == ("fleet.yml", 9, "vars.port") and "octal (15)" in p.message
    silent("fleet-octal-number")


def test_host_template_root_reads_overridden_host_files(tmp_path: Path) -> None:
    (tmp_path / "logrotate.cron.j2").write_text("# the override")
    h = host()
    hostile = release(h, extra={"logrotate.cron": '* * * * * root /bin/sh -c "id > /tmp/pwned"\n'})
    p = fires("host-template-root", fleet=spec(templates=str(tmp_path)), hosts=[h], releases=[hostile])
    assert "logrotate.cron line 1" in p.message and "/etc/cron.d/rosdeploy-p" in p.message
    assert "logrotate.cron.j2" in p.message
    silent("host-template-root", hosts=[h], releases=[hostile])    # no override: the built-in template wrote it

def test_every_rule_is_tested_and_documented() -> None:
    for r in RULES.values():
        assert r.severity in checks.SEVERITIES and r.scope in ("fleet", "host", "release", "service")
        assert r.summary and r.fix
    source = Path(__file__).read_text()
    untested = [rule_id for rule_id in RULES if f'fires("{rule_id}"' not in source]
    assert not untested, f"rules without a firing test: {untested}"


def test_identical_findings_merge_across_robots() -> None:
    hosts = [host(f"amr-{i}", ros_domain_id=i) for i in range(1, 8)]
    found = run("restart-missing", hosts=hosts, restart="no")
    assert len(found) == 1
    assert "'amr-1', 'amr-2', 'amr-3', 'amr-4', 'amr-5' (+2 more)" in found[0].message


def test_findings_are_sorted_errors_first() -> None:
    h = host()
    svc = dict(GOOD_SERVICE, restart="no", user="root")
    svc.pop("cpus")
    project = SimpleNamespace(spec=spec(), inventory=SimpleNamespace(hosts={h.name: h}))
    found = run_checks(project.spec, [h], [release(h, svc)])
    assert [p.severity for p in found] == sorted((p.severity for p in found), key=checks.SEVERITIES.index)
    assert {p.rule for p in found} == {"restart-missing", "user-root", "resources-missing"}


def test_robots_without_a_release_get_only_input_rules() -> None:
    found = run("restart-missing", releases=[])
    assert found == []


# ------------------------------------------------------------------ helpers

def test_parse_env_and_interpolate() -> None:
    env = parse_env("# c\nA=1\nexport B='x y'\nC=\"q\"\nbad line\n")
    assert env == {"A": "1", "B": "x y", "C": "q"}
    values = interpolate({"k": ["${A}", "$A-$$B", "${MISSING:-dflt}", "${A:?err}", "${EMPTY-x}", 3]},
                         {**env, "EMPTY": ""})
    assert values == {"k": ["1", "1-$B", "dflt", "1", "", 3]}


def test_dds_peers_reads_both_vendors() -> None:
    assert dds_peers(FASTDDS_PEERS) == ("driver",)
    assert dds_peers(CYCLONE_PEERS) == ("driver",)
    assert dds_peers(NO_PEERS) == ()


def test_every_rule_is_in_the_fleet_file_reference() -> None:
    doc = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    missing = [r.id for r in RULES.values() if f"| `{r.id}` | {r.severity} |" not in doc]
    assert not missing, f"document these rules in README.md: {missing}"


@pytest.mark.parametrize("service", [
    {}, {"healthcheck": "yes", "logging": "json", "deploy": "x", "devices": "/dev/ttyUSB0", "volumes": "/dev/shm"},
    {"deploy": {"resources": {"limits": ["1g"], "reservations": {"devices": "gpu"}}}, "environment": "A=1"},
    {"logging": {"options": ["max-size"]}, "shm_size": ["1g"], "user": 0, "restart": None, "image": 5},
])
def test_odd_compose_shapes_from_user_templates_never_crash(service: dict) -> None:
    h = host()
    project = SimpleNamespace(spec=spec(), inventory=SimpleNamespace(hosts={h.name: h}))
    found = run_checks(project.spec, [h], [release(h, service)])
    assert all(p.rule in RULES for p in found)
