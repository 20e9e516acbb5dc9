"""Probe M (ninth round) items 1-4 and 6: what a user's compose template renders past `check`.

A user template is held to the same checklist as the built-in one: relative and `~` bind sources
are judged as the robot path compose makes of them, a named volume the local driver binds is
judged by its device, keys that bring in what `check` never sees are refused, as are sysctls
runc refuses, and a writable /home (the deploy user's ~/.ssh, its deploy root) is root.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from rosdeploy.checks import RULES, run_checks
from test_checks import fires, host, release, silent, spec
import test_hostile
from test_hostile import cli, edit, refused_everywhere

lab = test_hostile.lab      # the fixture: the example fleet copied

BUILTIN = Path(__file__).resolve().parents[2] / "rosdeploy" / "templates" / "compose.yml.j2"
SHM_LINE = '      - "/dev/shm:/dev/shm"\n'


def user_template(lab: Path, *, volume: str = "", after_image: str = "", append: str = "") -> None:
    """The built-in compose template as the user's own, with a volume, service keys or top-level keys added."""
    text = BUILTIN.read_text()
    assert SHM_LINE in text and "    image: {{ svc.image | compose_str }}\n" in text
    if volume:
        text = text.replace(SHM_LINE, SHM_LINE + f'      - "{volume}"\n')
    if after_image:
        text = text.replace("    image: {{ svc.image | compose_str }}\n",
                            "    image: {{ svc.image | compose_str }}\n" + after_image + "\n")
    (lab / "templates").mkdir()
    (lab / "templates" / "compose.yml.j2").write_text(text + append)
    edit(lab, lambda d: d.update(templates="./templates"))


def findings(rule_id: str, compose: dict, h: Any = None) -> list:
    h = h or host()
    return run_checks(spec(), [h], [release(h, compose=yaml.safe_dump(compose))], rules=[RULES[rule_id]])


# -------------------------------------------- 1. relative and `~` bind sources

@pytest.mark.parametrize("volume", ["../../../../../../../../../../etc:/e", "~/../../etc:/e",
                                    "./../../../../../../etc:/e",
                                    {"type": "bind", "source": "x/../../../../../../../../etc", "target": "/e"},
                                    "~/../../../root/.ssh:/k", "../../../../../../../usr/bin:/b:rw"])
def test_a_relative_or_home_source_is_judged_where_it_lands(volume: object) -> None:
    p = fires("mount-system-writable", volumes=[volume])
    assert "on the robot)" in p.message and ":ro" in p.message, p.message


@pytest.mark.parametrize("volume", ["../../../../../../../var/run:/r", "~/../../run:/r:ro",
                                    "../../../../../..:/host:ro"])
def test_a_relative_source_that_reaches_the_engine_socket_is_refused(volume: str) -> None:
    p = fires("docker-socket-mounted", volumes=[volume])
    assert "holds the engine socket" in p.message and "on the robot)" in p.message, p.message


@pytest.mark.parametrize("volume", ["../../logs/driver:/ros_log", "../../store/ab12/cyclonedds.xml:/c.xml:ro",
                                    "~/maps:/maps", "../../../../../../../etc:/e:ro", "/home/ros/maps:/m"])
def test_the_release_own_folders_and_read_only_climbs_are_fine(volume: str) -> None:
    silent("mount-system-writable", volumes=[volume])
    silent("docker-socket-mounted", volumes=[volume])


def test_the_home_of_the_ssh_user_and_rosdeploy_home_decide_where_tilde_lands() -> None:
    # user ros: ~ is /home/ros, so ~/../../etc is /etc; rosdeploy_home moves it
    assert "/etc on the robot" in fires("mount-system-writable", hosts=[host(user="ros")],
                                        volumes=["~/../../etc:/e"]).message
    deep = host(user="ros", vars={"rosdeploy_home": "/srv/robots/ros"})
    silent("mount-system-writable", hosts=[deep], volumes=["~/../../etc:/e"])          # /srv/etc
    fires("mount-system-writable", hosts=[deep], volumes=["~/../../../etc:/e"])        # /etc


def test_a_relative_etc_in_a_user_template_is_refused_by_every_command(capsys: pytest.CaptureFixture,
                                                                       lab: Path) -> None:
    user_template(lab, volume="../../../../../../../../../../etc:/e")
    refused_everywhere(capsys, lab, "(/etc on the robot) writable")
    assert "error[mount-system-writable]" in cli(capsys, lab, "check")[1]


def test_a_user_template_unchanged_still_passes(capsys: pytest.CaptureFixture, lab: Path) -> None:
    # its ../../logs/<service> and ../../store mounts land in the deploy root, which is under /root here
    user_template(lab)
    code, text = cli(capsys, lab, "check")
    assert code == 0 and "mount-system-writable" not in text, text


