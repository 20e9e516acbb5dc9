"""Sixth hostile-input audit (issue #18): each case was let through, refused late, or blamed the wrong place.

1. `render --out` beside the inventory wrote robot `group_vars`'s files into group_vars/, which
   the next run read as the vars of a group.
2. An extra template named `.j2`, `..j2` or `...j2` passed validate and check, and render blamed
   --out; one named `a b.j2` or `-x.j2` rendered a file the robot's scripts would mishandle.
3. A bad value in the fleet file's `vars:` was reported at the inventory's lines.
4. `rollout.order_by: ''` was told the device-name rule (re caches one object for both patterns).
5. `images.controller_registry` took port 0 and port 99999 (a path stays: the registry's own, as
   `registry: host/acme` has one).
6. `rollout.max_fail` and `waves` took counts past 2**31 - 1.
7. An IPv6 `dds_peers` address went into a `<udpv4>` locator.
8. An inventory `ready`/`window` of another tool was called ignored, and then refused.
9. `rosdeploy_home` relative (fleet `vars:`) or `~` (inventory): logrotate runs as root.
10. The DDS and logrotate tunables were unbounded; an announcement period past the lease passed.
11. A mount inside a file mount, or in /proc: the container could not be created.
12. A dependency or the probe service with `profiles`, which a deploy never starts.
13. `ready:` conditions that always or never hold, or drop a key silently.
14. Gate waits longer than the gate, empty command words, one topic twice, retry 0.
15. `window.tz: localtime` (the controller's own zone), `Factory`, `posixrules`.
16. `ansible_host` holding a URL, user@host or 300 characters.
"""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from test_hostile import cli, edit, lab, refused_everywhere
from test_hostile_leftovers import run

__all__ = ["lab"]   # the fixture: tests/unit/data/fleet copied, its vault password in place


def add_host_vars(lab: Path, robot: str, text: str) -> None:
    path = lab / "inventory" / "host_vars" / f"{robot}.yml"
    path.write_text((path.read_text() if path.exists() else "") + text)


def set_hosts(lab: Path, old: str, new: str) -> None:
    hosts = lab / "inventory" / "hosts.yml"
    assert old in hosts.read_text()
    hosts.write_text(hosts.read_text().replace(old, new))


def rendered(lab: Path, robot: str, name: str) -> str:
    return (lab / "out" / robot / name).read_text()


# ------------------------------------------------------------------ 1. --out/<robot> is group_vars

def test_a_robot_folder_that_is_a_folder_the_inventory_reads_is_refused(capsys: pytest.CaptureFixture,
                                                                         lab: Path) -> None:
    set_hosts(lab, "          ros_domain_id: 2\n",
              "          ros_domain_id: 2\n        group_vars:\n          ansible_host: 127.0.0.3\n"
              "          ros_domain_id: 3\n")
    edit(lab, lambda d: d.update(inventory="./inventory/hosts.yml"))   # a file: its folder is not read
    before = sorted(p.name for p in (lab / "inventory" / "group_vars").iterdir())
    code, text = run(capsys, lab, "render", "--out", str(lab / "inventory"))
    assert code == 2, text
    assert "--out: robot group_vars's folder is" in text and "which the inventory is read from" in text, text
    assert sorted(p.name for p in (lab / "inventory" / "group_vars").iterdir()) == before
    code, text = run(capsys, lab, "validate")
    assert code == 0, text


# ------------------------------------------------------------------ 2. extra template names

@pytest.mark.parametrize("name, expect", [(".j2", "renders to ''"), ("..j2", "renders to '.'"),
                                          ("...j2", "renders to '..'"), ("a b.j2", "a blank"),
                                          ("-x.j2", "a leading `-`")])
def test_an_extra_template_that_names_no_plain_file_is_refused(capsys: pytest.CaptureFixture, lab: Path,
                                                               name: str, expect: str) -> None:
    (lab / "templates").mkdir()
    (lab / "templates" / name).write_text("x\n")
    edit(lab, lambda d: d.update(templates="templates"))
    refused_everywhere(capsys, lab, f"templates/{name}: ", expect)


# ------------------------------------------------------------------ 3. fleet vars located in the fleet file

