"""Benchmark: what the deploy guard costs, and how fast it brings a robot back.

    flock /tmp/rosdeploy-sim.lock python bench/guard_bench.py [--rounds 3]

On the simulated fleet (`rosdeploy sim up`, 3 robots), from clean robots on 1.0.0:

1. Overhead: upgrades 1.0.0 -> 1.1.0 of all 3 robots at once with `rollback.guard: off`
   and `revert`, alternating (the same robot state before each). Reported: the median
   over robots and rounds of the steps that carry the arming and disarming (lock, upload,
   activate, and `start`, whose first `up` re-arms), and the median wall time of the
   upgrade; then no-op applies with the guard on and off (no step of a no-op arms it).
2. Recovery: `apply --version 1.2.0-bad` on one robot, the controller SIGKILLed while it
   checks health; from the guard's deadline (its own clock, in its state file) to the
   robot back on its activated release with every container healthy (Docker's verdict).

Prints the figures; the README's guard section quotes them.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests" / "integration"))

from rosdeploy import sim  # noqa: E402
from robots import RobotShell, all_healthy, write_fleet, write_inventory  # noqa: E402

CARRIERS = ("lock", "upload", "activate")
DIR = "/home/robot/rosdeploy/demo"


def cli(*args: str, env: dict | None = None) -> dict:
    out = subprocess.run([sys.executable, "-m", "rosdeploy", "--json", *map(str, args)], capture_output=True,
                         text=True, cwd=REPO, env=env or dict(os.environ, PYTHONPATH=str(REPO)), timeout=600)
    try:
        return json.loads(out.stdout)
    except ValueError:
        raise SystemExit(f"rosdeploy {' '.join(map(str, args))} failed: {out.stderr[-2000:]}") from None


def timed(fleet_file: Path, *args: str) -> tuple[float, dict]:
    began = time.monotonic()
    doc = cli("apply", fleet_file, "--yes", "--waves", "100%", *args)
    if not doc["ok"]:
        raise SystemExit(f"apply failed: {[(h['host'], h['outcome'], h['reason']) for h in doc['hosts']]}")
    return time.monotonic() - began, doc


def step_times(doc: dict) -> dict[str, list[float]]:
    times: dict[str, list[float]] = {}
    for host in doc["hosts"]:
        for step in host["steps"]:
            name = "start" if step["name"].startswith("start ") else step["name"]
            times.setdefault(name, []).append(step["seconds"])
    return times


def overhead(files: dict[str, Path], rounds: int) -> None:
    walls: dict[str, list[float]] = {"off": [], "revert": []}
    steps: dict[str, dict[str, list[float]]] = {"off": {}, "revert": {}}
    noop: dict[str, list[float]] = {"off": [], "revert": []}
    for _ in range(rounds):
        for mode in ("off", "revert"):
            timed(files[mode], "--version", "1.0.0")
            wall, doc = timed(files[mode], "--version", "1.1.0")
            walls[mode].append(wall)
            for name, values in step_times(doc).items():
                steps[mode].setdefault(name, []).extend(values)
            # the first no-op after a deploy may still judge `starting` checks: the later ones
            noop[mode].extend(timed(files[mode], "--version", "1.1.0")[0] for _ in range(3))
    print("upgrade of 3 robots, 1.0.0 -> 1.1.0; medians over robots and rounds (s):")
    print(f"  {'step':<10} {'guard off':>10} {'revert':>10} {'added':>8}")
    added = 0.0
    for name in (*CARRIERS, "start"):
        off, on = statistics.median(steps["off"][name]), statistics.median(steps["revert"][name])
        added += on - off
        print(f"  {name:<10} {off:>10.3f} {on:>10.3f} {on - off:>+8.3f}")
    print(f"  {'sum':<10} {'':>10} {'':>10} {added:>+8.3f}")
    # The steps that arm nothing, where a guard container competing for the robot's CPU would show.
    for name in sorted(set(steps["off"]) & set(steps["revert"]) - {*CARRIERS, "start"}):
        off, on = statistics.median(steps["off"][name]), statistics.median(steps["revert"][name])
        print(f"  {name:<10} {off:>10.3f} {on:>10.3f} {on - off:>+8.3f}  (arms nothing)")
    for mode in ("off", "revert"):
        print(f"  upgrade wall times, {mode}: {[round(w, 2) for w in walls[mode]]}")
    print(f"  wall time of the upgrade: off {statistics.median(walls['off']):.2f}, "
          f"revert {statistics.median(walls['revert']):.2f}")
    print(f"  no-op apply: off {statistics.median(noop['off']):.2f}, revert {statistics.median(noop['revert']):.2f}")


def recovery(fleet_file: Path, rounds: int) -> None:
    figures = []
    for _ in range(rounds):
        timed(fleet_file, "--version", "1.0.0")
        env = dict(os.environ, PYTHONPATH=str(REPO))
        ctl = subprocess.Popen([sys.executable, "-m", "rosdeploy", "--json", "apply", str(fleet_file), "--yes",
                                "--limit", "robot1", "--version", "1.2.0-bad"], stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE, text=True, cwd=REPO, env=env)
        for line in ctl.stderr:
            if " health" in line:
                break
        ctl.send_signal(signal.SIGKILL)
        ctl.wait()
        shell = RobotShell(sim.load(sim.default_home()), "robot1")
        deadline = int(shell.run(f"sed -n 's/^deadline=//p' {DIR}/.guard/state | tail -n 1"))
        back = None
        while back is None:
            time.sleep(0.5)
            gone = not shell.run(f"ls {DIR}/.guard/state {DIR}/.guard/acting 2>/dev/null || true").strip()
            if gone and all_healthy(shell, settle=0):
                back = float(shell.run("date +%s.%N"))
        figures.append(back - deadline)
        shell.close()
    print(f"deadline -> back on the activated release, healthy (s): "
          f"median {statistics.median(figures):.1f}, all {[round(f, 1) for f in figures]}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--no-recovery", action="store_true", help="only the overhead part")
    args = p.parse_args()
    print(f"load average at the start: {os.getloadavg()}")
    fleet = sim.reset(sim.default_home())
    with tempfile.TemporaryDirectory() as tmp:
        inventory = write_inventory(fleet, Path(tmp))
        files = {}
        for mode in ("off", "revert"):
            folder = Path(tmp) / mode
            folder.mkdir()
            files[mode] = write_fleet(folder, inventory, health={"timeout": "30s", "stable": "2s"},
                                      rollback={"guard": mode, "guard_margin": "5s"})
        overhead(files, args.rounds)
        if not args.no_recovery:
            recovery(files["revert"], args.rounds)
    print(f"load average at the end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
