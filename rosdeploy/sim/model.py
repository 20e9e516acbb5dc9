"""The simulated fleet's plain values and the naming rules every other module shares.

Names, ports and domain IDs are derived from the robot's index, so nothing needs
a lookup table: robot3 is container rosdeploy-sim-robot3, ssh on 127.0.0.1:2203,
ROS_DOMAIN_ID 13.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

from rosdeploy.errors import SimError

CONTAINER_PREFIX = "rosdeploy-sim-"
LABEL = "rosdeploy.sim"                  # on every container, volume and image the sim creates
LABEL_HOME = "rosdeploy.sim.home"        # which state dir a container/volume belongs to
LABEL_ROBOT = "rosdeploy.sim.robot"      # robot containers only (demo images carry LABEL too)
LABEL_INPUTS = "rosdeploy.sim.inputs"    # content hash of an image's build inputs
SSH_PORT_BASE = 2200
DOMAIN_ID_BASE = 10
REGISTRY_HOST = "127.0.0.1:5000"         # as the host (builder, pusher) reaches it
REGISTRY_ROBOT = "registry.local:5000"   # as robots reach it (--add-host ... host-gateway)
ROBOT_USER = "robot"
MOTOR_DEVICE = "/dev/robot/motor"

_ROBOT_NAME = re.compile(r"robot([1-9][0-9]*)")


@dataclass(frozen=True)
class SimRobot:
    name: str                 # "robot1"
    ssh_port: int             # published on 127.0.0.1
    container: str            # host-side container name
    ros_domain_id: int = 0
    host: str = "127.0.0.1"


@dataclass(frozen=True)
class SimFleet:
    home: Path
    robots: tuple[SimRobot, ...]
    inventory: Path
    known_hosts: Path
    key_file: Path
    registry_host: str = REGISTRY_HOST
    registry_robot: str = REGISTRY_ROBOT

    def robot(self, name: str) -> SimRobot:
        for robot in self.robots:
            if robot.name == name:
                return robot
        raise SimError(f"no robot {name!r} in the simulated fleet (have: "
                       f"{', '.join(r.name for r in self.robots)})")


@dataclass(frozen=True)
class RobotStatus:
    robot: SimRobot
    state: str                # docker's container state, or "missing"


@dataclass(frozen=True)
class SimStatus:
    home: Path
    robots: tuple[RobotStatus, ...]
    registry: str             # address
    registry_up: bool
    registry_pid: int | None  # set when the sim started the registry itself

    @property
    def running(self) -> bool:
        return bool(self.robots) and self.registry_up and all(r.state == "running" for r in self.robots)


def robot_for(index: int) -> SimRobot:
    name = f"robot{index}"
    return SimRobot(name=name, ssh_port=SSH_PORT_BASE + index, container=CONTAINER_PREFIX + name,
                    ros_domain_id=DOMAIN_ID_BASE + index)


def robot_index(name: str) -> int:
    match = _ROBOT_NAME.fullmatch(name)
    if not match:
        raise SimError(f"{name!r} is not a simulated robot name (robot1, robot2, ...)")
    return int(match.group(1))


def container_of(robot_name: str) -> str:
    return robot_for(robot_index(robot_name)).container


def default_home() -> Path:
    configured = os.environ.get("ROSDEPLOY_SIM_HOME")
    return Path(configured).expanduser() if configured else Path.home() / ".rosdeploy" / "sim"


def resolve_home(home: Path | str | None) -> Path:
    return (Path(home).expanduser() if home is not None else default_home()).absolute()


@dataclass(frozen=True)
class SimPaths:
    """Every file the simulator keeps in its state dir."""

    home: Path

    @property
    def key_file(self) -> Path:
        return self.home / "id_ed25519"

    @property
    def known_hosts(self) -> Path:
        return self.home / "known_hosts"

    @property
    def inventory(self) -> Path:
        return self.home / "inventory.yml"

    @property
    def state(self) -> Path:
        return self.home / "state.json"

    @property
    def host_keys(self) -> Path:
        return self.home / "host-keys"

    @property
    def registry_data(self) -> Path:
        return self.home / "registry"

    @property
    def logs(self) -> Path:
        return self.home / "logs"

    def host_key(self, robot_name: str) -> Path:
        return self.host_keys / robot_name / "ssh_host_ed25519_key"