@pytest.mark.parametrize("var, value", [("dds_lease_duration", "ten"), ("dds_peers", ["bad peer!"])])
def test_a_bad_fleet_var_is_reported_at_its_line(capsys: pytest.CaptureFixture, lab: Path, var: str,
                                                 value: object) -> None:
    edit(lab, lambda d: d.update(vars={var: value}))
    for command in ("validate", "check", "render"):
        code, text = cli(capsys, lab, command)
        assert code == 2, (command, text)
        assert "fleet.yml:" in text and f"vars.{var}: robot 'r1'" in text, (command, text)
        assert "hosts.yml" not in text, (command, text)


def test_the_inventory_value_is_still_reported_where_the_inventory_sets_it(capsys: pytest.CaptureFixture,
                                                                           lab: Path) -> None:
    edit(lab, lambda d: d.update(vars={"dds_lease_duration": 10}))
    add_host_vars(lab, "r1", "dds_lease_duration: ten\n")
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "r1.yml:2: dds_lease_duration: robot 'r1'" in text, text


# ------------------------------------------------------------------ 4. order_by's own hint

def test_an_empty_order_by_is_told_the_group_prefix_rule(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, lambda d: d.update(rollout={"order_by": ""}))
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "rollout.order_by: '' is not a valid group prefix" in text, text
    assert "inventory group names" in text and "device" not in text, text


# ------------------------------------------------------------------ 5. controller_registry

@pytest.mark.parametrize("value, expect", [("http://127.0.0.1:0", "port 0 is not a TCP port"),
                                           ("127.0.0.1:99999/acme", "port 99999 is not a TCP port")])
def test_a_controller_registrys_port_is_a_tcp_port(capsys: pytest.CaptureFixture, lab: Path, value: str,
                                                   expect: str) -> None:
    edit(lab, lambda d: d.update(images={"controller_registry": value}))
    refused_everywhere(capsys, lab, "images.controller_registry", expect)


def test_a_controller_registry_with_the_registrys_path_is_taken(capsys: pytest.CaptureFixture, lab: Path) -> None:
    # refused for a while as "without a path", though `registry: host/acme` has the same path
    edit(lab, lambda d: d.update(registry="registry.local:5000/acme",
                                 images={"controller_registry": "http://127.0.0.1:5000/acme"}))
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


# ------------------------------------------------------------------ 6. rollout counts

@pytest.mark.parametrize("rollout", [{"max_fail": 10**30}, {"waves": [10**30]}, {"max_fail": 2**31}])
def test_rollout_counts_are_bounded(capsys: pytest.CaptureFixture, lab: Path, rollout: dict) -> None:
    edit(lab, lambda d: d.update(rollout=rollout))
    refused_everywhere(capsys, lab, f"rollout.{next(iter(rollout))}", "at most 2147483647")


# ------------------------------------------------------------------ 7. IPv6 peers

def test_an_ipv6_peer_is_a_udpv6_locator(capsys: pytest.CaptureFixture, lab: Path) -> None:
    add_host_vars(lab, "r1", "dds_peers: ['fe80::1%eth0', 10.0.0.5]\n")
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    profile = rendered(lab, "r1", "fastdds.xml")
    assert "<udpv6>\n                <address>fe80::1%eth0</address>" in profile, profile
    assert "<udpv4>\n                <address>10.0.0.5</address>" in profile, profile
    assert "<type>UDPv6</type>" in profile and "<transport_id>rosdeploy_udpv6</transport_id>" in profile
    assert "UDPv6" not in rendered(lab, "r2", "fastdds.xml")


def test_cyclonedds_takes_ipv6_peers_over_udp6_and_refuses_a_mix(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, lambda d: d.update(ros={"rmw": "cyclonedds"}))
    add_host_vars(lab, "r1", "dds_peers: ['fe80::1']\n")
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    assert "<Transport>udp6</Transport>" in rendered(lab, "r1", "cyclonedds.xml")
    assert "udp6" not in rendered(lab, "r2", "cyclonedds.xml")
    add_host_vars(lab, "r2", "dds_peers: ['fe80::2', 10.0.0.5]\n")
    code, text = cli(capsys, lab, "check")
    assert code == 2 and "dds_peers: robot 'r2': 'fe80::2': CycloneDDS talks either IPv4 or IPv6" in text, text


# ------------------------------------------------------------------ 8. another tool's ready/window

