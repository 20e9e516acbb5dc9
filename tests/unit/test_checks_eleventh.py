"""Probe R (eleventh round) items 2 and 3B: what a user's compose template renders past `check`.

A named volume the local driver mounts from a robot device as a file system is the robot's disk in
the container (device-root, as `devices: [/dev/sda1]`); and a user template's service values are held
to the checks the fleet's `compose:` pass-through gets where Docker or Compose refuses them at `up`.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
import yaml

from rosdeploy.checks import RULES, run_checks
from test_checks import host, release, spec
from test_checks_ninth import findings, user_template
import test_hostile
from test_hostile import cli, refused_everywhere

lab = test_hostile.lab      # the fixture: the example fleet copied

EXT4 = {"driver_opts": {"type": "ext4", "device": "/dev/sda1"}}


# ------------------------------------------------- 2. a named volume that mounts a disk

@pytest.mark.parametrize("volume", [EXT4, {"driver": "local", "driver_opts": {"type": "xfs", "device": "/dev/nvme0n1"}},
                                    {"driver_opts": {"type": "ext4", "device": "/dev/disk/by-uuid/1234"}},
                                    {"driver_opts": {"type": "vfat", "device": "/dev/robot/usbstick", "o": "rw"}},
                                    {"driver_opts": {"device": "/dev//sda1"}}])
def test_a_named_volume_mounted_from_a_device_is_a_disk(volume: dict) -> None:
    for mount in ("hostroot:/host", {"type": "volume", "source": "hostroot", "target": "/host"}):
        found = findings("device-root", {"services": {"driver": {"volumes": [mount]}}, "volumes": {"hostroot": volume}})
        assert len(found) == 1, (volume, mount, found)
        message = found[0].message
        assert "mounts volume 'hostroot'" in message and "which is a disk (every file on it, /etc/shadow included, " \
               "can be rewritten)" in message and "allow_privileged: true" in message, message


def test_a_read_only_disk_volume_is_refused_as_read() -> None:
    for mount, volume in (("hostroot:/host:ro", EXT4),
                          ("hostroot:/host", {"driver_opts": {"type": "ext4", "o": "ro", "device": "/dev/sda1"}})):
        found = findings("device-root", {"services": {"driver": {"volumes": [mount]}}, "volumes": {"hostroot": volume}})
        assert len(found) == 1 and "can be read)" in found[0].message, found


@pytest.mark.parametrize("volume", [{"driver_opts": {"type": "nfs", "o": "addr=10.0.0.1", "device": ":/export"}},
                                    {"driver_opts": {"type": "cifs", "device": "//nas/share"}},
                                    {"driver_opts": {"type": "tmpfs", "device": "tmpfs", "o": "size=100m"}},
                                    {"driver_opts": {"type": "none", "o": "bind", "device": "/dev/sda1"}},
                                    {"driver": "other", **EXT4}, {"external": True, **EXT4}, {}, None])
def test_remote_tmpfs_bind_and_other_volumes_are_not_disks(volume: object) -> None:
    compose = {"services": {"driver": {"volumes": ["hostroot:/host"]}}, "volumes": {"hostroot": volume}}
    assert not findings("device-root", compose)


def test_a_bind_mount_or_unused_disk_volume_is_not_this_finding() -> None:
    volumes = {"hostroot": EXT4}
    for mounts in (["./hostroot:/host"], [{"type": "bind", "source": "hostroot", "target": "/h"}], ["maps:/maps"]):
        assert not findings("device-root", {"services": {"driver": {"volumes": mounts}}, "volumes": volumes}), mounts


def test_allow_privileged_waives_a_disk_volume() -> None:
    fleet = spec()
    fleet = replace(fleet, services=(replace(fleet.services[0], allow_privileged=True),))
    h = host()
    compose = {"services": {"driver": {"volumes": ["hostroot:/host"]}}, "volumes": {"hostroot": EXT4}}
    assert not run_checks(fleet, [h], [release(h, compose=yaml.safe_dump(compose))], rules=[RULES["device-root"]])


def test_a_user_template_mounting_a_disk_through_a_volume_is_refused(capsys: pytest.CaptureFixture,
                                                                     lab: Path) -> None:
    user_template(lab, volume="hostroot:/host", append=(
        "volumes:\n  hostroot:\n    driver_opts: {type: ext4, device: /dev/sda1}\n"))
    refused_everywhere(capsys, lab, "which the engine mounts from /dev/sda1 as 'ext4'", "which is a disk")
    assert "error[device-root]" in cli(capsys, lab, "check")[1]


# ------------------------------- 3B. a user template's values the fleet's `compose:` refuses

def invalid(**svc: object) -> list[str]:
    compose = {"services": {"driver": {"image": "acme/driver:1.0", **svc}, "peer": {"image": "acme/peer:1.0"}}}
    return [p.message for p in findings("compose-invalid", compose)]


@pytest.mark.parametrize("svc, words", [
    ({"isolation": "x"}, "`isolation` in the rendered compose.yml, which Docker or Compose refuses at `up`: only "
                         "`default` exists on Linux"),
    ({"pid": "HOST"}, "`pid` in the rendered compose.yml, which Docker or Compose refuses at `up`: 'HOST' is none of "
                      "host, container:NAME, service:NAME"),
    ({"userns_mode": "bogus"}, "'bogus' is none of host"),
    ({"working_dir": "app"}, "must be an absolute path"),
    ({"stop_signal": "SIGNOPE"}, "is no signal"),
    ({"ulimits": {"nofile": {"soft": 10, "hard": 5}}}, "`ulimits.nofile` in the rendered compose.yml"),
    ({"ports": ["8080:80/xyz"]}, "'xyz' is not a protocol"),
    ({"cgroup": "HOST"}, "Compose takes only `host` or `private`"),
    ({"pid": "service:nobody"}, "shares pid: no service is named `nobody`"),
    ({"ipc": "service:driver"}, "shares its own ipc namespace (a cycle)"),
    ({"build": "/opt"}, "has `build` in the rendered compose.yml: it brings in an image built on the robot"),
    ({"label_file": ["/etc/x"]}, "has `label_file` in the rendered compose.yml: it brings in labels from a file"),
])
def test_a_user_template_value_docker_refuses_is_refused(svc: dict, words: str) -> None:
    found = invalid(**svc)
    assert any(words in m for m in found), found


def test_ipc_values_docker_refuses_are_refused_once_fleet_checks_them() -> None:
    # fleet._check_compose_values judges `ipc` (another fixer's item, probe R 3A): the template gets it too
    assert any("'bogus' is none of none, private, shareable" in m for m in invalid(ipc="bogus")), invalid(ipc="bogus")


@pytest.mark.parametrize("svc", [{"isolation": "default"}, {"pid": "host"}, {"ipc": "shareable"},
                                 {"ipc": "service:peer"}, {"pid": "service:peer"}, {"cgroup": "host"},
                                 {"gpus": "all"}, {"working_dir": "/ws"}, {"stop_signal": "SIGINT"},
                                 {"ports": ["8080:80/udp"]}, {}])
def test_values_docker_takes_pass(svc: dict) -> None:
    assert not invalid(**svc)


def test_a_user_template_isolation_is_refused_by_every_command(capsys: pytest.CaptureFixture, lab: Path) -> None:
    user_template(lab, after_image="    isolation: x\n    pid: HOST")
    refused_everywhere(capsys, lab, "only `default` exists on Linux", "'HOST' is none of host")
    assert "error[compose-invalid]" in cli(capsys, lab, "check")[1]
