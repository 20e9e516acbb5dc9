"""Change, at run time, what differs between real robots and the robot image: an `nvidia`
Docker runtime (the image has none), the `robot` user's sudo rule (the image has one).
Each has its undo, so a test leaves the shared fleet as it found it (robot-ctl reset does
not know about these).
"""
from __future__ import annotations

import json

from rosdeploy.errors import SimError
from rosdeploy.sim.robots import robot_exec

DAEMON_JSON = "/etc/docker/daemon.json"
FAKE_RUNTIME = "/usr/local/bin/nvidia-container-runtime"
SUDOERS = "/etc/sudoers.d/rosdeploy-robot"


def _daemon_config(robot: str) -> dict:
    return json.loads(robot_exec(robot, ["cat", DAEMON_JSON], check=True).stdout or "{}")


def _write_daemon_config(robot: str, config: dict) -> None:
    robot_exec(robot, ["sh", "-c", 'cat >"$1.new" && mv "$1.new" "$1"', "sh", DAEMON_JSON],
               input=json.dumps(config, indent=2) + "\n", check=True)
    # `runtimes` is one of the options dockerd reloads on SIGHUP: no restart, containers keep running.
    robot_exec(robot, ["sh", "-c", 'kill -HUP "$(cat /var/run/docker.pid)"'], check=True)


def gpu_runtime(robot: str, present: bool = True) -> None:
    """An `nvidia` runtime that is runc under another name: enough for a `gpu: true` robot's
    preflight and for `runtime: nvidia` services to start (without a GPU, of course).
    Taking it away writes daemon.json without it: dockerd (20.10, the robot image's) keeps it
    until it next starts (a robot restart)."""
    config = _daemon_config(robot)
    runtimes = dict(config.get("runtimes") or {})
    if present:
        robot_exec(robot, ["sh", "-c", 'ln -sfn "$(command -v runc)" "$1"', "sh", FAKE_RUNTIME], check=True)
        runtimes["nvidia"] = {"path": FAKE_RUNTIME}
    else:
        runtimes.pop("nvidia", None)
    config["runtimes"] = runtimes
    if not runtimes:
        config.pop("runtimes")
    _write_daemon_config(robot, config)
    if present:   # dockerd 20.10 adds a runtime on SIGHUP but drops one only when it next starts
        _wait_runtime(robot)


def _wait_runtime(robot: str, tries: int = 50) -> None:
    for _ in range(tries):
        out = robot_exec(robot, ["docker", "info", "--format", "{{json .Runtimes}}"]).stdout
        if "nvidia" in json.loads(out or "{}"):
            return
        robot_exec(robot, ["sleep", "0.1"])
    raise SimError(f"{robot}: dockerd did not add the nvidia runtime on SIGHUP")


def sudo(robot: str, present: bool = True) -> None:
    """The image's `robot ALL=(ALL) NOPASSWD: ALL` (present), or that rule taken away (sudo
    stays installed: a robot with sudo but no rule for the user is the case to test)."""
    if not present:
        robot_exec(robot, ["rm", "-f", SUDOERS], check=True)
        return
    robot_exec(robot, ["sh", "-c", 'umask 0337; printf "robot ALL=(ALL) NOPASSWD: ALL\\n" >"$1"', "sh", SUDOERS],
               check=True)
