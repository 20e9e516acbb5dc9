"""Container entry point: the health watcher as a child process, the node in this one.

The watcher is its own process with its own DDS participant, so a healthy verdict
means the topic really crossed DDS discovery, not just that a publisher exists.
"""
from __future__ import annotations

import subprocess
import sys

from demo_nodes import config


def main() -> int:
    cfg = config()
    watcher = subprocess.Popen([sys.executable, "-m", "demo_nodes.watch"])
    try:
        if cfg.node == "driver":
            from demo_nodes.driver import run
        else:
            from demo_nodes.perception import run
        return run(cfg)
    finally:
        stop(watcher)


def stop(watcher: subprocess.Popen) -> None:
    # The watcher holds no state: if it is not gone a second after SIGTERM (seen: rclpy
    # missing the signal under load), kill it rather than hold `docker stop` for its grace.
    watcher.terminate()
    try:
        watcher.wait(timeout=1.0)
    except subprocess.TimeoutExpired:
        watcher.kill()
        watcher.wait()


if __name__ == "__main__":
    sys.exit(main())
