"""The simulated fleet's inventory, known_hosts and naming rules (pure logic)."""
from __future__ import annotations

from pathlib import Path

import paramiko
import pytest
import yaml

from rosdeploy.errors import SimError
from rosdeploy.sim.inventory import inventory_data, inventory_text
from rosdeploy.sim.keys import known_hosts_text
from rosdeploy.sim.model import SimPaths, container_of, resolve_home, robot_for, robot_index

ED25519 = "ssh-ed25519 AAAAC3NzaC1lZDI1NTE5AAAAIELOlA1bm/j/Fk8Oo3Ir5tfSxIw2Ye7iFMWrMMKPDgm9"


def test_robots_are_named_ported_and_domained_by_index() -> None:
    robot = robot_for(3)
    assert (robot.name, robot.ssh_port, robot.container, robot.ros_domain_id, robot.host) == \
           ("robot3", 2203, "rosdeploy-sim-robot3", 13, "127.0.0.1")
    assert robot_index("robot12") == 12
    assert container_of("robot1") == "rosdeploy-sim-robot1"


@pytest.mark.parametrize("name", ["robot0", "robot", "robot1; rm -rf /", "Robot1", "robot01"])
def test_other_names_are_not_robots(name: str) -> None:
    with pytest.raises(SimError):
        robot_index(name)


def test_inventory_is_the_ansible_layout_the_issue_asks_for(tmp_path: Path) -> None:
    paths = SimPaths(tmp_path)
    robots = [robot_for(i) for i in (1, 2)]
    data = yaml.safe_load(inventory_text(robots, paths.key_file, paths.known_hosts))
    assert data == inventory_data(robots, paths.key_file, paths.known_hosts)
    assert data["all"]["vars"] == {"ansible_user": "robot",
                                   "ansible_ssh_private_key_file": str(tmp_path / "id_ed25519"),
                                   "rosdeploy_known_hosts": str(tmp_path / "known_hosts"),
                                   "udev": [{"symlink": "robot/motor", "subsystem": "tty", "vendor": "0403",
                                             "product": "6001", "group": "dialout"}]}
    assert data["all"]["children"]["sim"]["hosts"] == {
        "robot1": {"ansible_host": "127.0.0.1", "ansible_port": 2201, "ros_domain_id": 11,
                   "devices": {"motor": "/dev/robot/motor"}},
        "robot2": {"ansible_host": "127.0.0.1", "ansible_port": 2202, "ros_domain_id": 12,
                   "devices": {"motor": "/dev/robot/motor"}},
    }


def test_known_hosts_lines_are_read_by_paramiko_for_non_default_ports(tmp_path: Path) -> None:
    path = tmp_path / "known_hosts"
    path.write_text(known_hosts_text([(robot_for(1), ED25519)]))
    assert path.read_text() == f"[127.0.0.1]:2201 {ED25519}\n"
    keys = paramiko.HostKeys(str(path))
    assert keys.lookup("[127.0.0.1]:2201")["ssh-ed25519"].get_base64() == ED25519.split()[1]
    assert keys.lookup("127.0.0.1") is None


def test_home_comes_from_the_environment_or_the_default(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("ROSDEPLOY_SIM_HOME", str(tmp_path / "h"))
    assert resolve_home(None) == tmp_path / "h"
    monkeypatch.delenv("ROSDEPLOY_SIM_HOME")
    assert resolve_home(None) == Path.home() / ".rosdeploy" / "sim"
    assert resolve_home(tmp_path) == tmp_path
