#!/usr/bin/env python3
"""What the readiness gate costs (issue 15), on the simulated fleet.

    python bench/ready_bench.py --rounds 5

Three no-op `apply` runs of playbooks/demo.yml on the 3 simulated robots, each a fresh
process as a user would run it, `--rounds` times, in turn:

  main      the code at --main (default /work/main): what a no-op costs today
  branch    this checkout, no `ready:`
  ready     this checkout, `ready:` with a ROS condition (/robot_mode .data == IDLE)

A no-op changes nothing, so the gate (which runs only before a restart) must cost nothing
beyond loading its few fleet-file lines. Then, for the deploys that do switch: the time of
one readiness check on robot1 (the ROS probe in its driver container: rclpy start,
discovery, the latched /robot_mode), measured the same way deploy.py runs it.

Needs `rosdeploy sim up`; resets the robots (as the tests' fixture does), deploys 1.0.0
once. Hold /tmp/rosdeploy-sim.lock around it when the tests may run (the sim is shared).
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
GATE = {"interval": "5s", "max_wait": "1m", "when": [{"topic": "/robot_mode", "field": "data", "is": "IDLE"}]}


def fleet_file(folder: Path, name: str, inventory: str, **extra: object) -> Path:
    data = yaml.safe_load((REPO / "playbooks" / "demo.yml").read_text())
    data.update(inventory=inventory, **extra)
    path = folder / f"{name}.yml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def apply_seconds(code: Path, fleet: Path, env: dict) -> float:
    began = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "rosdeploy", "apply", str(fleet), "--yes"], cwd=code,
                          env={**env, "PYTHONPATH": str(code)}, capture_output=True, text=True)
    seconds = time.monotonic() - began
    if done.returncode != 0:
        raise SystemExit(f"apply failed ({code}):\n{done.stdout}\n{done.stderr}")
    return seconds


def one_check(fleet: Path) -> float:
    """One readiness check on robot1, as hold.before_switch runs it."""
    from rosdeploy import ready
    from rosdeploy.health import PROBE_SOURCE, read_containers
    from rosdeploy.fleet import load_fleet
    from rosdeploy.inventory import load_inventory
    from rosdeploy.transport import SSHOptions, connect

    spec = load_fleet(fleet)
    host = load_inventory(spec.inventory).hosts["robot1"]
    t = connect(host, SSHOptions())
    try:
        name = next(c.name for c in read_containers(t, spec.project) if c.service == "driver")
        began = time.monotonic()
        verdict = ready.check(t.run, spec.ready, {"driver": name}, name, PROBE_SOURCE)
        seconds = time.monotonic() - began
        assert verdict.ok, verdict.reason
        return seconds
    finally:
        t.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--main", default="/work/main", help="checkout of today's code")
    args = parser.parse_args()
    from rosdeploy import sim
    sim.reset(sim.default_home())          # clean robots, registry up, no fault left by a test
    inventory = str(sim.default_home() / "inventory.yml")
    env = dict(os.environ)
    with tempfile.TemporaryDirectory() as tmp:
        env["ROSDEPLOY_RUNS_DIR"] = env["ROSDEPLOY_PENDING_DIR"] = tmp
        folder = Path(tmp)
        plain = fleet_file(folder, "plain", inventory)
        gated = fleet_file(folder, "gated", inventory, ready=GATE)
        apply_seconds(REPO, plain, env)                   # 1.0.0 everywhere: every later run is a no-op
        runs: dict[str, list[float]] = {"main": [], "branch": [], "ready": []}
        for _ in range(args.rounds):
            runs["main"].append(apply_seconds(Path(args.main), plain, env))
            runs["branch"].append(apply_seconds(REPO, plain, env))
            runs["ready"].append(apply_seconds(REPO, gated, env))
        for name, seconds in runs.items():
            print(f"no-op apply, 3 robots, {name:<7} median {statistics.median(seconds):.2f} s  "
                  f"(min {min(seconds):.2f}, max {max(seconds):.2f}, {len(seconds)} runs)", flush=True)
        checks = [one_check(gated) for _ in range(args.rounds)]
    print(f"one readiness check (ROS condition) on robot1: median {statistics.median(checks):.2f} s "
          f"(min {min(checks):.2f}, max {max(checks):.2f})")


if __name__ == "__main__":
    main()
