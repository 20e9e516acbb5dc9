"""Demo ROS 2 nodes of the simulated fleet (run inside the demo images, not by rosdeploy).

Configured by the image's environment:
    DEMO_NODE      driver | perception
    DEMO_VERSION   the release, logged at start and published by perception
    DEMO_RATE_HZ   publish rate
    DEMO_FAULT     "" or "silent" (starts, logs, never publishes: never healthy)
"""
from __future__ import annotations

import os
from dataclasses import dataclass

# node -> (topic, message type) it publishes; the watcher checks exactly this topic.
TOPICS = {
    "driver": ("/joint_states", "sensor_msgs/msg/JointState"),
    "perception": ("/detections", "std_msgs/msg/String"),
}


@dataclass(frozen=True)
class Config:
    node: str
    version: str
    rate_hz: float
    fault: str
    health_file: str

    @property
    def topic(self) -> str:
        return TOPICS[self.node][0]

    @property
    def msg_type(self) -> str:
        return TOPICS[self.node][1]

    @property
    def min_healthy_hz(self) -> float:
        # Half the nominal rate: a loaded machine must not flap the health status.
        return float(os.environ.get("DEMO_HEALTH_MIN_HZ", self.rate_hz / 2))


def config() -> Config:
    node = os.environ.get("DEMO_NODE", "driver")
    if node not in TOPICS:
        raise SystemExit(f"DEMO_NODE must be one of {sorted(TOPICS)}, not {node!r}")
    return Config(node=node, version=os.environ.get("DEMO_VERSION", "0.0.0"),
                  rate_hz=float(os.environ.get("DEMO_RATE_HZ", "10")),
                  fault=os.environ.get("DEMO_FAULT", ""),
                  health_file=os.environ.get("DEMO_HEALTH_FILE", "/tmp/rosdeploy-health"))
