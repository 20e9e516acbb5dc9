"""Ninth audit, per-robot vars (probe N): values rosdeploy took that Ansible, Linux or a resolver read otherwise.

3. `rosdeploy_deploy_root: /./` (the robot's root folder) passed; the fleet's deploy_root refuses it.
4. `ansible_become: off` (`n`, `f`, 0.0) was read as true: rosdeploy would have used sudo.
8. Device paths, udev symlinks and serials past Linux's limits passed; Docker failed at create.
9. `ansible_user: ../../etc` reached logrotate.conf as /home/../../etc.
10. `ROS_DOMAIN_ID`, `GPU`: a short name in another case got no did-you-mean.
15. `ansible_host: a,b`, `a%b`, `a=b`, Arabic-Indic digits: no resolver takes them.
"""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from rosdeploy.hostchanges import become
from rosdeploy.inventory import hostvars
from test_hostile import cli, lab, refused_everywhere
from test_hostile_sixth import add_host_vars, set_hosts
from test_render import make_host

__all__ = ["lab"]   # the fixture: tests/unit/data/fleet copied, its vault password in place

EVERY = ("validate", "check", "render")
VALIDATE = ("validate",)    # the other commands load the same way: run once per item, the suite is at its limit


def ini(lab: Path, extra: str) -> tuple[str, str]:
    """An INI inventory of r1 (with `extra` on its line) and r2: the `-i` arguments."""
    path = lab / "robots.ini"
    path.write_text(f"[lab]\nr1 ansible_host=127.0.0.1 ros_domain_id=1 {extra}\n"
                    "r2 ansible_host=127.0.0.2 ros_domain_id=2\n")
    return "-i", str(path)


def validate_refuses(capsys: pytest.CaptureFixture, lab: Path, *expect: str, argv: tuple[str, ...] = ()) -> None:
    code, text = cli(capsys, lab, "validate", *argv)
    assert code == 2, text
    for part in expect:
        assert part in text, (part, text)


# ------------------------------------------------------------------ 4. ansible_become

@pytest.mark.parametrize("value", ["off", "n", "f", "0.0", "no"])
def test_ansible_false_words_in_become_are_false(capsys: pytest.CaptureFixture, lab: Path, value: str) -> None:
    # `off` was read as true: check said nothing, and apply would have run sudo against the inventory
    argv = ini(lab, f"ansible_user=ubuntu ansible_become={value}")
    code, text = cli(capsys, lab, "check", *argv)
    assert "ansible_become is false for ubuntu, who is not root" in text, text


@pytest.mark.parametrize("value, refused", [("off", True), ("n", True), (0.0, True), ("f", True),
                                            ("on", False), ("y", False), (1, False), (True, False)])
def test_become_reads_a_value_as_ansible_does(value: object, refused: bool) -> None:
    host = make_host("r1", user="ubuntu", vars={"ansible_become": value})
    assert bool(become(host).refused) is refused


def test_an_ansible_become_that_is_no_boolean_is_refused_at_its_var(capsys: pytest.CaptureFixture,
                                                                   lab: Path) -> None:
    add_host_vars(lab, "r1", "ansible_user: ubuntu\nansible_become: maybe\n")
    refused_everywhere(capsys, lab, "r1.yml:", "ansible_become: robot 'r1': must be true or false, got 'maybe'")


def test_a_yaml_false_word_in_become_is_a_bool_for_every_reader(capsys: pytest.CaptureFixture, lab: Path) -> None:
    add_host_vars(lab, "r1", "ansible_user: ubuntu\nansible_become: 'off'\n")
    code, text = cli(capsys, lab, "check")
    assert "r1.yml:" in text and "ansible_become is false for ubuntu" in text, text


# ------------------------------------------------------------------ 3. rosdeploy_deploy_root

