"""Start-up of the rosdeploy command: what a user waits for before any robot is contacted.

    python bench/startup_bench.py [--runs 20] [--top 8]

Median and fastest wall time of N runs each of: the bare interpreter (`python -c pass`, the
floor no Python CLI goes below), `rosdeploy --help`, `rosdeploy version`, `validate` of a fleet
without vault files (tests/unit/data/fleet minus its vault), and `validate` of the warehouse
example (a vault file: cryptography is needed there). Then `python -X importtime`'s heaviest
top-level imports for `--help` and the vault-free `validate`, and whether any SSH or crypto
module was loaded. Runs from bytecode, as an installed rosdeploy does (compileall first; the
children run without PYTHONDONTWRITEBYTECODE). Target (issue #19): `--help` ≤ 0.15 s.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Sequence

import yaml

REPO = Path(__file__).resolve().parents[1]
LAB = REPO / "tests" / "unit" / "data" / "fleet"
HEAVY = ("paramiko", "fabric", "invoke", "cryptography")
TARGET_HELP = 0.15


def env() -> dict[str, str]:
    clean = {k: v for k, v in os.environ.items()
             if k not in ("PYTHONDONTWRITEBYTECODE", "ROSDEPLOY_VAULT_PASSWORD", "ROSDEPLOY_VAULT_PASSWORD_FILE")}
    clean["PYTHONPATH"] = str(REPO) + os.pathsep + clean.get("PYTHONPATH", "")
    return clean


def plain_fleet(folder: Path) -> Path:
    """The unit tests' lab fleet without its vault file and secrets."""
    shutil.copytree(LAB, folder / "lab")
    (folder / "lab" / "inventory" / "group_vars" / "all" / "vault.yml").unlink()
    fleet = folder / "lab" / "fleet.yml"
    data = yaml.safe_load(fleet.read_text())
    for service in data["services"].values():
        service.pop("secrets", None)
    fleet.write_text(yaml.safe_dump(data, sort_keys=False))
    return fleet


def wall(argv: Sequence[str], runs: int) -> list[float]:
    subprocess.run(argv, env=env(), cwd=REPO, capture_output=True, check=False)   # warm: caches, bytecode
    times = []
    for _ in range(runs):
        started = time.perf_counter()
        done = subprocess.run(argv, env=env(), cwd=REPO, capture_output=True, check=False)
        times.append(time.perf_counter() - started)
        if done.returncode != 0:
            raise SystemExit(f"{' '.join(argv)} exited {done.returncode}: {done.stderr.decode()[-500:]}")
    return times


def import_profile(args: Sequence[str], top: int) -> tuple[list[tuple[str, float]], list[str]]:
    """The heaviest top-level imports (cumulative ms) and which HEAVY modules were loaded."""
    done = subprocess.run([sys.executable, "-X", "importtime", "-m", "rosdeploy", *args], env=env(), cwd=REPO,
                          capture_output=True, text=True, check=False)
    rows = []
    for line in done.stderr.splitlines():
        match = re.match(r"import time:\s+\d+ \|\s+(\d+) \| (\s*)(\S+)", line)
        if match and len(match.group(2)) <= 1:      # top level: `site`, `rosdeploy.cli`, ...
            rows.append((match.group(3), int(match.group(1)) / 1000))
    loaded = sorted({m for m in HEAVY for line in done.stderr.splitlines()
                     if re.search(rf"\| +{m}(\.|$)", line)})
    return sorted(rows, key=lambda r: -r[1])[:top], loaded


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=20, help="runs per command (median reported)")
    p.add_argument("--top", type=int, default=8, help="heaviest top-level imports to list")
    args = p.parse_args(argv)
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(REPO / "rosdeploy")], check=True)
    with tempfile.TemporaryDirectory() as tmp:
        plain = str(plain_fleet(Path(tmp)))
        warehouse = ["validate", "playbooks/warehouse.yml", "--vault-password-file",
                     "inventory/warehouse/.vault-password-example"]
        commands = {"python -c pass (interpreter floor)": [sys.executable, "-c", "pass"],
                    "rosdeploy --help": [sys.executable, "-m", "rosdeploy", "--help"],
                    "rosdeploy version": [sys.executable, "-m", "rosdeploy", "version"],
                    "rosdeploy validate (no vault files)": [sys.executable, "-m", "rosdeploy", "validate", plain],
                    "rosdeploy validate warehouse (vault)": [sys.executable, "-m", "rosdeploy", *warehouse]}
        print("| command | median | fastest | runs |\n|---|---:|---:|---:|")
        medians = {}
        for name, command in commands.items():
            times = wall(command, args.runs)
            medians[name] = statistics.median(times)
            print(f"| `{name}` | {medians[name]:.3f} s | {min(times):.3f} s | {len(times)} |")
        for label, cmd in (("--help", ["--help"]), ("validate (no vault files)", ["validate", plain])):
            rows, loaded = import_profile(cmd, args.top)
            print(f"\nheaviest top-level imports, `rosdeploy {label}` (cumulative ms): "
                  + ", ".join(f"{name} {ms:.1f}" for name, ms in rows))
            print(f"SSH/crypto modules loaded: {', '.join(loaded) or 'none'}")
    help_median = medians["rosdeploy --help"]
    verdict = "met" if help_median <= TARGET_HELP else "MISSED"
    print(f"\n--help median {help_median:.3f} s, target ≤ {TARGET_HELP} s: {verdict} "
          f"(interpreter floor {medians['python -c pass (interpreter floor)']:.3f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
