"""`sim up/down/status`, loading a running fleet, and the fault-injection helpers tests use.

What `up` creates is recorded (state.json, container and volume labels with the
state dir), so `down` removes exactly that: robot containers, their volumes and
the registry process it started. Images and the registry's data stay as a cache,
so the next `up` takes seconds; `down(purge=True)` removes those too.
"""
from __future__ import annotations

import json
import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Sequence

import paramiko

from rosdeploy.errors import InputError, Problem, SimError
from rosdeploy.sim import registry
from rosdeploy.sim.faults import faults, heal
from rosdeploy.sim.images import ensure_images, remove_images
from rosdeploy.sim.inventory import inventory_text
from rosdeploy.sim.keys import ensure_keypair, known_hosts_text, public_key
from rosdeploy.sim.model import (REGISTRY_HOST, RobotStatus, SimFleet, SimPaths, SimRobot, SimStatus,
                                 container_of, resolve_home, robot_for, robot_index)
from rosdeploy.sim.proc import Progress, docker, engine_up, quiet, require_engine
from rosdeploy.sim.robots import (Container, copy_host_key, create_robot, current_host_key, remove_containers,
                                  remove_volumes, robot_ctl, robot_exec, sim_containers, start_container, wait_ready)

MAX_ROBOTS = 90    # domain IDs 11..100: IDs up to 101 are valid on every Linux host


@dataclass(frozen=True)
class SimState:
    robots: tuple[str, ...]
    registry_pid: int | None     # the registry process this state dir started, if any


def read_state(paths: SimPaths) -> SimState | None:
    try:
        data = json.loads(paths.state.read_text())
    except FileNotFoundError:
        return None
    except ValueError as exc:
        raise SimError(f"{paths.state} is damaged ({exc}); `rosdeploy sim down` clears it") from exc
    return SimState(robots=tuple(data.get("robots", ())), registry_pid=data.get("registry_pid"))


def write_state(paths: SimPaths, state: SimState) -> None:
    tmp = paths.state.with_suffix(".tmp")
    tmp.write_text(json.dumps(asdict(state), indent=2) + "\n")
    tmp.replace(paths.state)


def fleet_of(paths: SimPaths, robots: Sequence[SimRobot]) -> SimFleet:
    return SimFleet(home=paths.home, robots=tuple(robots), inventory=paths.inventory,
                    known_hosts=paths.known_hosts, key_file=paths.key_file)


# ------------------------------------------------------------------------- up

def up(robots: int = 3, home: Path | str | None = None, progress: Progress | None = None) -> SimFleet:
    """Bring up (or complete) a fleet of `robots` robots; idempotent and incremental."""
    progress = progress or quiet
    if not 1 <= robots <= MAX_ROBOTS:
        raise InputError([Problem("--robots", None, "", f"must be between 1 and {MAX_ROBOTS}, not {robots}")])
    require_engine()
    paths = SimPaths(resolve_home(home))
    paths.home.mkdir(parents=True, exist_ok=True)
    containers = _own_containers(paths)
    if not paths.key_file.exists():
        # Robots authorize the client key when they are created: a new key needs new robots.
        remove_containers(list(containers))
        containers = {}
    ensure_keypair(paths.key_file, comment="rosdeploy-sim")
    previous = read_state(paths)
    pid = _ensure_registry(paths, previous.registry_pid if previous else None, progress)
    # Recorded before the long build, so a failed build still lets `down` find the registry.
    write_state(paths, SimState(previous.robots if previous else (), pid))
    images = ensure_images(progress, paths.home)
    fleet = tuple(robot_for(i) for i in range(1, robots + 1))
    _ensure_robots(paths, fleet, containers, images.robot, progress)
    _write_fleet_files(paths, fleet)
    write_state(paths, SimState(tuple(r.name for r in fleet), pid))
    _heal_left_faults([r for r in fleet if r.container in containers], progress)
    progress(f"waiting for {len(fleet)} robots (sshd and their own dockerd)")
    wait_ready(fleet)
    progress(f"fleet up: inventory {paths.inventory}")
    return fleet_of(paths, fleet)


def _heal_left_faults(robots: Sequence[SimRobot], progress: Progress) -> None:
    """`up` brings every robot up reachable: a fault left in force (a run killed between `sim cut`
    and `sim heal`) kept a robot's sshd silent, and `up` waited 90 s for it, then failed."""
    for robot in robots:
        left = faults(robot.name)
        if left:
            progress(f"{robot.name}: healing a fault left in force ({'; '.join(left)[:120]})")
            heal(robot.name)


