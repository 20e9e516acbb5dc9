#!/usr/bin/env python3
"""How fast can the simulated fleet go back from 1.1.0 to 1.0.0 with no tool at all?

The emergency rollback's target is a ratio (≤ ¼ of Ansible's redeploy), and most of a
rollback's time is the demo nodes' own: stopping, then starting and passing their health
checks on a shared CPU. This measures that floor on the same robots: as root inside each
robot at once, stop the project's containers, `compose up --no-start` the kept 1.0.0
release, start every container in parallel, and poll each container's verdict file from
the robot's own filesystem every 20 ms (no `docker exec`, no SSH, no Python). What a tool
adds on top of this is its own cost.

    python bench/rollback_floor.py --rounds 5

Needs `rosdeploy sim up` and 1.0.0 kept on every robot (this deploys 1.0.0 once if it is
not). Each round first deploys 1.1.0 with rosdeploy and waits `--settle` seconds. It leaves
the robots running 1.0.0 under a `current` that says 1.1.0; the next `rosdeploy apply`
repairs that. Not run by the tests: like the fleet benchmark, it resets nothing else but
must not run beside them.
"""
from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

# Runs inside a robot as root. $1: the project dir, $2: the project, $3: the version to go to.
FLOOR_SCRIPT = r'''
dir=$1; project=$2; version=$3
release=$(ls "$dir/releases" | grep "^$version-" | head -n 1)
[ -n "$release" ] || { echo "no kept release of $version in $dir" >&2; exit 4; }
cd "$dir/releases/$release" || exit 4
clock() { read -r u _ </proc/uptime; echo "$u"; }
t0=$(clock)
running=$(docker ps -q --filter "label=com.docker.compose.project=$project")
[ -z "$running" ] || docker stop $running >/dev/null
t1=$(clock)
docker compose -p "$project" -f compose.yml up --no-start --remove-orphans >/dev/null 2>&1 || exit 5
t2=$(clock)
ids=$(docker ps -aq --filter "label=com.docker.compose.project=$project")
for id in $ids; do docker start "$id" >/dev/null & done; wait
t3=$(clock)
files=
for id in $ids; do files="$files $(docker inspect -f '{{.GraphDriver.Data.UpperDir}}' "$id")/tmp/rosdeploy-health"; done
while :; do
  ok=0; n=0
  for f in $files; do n=$((n + 1)); [ -r "$f" ] && read -r v _ <"$f" && [ "$v" = healthy ] && ok=$((ok + 1)); done
  [ "$ok" -eq "$n" ] && break
  sleep 0.02
done
t4=$(clock)
echo "$t0 $t1 $t2 $t3 $t4"
'''


def rosdeploy(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "rosdeploy", *args], cwd=REPO, check=True, capture_output=True)


def floor_on(container: str, project_dir: str, project: str, version: str) -> list[float]:
    out = subprocess.run(["docker", "exec", container, "sh", "-c", FLOOR_SCRIPT, "sh", project_dir, project, version],
                         capture_output=True, text=True, check=True)
    t0, *rest = (float(x) for x in out.stdout.split())
    return [t - t0 for t in rest]       # stopped, created, started, healthy (s after t0)


def one_round(containers: list[str], args: argparse.Namespace) -> tuple[float, list[list[float]]]:
    rosdeploy("apply", str(args.fleet), "--version", args.upgrade_to, "--waves", "100%", "--yes")
    time.sleep(args.settle)
    began = time.monotonic()
    with ThreadPoolExecutor(len(containers)) as pool:
        phases = list(pool.map(lambda c: floor_on(c, args.project_dir, args.project, args.version), containers))
    return time.monotonic() - began, phases


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--settle", type=float, default=8.0, help="seconds between the deploy of 1.1.0 and the switch")
    p.add_argument("--fleet", type=Path, default=REPO / "playbooks" / "demo.yml")
    p.add_argument("--version", default="1.0.0", help="the kept version to go back to")
    p.add_argument("--upgrade-to", default="1.1.0")
    p.add_argument("--project", default="demo")
    p.add_argument("--project-dir", default="/home/robot/rosdeploy/demo")
    args = p.parse_args()
    sys.path.insert(0, str(REPO))
    from rosdeploy import sim
    containers = [r.container for r in sim.load().robots]
    rosdeploy("apply", str(args.fleet), "--version", args.version, "--waves", "100%", "--yes")
    walls = []
    for n in range(1, args.rounds + 1):
        wall, phases = one_round(containers, args)
        walls.append(wall)
        slowest = max(phases, key=lambda ph: ph[-1])
        print(f"round {n}: fleet {wall:.2f} s; slowest robot: stop {slowest[0]:.2f}, create "
              f"{slowest[1] - slowest[0]:.2f}, start {slowest[2] - slowest[1]:.2f}, "
              f"healthy {slowest[3] - slowest[2]:.2f} s", flush=True)
    print(f"median of {len(walls)}: {statistics.median(walls):.2f} s (min {min(walls):.2f}, max {max(walls):.2f})")
    rosdeploy("apply", str(args.fleet), "--version", args.upgrade_to, "--waves", "100%", "--yes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
