"""Give a simulated robot, at run time, what some robots have and the robot image lacks:
an `nvidia` Docker runtime, sudo for the `robot` user. Each has its undo, so a test
leaves the shared fleet as it found it (robot-ctl reset does not know about these).

Nothing here changes the robot image (three engineers share one fleet; a changed image
recreates every robot). What is worth folding into the image later: see the README
("Host changes, per-robot files, GPUs").
"""
from __future__ import annotations

import json
import subprocess
from pathlib import Path

from rosdeploy.errors import SimError
from rosdeploy.sim.model import container_of, default_home
from rosdeploy.sim.proc import docker
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


def _sudo_deb(home: Path) -> Path:
    """sudo's .deb, downloaded once by the host into the sim home (the robots have no network)."""
    cache = home / "debs"
    found = sorted(cache.glob("sudo_*.deb"))
    if found:
        return found[-1]
    cache.mkdir(parents=True, exist_ok=True)
    for argv in (["apt-get", "download", "sudo"], ["apt-get", "update", "-qq"], ["apt-get", "download", "sudo"]):
        done = subprocess.run(argv, cwd=cache, capture_output=True, text=True)
        if argv[1] == "download" and done.returncode == 0:
            break
    found = sorted(cache.glob("sudo_*.deb"))
    if not found:
        raise SimError(f"could not download sudo's .deb into {cache}: {done.stderr.strip()[-300:]}")
    return found[-1]


def sudo(robot: str, present: bool = True, home: Path | None = None) -> None:
    """sudo with `robot ALL=(ALL) NOPASSWD: ALL` (present), or that entry taken away (the
    package stays: a robot with sudo installed but no rule for the user is the case to test)."""
    if not present:
        robot_exec(robot, ["rm", "-f", SUDOERS], check=True)
        return
    if robot_exec(robot, ["sh", "-c", "command -v sudo"]).returncode != 0:
        deb = _sudo_deb(home or default_home())
        # not /tmp: a tmpfs in the robot, which `docker cp` writes beneath, unseen
        docker("cp", str(deb), f"{container_of(robot)}:/root/sudo.deb", what=f"{robot}: copy sudo's .deb")
        robot_exec(robot, ["sh", "-c", "dpkg -i /root/sudo.deb >/dev/null && rm /root/sudo.deb"], check=True)
    robot_exec(robot, ["sh", "-c", 'umask 0337; printf "robot ALL=(ALL) NOPASSWD: ALL\\n" >"$1"', "sh", SUDOERS],
               check=True)