@pytest.mark.parametrize("var, value", [("ready", '"true"'), ("window", "'off'")])
def test_another_tools_gate_var_is_ignored_as_the_warning_says(capsys: pytest.CaptureFixture, lab: Path,
                                                               var: str, value: str) -> None:
    add_host_vars(lab, "r1", f"{var}: {value}\n")
    for command in ("validate", "check", "render"):
        code, text = cli(capsys, lab, command)
        assert code == 0, (command, text)
        assert "another tool's variable, ignored by rosdeploy" in text, (command, text)


def test_rosdeploy_own_gate_var_is_still_checked(capsys: pytest.CaptureFixture, lab: Path) -> None:
    add_host_vars(lab, "r1", 'rosdeploy_ready: "true"\n')
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "rosdeploy_ready" in text, text


# ------------------------------------------------------------------ 9. rosdeploy_home

def test_a_relative_home_in_the_fleet_vars_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, lambda d: d.update(vars={"rosdeploy_home": "relative/dir"}))
    refused_everywhere(capsys, lab, "fleet.yml:", "vars.rosdeploy_home: must be the absolute path")


@pytest.mark.parametrize("value", ["'~'", "'~/x'", "relative"])
def test_a_home_under_tilde_in_the_inventory_is_refused(capsys: pytest.CaptureFixture, lab: Path,
                                                        value: str) -> None:
    (lab / "inventory" / "group_vars" / "all" / "vars.yml").write_text(f"rosdeploy_home: {value}\n")
    refused_everywhere(capsys, lab, "vars.yml:1: rosdeploy_home:", "logrotate runs as root")


def test_an_absolute_home_makes_the_log_glob(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, lambda d: d.update(vars={"rosdeploy_home": "/home/ubuntu"}))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    assert "/home/ubuntu/rosdeploy/lab/logs/*/*.log {" in rendered(lab, "r1", "logrotate.conf")


# ------------------------------------------------------------------ 10. tunables

@pytest.mark.parametrize("var, value", [("dds_lease_duration", 10**20), ("dds_initial_announcement_period_ms", 2**31),
                                        ("dds_initial_announcements", 10**20), ("logrotate_keep", 10**20),
                                        ("dds_socket_buffer", "99999999999GB"), ("dds_socket_buffer", "2GiB"),
                                        ("logrotate_size", "2000G"), ("logrotate_size", "-1")])
def test_tunables_are_bounded(capsys: pytest.CaptureFixture, lab: Path, var: str, value: object) -> None:
    edit(lab, lambda d: d.update(vars={var: value}))
    refused_everywhere(capsys, lab, f"vars.{var}:", f"{var} must be")


@pytest.mark.parametrize("announcement", [10, 11])
def test_the_lease_announcement_is_shorter_than_the_lease(capsys: pytest.CaptureFixture, lab: Path,
                                                          announcement: int) -> None:
    edit(lab, lambda d: d.update(vars={"dds_lease_duration": 10, "dds_lease_announcement": announcement}))
    refused_everywhere(capsys, lab, "vars.dds_lease_announcement:", "must be shorter than dds_lease_duration")


def test_tunables_within_bounds_render(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, lambda d: d.update(vars={"dds_lease_duration": 2**31 - 1, "dds_socket_buffer": "1GiB",
                                       "logrotate_size": "0", "logrotate_keep": 0}))   # size 0: rotate when not empty
    code, text = cli(capsys, lab, "render")
    assert code == 0, text


def test_the_lease_rule_is_fast_dds_and_points_at_the_var_given(capsys: pytest.CaptureFixture, lab: Path) -> None:
    # CycloneDDS's profile renders neither var, and the error pointed at the robot's declaration
    edit(lab, lambda d: d.update(vars={"dds_lease_duration": 2}))
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "vars.dds_lease_duration: robot 'r1': dds_lease_announcement (3 s) must be shorter" in text
    edit(lab, lambda d: d.update(ros={"rmw": "cyclonedds"}))
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


def test_cyclonedds_takes_ipv6_peers_with_host_names(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, lambda d: d.update(ros={"rmw": "cyclonedds"}))
    add_host_vars(lab, "r1", "dds_peers: ['fd00::12', amr-3.local]\n")
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


# ------------------------------------------------------------------ 11. mounts under a file, in /proc

