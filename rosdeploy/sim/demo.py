"""The demo ROS 2 application the simulator builds and pushes: what each tag does.

Tests and the demo fleet file rely on these facts; the node code that implements
them lives in images/demo/demo_nodes (inside the images, not imported here).
"""
from __future__ import annotations

from dataclasses import dataclass

# node -> (topic, message type) it publishes; same table as images/demo/demo_nodes.
DEMO_TOPICS = {
    "driver": ("/joint_states", "sensor_msgs/msg/JointState"),
    "perception": ("/detections", "std_msgs/msg/String"),
}
# The driver also publishes the robot's mission state, IDLE or BUSY (`rosdeploy sim busy`).
MODE_TOPIC = ("/robot_mode", "std_msgs/msg/String")


@dataclass(frozen=True)
class DemoImage:
    node: str           # "driver" | "perception"
    tag: str            # "1.0.0", "1.1.0", "1.2.0-bad"
    rate_hz: float
    fault: str = ""     # "silent": starts, never publishes, so never becomes healthy

    @property
    def repository(self) -> str:
        return f"demo/{self.node}"

    @property
    def topic(self) -> str:
        return DEMO_TOPICS[self.node][0]

    @property
    def msg_type(self) -> str:
        return DEMO_TOPICS[self.node][1]

    @property
    def healthy(self) -> bool:
        return not self.fault

    def build_args(self) -> dict[str, str]:
        return {"NODE": self.node, "VERSION": self.tag, "RATE_HZ": f"{self.rate_hz:g}", "FAULT": self.fault}


DEMO_IMAGES: tuple[DemoImage, ...] = (
    DemoImage("driver", "1.0.0", 10),
    DemoImage("perception", "1.0.0", 5),
    # 1.1.0: the driver publishes twice as fast; both log (perception also publishes) "1.1.0".
    DemoImage("driver", "1.1.0", 20),
    DemoImage("perception", "1.1.0", 5),
    # 1.2.0-bad: containers start and stay up, but nothing is published: never healthy.
    DemoImage("driver", "1.2.0-bad", 10, fault="silent"),
    DemoImage("perception", "1.2.0-bad", 5, fault="silent"),
)


def demo_image(node: str, tag: str) -> DemoImage:
    for image in DEMO_IMAGES:
        if (image.node, image.tag) == (node, tag):
            return image
    raise KeyError(f"no demo image demo/{node}:{tag}")
