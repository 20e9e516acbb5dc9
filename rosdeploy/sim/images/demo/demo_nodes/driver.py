"""demo/driver: the motor controller's node, sensor_msgs/JointState on /joint_states, and the
robot's mission state on /robot_mode (std_msgs/String: IDLE or BUSY, read from a file that
`rosdeploy sim busy ROBOT on|off` writes in this container)."""
from __future__ import annotations

import math
import os

import rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from demo_nodes import Config
from demo_nodes.spin import spin_until_stopped

JOINTS = ["wheel_left_joint", "wheel_right_joint", "arm_joint"]
# Where a compose file may map the motor controller: its stable name, or the raw tty.
DEVICES = ("/dev/robot/motor", "/dev/ttyUSB0")
MODE_TOPIC = "/robot_mode"
MODE_FILE = os.environ.get("DEMO_MODE_FILE", "/tmp/robot_mode")
MODE_HZ = 2.0


def motor_controller() -> str:
    """Open the motor controller as a real driver would; say what happened (logged at start)."""
    candidates = [os.environ["MOTOR_DEVICE"]] if os.environ.get("MOTOR_DEVICE") else DEVICES
    path = next((p for p in candidates if os.path.exists(p)), None)
    if path is None:
        return "no motor controller device mapped; simulating it"
    try:
        with open(path, "wb"):
            return f"motor controller at {path} (opened)"
    except OSError as exc:    # e.g. not in the device's group (dialout)
        return f"motor controller at {path} cannot be opened ({exc.strerror}); simulating it"


def robot_mode() -> str:
    try:
        with open(MODE_FILE) as f:
            return f.read().strip() or "IDLE"
    except OSError:
        return "IDLE"


def publish_mode(node: Node) -> None:
    # Transient-local, so a probe that joins late still gets the latest mode at once.
    qos = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    publisher = node.create_publisher(String, MODE_TOPIC, qos)
    node.create_timer(1.0 / MODE_HZ, lambda: publisher.publish(String(data=robot_mode())))


def run(cfg: Config) -> int:
    rclpy.init()
    node = rclpy.create_node("driver")
    log = node.get_logger()
    log.info(f"driver {cfg.version}: {motor_controller()}")
    if cfg.fault == "silent":
        log.error(f"driver {cfg.version}: motor controller does not answer; waiting (publishing nothing)")
        return spin_until_stopped(node)
    publish_mode(node)
    publisher = node.create_publisher(JointState, cfg.topic, 10)
    clock = node.get_clock()

    def publish() -> None:
        now = clock.now()
        t = now.nanoseconds / 1e9
        msg = JointState(name=JOINTS, position=[math.sin(t + i) for i in range(len(JOINTS))],
                         velocity=[math.cos(t + i) for i in range(len(JOINTS))])
        msg.header.stamp = now.to_msg()
        msg.header.frame_id = "base_link"
        publisher.publish(msg)

    node.create_timer(1.0 / cfg.rate_hz, publish)
    log.info(f"driver {cfg.version}: publishing {cfg.topic} at {cfg.rate_hz:g} Hz")
    return spin_until_stopped(node)
