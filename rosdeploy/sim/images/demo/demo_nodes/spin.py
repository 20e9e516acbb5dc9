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
    except Exception:
        # The signal can shut the context down while the executor builds its wait set;
        # rclpy then raises RCLError instead of ExternalShutdownException (seen: exit 1
        # on `docker stop`). After a shutdown that is a clean stop, not a crash.
        if rclpy.ok():
            raise
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