# ------------------------------------------------- 2. a named volume that binds

BIND_ROOT = {"driver": "local", "driver_opts": {"type": "none", "o": "bind", "device": "/"}}


@pytest.mark.parametrize("device, rule, words", [("/", "docker-socket-mounted", "holds the engine socket"),
                                                  ("/etc", "mount-system-writable", "/etc"),
                                                  ("/var/run", "docker-socket-mounted", "holds the engine socket"),
                                                  ("~/../../etc", "mount-system-writable", "/etc")])
def test_a_named_volume_the_local_driver_binds_is_judged_by_its_device(device: str, rule: str, words: str) -> None:
    volume = {**BIND_ROOT, "driver_opts": {**BIND_ROOT["driver_opts"], "device": device}}
    for mount in ("hostroot:/host", {"type": "volume", "source": "hostroot", "target": "/host"}):
        found = findings(rule, {"services": {"driver": {"volumes": [mount]}}, "volumes": {"hostroot": volume}})
        assert found and words in found[0].message, (device, mount, found)


def test_a_read_only_or_ordinary_named_volume_is_fine() -> None:
    ro = {**BIND_ROOT, "driver_opts": {"type": "none", "o": "bind,ro", "device": "/etc"}}
    for volumes, mount in (({"maps": {}}, "maps:/maps"), ({"maps": None}, "maps:/maps"),
                           ({"hostetc": ro}, "hostetc:/e"), ({"hostetc": {**BIND_ROOT, "driver_opts": {
                               "o": "bind", "device": "/etc"}}}, "hostetc:/e:ro"),
                           ({"nfs": {"driver_opts": {"type": "nfs", "o": "addr=10.0.0.1", "device": ":/"}}}, "nfs:/n")):
        compose = {"services": {"driver": {"volumes": [mount]}}, "volumes": volumes}
        assert not findings("mount-system-writable", compose) and not findings("docker-socket-mounted", compose)


def test_a_user_template_binding_the_root_through_a_volume_is_refused(capsys: pytest.CaptureFixture,
                                                                      lab: Path) -> None:
    user_template(lab, volume="hostroot:/host", append=(
        "volumes:\n  hostroot:\n    driver: local\n    driver_opts: {type: none, o: bind, device: /}\n"))
    refused_everywhere(capsys, lab, "mounts hostroot (/ on the robot), which holds the engine socket")
    assert "error[docker-socket-mounted]" in cli(capsys, lab, "check")[1]


# ------------------------------------- 3. what compose brings in that check never sees

@pytest.mark.parametrize("compose, words", [
    ({"include": ["/opt/evil/compose.yml"]}, "`include:`"),
    ({"services": {"driver": {"extends": {"file": "/opt/x.yml", "service": "x"}}}}, "`extends`"),
    ({"services": {"driver": {"volumes_from": ["container:other"]}}}, "`volumes_from`"),
    ({"services": {"driver": {"env_file": ["/etc/shadow"]}}}, "`env_file`"),
    ({"services": {"driver": {"env_file": "/etc/shadow"}}}, "`env_file`"),
    ({"services": {"driver": {"pid": "container:guard"}}}, "`pid`"),
    ({"services": {"driver": {"ipc": "container:guard"}}}, "`ipc`"),
    ({"services": {"driver": {"network_mode": "container:guard"}}}, "`network_mode`")])
def test_keys_that_bring_in_what_check_never_sees_are_refused(compose: dict, words: str) -> None:
    compose = {"services": {"driver": {}}, **compose}
    found = findings("compose-invalid", compose)
    assert found and found[0].severity == "error" and words in found[0].message and "never sees" in found[0].message


@pytest.mark.parametrize("svc", [{"ipc": "service:other"},
                                 {"pid": "service:other"}, {"network_mode": "host"}, {"ipc": "shareable"}])
def test_keys_that_stay_in_the_compose_file_are_fine(svc: dict) -> None:
    assert not findings("compose-invalid", {"services": {"driver": svc, "other": {}}})


@pytest.mark.parametrize("after_image, append, words", [
    ("    extends: {file: /opt/x.yml, service: x}", "", "`extends`"),
    ('    volumes_from: ["container:other"]', "", "`volumes_from`"),
    ('    env_file: ["/etc/shadow"]', "", "`env_file`"),
    ('    pid: "container:guard"', "", "`pid`"),
    ("", "include:\n  - /opt/evil/compose.yml\n", "`include:`")])
