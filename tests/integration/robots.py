"""Test helpers: write fleet files for the simulated fleet, run the CLI, and read a
robot's REAL state over SSH (strict host keys), independently of rosdeploy's code."""
from __future__ import annotations

import io
import json
import os
import time
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import paramiko
import yaml

from rosdeploy.cli import main

REPO = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class CliRun:
    code: int
    stdout: str
    stderr: str

    @property
    def doc(self) -> dict:
        return json.loads(self.stdout)

    def host(self, name: str) -> dict:
        return next(h for h in self.doc["hosts"] if h["host"] == name)


def rosdeploy(*args: str) -> CliRun:
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = main([str(a) for a in args])
    return CliRun(code, out.getvalue(), err.getvalue())


def apply(fleet_file: Path, *args: str) -> CliRun:
    """`rosdeploy --json apply FLEET --yes ...`"""
    return rosdeploy("--json", "apply", fleet_file, "--yes", *args)


def write_inventory(sim, tmp_path: Path, **overrides: Any) -> Path:
    """The sim's inventory, with vars overridden for every robot (e.g. ansible_user=root)."""
    data = yaml.safe_load(Path(sim.inventory).read_text())
    data["all"].setdefault("vars", {}).update(overrides)
    path = tmp_path / f"inventory-{len(list(tmp_path.glob('inventory-*')))}.yml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def write_fleet(tmp_path: Path, inventory: Path, **changes: Any) -> Path:
    """playbooks/demo.yml pointed at `inventory`, with quicker health settings for tests."""
    data = yaml.safe_load((REPO / "playbooks" / "demo.yml").read_text())
    data["inventory"] = str(inventory)
    data.setdefault("health", {}).update({"timeout": "90s", "stable": "2s"})
    for key, value in changes.items():
        if isinstance(value, dict) and isinstance(data.get(key), dict):
            data[key].update(value)
        else:
            data[key] = value
    path = tmp_path / "fleet.yml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


class RobotShell:
    """An SSH session to a simulated robot as root, host key verified, for assertions."""

    def __init__(self, sim, name: str) -> None:
        robot = next(r for r in sim.robots if r.name == name)
        self.client = paramiko.SSHClient()
        self.client.set_missing_host_key_policy(paramiko.RejectPolicy())
        self.client.load_host_keys(str(sim.known_hosts))
        self.client.connect(robot.host, port=robot.ssh_port, username="root", key_filename=str(sim.key_file),
                            allow_agent=False, look_for_keys=False, timeout=10)

    def run(self, command: str) -> str:
        _, stdout, stderr = self.client.exec_command(command, timeout=60)
        out = stdout.read().decode()
        if stdout.channel.recv_exit_status() != 0:
            raise AssertionError(f"{command!r} failed: {stderr.read().decode()}")
        return out

    def containers(self, project: str = "demo") -> dict[str, dict]:
        """service -> {id, image, status, health, restarts, started} from the robot's own engine."""
        ids = self.run(f"docker ps -aq --filter label=com.docker.compose.project={project}").split()
        if not ids:
            return {}
        fmt = ('{"service":{{json (index .Config.Labels "com.docker.compose.service")}},"id":{{json .Id}},'
               '"image":{{json .Config.Image}},"status":{{json .State.Status}},'
               '"health":{{if .State.Health}}{{json .State.Health.Status}}{{else}}null{{end}},'
               '"restarts":{{.RestartCount}},"started":{{json .State.StartedAt}},'
               '"compose":{{json (index .Config.Labels "com.docker.compose.version")}}}')
        rows = [json.loads(line) for line in self.run(f"docker inspect --format '{fmt}' {' '.join(ids)}").splitlines()]
        return {r["service"]: r for r in rows}

    def current(self, home: str = "/home/robot", project: str = "demo") -> str:
        return self.run(f"readlink {home}/rosdeploy/{project}/current || true").strip().rsplit("/", 1)[-1]

    def history(self, home: str = "/home/robot", project: str = "demo") -> list[dict]:
        text = self.run(f"cat {home}/rosdeploy/{project}/history.jsonl 2>/dev/null || true")
        return [json.loads(line) for line in text.splitlines() if line.strip()]

    def close(self) -> None:
        self.client.close()


def shells(sim) -> dict[str, RobotShell]:
    return {r.name: RobotShell(sim, r.name) for r in sim.robots}


def versions(shell: RobotShell) -> dict[str, str]:
    return {s: c["image"].rsplit(":", 1)[-1] for s, c in shell.containers().items()}


def identity(shell: RobotShell) -> dict[str, tuple]:
    """What must not change when nothing may change: which containers run, since when, from what."""
    return {s: (c["id"], c["started"], c["restarts"], c["image"]) for s, c in shell.containers().items()}


def all_healthy(shell: RobotShell, settle: float = 20.0) -> bool:
    """Docker's own verdict. rosdeploy may run a `starting` container's check itself and go
    on before Docker's first tick (one `interval`, 5 s in the demo images), so give Docker
    that long to agree; `starting` never counts as healthy."""
    deadline = time.monotonic() + settle
    cs = shell.containers()
    while any(c["health"] == "starting" for c in cs.values()) and time.monotonic() < deadline:
        time.sleep(0.5)
        cs = shell.containers()
    return bool(cs) and all(c["status"] == "running" and c["health"] in (None, "healthy") for c in cs.values())


def env_without_vault() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if not k.startswith("ROSDEPLOY_VAULT")}


# Inside a container on the robot's ROS graph: the arrival times of /joint_states over
# $1 seconds from the first one, as a JSON list (a restart shows as a gap of seconds; the driver publishes at 10 Hz).
JOINT_STATES_STAMPS = r'''
import json, sys, time
import rclpy
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState
rclpy.init()
node = rclpy.create_node("rosdeploy_joint_states_stamps")
stamps = []
node.create_subscription(JointState, "/joint_states", lambda m: stamps.append(time.monotonic()),
                         qos_profile_sensor_data)
# The window opens at the first message: discovery on a loaded robot takes seconds of its own.
first = time.monotonic() + 20
while not stamps and time.monotonic() < first:
    rclpy.spin_once(node, timeout_sec=0.05)
end = time.monotonic() + float(sys.argv[1])
while time.monotonic() < end:
    rclpy.spin_once(node, timeout_sec=0.05)
print(json.dumps(stamps))
'''


def longest_gap(stamps: list[float]) -> float:
    return max((b - a for a, b in zip(stamps, stamps[1:], strict=False)), default=-1.0)