def with_files(*targets: str, volumes: tuple[str, ...] = ()) -> object:
    def change(d: dict) -> None:
        d["files"] = {f"f{i}": {"copy": "params.yaml", "target": t} for i, t in enumerate(targets)}
        d["services"]["driver"]["files"] = [f"f{i}" for i in range(len(targets))]
        if volumes:
            d["services"]["driver"]["volumes"] = list(volumes)
    return change


@pytest.mark.parametrize("targets, volumes, key, expect", [
    (("/config",), ("/x:/config/sub",), "services.driver.volumes[0]", "/config/sub is inside /config, where files.f0"),
    (("/config", "/config/q"), (), "services.driver.files[1]", "/config/q is inside /config, where files.f0"),
    ((), ("/x:/proc/x",), "services.driver.volumes[0]", "/proc/x is in /proc"),
    (("/proc/sys/kernel/core_pattern",), (), "files.f0.target", "/proc/sys/kernel/core_pattern is in /proc"),
])
def test_a_mount_no_container_can_have_is_refused(capsys: pytest.CaptureFixture, lab: Path, targets: tuple,
                                                  volumes: tuple, key: str, expect: str) -> None:
    (lab / "params.yaml").write_text("a: 1\n")
    edit(lab, with_files(*targets, volumes=volumes))
    refused_everywhere(capsys, lab, f"{key}: {expect}")


def test_a_file_in_a_folder_mount_and_lxcfs_proc_files_are_fine(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "params.yaml").write_text("a: 1\n")
    edit(lab, with_files("/config/q", volumes=("/x:/config", "/var/lib/lxcfs/proc/cpuinfo:/proc/cpuinfo:ro")))
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


# ------------------------------------------------------------------ 12. profiles

def test_depending_on_a_profiled_service_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(profiles=["dev"]))
    refused_everywhere(capsys, lab, "services.bridge.depends_on[0]: `driver` has profiles, and a deploy never starts")


def test_a_profiled_dependency_of_a_profiled_service_is_fine(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, lambda d: [d["services"][s].update(profiles=["dev"]) for s in ("driver", "bridge")])
    code, text = cli(capsys, lab, "validate")
    assert "depends_on" not in text, text


def test_a_profiled_probe_service_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    def change(d: dict) -> None:
        d["services"]["tools"] = {"image": "lab/tools", "profiles": ["dev"], "user": "1000:1000",
                                  "resources": {"memory": "64m", "cpus": 0.5}}
        d["health"] = {"probe_service": "tools"}
    edit(lab, change)
    refused_everywhere(capsys, lab, "health.probe_service: `tools` has profiles")


# ------------------------------------------------------------------ 13. ready conditions

@pytest.mark.parametrize("ready, expect", [
    ({"when": [{"topic": "/m", "quiet": "5s", "field": "data", "is": "x"}]}, "ready.when[0].field: `quiet:`"),
    ({"when": [{"topic": "/m", "quiet": "5s", "is": "x"}]}, "ready.when[0].is: `quiet:`"),
    ({"when": [{"service": "driver", "command": ""}]}, "ready.when[0].command: required"),
    ({"when": [{"service": "driver", "command": "  "}]}, "ready.when[0].command: required"),
    ({"when": [{"service": "driver", "command": [""]}]}, "ready.when[0].command[0]: is empty"),
    ({"topic_wait": 0, "when": [{"lock": "/tmp/x"}]}, "ready.topic_wait: must be above 0"),
])
def test_a_ready_condition_that_cannot_mean_what_it_says_is_refused(capsys: pytest.CaptureFixture, lab: Path,
                                                                    ready: dict, expect: str) -> None:
    edit(lab, lambda d: d.update(ready=ready))
    refused_everywhere(capsys, lab, expect)


# ------------------------------------------------------------------ 14. gate timing and words

@pytest.mark.parametrize("health", [{"topic_window": "30s", "timeout": "30s"}, {"topics_within": "120s"}])
def test_topic_bounds_at_or_past_the_timeout_are_taken(capsys: pytest.CaptureFixture, lab: Path,
                                                       health: dict) -> None:
    # bounds, not waits: a topic that appears or proves its rate early ends them; a review found
    # them refused as "no release could pass the gate" (README: raise topics_within for late nodes)
    edit(lab, lambda d: d.update(health=health))
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


