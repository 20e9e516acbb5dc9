"""A simulated robot fleet on one machine: robots are Docker-in-Docker containers with
sshd, a local registry serves demo ROS 2 images built here (no Docker Hub needed).

    fleet = up(robots=3)            # SimFleet: robots, inventory, known_hosts, key_file
    robot_exec("robot1", ["docker", "ps"])
    cut("robot2"); heal("robot2")   # field faults: cut, isolate, heal, busy, reboot (sim.faults)
    down()

The state dir is $ROSDEPLOY_SIM_HOME, default ~/.rosdeploy/sim. Library code never
prints: long steps report through the `progress` callback.
"""
from rosdeploy.sim.demo import DEMO_IMAGES, DEMO_TOPICS, MODE_TOPIC, DemoImage, demo_image
from rosdeploy.sim.faults import busy, cut, faults, heal, isolate, reboot
from rosdeploy.sim.fleet import (down, load, regenerate_host_key, reset, restore_host_key, served_host_key,
                                 start_registry, start_robot, status, stop_registry, stop_robot, up)
from rosdeploy.sim.images import SimImages, ensure_images
from rosdeploy.sim.model import (MOTOR_DEVICE, REGISTRY_HOST, REGISTRY_ROBOT, RobotStatus, SimFleet, SimRobot,
                                 SimStatus, default_home)
from rosdeploy.sim.proc import Progress
from rosdeploy.sim.robots import robot_exec

__all__ = [
    "DEMO_IMAGES", "DEMO_TOPICS", "MODE_TOPIC", "DemoImage", "demo_image",
    "busy", "cut", "faults", "heal", "isolate", "reboot",
    "down", "load", "regenerate_host_key", "reset", "restore_host_key", "served_host_key",
    "start_registry", "start_robot", "status", "stop_registry", "stop_robot", "up",
    "SimImages", "ensure_images",
    "MOTOR_DEVICE", "REGISTRY_HOST", "REGISTRY_ROBOT", "RobotStatus", "SimFleet", "SimRobot", "SimStatus",
    "default_home", "Progress", "robot_exec",
]