@pytest.mark.parametrize("value", ["/./", "/.", "/./."])
def test_a_robots_deploy_root_that_is_the_root_folder_is_refused(capsys: pytest.CaptureFixture, lab: Path,
                                                                 value: str) -> None:
    add_host_vars(lab, "r1", f"rosdeploy_deploy_root: '{value}'\n")
    refused_everywhere(capsys, lab, "r1.yml:", f"'{value}' is the robot's root folder: releases need a folder",
                       commands=EVERY if value == "/./" else VALIDATE)


def test_a_robots_root_deploy_root_in_ini_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    validate_refuses(capsys, lab, "robots.ini:", "is the robot's root folder",
                     argv=ini(lab, "rosdeploy_deploy_root=/./"))


def test_a_robots_deploy_root_under_the_root_still_passes(capsys: pytest.CaptureFixture, lab: Path) -> None:
    add_host_vars(lab, "r1", "rosdeploy_deploy_root: /./opt/x\n")
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


# ------------------------------------------------------------------ 9. ansible_user

@pytest.mark.parametrize("value", ["..", ".", "../../etc", "a/b"])
@pytest.mark.parametrize("var", ["ansible_user", "ansible_ssh_user"])
def test_a_user_no_linux_user_can_have_is_refused_at_its_var(capsys: pytest.CaptureFixture, lab: Path,
                                                             var: str, value: str) -> None:
    add_host_vars(lab, "r1", f"{var}: '{value}'\n")
    refused_everywhere(capsys, lab, "r1.yml:", f"{var}: robot 'r1': '{value}' is no user name",
                       commands=EVERY if value == ".." and var == "ansible_user" else VALIDATE)


@pytest.mark.parametrize("value", ["ubuntu", "robot.op", "ci-bot_2", "..x"])
def test_ordinary_user_names_still_pass(capsys: pytest.CaptureFixture, lab: Path, value: str) -> None:
    add_host_vars(lab, "r1", f"ansible_user: '{value}'\n")
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    assert f"/home/{value}/rosdeploy/" in (lab / "out" / "r1" / "logrotate.conf").read_text()


# ------------------------------------------------------------------ 8. lengths Linux refuses

TOO_LONG = "a path of {size} characters: Linux allows 4096, and 255 for each name in it; shorten it"


@pytest.mark.parametrize("path", ["/dev/" + "a" * 5000, "/dev/" + "a" * 300, "/dev/x/" + "b" * 256],
                         ids=["5000", "name-300", "name-256"])
def test_a_device_path_too_long_for_linux_is_refused(capsys: pytest.CaptureFixture, lab: Path, path: str) -> None:
    add_host_vars(lab, "r1", f"rosdeploy_devices: {{motor: '{path}'}}\n")
    refused_everywhere(capsys, lab, "r1.yml:", "rosdeploy_devices.motor:", TOO_LONG.format(size=len(path)),
                       commands=EVERY if len(path) > 4096 else VALIDATE)


def test_a_device_path_at_linuxs_limits_passes(capsys: pytest.CaptureFixture, lab: Path) -> None:
    path = "/dev/" + "a" * 255
    add_host_vars(lab, "r1", f"rosdeploy_devices: {{motor: '{path}'}}\n")
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


def test_a_non_ascii_device_name_is_counted_in_bytes() -> None:
    with pytest.raises(hostvars.BadValue, match="a path of 263 bytes: Linux allows 4096, and 255 for each"):
        hostvars._device_path("/dev/" + "é" * 128 + "ab", ())
    assert hostvars._device_path("/dev/" + "é" * 127, ()) == "/dev/" + "é" * 127


def udev_entry(**values: str) -> str:
    entry = {"symlink": "robot/motor", "subsystem": "tty", "vendor": "0403", "product": "6001", **values}
    return yaml.safe_dump({"udev": [entry]}, width=100000)


@pytest.mark.parametrize("symlink", ["robot/" + "m" * 300, "/".join(["x" * 200] * 21)], ids=["name", "path"])
def test_a_udev_symlink_too_long_for_linux_is_refused(capsys: pytest.CaptureFixture, lab: Path,
                                                      symlink: str) -> None:
    (lab / "inventory" / "host_vars" / "r1.yml").write_text(
        "gpu: true\nros_network: lab\ndevices: {motor: /dev/robot/motor}\n" + udev_entry(symlink=symlink))
    refused_everywhere(capsys, lab, "r1.yml:", "udev[0].symlink:", "Linux allows 4096, and 255 for each name",
                       commands=VALIDATE)


