"""Benchmark: `validate`, `check` and `render` over a generated fleet, each in its own process.

    python bench/validate_bench.py [--robots 500 5000] [--runs 3] [--against DIR] [--render-out DIR]

Builds the same project as bench/render_bench.py (YAML inventory, group_vars, 3 services,
devices, udev, a vault file, one robot in ten with a GPU) for each robot count, then
runs `python -m rosdeploy validate|check|render` on it in a subprocess, as a user would.
Reports the median wall time of the rosdeploy process (start to exit, as `time rosdeploy ...`
shows it; timed by a probe process that starts it, so the probe's own start-up is left out) and
its peak RSS (resource.getrusage of RUSAGE_CHILDREN, read after each run: one child per
measurement, so the peak is its own).

`--against DIR` measures another checkout's code (e.g. a worktree of main) in the same run,
alternating the two run by run so both see the same load, and prints the ratio of the
medians (this code / DIR's). The load average is printed before and after: the machine may
be shared. Children run with bytecode caching on whatever the caller's environment says
(PYTHONDONTWRITEBYTECODE dropped), as an installed rosdeploy has its .pyc files; one warm-up
run per checkout writes them. `render` writes into a new folder each run (none is deleted
until the end: removing 30,000 files while the next run writes costs that run the disk's time).

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


Run = tuple[float, float, int, float]   # wall seconds, peak RSS in MB, exit code, CPU seconds


def measure(fleet: Path, command: str, out: Path, code: Path = REPO) -> Run:
    """One child process running `code`'s rosdeploy (render writes into a new folder under `out`)."""
    argv = [sys.executable, "-m", "rosdeploy", command, str(fleet),
            "--vault-password-file", str(fleet.parent / "vault-password")]
    if command == "render":
        argv += ["--out", str(Path(tempfile.mkdtemp(dir=out)) / "out")]
    # Each run starts from a quiet disk: without this, the writeback of the runs before (30,000
    # files a render of 5,000 robots) slows the next one's file creation several times over.
    os.sync()
    # A fresh interpreter per run: RUSAGE_CHILDREN's ru_maxrss is the largest child so far,
    # so each measurement runs in a grandchild whose own peak and wall the child reports.
    probe = [sys.executable, "-c", _PROBE, *argv]
    done = subprocess.run(probe, cwd=code, env=_env(code), capture_output=True, text=True)
    exit_code, rss, cpu, wall = done.stdout.strip().rpartition("\n")[2].split()
    return float(wall), int(rss) / 1024, int(exit_code), float(cpu)


def _env(code: Path) -> dict[str, str]:
    env = {**os.environ, "PYTHONPATH": str(code)}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def startup() -> float:
    """Seconds for `python -c 'import rosdeploy.cli'`: the floor of every command on this machine."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import rosdeploy.cli; rosdeploy.cli.build_parser()"], cwd=REPO,
                   env=_env(REPO), check=True)
    return time.perf_counter() - t0


# Runs argv, then prints "<exit code> <peak RSS of that child in KiB> <its user+system CPU seconds>
# <its wall seconds>": the wall of the rosdeploy process alone, from its start to its exit, what
# `time rosdeploy ...` shows (the probe's own interpreter start is not rosdeploy's time).
_PROBE = """
import resource, subprocess, sys, time
t0 = time.perf_counter()
code = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode
wall = time.perf_counter() - t0
usage = resource.getrusage(resource.RUSAGE_CHILDREN)
print(code, usage.ru_maxrss, usage.ru_utime + usage.ru_stime, wall)
"""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, nargs="+", default=[500, 5000])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--against", metavar="DIR", type=Path,
                        help="another checkout to measure in the same run, alternating (e.g. a worktree of main)")
    parser.add_argument("--render-out", metavar="DIR", help="where render writes (default: beside the fleet, "
                        "on disk; /dev/shm separates rosdeploy's time from the disk's)")
    args = parser.parse_args(argv)
    codes = [REPO] + ([args.against.resolve()] if args.against else [])
    missed = 0
    print(f"load average {_load()}; interpreter + imports alone: {startup():.2f} s")
    other = f"{'other s':>9}{'ratio':>7}{'cpu ratio':>10}" if args.against else ""
    print(f"{'robots':>7} {'command':<9}{'median s':>9}{'best s':>8}{'cpu s':>7}{'peak MB':>9}{other}  target")
    for robots in args.robots:
        with tempfile.TemporaryDirectory(prefix="rosdeploy-vbench-") as tmp, \
                tempfile.TemporaryDirectory(prefix="rosdeploy-vbench-out-", dir=args.render_out) as rendered:
            fleet = build_project(Path(tmp), robots)
            out = Path(rendered)
            for command in COMMANDS:
                for code in codes:   # warm-up: .pyc files written, the inventory in the page cache
                    measure(fleet, command, out, code)
                runs: dict[Path, list[Run]] = {code: [] for code in codes}
                for _ in range(args.runs):
                    for code in codes:
                        runs[code].append(measure(fleet, command, out, code))
                mine = runs[REPO]
                exits = {run[2] for run in mine}
                walls = [run[0] for run in mine]
                peak = max(run[1] for run in mine)
                median, cpu = statistics.median(walls), statistics.median(run[3] for run in mine)
                seconds, megabytes = TARGETS.get(robots, (None, None))
                ok = (seconds is None or median <= seconds) and (megabytes is None or peak < megabytes)
                ok = ok and exits == {0}
                missed += not ok
                goal = "" if seconds is None else f"<= {seconds} s" + (f", < {megabytes} MB" if megabytes else "")
                verdict = "" if not goal else ("met" if ok else f"MISSED (exit {sorted(exits)})")
                compared = ""
                if args.against:
                    theirs = statistics.median(run[0] for run in runs[codes[1]])
                    their_cpu = statistics.median(run[3] for run in runs[codes[1]])
                    compared = f"{theirs:>9.2f}{median / theirs:>7.2f}{cpu / their_cpu:>10.2f}"
                print(f"{robots:>7} {command:<9}{median:>9.2f}{min(walls):>8.2f}{cpu:>7.2f}{peak:>9.0f}{compared}  "
                      f"{goal} {verdict}")
    print(f"load average {_load()}")
    return 1 if missed else 0


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


if __name__ == "__main__":
    raise SystemExit(main())
