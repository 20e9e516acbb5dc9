#!/usr/bin/env python3
"""Images over the registry against images over SSH, on the simulated fleet; and what pinning
every tag to its digest costs a no-op apply.

    flock /tmp/rosdeploy-sim.lock python bench/images_bench.py [--rounds 5]

On robot3 (all its images removed first): a first deploy of 1.0.0 and an upgrade to 1.1.0,
once `via: registry` and once `via: ssh` (robot3 isolated from the registry). Bytes are
counted on robot3's own interface (what crossed its link; loopback excluded) and, over SSH,
by the forwarder too. Time is the `pull` step's. Then the no-op apply of 3 robots, and the
digest resolution alone (`rosdeploy.images.supply.from_registry`), `--rounds` times each.
Starts with `sim.reset()` (no release on any robot, no fault); never run it beside the tests.
"""
from __future__ import annotations

import argparse
import json
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / "tests" / "integration")]

from rosdeploy import sim  # noqa: E402
from rosdeploy.images.supply import from_registry  # noqa: E402
from rosdeploy.project import load_project, prepare  # noqa: E402
from robots import apply, write_fleet, write_inventory  # noqa: E402

ROBOT = "robot3"


def rx() -> int:
    text = sim.robot_exec(ROBOT, ["cat", "/proc/net/dev"]).stdout
    return sum(int(line.split(":", 1)[1].split()[0]) for line in text.splitlines()[2:]
               if not line.strip().startswith("lo:"))


def wipe() -> None:
    sim.robot_exec(ROBOT, ["sh", "-c", "docker ps -aq | xargs -r docker rm -f >/dev/null; "
                                       "docker images -q | sort -u | xargs -r docker rmi -f >/dev/null 2>&1; "
                                       "docker image prune -af >/dev/null; true"], timeout=300)


def deploy(fleet_file: Path, version: str) -> dict:
    before = rx()
    run = apply(fleet_file, "--limit", ROBOT, "--version", version)
    host = run.host(ROBOT)
    assert host["outcome"] == "deployed", host["reason"]
    steps = {s["name"]: s for s in host["steps"]}
    forwarded = re.search(r"(\d+) bytes sent", steps.get("images", {}).get("detail", ""))
    return {"link_bytes": rx() - before, "forwarded_bytes": int(forwarded.group(1)) if forwarded else None,
            "pull_s": round(steps["pull"]["seconds"], 2), "apply_s": round(host["seconds"], 2)}


def routes(tmp: Path, fleet) -> dict:
    out = {}
    for via in ("registry", "ssh"):
        fleet_file = write_fleet(tmp, write_inventory(fleet, tmp), images={"via": via})
        sim.heal(ROBOT)
        wipe()
        if via == "ssh":
            sim.isolate(ROBOT, "registry")
        out[via] = {"first 1.0.0": deploy(fleet_file, "1.0.0"), "upgrade 1.1.0": deploy(fleet_file, "1.1.0")}
        print(via, json.dumps(out[via]), file=sys.stderr)
    sim.heal(ROBOT)
    return out


def noop(tmp: Path, fleet, rounds: int) -> dict:
    fleet_file = write_fleet(tmp, write_inventory(fleet, tmp))
    first = apply(fleet_file, "--version", "1.1.0")
    assert first.code == 0, first.stdout[-2000:] + first.stderr
    walls, resolves = [], []
    for _ in range(rounds):
        began = time.monotonic()
        run = apply(fleet_file, "--version", "1.1.0")
        walls.append(time.monotonic() - began)
        assert {h["outcome"] for h in run.doc["hosts"]} == {"unchanged"}
        project = load_project(str(fleet_file), version="1.1.0")
        hosts = project.targets(None)
        releases, _ = prepare(project, hosts)
        supply = from_registry(project.spec, [releases[h.name] for h in hosts])
        resolves.append(supply.resolve_seconds)
    return {"noop_apply_s_median": round(statistics.median(walls), 3),
            "resolve_s_median": round(statistics.median(resolves), 4),
            "resolve_s_max": round(max(resolves), 4), "images": len(supply.pins), "robots": len(hosts)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    fleet = sim.reset()
    with tempfile.TemporaryDirectory() as tmp:
        result = {"routes": routes(Path(tmp), fleet), "digest_resolution": noop(Path(tmp), fleet, args.rounds),
                  "at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                  "commit": subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO,
                                           capture_output=True, text=True).stdout.strip()}
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
