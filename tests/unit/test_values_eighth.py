"""Values that reach the robot's files (probes J and K, eighth round).

A stored file missing from the project store is a mount source Docker creates as an empty
directory; devices and bind mounts that are root on the robot; values Compose, runc or
CycloneDDS refuse at the robot. Each case failed (or passed silently) before its fix.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
import yaml

import test_hostile
from rosdeploy import restarts
from test_checks import fires, silent, spec
from test_hostile import cli, edit
from test_vault_taint import vault_file

lab = test_hostile.lab      # the fixture: the example fleet copied


# ----------------------------------------------------------- link-store.sh (J1, J2)

def _release(root: Path, release: str, files: dict[str, str]) -> None:
    """releases/<release>/store/<key>/<name> as an upload leaves them."""
    for name, content in files.items():
        path = root / "lab" / "releases" / release / "store" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(content)


def _link(root: Path, release: str) -> subprocess.CompletedProcess:
    cmd = restarts.link_store(str(root), "lab", release)
    return subprocess.run(list(cmd.argv), capture_output=True, text=True, timeout=20)


def _store(root: Path) -> dict[str, str]:
    store = root / "lab" / "store"
    return {str(p.relative_to(store)): p.read_text() for p in sorted(store.rglob("*")) if p.is_file()}


def test_link_store_adds_a_name_to_an_entry_stored_under_another(tmp_path: Path) -> None:
    """J1: release 2 stores the same content as /config/b.yaml; the entry was there as a.yaml."""
    _release(tmp_path, "rel0", {"d1/a.yaml": "hello"})
    assert _link(tmp_path, "rel0").returncode == 0
    _release(tmp_path, "rel1", {"d1/b.yaml": "hello", "d1/a.yaml": "hello"})
    assert _link(tmp_path, "rel1").returncode == 0
    assert _store(tmp_path) == {"d1/a.yaml": "hello", "d1/b.yaml": "hello"}
    assert not [p for p in (tmp_path / "lab" / "store").iterdir() if p.name.startswith(".tmp")]


def test_link_store_replaces_the_empty_folder_docker_made_for_a_missing_name(tmp_path: Path) -> None:
    _release(tmp_path, "rel0", {"d1/a.yaml": "hello"})
    assert _link(tmp_path, "rel0").returncode == 0
    (tmp_path / "lab" / "store" / "d1" / "b.yaml").mkdir()     # what `docker compose up` left
    _release(tmp_path, "rel1", {"d1/b.yaml": "hello"})
    assert _link(tmp_path, "rel1").returncode == 0
    assert (tmp_path / "lab" / "store" / "d1" / "b.yaml").is_file()


def test_link_store_copies_dotfiles(tmp_path: Path) -> None:
    """J2: `*` does not match `.hidden`; `..x` and a name with a blank must arrive too."""
    files = {"d2/.hidden": "a", "d3/..x": "b", "d4/-n": "c", "d5/a b": "d", "d6/.env": "e", "d6/env": "e"}
    _release(tmp_path, "rel1", files)
    done = _link(tmp_path, "rel1")
    assert done.returncode == 0, done.stderr
    assert _store(tmp_path) == files
    # a second run changes nothing and an entry no release holds goes
    (tmp_path / "lab" / "store" / "gone").mkdir()
    assert _link(tmp_path, "rel1").returncode == 0
    assert _store(tmp_path) == files and not (tmp_path / "lab" / "store" / "gone").exists()


# ------------------------------------------------- devices and mounts that are root (J8, J10)

def _vars(lab: Path, **values: object) -> None:
    path = lab / "inventory" / "group_vars" / "all" / "vars.yml"
    data = yaml.safe_load(path.read_text())
    data.update(values)
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def test_a_device_path_is_written_as_the_kernel_reads_it(capsys: pytest.CaptureFixture, lab: Path) -> None:
    _vars(lab, devices={"motor": "/dev//robot/./motor/"})
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    compose = (lab / "out" / "r1" / "compose.yml").read_text()
    assert "/dev/robot/motor:/dev/robot/motor" in compose and "/dev//" not in compose


@pytest.mark.parametrize("path", ["/dev//", "//dev/./"])
def test_a_device_path_naming_dev_itself_is_refused(capsys: pytest.CaptureFixture, lab: Path, path: str) -> None:
    _vars(lab, devices={"motor": path})
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "vars.yml:" in text and "devices.motor" in text and "not /dev itself" in text, text


@pytest.mark.parametrize("path", ["/dev", "/dev/", "/dev//", "/dev/mem", "/dev/kmem", "/dev/port", "/dev/sda",
                                  "/dev/sdb1", "/dev/nvme0n1p2", "/dev/vda", "/dev/mmcblk0p1", "/dev/./mem",
                                  "/dev/cpu", "/dev/mapper/root", "/dev/disk/by-uuid/0a1b", "/dev/disk/by-id/ata-x",
                                  "/dev/disk", "/dev/block/8:1", "/dev/root", "/dev/mtd0", "/dev/mtdblock2",
                                  "/dev/nbd0", "/dev/ubi0_1"])
def test_a_device_that_is_root_on_the_robot_is_an_error(path: str) -> None:
    p = fires("device-root", devices=[f"{path}:/dev/x"])
    assert p.severity == "error" and p.key == "services.driver.devices" and "allow_privileged" in p.message


@pytest.mark.parametrize("path", ["/dev/robot/motor", "/dev/ttyUSB0", "/dev/video0", "/dev/hidraw0", "/dev/snd",
                                  "/dev/dri", "/dev/serial/by-id/usb-x", "/dev/input/event3", "/dev/fuse",
                                  "/dev/rootx", "/dev/diskette", "/dev/blockx"])
def test_an_ordinary_device_is_not_root(path: str) -> None:
    silent("device-root", devices=[f"{path}:{path}"])


def test_allow_privileged_waives_root_devices_and_mounts() -> None:
    fleet = spec(driver={"allow_privileged": True})
    silent("device-root", fleet=fleet, devices=["/dev/mem:/dev/mem"])
    silent("mount-system-writable", fleet=fleet, volumes=["/etc:/etc"])


@pytest.mark.parametrize("volume", ["/etc:/etc", "/etc/sudoers.d:/s", "/proc:/hostproc", "/proc/sysrq-trigger:/t",
                                    "/sys:/hostsys", "/sys/fs/cgroup:/c", "/root:/r", "/boot:/b", "/lib/modules:/m",
                                    "/var/lib/docker:/d", "/var/lib:/v", "/etc/:/e:rw", "//etc/./cron.d:/c",
                                    "/usr/local/bin:/b:z", {"type": "bind", "source": "/etc", "target": "/e"}])
def test_a_writable_mount_of_a_system_folder_is_an_error(volume: object) -> None:
    p = fires("mount-system-writable", volumes=[volume])
    assert p.key == "services.driver.volumes" and ":ro" in p.message and "allow_privileged" in p.message


@pytest.mark.parametrize("volume", ["/etc:/etc:ro", "/proc:/hostproc:ro,z", "/opt/maps:/maps", "/home/ros/maps:/m",
                                    "/data:/data", "maps:/maps", "../../logs/driver:/ros_log", "/dev/shm:/dev/shm",
                                    {"type": "bind", "source": "/etc", "target": "/e", "read_only": True},
                                    {"type": "volume", "source": "etc", "target": "/e"}, "/etc-backup:/b",
                                    "/etc/localtime:/etc/localtime", "/sys/class/gpio:/sys/class/gpio"])
def test_a_read_only_or_ordinary_mount_is_fine(volume: object) -> None:
    silent("mount-system-writable", volumes=[volume])


def test_root_mounts_are_refused_end_to_end(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(volumes=["/etc:/etc", "/opt/maps:/maps"]))
    _vars(lab, devices={"motor": "/dev/mem"})
    code, text = cli(capsys, lab, "check")
    assert code == 2 and "error[mount-system-writable]" in text and "error[device-root]" in text, text
    edit(lab, lambda d: d["services"]["driver"].update(allow_privileged=True))
    code, text = cli(capsys, lab, "check")
    assert "mount-system-writable" not in text and "device-root" not in text, text


# ------------------------------------------------------- two names, one device (J9)

def test_two_device_names_on_one_path_are_refused_with_both_names(capsys: pytest.CaptureFixture, lab: Path) -> None:
    _vars(lab, devices={"motor": "/dev/robot/motor", "lidar": "/dev//robot/motor"})
    edit(lab, lambda d: d["services"]["driver"].update(devices=["motor", "lidar"]))
    for command in ("validate", "render"):
        code, text = cli(capsys, lab, command)
        assert code == 2 and "`motor` and `lidar`, which are both '/dev/robot/motor'" in text, (command, text)
        assert "fleet.yml:" in text and "services.driver.devices[1]" in text, text
        assert not (lab / "out").exists()
    silent("device-duplicate")


# ----------------------------------------------------- fleet values the robot refuses (J12, J13)

def test_cmd_shell_with_two_words_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(healthcheck={"test": ["CMD-SHELL", "a", "b"]}))
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "services.driver.healthcheck.test[2]" in text and "CMD-SHELL takes one string" in text, text
    edit(lab, lambda d: d["services"]["driver"].update(healthcheck={"test": ["CMD", "a", "b"]}))
    assert cli(capsys, lab, "validate")[0] == 0


@pytest.mark.parametrize("user", ["4294967296", "2147483648", "1000:2147483648", "99999999999999999999999"])
def test_a_uid_or_gid_runc_refuses_is_refused(capsys: pytest.CaptureFixture, lab: Path, user: str) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(user=user))
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "services.driver.user" in text and "at most 2147483647" in text, text


@pytest.mark.parametrize("user", ["2147483647", "0:2147483647", "ros", "1000:1000"])
def test_a_uid_in_runc_range_is_fine(capsys: pytest.CaptureFixture, lab: Path, user: str) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(user=user))
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


# ------------------------------------------------------------ gpu: 1 (J14)

@pytest.mark.parametrize("var", ["gpu", "rosdeploy_gpu"])
@pytest.mark.parametrize("value, gpu", [(1, True), (0, False), (1.0, True)])
def test_gpu_reads_one_and_zero_as_ansible_does(capsys: pytest.CaptureFixture, lab: Path, var: str, value: object,
                                                gpu: bool) -> None:
    _vars(lab, **{var: value})
    code, text = cli(capsys, lab, "render")
    assert code == 0 and "another tool's" not in text, text
    compose = (lab / "out" / "r2" / "compose.yml").read_text()
    assert ("runtime: nvidia" in compose) is gpu, compose


def test_another_number_for_gpu_is_still_another_tools(capsys: pytest.CaptureFixture, lab: Path) -> None:
    _vars(lab, gpu=2)
    code, text = cli(capsys, lab, "validate")
    assert code == 0 and "another tool's variable" in text, text
    _vars(lab, rosdeploy_gpu=2)
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "must be true or false, got 2" in text, text


# ------------------------------------------------------------ secrets (K7, K9)

def test_secret_short_warns_below_the_length_masked_everywhere() -> None:
    from rosdeploy.output import LONG_SECRET
    fleet = spec(driver={"secret_env": {"TOKEN": "api_token"}})
    short = "x" * (LONG_SECRET - 1)
    p = fires("secret-short", fleet=fleet, hosts=[_host(api_token=short)])
    assert f"shorter than {LONG_SECRET} characters" in p.message and "whole word" in p.message
    silent("secret-short", fleet=fleet, hosts=[_host(api_token="x" * LONG_SECRET)])


@pytest.mark.parametrize("text, what", [("api_token: null\n", "null"), ("api_token: ''\n", "empty")])
def test_a_null_or_empty_secret_is_refused_at_the_vault_var(capsys: pytest.CaptureFixture, lab: Path, text: str,
                                                            what: str) -> None:
    vault_file(lab, "vault.yml", text)
    for command in ("validate", "check", "render"):
        code, out = cli(capsys, lab, command)
        assert code == 2 and "vault.yml:1: api_token:" in out and f"is {what}" in out, (command, out)
        assert "secret-short" not in out
        assert not (lab / "out").exists()


def _host(**vars_: str) -> object:
    from test_checks import host
    return host(vars=vars_, secret_values=frozenset(vars_.values()))


# ------------------------------------------------ compose: values Compose refuses (J11)

@pytest.mark.parametrize("extra, key, words", [
    ({"links": ["driver"]}, "links", "Docker refuses links on host networking"),
    ({"links": ["driver:alias"]}, "links", "Docker refuses links on host networking"),
    ({"mem_swappiness": 101}, "mem_swappiness", "0-100"),
    ({"ports": ["99999:80"]}, "ports[0]", "at most 65535"),
    ({"ports": ["127.0.0.1:8080:70000/udp"]}, "ports[0]", "at most 65535"),
    ({"ports": [{"target": 80, "published": 99999}]}, "ports[0]", "at most 65535"),
    ({"stop_grace_period": "forever"}, "stop_grace_period", "not a duration"),
    ({"cpu_rt_runtime": "1s"}, "cpu_rt_runtime", "microseconds"),
    ({"mac_address": "02:42:ac:11:00:02"}, "mac_address", "host networking"),
    ({"blkio_config": {"device_read_bps": [{"path": "/dev/sda", "rate": "1x"}]}},
     "blkio_config.device_read_bps[0].rate", "bytes per second"),
])
def test_compose_values_compose_refuses_are_refused(capsys: pytest.CaptureFixture, lab: Path, extra: dict, key: str,
                                                    words: str) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(compose=extra))
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and f"services.driver.compose.{key}" in text and words in text, text


def test_compose_values_compose_takes_pass(capsys: pytest.CaptureFixture, lab: Path) -> None:
    extra = {"mem_swappiness": 0, "ports": ["127.0.0.1:8080:80/udp", "8000-8010:80-90", 9090],
             "stop_grace_period": "1m30s", "cpu_rt_runtime": 950000, "cpu_rt_period": "1000000",
             "blkio_config": {"device_read_bps": [{"path": "/dev/sda", "rate": "10mb"}],
                              "device_write_iops": [{"path": "/dev/sda", "rate": 100}]}}
    edit(lab, lambda d: d["services"]["driver"].update(compose=extra))
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


def test_a_mac_address_off_host_networking_is_checked(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, lambda d: (d.update(ros={"network_mode": "bridge"}),
                         d["services"]["driver"].update(compose={"mac_address": "zz"})))
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "'zz' is not a MAC address" in text, text
    edit(lab, lambda d: d["services"]["driver"].update(compose={"mac_address": "02:42:ac:11:00:02"}))
    assert cli(capsys, lab, "validate")[0] == 0
