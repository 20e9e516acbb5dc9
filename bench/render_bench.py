"""Benchmark: load a 500-robot project, render every robot's release and run the checks.

    python bench/render_bench.py [--robots 500] [--runs 5] [--profile]

Builds the inventory in a temp dir (YAML hosts, group_vars, 3 services, devices,
udev rules, one robot in ten with a GPU), then times, for each of N runs, in this process:
load_project (fleet file + inventory) and project.prepare (Renderer, render of every robot
and every check, as validate, check, render and apply run them). Prints best and median.
The goal on the project's 2-core machine: under 2 s total.
"""
from __future__ import annotations

import argparse
import cProfile
import pstats
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from rosdeploy.project import load_project, prepare  # noqa: E402
from rosdeploy.vault import ansible_encrypt  # noqa: E402

SITES = 5
# The secret lives in a vault file, as `check` demands; Ansible's format (PBKDF2), as an existing
# Ansible inventory has it. rosdeploy's own format (scrypt) costs a fixed 0.27 s more per run.
VAULT_PASSWORD = "bench-vault-password"
GOAL_SECONDS = 2.0

FLEET = {
    "project": "bench",
    "inventory": "inventory",
    "registry": "registry.local:5000",
    "version": "1.4.2",
    "ros": {"rmw": "fastdds", "network_mode": "bridge", "shm_size": "512m"},
    "services": {
        "driver": {
            "image": "acme/amr-driver", "command": ["ros2", "launch", "amr_driver", "driver.launch.py"],
            "environment": {"RATE_HZ": 50, "ROBOT_NAME": "{{ inventory_hostname }}"},
            "secrets": {"FLEET_TOKEN": "fleet_token"},
            "devices": ["motor", "lidar"], "restart": "always",
            "resources": {"memory": "256m", "cpus": 0.5},
            "healthcheck": {"test": "test -f /tmp/healthy", "interval": "5s"},
        },
        "perception": {
            "image": "acme/amr-perception", "gpu": True, "devices": ["camera"],
            "depends_on": ["driver"], "resources": {"memory": "1g", "cpus": 1.0},
            "healthcheck": {"test": ["CMD", "cat", "/tmp/healthy"]},
        },
        "watchdog": {
            "image": "acme/amr-watchdog", "profiles": ["deploy"], "restart": "always",
            "resources": {"memory": "64m", "cpus": 0.1}, "healthcheck": "image",
            "compose": {"cap_add": ["SYS_NICE"]},
        },
    },
}


def build_project(root: Path, robots: int) -> Path:
    """Write fleet.yml + an inventory dir (hosts.yml, group_vars/) for `robots` robots, and vault-password."""
    inv = root / "inventory"
    (inv / "group_vars").mkdir(parents=True)
    sites: dict = {}
    for i in range(robots):
        site = f"site_{i % SITES}"
        # 100 robots per ROS network (a domain ID is unique per network, at most 233 of them)
        host = {"ansible_host": f"10.{i % SITES}.{i // 250}.{i % 250 + 1}", "ros_domain_id": (i // SITES) % 100,
                "ros_network": f"{site}_{i // SITES // 100}"}
        if i % 10 == 0:
            host["gpu"] = True
        sites.setdefault(site, {"hosts": {}})["hosts"][f"amr{i:04d}"] = host
    (inv / "hosts.yml").write_text(yaml.safe_dump({"all": {"children": sites}}, sort_keys=False))
    (inv / "group_vars" / "all").mkdir()
    (inv / "group_vars" / "all" / "vault.yml").write_bytes(
        ansible_encrypt(yaml.safe_dump({"fleet_token": "not-a-real-token-0123456789"}).encode(),
                        VAULT_PASSWORD.encode()))
    (root / "vault-password").write_text(VAULT_PASSWORD + "\n")
    (inv / "group_vars" / "all" / "vars.yml").write_text(yaml.safe_dump({
        "ansible_user": "root",
        "devices": {"motor": "/dev/robot/motor", "lidar": "/dev/ttyUSB0", "camera": "/dev/video0"},
        "udev": [{"symlink": "robot/motor", "subsystem": "tty", "vendor": "0403", "product": "6001"}],
    }))
    for s in range(SITES):
        (inv / "group_vars" / f"site_{s}.yml").write_text(yaml.safe_dump({"site": f"site {s}"}))
    fleet = root / "fleet.yml"
    fleet.write_text(yaml.safe_dump(FLEET, sort_keys=False))
    return fleet


def run_once(fleet: Path) -> tuple[float, float, int]:
    t0 = time.perf_counter()
    project = load_project(str(fleet), vault_password_file=str(fleet.parent / "vault-password"))
    t1 = time.perf_counter()
    releases, _ = prepare(project, project.targets())
    t2 = time.perf_counter()
    return t1 - t0, t2 - t1, len(releases)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=500)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--profile", action="store_true", help="print the top functions of one run")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="rosdeploy-bench-") as tmp:
        fleet = build_project(Path(tmp), args.robots)
        if args.profile:
            profiler = cProfile.Profile()
            profiler.runcall(run_once, fleet)
            pstats.Stats(profiler).sort_stats("cumulative").print_stats(25)
            return 0
        runs = [run_once(fleet) for _ in range(args.runs)]
    count = runs[0][2]
    columns: dict[str, Callable[[tuple[float, float, int]], float]] = {
        "load_project": lambda r: r[0], "prepare": lambda r: r[1], "total": lambda r: r[0] + r[1]}
    print(f"{count} robots, {args.runs} runs")
    print(f"{'stage':<14}{'best s':>9}{'median s':>10}{'per robot ms':>14}")
    for name, pick in columns.items():
        values = [pick(r) for r in runs]
        best, median = min(values), statistics.median(values)
        print(f"{name:<14}{best:>9.3f}{median:>10.3f}{median / count * 1000:>14.2f}")
    median_total = statistics.median(r[0] + r[1] for r in runs)
    verdict = "ok" if median_total < GOAL_SECONDS else "SLOW"
    print(f"goal: total under {GOAL_SECONDS:.0f} s -> {verdict}")
    return 0 if median_total < GOAL_SECONDS else 1


if __name__ == "__main__":
    raise SystemExit(main())
