"""Spinning a node until the container is stopped (SIGTERM) or interrupted."""
from __future__ import annotations

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node


def spin_until_stopped(node: Node) -> int:
    # rclpy's own SIGINT/SIGTERM handlers shut the context down; as PID 1 of a
    # container this process would otherwise ignore `docker stop`'s SIGTERM.
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
