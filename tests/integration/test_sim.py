"""The simulated fleet is real: strict-host-key SSH, Compose v1 and v2, pulls from the
local registry, ROS 2 discovery across containers, and Docker health of the demo images."""
from __future__ import annotations

import io
import json
import subprocess
import time
from contextlib import redirect_stdout
from typing import Callable

import paramiko
import pytest

from rosdeploy import sim
from rosdeploy.cli import main
from rosdeploy.errors import SimError
from rosdeploy.sim import SimFleet, robot_exec

pytestmark = pytest.mark.integration

REGISTRY = "registry.local:5000"

# Runs inside a demo container: what a second participant sees of the ROS graph.
PROBE = """
import json, time, rclpy
from std_msgs.msg import String
rclpy.init()
node = rclpy.create_node("sim_test_probe")
got = []
node.create_subscription(String, "/detections", lambda m: got.append(m.data), 10)
deadline = time.monotonic() + 20
# Until perception says it has received the driver's samples AND this node has itself
# discovered the driver's publisher (each participant is discovered on its own: seeing
# perception's data says nothing about when the driver's endpoint shows up here).
def done():
    return got and "received: 0)" not in got[-1] and node.count_publishers("/joint_states") >= 1
while time.monotonic() < deadline and not done():
    rclpy.spin_once(node, timeout_sec=0.2)
topics = dict(node.get_topic_names_and_types())
print(json.dumps({"topics": {k: v for k, v in topics.items()}, "detections": got[-1:],
                  "joint_states_publishers": node.count_publishers("/joint_states")}))
"""


def run(client: paramiko.SSHClient, command: str, timeout: float = 120) -> str:
    _, stdout, stderr = client.exec_command(command, timeout=timeout)
    out = stdout.read().decode()
    assert stdout.channel.recv_exit_status() == 0, f"{command!r}: {stderr.read().decode()}"
    return out


def docker_on(robot: str, *argv: str) -> str:
    result = robot_exec(robot, ["docker", *argv], timeout=180)
    assert result.returncode == 0, f"docker {' '.join(argv)} on {robot}: {result.stderr}"
    return result.stdout


def health(robot: str, container: str) -> str:
    return docker_on(robot, "inspect", "--format", "{{.State.Health.Status}}", container).strip()


def wait_health(robot: str, containers: dict[str, str], timeout: float = 90) -> dict[str, str]:
    """Poll until each container reached its wanted health status (or time runs out)."""
    deadline = time.monotonic() + timeout
    seen = {name: health(robot, name) for name in containers}
    while seen != containers and time.monotonic() < deadline:
        time.sleep(0.5)
        seen = {name: health(robot, name) for name in containers}
    return seen


def demo_run(robot: str, name: str, image: str, domain_id: int, *extra: str) -> None:
    # --pull always: a robot may hold an older build of the same tag (the sim rebuilds
    # demo images under their tags when their code changes).
    docker_on(robot, "run", "-d", "--pull", "always", "--name", name, "--network", "host", "--label",
              "com.docker.compose.project=simtest",   # so the per-test reset removes it
              "-e", f"ROS_DOMAIN_ID={domain_id}", *extra, f"{REGISTRY}/{image}")


def test_every_robot_takes_ssh_with_strict_host_keys_and_has_both_composes(
        fleet: SimFleet, ssh: Callable[..., paramiko.SSHClient]) -> None:
    assert [r.name for r in fleet.robots] == ["robot1", "robot2", "robot3"]
    assert [r.ssh_port for r in fleet.robots] == [2201, 2202, 2203]
    for robot in fleet.robots:
        client = ssh(robot.name, "robot")
        assert run(client, "id -un; id -u; id -Gn").split()[:3] == ["robot", "1000", "robot"]
        assert "docker" in run(client, "id -Gn").split()
        assert run(client, "docker compose version").startswith("Docker Compose version v2")
        assert "1.29" in run(client, "docker-compose version --short")
        assert run(client, "readlink /dev/robot/motor").strip() == "/dev/ttyUSB0"
        assert run(client, "stat -c %F /dev/ttyUSB0").strip() == "character special file"
        assert run(ssh(robot.name, "root"), "id -un").strip() == "root"


def test_a_changed_host_key_is_refused(fleet: SimFleet, ssh: Callable[..., paramiko.SSHClient]) -> None:
    new_key = sim.regenerate_host_key("robot2")
    assert new_key not in fleet.known_hosts.read_text()
    with pytest.raises(paramiko.BadHostKeyException):
        ssh("robot2")
    ssh("robot1").close()   # the others still verify
    # The next test's `fleet` fixture puts the original key back; prove that works too.
    sim.restore_host_key("robot2")
    assert run(ssh("robot2"), "hostname").strip() == "robot2"


