"""Fixer R, round eleven: fixes that were too narrow, reached through a neighbouring key (probe R):
ssh config host names, `ipc`, long-syntax ports, a tmpfs at `/`, long bind-mount paths, a deploy
root in the kernel's folders, and the minor items (storage_opt size, case variants in `vars:`, a bad
service name, ...)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from rosdeploy import fleet
from test_hostile import cli, edit, lab  # noqa: F401  (lab is a fixture)

ALL = ("validate", "check", "render")
KNOWN_HOST = "robot1 ssh-ed25519 AAAAC3NzaC1lZDI1NTE5AAAAIOMqqnkVzrm0SdG6UOoqKLsabgH5C9okWi0dh2l9GKJl\n"


def _service(lab: Path, **keys: Any) -> None:  # noqa: F811
    def change(d: dict) -> None:
        d["services"]["driver"].update(keys)
        d.setdefault("ros", {})["network_mode"] = "bridge"    # ports are published on bridge networking only
    edit(lab, change)


def _refused(capsys: pytest.CaptureFixture, lab: Path, where: str, words: str,  # noqa: F811
             commands: tuple[str, ...] = ("validate",)) -> None:
    for command in commands:
        code, text = cli(capsys, lab, command)
        assert code == 2 and where in text and words in text, (command, text)


def _accepted(capsys: pytest.CaptureFixture, lab: Path) -> None:  # noqa: F811
    """The fleet file loads (its checks are all in fleet.py): quicker than a whole validate."""
    fleet.load_fleet(lab / "fleet.yml")


# defect 1: ssh config HostName / ProxyJump ------------------------------------------------------

def _ssh_config(lab: Path, text: str) -> None:  # noqa: F811
    (lab / "ssh_config").write_text(text)
    (lab / "known_hosts").write_text(KNOWN_HOST)
    edit(lab, lambda d: d.update(ssh={"config": "ssh_config", "known_hosts": "known_hosts"}))


@pytest.mark.parametrize("line, words", [
    ("HostName a..b", "HostName: 'a..b' is not a valid host name"),
    ("HostName " + "x" * 64 + ".example", "is not a valid host name"),
    ("HostName robot\x85one", "HostName: 'robot\\x85one' holds '\\x85'"),
    ("HostName robot\x01one", "holds '\\x01'"),
    ("ProxyJump a..b", "ProxyJump: jump host 'a..b' is not a valid host name"),
    ("ProxyJump ok.example,me@a..b:22", "jump host 'a..b' is not a valid host name"),
])
def test_a_literal_host_name_no_resolver_takes_is_refused_at_its_line(
        capsys: pytest.CaptureFixture, lab: Path, line: str, words: str) -> None:  # noqa: F811
    _ssh_config(lab, f"Host robot1\n  Port 22\n  {line}\n")
    _refused(capsys, lab, "ssh_config:3", words, ALL if line.startswith("HostName a..") else ("validate",))


@pytest.mark.parametrize("line", ["HostName %h..x", "HostName ok.example", "HostName fe80::1%eth0",
                                  "HostName bücher.example", "ProxyJump [::1]:2222", "ProxyJump none"])
def test_a_host_name_known_only_at_connect_time_or_valid_passes(
        capsys: pytest.CaptureFixture, lab: Path, line: str) -> None:  # noqa: F811
    _ssh_config(lab, f"Host *\n  {line}\n")
    _accepted(capsys, lab)


# defect 3A: ipc -------------------------------------------------------------------------------

@pytest.mark.parametrize("value", ["bogus", "HOST", "Private", "container:"])
def test_an_ipc_mode_docker_refuses_is_refused(capsys: pytest.CaptureFixture, lab: Path,  # noqa: F811
                                               value: str) -> None:
    _service(lab, compose={"ipc": value})
    _refused(capsys, lab, "services.driver.compose.ipc", "is none of none, private, shareable, host",
             ALL if value == "bogus" else ("validate",))


@pytest.mark.parametrize("value", ["none", "private", "shareable", "host", "service:bridge"])
def test_docker_s_ipc_modes_pass(capsys: pytest.CaptureFixture, lab: Path, value: str) -> None:  # noqa: F811
    _service(lab, compose={"ipc": value})
    _accepted(capsys, lab)


# defect 4: long-syntax ports --------------------------------------------------------------------

@pytest.mark.parametrize("port, words", [
    ({"target": 80, "protocol": "xyz"}, "'xyz' is not a protocol: tcp, udp or sctp (Compose refuses it)"),
    ({"target": 0}, "the container port must be from 1 to 65535, not 0"),
    ({"target": -5, "published": 80}, "the container port must be from 1 to 65535, not -5"),
    ({"target": 80, "published": -1}, "the host port must be from 0 to 65535, not -1"),
    ({"target": 70000}, "a port number is at most 65535"),
])
def test_a_long_syntax_port_gets_the_short_syntax_checks(capsys: pytest.CaptureFixture, lab: Path,  # noqa: F811
                                                         port: dict, words: str) -> None:
    _service(lab, compose={"ports": [port]})
    _refused(capsys, lab, "services.driver.compose.ports[0]", words, ALL if port.get("protocol") else ("validate",))


@pytest.mark.parametrize("port", [{"target": 80}, {"target": 80, "published": 8080, "protocol": "UDP"},
                                  {"target": 80, "published": 0, "protocol": "sctp", "mode": "host"}])
def test_a_valid_long_syntax_port_passes(capsys: pytest.CaptureFixture, lab: Path, port: dict) -> None:  # noqa: F811
    _service(lab, compose={"ports": [port]})
    _accepted(capsys, lab)


def test_a_long_syntax_published_range_is_checked_like_the_short_one() -> None:
    assert fleet.long_port_problem({"target": 80, "published": "8000-8010"}) is None
    assert "runs backwards" in str(fleet.long_port_problem({"target": 80, "published": "9000-8000"}))
    assert "is not a host port" in str(fleet.long_port_problem({"target": 80, "published": "x"}))


# defect 5: tmpfs at / ---------------------------------------------------------------------------

@pytest.mark.parametrize("tmpfs, where", [(["/"], "compose.tmpfs[0]"), (["/tmp", "/./"], "compose.tmpfs[1]"),
                                          ("/:size=1m", "compose.tmpfs:")])
def test_a_tmpfs_at_the_container_root_is_refused(capsys: pytest.CaptureFixture, lab: Path,  # noqa: F811
                                                  tmpfs: Any, where: str) -> None:
    _service(lab, compose={"tmpfs": tmpfs})
    _refused(capsys, lab, f"services.driver.{where}", "is the container's root: Docker refuses a tmpfs there",
             ALL if tmpfs == ["/"] else ("validate",))


# defect 6: bind-mount path lengths ----------------------------------------------------------------

@pytest.mark.parametrize("mount, words", [
    ("/data/" + "a" * 300 + ":/x", "the robot path is a path of 306 characters: Linux allows 4096, and 255"),
    ("/data:/" + "a/" * 2100 + "b", "the container path is a path of 4202 characters"),
    ("/" + "d/" * 2100 + "e:/x:ro", "the robot path is a path of 4202 characters"),
])
def test_a_bind_mount_path_linux_cannot_take_is_refused(capsys: pytest.CaptureFixture, lab: Path,  # noqa: F811
                                                        mount: str, words: str) -> None:
    _service(lab, volumes=[mount])
    _refused(capsys, lab, "services.driver.volumes[0]", words, ALL if mount.endswith(":/x") else ("validate",))


def test_a_bind_mount_at_the_limits_passes(capsys: pytest.CaptureFixture, lab: Path) -> None:  # noqa: F811
    _service(lab, volumes=["/data/" + "a" * 255 + ":/x/" + "b" * 255])
    _accepted(capsys, lab)


# defect 8: deploy root in the kernel's folders --------------------------------------------------

@pytest.mark.parametrize("root, kernel", [("/proc/x", "/proc"), ("/sys", "/sys"), ("/dev", "/dev"),
                                          ("/dev/shm/rosdeploy", "/dev"), ("/sys/class/x", "/sys")])
def test_a_deploy_root_in_the_kernel_s_folders_is_refused(capsys: pytest.CaptureFixture, lab: Path,  # noqa: F811
                                                          root: str, kernel: str) -> None:
    edit(lab, lambda d: d.update(deploy_root=root))
    for command in ALL if root == "/dev" else ("validate",):
        code, text = cli(capsys, lab, command)
        assert code == 2 and f"deploy_root: '{root}' is in {kernel}, the kernel's own file system" in text, text
        assert "/dev/shm writable" not in text, text    # not blamed on rosdeploy's own /dev/shm mount


@pytest.mark.parametrize("root", ["/devices/x", "/opt/sys", "~/proc", "/system"])
def test_a_deploy_root_that_only_looks_like_a_kernel_folder_passes(root: str) -> None:
    assert fleet.deploy_root_problem(root) is None


# defect 9: minors -------------------------------------------------------------------------------

@pytest.mark.parametrize("size", ["1x", "ten", " 1g", "1.5q"])
def test_a_storage_opt_size_docker_cannot_read_is_refused(capsys: pytest.CaptureFixture, lab: Path,  # noqa: F811
                                                          size: str) -> None:
    _service(lab, compose={"storage_opt": {"size": size}})
    _refused(capsys, lab, "services.driver.compose.storage_opt.size", "is not a size in bytes",
             ALL if size == "1x" else ("validate",))


@pytest.mark.parametrize("size", ["10g", "512m", 1073741824, "1024"])
def test_a_storage_opt_size_passes(capsys: pytest.CaptureFixture, lab: Path, size: Any) -> None:  # noqa: F811
    _service(lab, compose={"storage_opt": {"size": size}})
    _accepted(capsys, lab)


@pytest.mark.parametrize("name, meant", [("ROSDEPLOY_GPU", "rosdeploy_gpu"),
                                         ("Rosdeploy_deploy_root", "rosdeploy_deploy_root"),
                                         ("ansible_Host", "ansible_host"), ("ANSIBLE_USER", "ansible_user"),
                                         ("ROSDEPLOY_HOME", "rosdeploy_home")])
def test_a_case_variant_in_fleet_vars_gets_a_did_you_mean(capsys: pytest.CaptureFixture, lab: Path,  # noqa: F811
                                                         name: str, meant: str) -> None:
    edit(lab, lambda d: d.update(vars={name: "/home/x"}))
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and f"vars.{name}:" in text and "names are case-sensitive" in text, text
    assert f"did you mean `{meant}`?" in text and "Ansible's per-robot variable, which" not in text.split(meant)[0]


def test_a_mixed_case_ansible_name_is_not_called_ansible_s_variable(capsys: pytest.CaptureFixture,
                                                                     lab: Path) -> None:  # noqa: F811
    edit(lab, lambda d: d.update(vars={"ansible_Foo": 1}))
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "ansible_Foo is in Ansible's `ansible_` namespace" in text, text
    assert "Ansible's per-robot variable" not in text, text


@pytest.mark.parametrize("name", ["MY_GPU", "GPU", "ROSDEPLOY_WHATEVER", "rosdeploy_home"])
def test_a_user_s_own_template_variable_passes(capsys: pytest.CaptureFixture, lab: Path,  # noqa: F811
                                               name: str) -> None:
    edit(lab, lambda d: d.update(vars={name: "/home/x"}))
    _accepted(capsys, lab)


@pytest.mark.parametrize("name", ["=", "~", "12:30"])
def test_an_invalid_service_name_is_not_reported_as_no_service(capsys: pytest.CaptureFixture, lab: Path,  # noqa: F811
                                                               name: str) -> None:
    def change(d: dict) -> None:
        d["services"] = {name: d["services"]["driver"]}
    edit(lab, change)
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "is not a valid service name" in text, text
    assert "declares no service" not in text, text


def test_an_empty_services_mapping_still_declares_no_service(capsys: pytest.CaptureFixture,
                                                             lab: Path) -> None:  # noqa: F811
    edit(lab, lambda d: d.update(services={}))
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "declares no service" in text, text