@pytest.mark.parametrize("change, expect", [
    (lambda s: s.update(command=["", "x"]), "services.driver.command[0]: is empty"),
    (lambda s: s.update(healthcheck={"test": ["CMD", ""]}), "services.driver.healthcheck.test[1]: is empty"),
    (lambda s: s.update(healthcheck={"test": ["CMD-SHELL", " "]}), "services.driver.healthcheck.test[1]: is empty"),
    (lambda s: s.update(topics=["/joint_states", {"name": "/joint_states", "min_rate": 5}]),
     "services.driver.topics[1]: /joint_states is already declared at topics[0]"),
])
def test_empty_words_and_twice_declared_topics_are_refused(capsys: pytest.CaptureFixture, lab: Path,
                                                           change: object, expect: str) -> None:
    edit(lab, lambda d: change(d["services"]["driver"]))   # type: ignore[operator]
    refused_everywhere(capsys, lab, expect)


@pytest.mark.parametrize("key", ["retry", "retry_max"])
def test_a_retry_of_zero_is_refused(capsys: pytest.CaptureFixture, lab: Path, key: str) -> None:
    edit(lab, lambda d: d.update(rollout={key: 0}))
    refused_everywhere(capsys, lab, f"rollout.{key}: must be a number above 0")


# ------------------------------------------------------------------ 15. window.tz

@pytest.mark.parametrize("tz", ["localtime", "Factory", "posixrules", "right/UTC", "posix/Europe/Berlin"])
def test_a_window_zone_is_an_iana_name(capsys: pytest.CaptureFixture, lab: Path, tz: str) -> None:
    edit(lab, lambda d: d.update(window={"start": "01:00", "duration": "3h", "tz": tz}))
    refused_everywhere(capsys, lab, f"window.tz: '{tz}' is not a time zone name")


# ------------------------------------------------------------------ 16. ansible_host

@pytest.mark.parametrize("value, expect", [("ssh://x", "is a URL or a path"), ("user@host", "ansible_user"),
                                           ("host:22", "ansible_port"), ("a" * 300, "longer than a host name")])
def test_an_ansible_host_that_is_no_address_is_refused(capsys: pytest.CaptureFixture, lab: Path, value: str,
                                                       expect: str) -> None:
    set_hosts(lab, "ansible_host: 127.0.0.1", f"ansible_host: {yaml.safe_dump(value).splitlines()[0]}")
    refused_everywhere(capsys, lab, "hosts.yml:", "ansible_host: robot 'r1'", expect)


@pytest.mark.parametrize("value", ["fe80::1", "robot-1.local", "robot_alias", "10.0.0.1"])
def test_addresses_and_ssh_aliases_pass(capsys: pytest.CaptureFixture, lab: Path, value: str) -> None:
    set_hosts(lab, "ansible_host: 127.0.0.1", f"ansible_host: {yaml.safe_dump(value).splitlines()[0]}")
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


# ------------------------------------------------------------------ compose: beside what rosdeploy renders

COMPOSE_REFUSED = [
    ({"cpu_quota": 50000}, "compose.cpu_quota: Docker refuses cpu_quota beside `resources.cpus`"),
    ({"cpu_period": 100000}, "compose.cpu_period: Docker refuses cpu_period beside `resources.cpus`"),
    ({"mem_reservation": "1g"}, "compose.mem_reservation: above `resources.memory`"),
    ({"memswap_limit": "10m"}, "compose.memswap_limit: below `resources.memory`"),
    ({"sysctls": {"net.ipv4.ip_forward": 1}}, "compose.sysctls.net.ipv4.ip_forward: Docker refuses "
                                              "net.ipv4.ip_forward in the host's namespaces"),
    ({"sysctls": ["kernel.core_pattern=|/bin/sh"]}, "compose.sysctls[0]: kernel.core_pattern is not a namespaced"),
    ({"tmpfs": ["/calib"]}, "compose.tmpfs[0]: /calib is also a target of `volumes`"),
    ({"links": ["other"]}, "compose.links: Docker refuses links on host networking"),
    ({"working_dir": "relative"}, "compose.working_dir: must be an absolute path"),
    ({"dns": ["not an ip"]}, "compose.dns[0]: 'not an ip' is not an IP address"),
    ({"isolation": "hyperv"}, "compose.isolation: only `default` exists on Linux"),
    ({"pid": "HOST"}, "compose.pid: 'HOST' is none of host, container:NAME, service:NAME"),
    ({"stop_signal": "SIGFOO"}, "compose.stop_signal: 'SIGFOO' is no signal"),
    ({"ulimits": {"nofilez": 10}}, "compose.ulimits.nofilez: no ulimit Docker sets is named 'nofilez'"),
    ({"ulimits": {"nofile": {"soft": 10, "hard": 5}}}, "compose.ulimits.nofile: soft is above hard"),
    ({"ulimits": {"nofile": {"soft": -1, "hard": 5}}}, "compose.ulimits.nofile: soft is above hard"),
    ({"sysctls": {"kernel.hostname": "x"}}, "compose.sysctls.kernel.hostname: Docker refuses kernel.hostname"),
    ({"ipc": "host", "sysctls": {"kernel.shmmax": 1}}, "compose.sysctls.kernel.shmmax: Docker refuses kernel.shmmax "
                                                       "with `ipc: host`"),
]