def test_a_robot_pulls_the_demo_image_from_the_local_registry(
        fleet: SimFleet, ssh: Callable[..., paramiko.SSHClient]) -> None:
    out = run(ssh("robot3"), f"docker pull {REGISTRY}/demo/driver:1.0.0", timeout=300)
    assert f"{REGISTRY}/demo/driver:1.0.0" in out


def test_a_stopped_registry_fails_pulls_until_it_is_started(fleet: SimFleet) -> None:
    image = f"{REGISTRY}/demo/perception:1.0.0"
    sim.stop_registry()
    try:
        assert robot_exec("robot1", ["docker", "pull", image]).returncode != 0
    finally:
        sim.start_registry()
    assert robot_exec("robot1", ["docker", "pull", image], timeout=300).returncode == 0


def test_driver_topic_is_seen_from_another_container_on_the_robot(fleet: SimFleet) -> None:
    robot = fleet.robot("robot1")
    demo_run(robot.name, "simtest-driver", "demo/driver:1.0.0", robot.ros_domain_id,
             "--device", "/dev/robot/motor:/dev/ttyUSB0")
    demo_run(robot.name, "simtest-perception", "demo/perception:1.0.0", robot.ros_domain_id)
    probe = docker_on(robot.name, "run", "--rm", "--network", "host", "-e", f"ROS_DOMAIN_ID={robot.ros_domain_id}",
                      "--entrypoint", "python3", f"{REGISTRY}/demo/perception:1.0.0", "-c", PROBE)
    seen = json.loads(probe.strip().splitlines()[-1])
    assert seen["topics"]["/joint_states"] == ["sensor_msgs/msg/JointState"]
    assert seen["topics"]["/detections"] == ["std_msgs/msg/String"]
    assert seen["joint_states_publishers"] == 1
    # perception (a third container) received the driver's samples: data, not only discovery.
    assert seen["detections"] and seen["detections"][0].startswith("perception 1.0.0: detection")
    assert "joint_states received: 0)" not in seen["detections"][0]
    # rosdeploy's health gate runs rclpy through `docker exec` without sourcing anything.
    exec_probe = docker_on(robot.name, "exec", "simtest-driver", "python3", "-c", PROBE)
    assert "/joint_states" in json.loads(exec_probe.strip().splitlines()[-1])["topics"]
    logs = robot_exec(robot.name, ["docker", "logs", "simtest-driver"])      # ROS logs go to stderr
    assert "driver 1.0.0: motor controller at /dev/ttyUSB0 (opened)" in logs.stdout + logs.stderr


def test_good_image_becomes_healthy_and_bad_image_unhealthy(fleet: SimFleet) -> None:
    robot = fleet.robot("robot2")
    # Different domains: the bad driver must not see the good one's /joint_states.
    demo_run(robot.name, "simtest-good", "demo/driver:1.0.0", robot.ros_domain_id)
    demo_run(robot.name, "simtest-bad", "demo/driver:1.2.0-bad", robot.ros_domain_id + 50)
    wanted = {"simtest-good": "healthy", "simtest-bad": "unhealthy"}
    assert wait_health(robot.name, wanted) == wanted
    assert docker_on(robot.name, "inspect", "--format", "{{.State.Status}}", "simtest-bad").strip() == "running"


def test_a_stopped_robot_comes_back_with_its_device_and_host_key(
        fleet: SimFleet, ssh: Callable[..., paramiko.SSHClient]) -> None:
    sim.stop_robot("robot3")
    states = {r.robot.name: r.state for r in sim.status(fleet.home).robots}
    assert states == {"robot1": "running", "robot2": "running", "robot3": "exited"}
    with pytest.raises(SimError, match="robot3: exited"):
        sim.load(fleet.home)
    sim.start_robot("robot3")
    client = ssh("robot3")      # same host key: known_hosts still verifies it
    # /dev is new on every container start: the device and its stable name are made again.
    assert run(client, "readlink /dev/robot/motor; stat -c %t:%T /dev/ttyUSB0").split() == ["/dev/ttyUSB0", "1:3"]


def test_status_lists_the_running_fleet(fleet: SimFleet) -> None:
    current = sim.status(fleet.home)
    assert current.running and current.registry_up
    assert [(r.robot.name, r.state) for r in current.robots] == [(f"robot{i}", "running") for i in (1, 2, 3)]
    out = io.StringIO()
    with redirect_stdout(out):
        assert main(["sim", "status", "--json"]) == 0
    doc = json.loads(out.getvalue())
    assert [(r["name"], r["ssh_port"], r["ros_domain_id"]) for r in doc["robots"]] == \
           [("robot1", 2201, 11), ("robot2", 2202, 12), ("robot3", 2203, 13)]


