"""demo/perception: consumes /joint_states, publishes std_msgs/String on /detections."""
from __future__ import annotations

import rclpy
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from demo_nodes import TOPICS, Config
from demo_nodes.spin import spin_until_stopped


def run(cfg: Config) -> int:
    rclpy.init()
    node = rclpy.create_node("perception")
    log = node.get_logger()
    if cfg.fault == "silent":
        log.error(f"perception {cfg.version}: camera pipeline failed to start; publishing nothing")
        return spin_until_stopped(node)
    seen = {"joint_states": 0, "detections": 0}

    def on_joint_states(_msg: JointState) -> None:
        seen["joint_states"] += 1

    node.create_subscription(JointState, TOPICS["driver"][0], on_joint_states, 10)
    publisher = node.create_publisher(String, cfg.topic, 10)

    def publish() -> None:
        seen["detections"] += 1
        publisher.publish(String(data=f"perception {cfg.version}: detection {seen['detections']} "
                                      f"(joint_states received: {seen['joint_states']})"))

    node.create_timer(1.0 / cfg.rate_hz, publish)
    log.info(f"perception {cfg.version}: publishing {cfg.topic} at {cfg.rate_hz:g} Hz")
    return spin_until_stopped(node)