def _own_containers(paths: SimPaths) -> dict[str, Container]:
    """This state dir's robot containers; refuse while another state dir's fleet exists,
    since container names and ports are the same for every fleet."""
    containers = sim_containers()
    others = sorted({c.home for c in containers.values() if c.home != str(paths.home)})
    if others:
        raise SimError(f"a simulated fleet of another state dir exists ({others[0]}); "
                       f"run `ROSDEPLOY_SIM_HOME={others[0]} rosdeploy sim down` first")
    return containers


def _ensure_registry(paths: SimPaths, pid: int | None, progress: Progress) -> int | None:
    if registry.is_ours(pid, paths):
        if registry.answers():
            return pid
        registry.stop(pid)
    if registry.answers():
        progress(f"reusing the registry that answers on {REGISTRY_HOST}")
        return None
    progress(f"starting a registry on {REGISTRY_HOST} (data in {paths.registry_data})")
    return registry.start(paths)


def _ensure_robots(paths: SimPaths, fleet: Sequence[SimRobot], containers: dict[str, Container],
                   image: str, progress: Progress) -> None:
    wanted = {robot.container for robot in fleet}
    # Fewer robots than last time: the extra ones go, with their volumes.
    remove_containers([name for name in containers if name not in wanted], volumes=True)
    for robot in fleet:
        existing = containers.get(robot.container)
        if existing and (existing.image != image or not paths.host_key(robot.name).exists()):
            remove_containers([robot.container])    # a new robot image: a new robot
            existing = None
        if existing is None:
            create_robot(paths, robot, image, public_key(paths.key_file))
            progress(f"{robot.name}: created (ssh 127.0.0.1:{robot.ssh_port}, ROS_DOMAIN_ID {robot.ros_domain_id})")
        elif existing.state != "running":
            start_container(robot)
            progress(f"{robot.name}: started")


def _write_fleet_files(paths: SimPaths, fleet: Sequence[SimRobot]) -> None:
    entries = [(robot, public_key(paths.host_key(robot.name))) for robot in fleet]
    paths.known_hosts.write_text(known_hosts_text(entries))
    paths.inventory.write_text(inventory_text(fleet, paths.key_file, paths.known_hosts))


# ----------------------------------------------------------------- down / status

def down(home: Path | str | None = None, progress: Progress | None = None, purge: bool = False) -> None:
    """Remove what `up` created for this state dir (and, with purge, its caches and images)."""
    progress = progress or quiet
    paths = SimPaths(resolve_home(home))
    if engine_up():
        containers = [name for name, c in sim_containers().items() if c.home == str(paths.home)]
        remove_containers(containers)
        remove_volumes(paths.home)
        progress(f"removed {len(containers)} robot containers and their volumes")
    state = read_state(paths) if paths.state.exists() else None
    if state and registry.is_ours(state.registry_pid, paths):
        registry.stop(state.registry_pid)
        progress(f"stopped the registry (pid {state.registry_pid})")
    for path in (paths.state, paths.inventory, paths.known_hosts, paths.home / "registry.yml"):
        path.unlink(missing_ok=True)
    shutil.rmtree(paths.host_keys, ignore_errors=True)
    if purge:
        _purge(paths, progress)


def _purge(paths: SimPaths, progress: Progress) -> None:
    if engine_up():
        left = remove_images()
        kept = f"; {len(left)} stay, used by containers (or parents of those)" if left else ""
        progress(f"removed the simulator's images{kept}")
    shutil.rmtree(paths.home, ignore_errors=True)
    progress(f"removed {paths.home}")


def status(home: Path | str | None = None) -> SimStatus:
    paths = SimPaths(resolve_home(home))
    state = read_state(paths)
    containers = sim_containers() if engine_up() else None
    robots = tuple(robot_for(robot_index(name)) for name in (state.robots if state else ()))
    rows = tuple(RobotStatus(robot, _state_of(robot, containers)) for robot in robots)
    pid = state.registry_pid if state and registry.is_ours(state.registry_pid, paths) else None
    return SimStatus(home=paths.home, robots=rows, registry=REGISTRY_HOST, registry_up=registry.answers(),
                     registry_pid=pid)


def _state_of(robot: SimRobot, containers: dict[str, Container] | None) -> str:
    if containers is None:
        return "unknown (no Docker engine)"
    return containers[robot.container].state if robot.container in containers else "missing"