def test_up_again_is_incremental_heals_a_left_fault_and_down_then_up_works(fleet: SimFleet) -> None:
    sim.cut("robot2")     # as a run killed between cut and heal leaves it: `up` waited 90 s, then failed
    started = time.monotonic()
    again = sim.up(robots=3, home=fleet.home)
    assert time.monotonic() - started < 30, "a warm `sim up` rebuilds nothing"
    assert again == fleet and sim.faults("robot2") == []

    sim.down(fleet.home)
    assert sim.status(fleet.home).robots == ()
    with pytest.raises(SimError, match="sim up"):
        sim.load(fleet.home)
    assert "rosdeploy-sim-robot1" not in docker_ps_names()

    assert sim.up(robots=3, home=fleet.home) == fleet
    assert sim.load(fleet.home) == fleet


def docker_ps_names() -> str:
    return subprocess.run(["docker", "ps", "-a", "--format", "{{.Names}}"], capture_output=True, text=True,
                          check=True).stdout


MODE_PROBE = """
import rclpy, time
from std_msgs.msg import String
rclpy.init()
node = rclpy.create_node("sim_mode_probe")
got = []
node.create_subscription(String, "/robot_mode", lambda m: got.append(m.data), 10)
deadline = time.monotonic() + 15
while time.monotonic() < deadline and not got:
    rclpy.spin_once(node, timeout_sec=0.2)
print(got[-1] if got else "NOTHING")
"""


def ssh_answers(fleet: SimFleet, robot_name: str) -> bool:
    from conftest import connect
    try:
        connect(fleet, robot_name).close()
        return True
    except (OSError, paramiko.SSHException):
        return False


def test_a_cut_link_drops_ssh_but_the_robot_runs_on_until_healed(fleet: SimFleet) -> None:
    sim.cut("robot2")
    try:
        assert not ssh_answers(fleet, "robot2")
        assert ssh_answers(fleet, "robot1")                     # only robot2 is cut
        assert robot_exec("robot2", ["docker", "info"]).returncode == 0   # its engine runs on
        assert sim.faults("robot2") == ["-A ROSDEPLOY-SIM-IN -p tcp -m tcp --dport 22 -j DROP"]
    finally:
        sim.heal("robot2")
    assert ssh_answers(fleet, "robot2") and sim.faults("robot2") == []


def greets(fleet: SimFleet, robot_name: str) -> bool:
    """sshd's banner within half a second (a full login would outlast a short cut)."""
    import socket
    robot = fleet.robot(robot_name)
    try:
        with socket.create_connection((robot.host, robot.ssh_port), timeout=0.5) as conn:
            conn.settimeout(0.5)
            return conn.recv(4) == b"SSH-"
    except OSError:
        return False


def test_a_timed_cut_heals_by_itself(fleet: SimFleet) -> None:
    sim.cut("robot3", seconds=3)
    assert not greets(fleet, "robot3")
    time.sleep(3.5)
    assert greets(fleet, "robot3") and sim.faults("robot3") == []


def test_an_isolated_robot_cannot_pull_but_keeps_its_ssh_link(fleet: SimFleet) -> None:
    image = f"{REGISTRY}/demo/driver:1.0.0"
    sim.isolate("robot1", "registry")
    try:
        pulled = robot_exec("robot1", ["docker", "pull", image], timeout=60)
        assert pulled.returncode != 0 and "no route to host" in pulled.stderr
        assert ssh_answers(fleet, "robot1")
    finally:
        sim.heal("robot1")
    assert robot_exec("robot1", ["docker", "pull", image], timeout=300).returncode == 0


def test_busy_sets_the_demo_drivers_robot_mode(fleet: SimFleet) -> None:
    robot = fleet.robot("robot1")
    demo_run(robot.name, "simtest-driver", "demo/driver:1.0.0", robot.ros_domain_id,
             "--label", "com.docker.compose.service=driver")
    probe = ("exec", "simtest-driver", "python3", "-c", MODE_PROBE)
    assert docker_on(robot.name, *probe).strip().splitlines()[-1] == "IDLE"
    sim.busy(robot.name, True)
    assert docker_on(robot.name, *probe).strip().splitlines()[-1] == "BUSY"
    sim.busy(robot.name, False)
    assert docker_on(robot.name, *probe).strip().splitlines()[-1] == "IDLE"
    with pytest.raises(SimError, match="no running driver container"):
        sim.busy("robot2", True)
