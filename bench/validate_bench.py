"""Benchmark: `validate`, `check` and `render` over a generated fleet, each in its own process.

    python bench/validate_bench.py [--robots 500 5000] [--runs 3]

Builds the same project as bench/render_bench.py (YAML inventory, group_vars, 3 services,
devices, udev, a vault-free secret, one robot in ten with a GPU) for each robot count, then
runs `python -m rosdeploy validate|check|render` on it in a subprocess, as a user would.
Reports the median wall time and the peak RSS of the child (resource.getrusage of
RUSAGE_CHILDREN, read after each run: one child per measurement, so the peak is its own).

Targets (issue 18): 500 robots <= 0.5 s each; 5,000 robots <= 5 s and under 300 MB each.
Exit 1 when a target is missed.
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

sys.path.insert(0, str(Path(__file__).resolve().parent))

from render_bench import build_project  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
COMMANDS = ("validate", "check", "render")
TARGETS = {500: (0.5, None), 5000: (5.0, 300)}   # robots -> (seconds, MB or None)


def measure(fleet: Path, command: str, out: Path) -> tuple[float, float, int]:
    """One child process: (wall seconds, peak RSS in MB, exit code)."""
    argv = [sys.executable, "-m", "rosdeploy", command, str(fleet),
            "--vault-password-file", str(fleet.parent / "vault-password")]
    if command == "render":
        argv += ["--out", str(out)]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    t0 = time.perf_counter()
    # A fresh interpreter per run: RUSAGE_CHILDREN's ru_maxrss is the largest child so far,
    # so each measurement runs in a grandchild whose own peak the child reports.
    probe = [sys.executable, "-c", _PROBE, *argv]
    done = subprocess.run(probe, cwd=REPO, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    code_text, _, rss_text = done.stdout.strip().rpartition("\n")[2].partition(" ")
    return wall, int(rss_text) / 1024, int(code_text)


def startup() -> float:
    """Seconds for `python -c 'import rosdeploy.cli'`: the floor of every command on this machine."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import rosdeploy.cli; rosdeploy.cli.build_parser()"], cwd=REPO,
                   env={**os.environ, "PYTHONPATH": str(REPO)}, check=True)
    return time.perf_counter() - t0


# Runs argv, then prints "<exit code> <peak RSS of that child in KiB>".
_PROBE = """
import resource, subprocess, sys
code = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode
print(code, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
"""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, nargs="+", default=[500, 5000])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--render-out", metavar="DIR", help="where render writes (default: beside the fleet, "
                        "on disk; /dev/shm separates rosdeploy's time from the disk's)")
    args = parser.parse_args(argv)
    missed = 0
    print(f"interpreter + imports alone: {startup():.2f} s")
    print(f"{'robots':>7} {'command':<9}{'median s':>9}{'best s':>8}{'peak MB':>9}  target")
    for robots in args.robots:
        with tempfile.TemporaryDirectory(prefix="rosdeploy-vbench-") as tmp:
            fleet = build_project(Path(tmp), robots)
            for command in COMMANDS:
                out = Path(args.render_out or tmp) / f"out-{robots}"
                runs = [measure(fleet, command, out) for _ in range(args.runs)]
                codes = {code for _, _, code in runs}
                walls = [wall for wall, _, _ in runs]
                peak = max(rss for _, rss, _ in runs)
                median = statistics.median(walls)
                seconds, megabytes = TARGETS.get(robots, (None, None))
                ok = (seconds is None or median <= seconds) and (megabytes is None or peak < megabytes)
                ok = ok and codes == {0}
                missed += not ok
                goal = "" if seconds is None else f"<= {seconds} s" + (f", < {megabytes} MB" if megabytes else "")
                verdict = "" if not goal else ("met" if ok else f"MISSED (exit {sorted(codes)})")
                print(f"{robots:>7} {command:<9}{median:>9.2f}{min(walls):>8.2f}{peak:>9.0f}  {goal} {verdict}")
    return 1 if missed else 0


if __name__ == "__main__":
    raise SystemExit(main())
