"""The health watcher: one long-lived DDS participant that subscribes to the node's
topic and writes a verdict file the Docker HEALTHCHECK reads.

A one-shot rclpy probe per health check costs ~0.4 CPU-s (interpreter, participant,
discovery); this costs one idle subscriber per container instead.
"""
from __future__ import annotations

import importlib
import os
import time
from collections import deque

import rclpy
from rclpy.node import Node

from demo_nodes import Config, config
from demo_nodes.spin import spin_until_stopped

WINDOW_S = 4.0      # rate is measured over this sliding window
WARM_UP_S = 1.0     # no verdict of "healthy" before this much of the window (10 samples at 10 Hz)
CHECK_EVERY_S = 0.5


def message_class(type_name: str) -> type:
    package, _, name = type_name.split("/")          # "sensor_msgs/msg/JointState"
    return getattr(importlib.import_module(f"{package}.msg"), name)


def write_verdict(path: str, healthy: bool, detail: str) -> None:
    tmp = f"{path}.tmp"
    with open(tmp, "w") as sink:
        sink.write(f"{'healthy' if healthy else 'unhealthy'} {int(time.time())} {detail}\n")
    os.replace(tmp, path)       # the check never reads a half-written file


class Watcher:
    def __init__(self, node: Node, cfg: Config) -> None:
        self.node, self.cfg = node, cfg
        self.started = time.monotonic()
        self.stamps: deque[float] = deque()
        node.create_subscription(message_class(cfg.msg_type), cfg.topic, self.on_message, 10)
        node.create_timer(CHECK_EVERY_S, self.check)

    def on_message(self, _msg: object) -> None:
        self.stamps.append(time.monotonic())

    def check(self) -> None:
        now = time.monotonic()
        while self.stamps and self.stamps[0] < now - WINDOW_S:
            self.stamps.popleft()
        window = min(WINDOW_S, now - self.started)
        rate = len(self.stamps) / window if window > 0 else 0.0
        publishers = self.node.count_publishers(self.cfg.topic)
        healthy = publishers > 0 and rate >= self.cfg.min_healthy_hz and window >= WARM_UP_S
        write_verdict(self.cfg.health_file, healthy,
                      f"{self.cfg.topic} publishers={publishers} rate={rate:.1f}Hz "
                      f"min={self.cfg.min_healthy_hz:g}Hz")


def main() -> int:
    cfg = config()
    rclpy.init()
    node = rclpy.create_node(f"health_watch_{cfg.node}")
    Watcher(node, cfg)
    return spin_until_stopped(node)


if __name__ == "__main__":
    raise SystemExit(main())
