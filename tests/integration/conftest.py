"""Fixtures of the integration suite: a real simulated fleet (rosdeploy.sim).

Every test under tests/integration is marked `integration`. Nothing here skips:
without a Docker engine, registry or sshd robots the fixtures fail loudly, since
CI installs all of them (scripts/host-setup).

    sim_fleet   session: the fleet, brought up once ($ROSDEPLOY_SIM_HOME, default
                ~/.rosdeploy/sim); torn down at the end only if this session started it
    fleet       function: the same fleet in a clean state (see rosdeploy.sim.reset)
    ssh         function: ssh(robot_name, user="robot") -> paramiko.SSHClient, host key
                verified against the fleet's known_hosts (RejectPolicy), closed after the test
    (autouse)   session: a connection keeper of the suite's own, stopped at the end
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterator

import paramiko
import pytest

from rosdeploy import keeper, sim
from rosdeploy.sim import SimFleet

INTEGRATION_DIR = Path(__file__).parent


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if INTEGRATION_DIR in Path(str(item.fspath)).parents:
            item.add_marker(pytest.mark.integration)


@pytest.fixture(scope="session", autouse=True)
def own_keeper(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """status/plan/history hold connections in a keeper: the suite's is its own and ends with it."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("ROSDEPLOY_CONTROL_DIR", str(tmp_path_factory.mktemp("control")))
        yield
        keeper.ask({"op": "exit"})


@pytest.fixture(scope="session")
def sim_fleet() -> Iterator[SimFleet]:
    home = sim.default_home()
    was_running = sim.status(home).running
    fleet = sim.up(robots=3, home=home)
    yield fleet
    if not was_running:
        sim.down(home)


@pytest.fixture
def fleet(sim_fleet: SimFleet) -> SimFleet:
    """No compose containers or rosdeploy dirs on any robot, /dev/ttyUSB0 and
    /dev/robot/motor present, original host keys, registry up (and `sudo -n` for `robot`,
    which `sim.up` provisions: the inventory's udev rules need root)."""
    return sim.reset(sim_fleet.home)


def connect(fleet: SimFleet, robot_name: str, user: str = "robot") -> paramiko.SSHClient:
    robot = fleet.robot(robot_name)
    client = paramiko.SSHClient()
    client.load_host_keys(str(fleet.known_hosts))
    client.set_missing_host_key_policy(paramiko.RejectPolicy())
    client.connect(robot.host, port=robot.ssh_port, username=user, key_filename=str(fleet.key_file),
                   allow_agent=False, look_for_keys=False, timeout=10)
    return client


@pytest.fixture
def ssh(fleet: SimFleet) -> Iterator[Callable[..., paramiko.SSHClient]]:
    clients: list[paramiko.SSHClient] = []

    def open_client(robot_name: str, user: str = "robot") -> paramiko.SSHClient:
        clients.append(connect(fleet, robot_name, user))
        return clients[-1]

    yield open_client
    for client in clients:
        client.close()


@pytest.fixture
def fleet_file(fleet: SimFleet, tmp_path: Path) -> Path:
    """playbooks/demo.yml on a clean fleet, through a copy of the sim's inventory."""
    from robots import write_fleet, write_inventory
    return write_fleet(tmp_path, write_inventory(fleet, tmp_path))