def test_a_udev_serial_no_device_has_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "inventory" / "host_vars" / "r1.yml").write_text(
        "gpu: true\nros_network: lab\ndevices: {motor: /dev/robot/motor}\n" + udev_entry(serial="S" * 5000))
    refused_everywhere(capsys, lab, "r1.yml:", "udev[0].serial:", "a serial of 5000 characters",
                       commands=VALIDATE)


def test_a_real_udev_serial_passes(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "inventory" / "host_vars" / "r1.yml").write_text(
        "gpu: true\nros_network: lab\ndevices: {motor: /dev/robot/motor}\n" + udev_entry(serial="A" * 126))
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


# ------------------------------------------------------------------ 10. short names in another case

@pytest.mark.parametrize("var, meant", [("GPU", "gpu"), ("Ros_Domain_Id", "ros_domain_id"),
                                        ("ANSIBLE_HOST", "ansible_host"), ("UDEV", "udev")])
def test_a_short_name_in_another_case_gets_a_did_you_mean(capsys: pytest.CaptureFixture, lab: Path,
                                                          var: str, meant: str) -> None:
    add_host_vars(lab, "r1", f"{var}: 1\n")
    code, text = cli(capsys, lab, "validate")
    assert f"'{var}' is not a variable rosdeploy reads: did you mean '{meant}'?" in text, text


def test_a_missing_domain_id_beside_its_upper_case_spelling_warns_at_that_var(capsys: pytest.CaptureFixture,
                                                                              lab: Path) -> None:
    set_hosts(lab, "          ros_domain_id: 1\n", "          ROS_DOMAIN_ID: 1\n")
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "declares no ros_domain_id" in text, text
    assert ("hosts.yml:8: all.children.lab.hosts.r1.ROS_DOMAIN_ID: 'ROS_DOMAIN_ID' is not a variable rosdeploy "
            "reads: did you mean 'ros_domain_id'?") in text, text


def test_case_variant_names_the_misspelt_var() -> None:
    assert hostvars.case_variant(["gpu", "ROS_DOMAIN_ID"], "ros_domain_id") == "ROS_DOMAIN_ID"
    assert hostvars.case_variant(["ros_domain_id", 5], "ros_domain_id") is None


def test_the_case_lookup_is_one_dict_lookup_per_name() -> None:
    hostvars._near_miss.cache_clear()
    assert hostvars._near_miss("DEVICES") == "devices"
    assert hostvars._near_miss("dds_peers") is None and hostvars._near_miss("ansible_become") is None


# ------------------------------------------------------------------ 15. ansible_host characters

@pytest.mark.parametrize("value, shown", [("a,b", "','"), ("a%b", "'%'"), ("a=b", "'='"),
                                          ("١٢٧.0.0.1", "'١', '٢', '٧'"), ("robot+1", "'+'")])
def test_an_address_no_resolver_takes_is_refused_at_its_var(capsys: pytest.CaptureFixture, lab: Path,
                                                            value: str, shown: str) -> None:
    set_hosts(lab, "ansible_host: 127.0.0.1", f"ansible_host: '{value}'")
    refused_everywhere(capsys, lab, "hosts.yml:", "ansible_host: robot 'r1'", f"holds {shown}: a host name",
                       commands=VALIDATE)


@pytest.mark.parametrize("value", ["fe80::1%eth0", "bücher.example", "robot_alias", "robot-1.local.", "10.0.0.7",
                                   "::1", "ROBOT1"])
def test_good_addresses_and_aliases_still_pass(capsys: pytest.CaptureFixture, lab: Path, value: str) -> None:
    set_hosts(lab, "ansible_host: 127.0.0.1", f"ansible_host: '{value}'")
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text
