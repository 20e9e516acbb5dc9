#!/usr/bin/env python3
"""Does the untouched driver keep publishing while another service is upgraded? (issue 17)

On robot1 of the simulated fleet: deploy 1.0.0 with the driver pinned to 1.0.0, start a
subscriber to /joint_states inside the driver's own container (rclpy, the robot's domain),
then `rosdeploy apply --version 1.1.0`, which upgrades perception only. The subscriber
records every arrival; the figure is the longest gap between two messages during the
upgrade, against the driver's period (10 Hz: 100 ms). The goal is a gap under 2 x period.

    flock /tmp/rosdeploy-sim.lock python bench/restart_gap.py

Needs `rosdeploy sim up`. Resets nothing but robot1's project; must not run beside the tests.
"""
from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests" / "integration"))

from robots import JOINT_STATES_STAMPS, RobotShell, apply, write_fleet, write_inventory  # noqa: E402

from rosdeploy import sim  # noqa: E402


def main() -> int:
    fleet = sim.reset(sim.default_home())
    tmp = Path(tempfile.mkdtemp(prefix="restart-gap-"))
    inventory = write_inventory(fleet, tmp)
    driver = yaml.safe_load((REPO / "playbooks" / "demo.yml").read_text())["services"]["driver"]
    fleet_file = write_fleet(tmp, inventory, services={"driver": {**driver, "tag": "1.0.0"}})
    assert apply(fleet_file, "--limit", "robot1", "--no-host-changes").code == 0
    shell = RobotShell(fleet, "robot1")
    driver_id = shell.containers()["driver"]["id"]
    listen_for = 40.0
    out: dict[str, str] = {}

    def listen() -> None:
        # the ROS base image needs no setup script: rclpy imports as is (sim/images/ros-base)
        done = subprocess.run(["docker", "exec", "rosdeploy-sim-robot1", "docker", "exec", driver_id,
                               "python3", "-c", JOINT_STATES_STAMPS, str(listen_for)], capture_output=True, text=True)
        out["stdout"], out["stderr"] = done.stdout, done.stderr

    listener = threading.Thread(target=listen)
    listener.start()
    time.sleep(5.0)                       # discovery, and a baseline before the upgrade
    began = time.monotonic()
    up = apply(fleet_file, "--limit", "robot1", "--version", "1.1.0", "--no-host-changes")
    took = time.monotonic() - began
    listener.join()
    stamps = json.loads(out["stdout"] or "[]")
    if up.code != 0 or len(stamps) < 10:
        print(f"failed: apply exit {up.code}; {len(stamps)} messages; {out.get('stderr', '')[-500:]}")
        return 1
    gaps = [b - a for a, b in zip(stamps, stamps[1:], strict=False)]
    period = sorted(gaps)[len(gaps) // 2]
    untouched = shell.containers()["driver"]["id"] == driver_id
    print(f"upgrade of perception took {took:.1f} s; driver container untouched: {untouched}")
    print(f"/joint_states: {len(stamps)} messages in {listen_for:.0f} s, median period {period * 1000:.0f} ms, "
          f"longest gap {max(gaps) * 1000:.0f} ms ({max(gaps) / period:.2f} x period; goal < 2 x)")
    return 0 if untouched and max(gaps) < 2 * period else 1


if __name__ == "__main__":
    sys.exit(main())