def load(home: Path | str | None = None) -> SimFleet:
    """The running fleet of a state dir; SimError saying what to do when it is not running."""
    current = status(home)
    if not current.robots:
        raise SimError(f"no simulated fleet in {current.home}; run `rosdeploy sim up`")
    if not current.running:
        broken = [f"{r.robot.name}: {r.state}" for r in current.robots if r.state != "running"]
        if not current.registry_up:
            broken.append(f"registry {current.registry}: not answering")
        raise SimError(f"the simulated fleet in {current.home} is not running ({', '.join(broken)}); "
                       "run `rosdeploy sim up`")
    return fleet_of(SimPaths(current.home), [r.robot for r in current.robots])


# ------------------------------------------------------------- fault injection

def stop_registry(home: Path | str | None = None) -> None:
    """Stop the registry the simulator started (robots' pulls then fail)."""
    paths = SimPaths(resolve_home(home))
    state = read_state(paths)
    if not (state and registry.is_ours(state.registry_pid, paths)):
        if registry.answers():
            raise SimError(f"the registry on {REGISTRY_HOST} was not started by the simulator; "
                           "stop it yourself")
        return
    registry.stop(state.registry_pid)


def start_registry(home: Path | str | None = None) -> None:
    """Start the registry again (a no-op while one answers)."""
    paths = SimPaths(resolve_home(home))
    if registry.answers():
        return
    state = read_state(paths) or SimState((), None)
    write_state(paths, SimState(state.robots, registry.start(paths)))


def regenerate_host_key(robot_name: str, home: Path | str | None = None) -> str:
    """Give a robot a new host key, leaving known_hosts as it was; returns the new key."""
    robot_ctl(robot_name, "new-host-key")
    key = current_host_key(robot_name)
    _wait_serving(robot_name, key)
    return key


def restore_host_key(robot_name: str, home: Path | str | None = None) -> None:
    """Put back the host key known_hosts has for the robot."""
    paths = SimPaths(resolve_home(home))
    robot = robot_for(robot_index(robot_name))
    copy_host_key(robot, paths.host_key(robot_name))
    robot_ctl(robot_name, "reload-sshd")
    _wait_serving(robot_name, public_key(paths.host_key(robot_name)))


def served_host_key(robot: SimRobot) -> str | None:
    """The host key sshd presents right now (no authentication, nothing trusted)."""
    try:
        with paramiko.Transport((robot.host, robot.ssh_port)) as transport:
            transport.start_client(timeout=5)
            key = transport.get_remote_server_key()
            return f"{key.get_name()} {key.get_base64()}"
    except (paramiko.SSHException, OSError):
        return None


def _wait_serving(robot_name: str, key: str, timeout: float = 20.0) -> None:
    # sshd re-execs on HUP: wait until it is back and presents the key we expect.
    robot = robot_for(robot_index(robot_name))
    deadline = time.monotonic() + timeout
    while served_host_key(robot) != key:
        if time.monotonic() > deadline:
            raise SimError(f"{robot_name}: sshd does not present the expected host key after a reload")
        time.sleep(0.2)


def stop_robot(robot_name: str) -> None:
    """Stop a robot's container: its sshd and engine go away (an unreachable robot)."""
    docker("stop", "-t", "5", container_of(robot_name), what=f"stopping {robot_name}")


def start_robot(robot_name: str) -> None:
    """Start a stopped robot again and wait until it takes SSH and its engine answers."""
    robot = robot_for(robot_index(robot_name))
    start_container(robot)
    wait_ready([robot])


def reset(home: Path | str | None = None) -> SimFleet:
    """Per-test clean state: every robot running with no fault in force (link cut, registry
    isolated), no compose projects or rosdeploy files on any, the device present, the
    original host keys, and the registry up."""
    paths = SimPaths(resolve_home(home))
    current = status(paths.home)
    if not current.running:     # a test stopped a robot or the registry: bring them back
        up(robots=len(current.robots) or 3, home=paths.home)
    fleet = load(paths.home)
    with ThreadPoolExecutor(max_workers=len(fleet.robots)) as pool:
        list(pool.map(lambda robot: _reset_robot(paths, robot), fleet.robots))
    return fleet


def _reset_robot(paths: SimPaths, robot: SimRobot) -> None:
    heal(robot.name)
    robot_ctl(robot.name, "reset")
    # rosdeploy's host changes (hostchanges.py): robot-ctl, in the image, predates them.
    robot_exec(robot.name, ["sh", "-c", "rm -f /etc/udev/rules.d/99-rosdeploy-* /etc/cron.d/rosdeploy-* "
                            "/etc/logrotate.d/rosdeploy-* /var/lib/logrotate/rosdeploy-*"], check=True)
    if current_host_key(robot.name) != public_key(paths.host_key(robot.name)):
        restore_host_key(robot.name, paths.home)