def test_a_user_template_that_brings_in_a_file_is_refused_at_the_template(
        capsys: pytest.CaptureFixture, lab: Path, after_image: str, append: str, words: str) -> None:
    user_template(lab, after_image=after_image, append=append)
    refused_everywhere(capsys, lab, words, "never sees", "templates/compose.yml.j2", commands=("validate", "render"))
    assert "error[compose-invalid]" in cli(capsys, lab, "check")[1]


# --------------------------------------------------------------- 4. sysctls

@pytest.mark.parametrize("svc", [{"sysctls": ["kernel.sysrq=1"]}, {"sysctls": {"kernel.core_pattern": "|/tmp/x"}},
                                 {"sysctls": {"vm.swappiness": 1}},
                                 {"network_mode": "host", "sysctls": {"net.core.somaxconn": 1024}},
                                 {"ipc": "host", "sysctls": ["kernel.shmmax=1"]}])
def test_a_sysctl_docker_refuses_is_an_error(svc: dict) -> None:
    found = findings("compose-invalid", {"services": {"driver": svc}})
    assert found and "sysctl" in found[0].message and "set it on the robot" in found[0].message, found


@pytest.mark.parametrize("svc", [{"sysctls": {"net.core.somaxconn": 1024}, "networks": ["ros"]},
                                 {"sysctls": ["kernel.shmmax=1", "fs.mqueue.msg_max=10"]}])
def test_a_namespaced_sysctl_is_fine(svc: dict) -> None:
    assert not findings("compose-invalid", {"services": {"driver": svc}})


def test_a_user_template_with_a_kernel_sysctl_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    user_template(lab, after_image='    sysctls: ["kernel.sysrq=1"]')
    refused_everywhere(capsys, lab, "'kernel.sysrq', which is not a namespaced sysctl", "templates/compose.yml.j2",
                       commands=("validate", "render"))
    assert "error[compose-invalid]" in cli(capsys, lab, "check")[1]


# ------------------------------------------------------------------ 6. /home

@pytest.mark.parametrize("volume", ["/home:/h", "/home/:/h:rw", "/home/ros:/h", "/home/ros/.ssh:/k",
                                    "/home/ros/.bashrc:/b", "~:/h", "~/.ssh:/k", "~/rosdeploy:/r",
                                    "../../releases:/r", "./compose.yml:/c", "../../../../rosdeploy:/r"])
def test_a_writable_home_or_deploy_root_is_root(volume: str) -> None:
    p = fires("mount-system-writable", hosts=[host(user="ros")], volumes=[volume])
    assert "is root on the robot" in p.message, p.message


def test_a_deploy_root_of_its_own_is_guarded_too() -> None:
    opt = host(user="ros", vars={"rosdeploy_deploy_root": "/opt/rosdeploy"})
    fires("mount-system-writable", hosts=[opt], volumes=["/opt/rosdeploy/p/releases:/r"])
    fires("mount-system-writable", hosts=[opt], volumes=["/opt:/o"])
    silent("mount-system-writable", hosts=[opt], volumes=["/opt/rosdeploy/p/logs/driver:/l", "/opt/maps:/m"])


@pytest.mark.parametrize("volume", ["/home:/h:ro", "/home/ros/maps:/m", "~/maps:/m", "~/bags/.cache:/c",
                                    "../../logs/driver:/ros_log", "../../logs:/l"])
def test_data_in_a_home_and_the_logs_are_fine(volume: str) -> None:
    silent("mount-system-writable", hosts=[host(user="ros")], volumes=[volume])


def test_a_fleet_mount_of_home_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(volumes=["/home:/h"]))
    code, text = cli(capsys, lab, "check")
    assert code == 2 and "error[mount-system-writable]" in text and "mounts /home writable" in text, text


@pytest.mark.parametrize("user", [None, "root", "ros"])
def test_the_built_in_logs_and_store_mounts_are_fine_for_every_ssh_user(user: str | None) -> None:
    # as root, the deploy root is /root/rosdeploy: inside a system folder, yet its logs are the release's own
    silent("mount-system-writable", hosts=[host(user=user)],
           volumes=["../../logs/driver:/ros_log", "../../store/ab12/fastdds.xml:/fastdds.xml:ro"])
    assert "/root/rosdeploy/p/releases" in fires("mount-system-writable", hosts=[host(user="root")],
                                                 volumes=["../../releases:/r"]).message


def test_a_null_sysctls_is_refused_by_the_schema_not_as_a_sysctl() -> None:
    """Both Compose versions refuse `sysctls:` with no value (checked with `config -q`)."""
    found = findings("compose-invalid", {"services": {"driver": {"sysctls": None}}})
    assert [p for p in found if "Compose schema at services.driver.sysctls" in p.message], found
    assert not [p for p in found if "set it on the robot" in p.message], found