@pytest.mark.parametrize("compose, expect", COMPOSE_REFUSED, ids=[next(iter(c)) + str(i)
                                                                  for i, (c, _) in enumerate(COMPOSE_REFUSED)])
def test_compose_keys_docker_refuses_beside_what_rosdeploy_renders_are_refused(
        capsys: pytest.CaptureFixture, lab: Path, compose: dict, expect: str) -> None:
    # each passed the Compose schema and validate, check and render; the robot's Docker refused it
    def add(d: dict) -> None:
        d["services"]["driver"]["volumes"] = ["/opt/calib:/calib:ro"]
        d["services"]["driver"]["compose"] = compose
    edit(lab, add)
    refused_everywhere(capsys, lab, "services.driver." + expect)


def test_compose_keys_docker_takes_pass(capsys: pytest.CaptureFixture, lab: Path) -> None:
    def add(d: dict) -> None:
        d["services"]["driver"]["compose"] = {
            "mem_reservation": "128m", "memswap_limit": "512m", "sysctls": {"kernel.shm_rmid_forced": 1},
            "working_dir": "/ws", "dns": ["10.0.0.1", "fd00::1"], "stop_signal": "SIGINT",
            "ulimits": {"nofile": {"soft": 1024, "hard": 4096}, "rtprio": 99, "memlock": {"soft": 1 << 26, "hard": -1}},
            "isolation": "Default"}
    edit(lab, add)
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


@pytest.mark.parametrize("signal_name", ["SIGRTMIN+3", "RTMIN+3", "SIGIOT", "SIGCLD", "SIGRTMAX-1", "15"])
def test_every_signal_docker_knows_is_a_stop_signal(capsys: pytest.CaptureFixture, lab: Path,
                                                    signal_name: str) -> None:
    # a review found SIGRTMIN+3 (systemd in a container's stop signal) and the aliases refused
    edit(lab, lambda d: d["services"]["driver"].update(compose={"stop_signal": signal_name}))
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


def test_interpolated_compose_values_are_the_robots_to_judge(capsys: pytest.CaptureFixture, lab: Path) -> None:
    # with compose_interpolate, `${WS:-/ws}` becomes /ws on the robot: it was refused as relative
    edit(lab, lambda d: d["services"]["driver"].update(compose_interpolate=True, compose={
        "working_dir": "${WS_DIR:-/ws}", "dns": ["${DNS_SERVER}"], "stop_signal": "${STOP:-SIGINT}",
        "links": ["${LINK:-bridge}"]}))
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


@pytest.mark.parametrize("var, value", [("ansible_become_method", "su"), ("ansible_become_user", "nobody"),
                                        ("ansible_become", False)])
def test_become_settings_every_deploy_refuses_are_said_by_validate(capsys: pytest.CaptureFixture, lab: Path,
                                                                   var: str, value: object) -> None:
    # validate and check said nothing; every apply to the robot then failed at its host changes
    add_host_vars(lab, "r1", f"ansible_user: robot\n{var}: {yaml.safe_dump(value).split()[0]}\n")
    for command in ("validate", "check"):
        code, text = cli(capsys, lab, command)
        assert code == 0 and "r1.yml:" in text and f"{var}: robot 'r1' gets udev rules or log rotation" in text, text
