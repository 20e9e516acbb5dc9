"""demo/driver: the motor controller's node, sensor_msgs/JointState on /joint_states."""
from __future__ import annotations

import math
import os

import rclpy
from sensor_msgs.msg import JointState

from demo_nodes import Config
from demo_nodes.spin import spin_until_stopped

JOINTS = ["wheel_left_joint", "wheel_right_joint", "arm_joint"]
# Where a compose file may map the motor controller: its stable name, or the raw tty.
DEVICES = ("/dev/robot/motor", "/dev/ttyUSB0")


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


def run(cfg: Config) -> int:
    rclpy.init()
    node = rclpy.create_node("driver")
    log = node.get_logger()
    log.info(f"driver {cfg.version}: {motor_controller()}")
    if cfg.fault == "silent":
        log.error(f"driver {cfg.version}: motor controller does not answer; waiting (publishing nothing)")
        return spin_until_stopped(node)
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
