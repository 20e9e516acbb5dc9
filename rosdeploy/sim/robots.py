"""Robot containers: Docker-in-Docker with sshd, without --privileged.

`--privileged` fails on this machine kind (CAP_SYS_RESOURCE is not in the bounding
set), so robots get every other capability, no seccomp/apparmor confinement, all
devices, and the host's cgroup tree; their own dockerd then runs overlay2 on a
volume of their own.
"""
from __future__ import annotations

import socket
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from rosdeploy.errors import SimError
from rosdeploy.sim.keys import new_keypair, public_of
from rosdeploy.sim.model import LABEL, LABEL_HOME, LABEL_ROBOT, REGISTRY_ROBOT, SimPaths, SimRobot, container_of
from rosdeploy.sim.proc import docker, run, tail

ROBOT_CTL = "/usr/local/sbin/robot-ctl"
HOST_KEY_IN_ROBOT = "/etc/ssh/ssh_host_ed25519_key"

_CONFINEMENT = (
    "--cap-add", "ALL", "--cap-drop", "SYS_RESOURCE",
    "--security-opt", "seccomp=unconfined", "--security-opt", "apparmor=unconfined",
    "--security-opt", "systempaths=unconfined", "--device-cgroup-rule", "a *:* rwm",
    "-v", "/sys/fs/cgroup:/sys/fs/cgroup:rw", "--tmpfs", "/run", "--tmpfs", "/tmp",
)


@dataclass(frozen=True)
class Container:
    name: str
    state: str          # docker's: running, exited, created, ...
    image: str
    home: str           # the state dir that created it


def sim_containers() -> dict[str, Container]:
    """Every robot container any simulator state dir created, by name."""
    fmt = "{{.Names}}\t{{.State}}\t{{.Image}}\t{{.Label \"" + LABEL_HOME + "\"}}"
    listing = docker("ps", "-a", "--filter", f"label={LABEL_ROBOT}", "--format", fmt, what="docker ps")
    containers = [Container(*line.split("\t")) for line in listing.stdout.splitlines() if line.count("\t") == 3]
    return {c.name: c for c in containers}


def volume_of(robot: SimRobot) -> str:
    return f"{robot.container}-docker"     # remove_containers(volumes=True) relies on this name


def create_robot(paths: SimPaths, robot: SimRobot, image: str, authorized_key: str) -> None:
    """Create and start a robot with a freshly generated host key."""
    labels = ("--label", f"{LABEL}=1", "--label", f"{LABEL_HOME}={paths.home}")
    docker("volume", "create", *labels, volume_of(robot), what=f"creating {robot.name}'s volume")
    docker("create", "--name", robot.container, "--hostname", robot.name, *labels,
           "--label", f"{LABEL_ROBOT}={robot.name}", *_CONFINEMENT,
           "-v", f"{volume_of(robot)}:/var/lib/docker",
           "-p", f"{robot.host}:{robot.ssh_port}:22",
           "--add-host", f"{REGISTRY_ROBOT.split(':')[0]}:host-gateway",
           "-e", f"ROBOT_AUTHORIZED_KEY={authorized_key}",
           "--restart", "unless-stopped", image, what=f"creating {robot.name}")
    key = new_keypair(paths.host_key(robot.name), comment=robot.name)
    copy_host_key(robot, key)
    start_container(robot)


def copy_host_key(robot: SimRobot, key: Path) -> None:
    for source, target in ((key, HOST_KEY_IN_ROBOT), (public_of(key), HOST_KEY_IN_ROBOT + ".pub")):
        docker("cp", str(source), f"{robot.container}:{target}", what=f"copying {robot.name}'s host key")


def start_container(robot: SimRobot) -> None:
    result = docker("start", robot.container, what=f"starting {robot.name}", check=False)
    if result.returncode != 0:
        hint = (f" (is 127.0.0.1:{robot.ssh_port} taken by another program?)"
                if "address already in use" in result.stderr or "port is already" in result.stderr else "")
        raise SimError(f"starting {robot.name} failed{hint}: {tail(result.stderr)}")


def remove_containers(names: Sequence[str], *, volumes: bool = False) -> None:
    """Remove robot containers; with volumes, their engine's storage (pulled images) too."""
    if names:
        docker("rm", "-f", *names, what="removing robot containers")
    if names and volumes:
        docker("volume", "rm", "-f", *(f"{name}-docker" for name in names), what="removing robot volumes")


def remove_volumes(home: Path) -> None:
    listing = docker("volume", "ls", "-q", "--filter", f"label={LABEL_HOME}={home}", what="docker volume ls")
    names = listing.stdout.split()
    if names:
        docker("volume", "rm", "-f", *names, what="removing robot volumes")


def wait_ready(robots: Sequence[SimRobot], timeout: float = 90.0) -> None:
    """Until every robot's sshd greets and its own Docker engine answers."""
    deadline = time.monotonic() + timeout
    for robot in robots:
        while not (ssh_greets(robot) and engine_answers(robot)):
            if time.monotonic() > deadline:
                log = robot_exec(robot.name, ["tail", "-n", "5", "/var/log/dockerd.log"], check=False)
                raise SimError(f"{robot.name} did not come up within {timeout:.0f} s "
                               f"(sshd on 127.0.0.1:{robot.ssh_port}, dockerd inside): {log.stdout.strip()}")
            time.sleep(0.5)


def ssh_greets(robot: SimRobot) -> bool:
    try:
        with socket.create_connection((robot.host, robot.ssh_port), timeout=2) as conn:
            conn.settimeout(2)
            return conn.recv(8).startswith(b"SSH-")
    except OSError:
        return False


def engine_answers(robot: SimRobot) -> bool:
    return robot_exec(robot.name, ["docker", "info", "--format", "{{.ServerVersion}}"], check=False).returncode == 0


def robot_exec(robot_name: str, argv: Sequence[str], user: str = "root", *, check: bool = False,
               input: str | None = None, timeout: float | None = 120) -> subprocess.CompletedProcess[str]:
    """Run argv inside a robot with `docker exec` (a fault-injection and inspection aid)."""
    stdin_flag = ("-i",) if input is not None else ()
    return run(("docker", "exec", *stdin_flag, "-u", user, container_of(robot_name), *argv),
               what=f"{robot_name}: {' '.join(argv[:2])}", check=check, input=input, timeout=timeout)


def robot_ctl(robot_name: str, action: str) -> None:
    robot_exec(robot_name, [ROBOT_CTL, action], check=True)


def current_host_key(robot_name: str) -> str:
    result = robot_exec(robot_name, ["cat", HOST_KEY_IN_ROBOT + ".pub"], check=True)
    return " ".join(result.stdout.split()[:2])
