"""The Ansible-style inventory of the simulated fleet (pure; the writer is one call)."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import yaml

from rosdeploy.sim.model import MOTOR_DEVICE, ROBOT_USER, SimRobot


def inventory_data(robots: Sequence[SimRobot], key_file: Path, known_hosts: Path) -> dict[str, Any]:
    hosts = {robot.name: {"ansible_host": robot.host,
                          "ansible_port": robot.ssh_port,
                          "ros_domain_id": robot.ros_domain_id,
                          "devices": {"motor": MOTOR_DEVICE}}
             for robot in robots}
    # The motor is declared as a real inventory would: a stable /dev/robot name from its
    # USB identity (an FTDI serial adapter). The robots have no udev, the sim makes the
    # link itself; the identity still renders the udev rule and tells rosdeploy it is
    # a tty (the container user needs `dialout`).
    motor = {"symlink": MOTOR_DEVICE.removeprefix("/dev/"), "subsystem": "tty",
             "vendor": "0403", "product": "6001", "group": "dialout"}
    return {"all": {"vars": {"ansible_user": ROBOT_USER,
                             "ansible_ssh_private_key_file": str(key_file.absolute()),
                             "rosdeploy_known_hosts": str(known_hosts.absolute()),
                             "udev": [motor]},
                    "children": {"sim": {"hosts": hosts}}}}


def inventory_text(robots: Sequence[SimRobot], key_file: Path, known_hosts: Path) -> str:
    header = "# Written by `rosdeploy sim up`; rewritten on every run.\n"
    return header + yaml.safe_dump(inventory_data(robots, key_file, known_hosts), sort_keys=False)
