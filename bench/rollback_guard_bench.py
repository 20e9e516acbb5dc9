#!/usr/bin/env python3
"""Benchmark: what arming the guard costs the emergency rollback (`rosdeploy rollback`).

    flock /tmp/rosdeploy-sim.lock python bench/rollback_guard_bench.py [--rounds 5] [--before /work/main]

On the simulated fleet (3 robots), each round deploys 1.1.0 on every robot, then times
`rosdeploy rollback FLEET --yes` (back to 1.0.0, every robot at once) as a user runs it, one
process, wall time, once per variant, in turns:

    before   the code in --before (default: /work/main): a rollback arms no guard
    after    this checkout, rollback.guard: revert (the guard armed in the lock+state round trip)
    off      this checkout, rollback.guard: off (nothing armed: the same code's floor)

Also the per-robot steps `lock+state` (arms) and `activate` (disarms), medians. Prints the
figures; docs/guard.md quotes them. Not run by the tests.
"""
from __future__ import annotations

import argparse
import json
import os
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
from robots import write_fleet, write_inventory  # noqa: E402

STEPS = ("lock+state", "activate")


def cli(code: Path, *args: str) -> tuple[float, dict]:
    began = time.monotonic()
    out = subprocess.run([sys.executable, "-m", "rosdeploy", "--json", *map(str, args)], capture_output=True,
                         text=True, cwd=REPO, env=dict(os.environ, PYTHONPATH=str(code)), timeout=600)
    wall = time.monotonic() - began
    try:
        doc = json.loads(out.stdout)
    except ValueError:
        raise SystemExit(f"rosdeploy {' '.join(map(str, args))} failed: {out.stderr[-2000:]}") from None
    if not doc.get("ok"):
        raise SystemExit(f"not ok: {[(h['host'], h['outcome'], h['reason']) for h in doc['hosts']]}")
    return wall, doc


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--before", type=Path, default=Path("/work/main"))
    args = p.parse_args()
    fleet = sim.load(sim.default_home())
    variants = {"before": (args.before, "revert"), "after": (REPO, "revert"), "off": (REPO, "off")}
    walls: dict[str, list[float]] = {v: [] for v in variants}
    steps: dict[str, dict[str, list[float]]] = {v: {s: [] for s in STEPS} for v in variants}
    with tempfile.TemporaryDirectory() as tmp:
        inventory = write_inventory(fleet, Path(tmp))
        files = {}
        for mode in ("revert", "off"):
            (Path(tmp) / mode).mkdir()
            files[mode] = write_fleet(Path(tmp) / mode, inventory, rollback={"guard": mode})
        cli(REPO, "apply", files["revert"], "--yes", "--waves", "100%", "--version", "1.0.0")
        for _ in range(args.rounds):
            for name, (code, mode) in variants.items():
                cli(REPO, "apply", files[mode], "--yes", "--waves", "100%", "--version", "1.1.0")
                time.sleep(3)        # the deploy's guard container has left; the nodes settled
                wall, doc = cli(code, "rollback", files[mode], "--yes")
                walls[name].append(wall)
                for host in doc["hosts"]:
                    for step in host["steps"]:
                        if step["name"] in STEPS:
                            steps[name][step["name"]].append(step["seconds"])
    print(f"rosdeploy rollback, 3 robots 1.1.0 -> 1.0.0, {args.rounds} rounds (s):")
    print(f"  {'':<22} {'before':>8} {'after':>8} {'off':>8}")
    print(f"  {'wall, median':<22} " + " ".join(f"{statistics.median(walls[v]):>8.2f}" for v in variants))
    print(f"  {'wall, min':<22} " + " ".join(f"{min(walls[v]):>8.2f}" for v in variants))
    for s in STEPS:
        print(f"  {s + ', median':<22} " + " ".join(f"{statistics.median(steps[v][s]):>8.3f}" for v in variants))
    print("  all walls: " + "; ".join(f"{v} {[round(w, 2) for w in walls[v]]}" for v in variants))


if __name__ == "__main__":
    main()
