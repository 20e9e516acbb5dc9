"""Benchmark: rosdeploy against an equivalent Ansible playbook, side by side in one run.

    python bench/fleet_bench.py [--runs 3] [--robots 3] [--fanout 10,25,50,100]

1. On the simulated fleet (`rosdeploy sim up`, reused when it runs), per round and
   per tool from clean robots: first deploy, no-op re-apply, upgrade 1.0.0 -> 1.1.0,
   1.2.0-bad until rolled back and healthy, emergency rollback of the whole fleet
   (`--scenarios` selects some). Tools: rosdeploy, rosdeploy-at-once (the same fleet file
   with `--waves 100%`: the demo deploys a canary robot first, minimal.yml every robot at
   once), Ansible with the equal-work playbook (bench/ansible/deploy.yml) and with the
   minimal one (bench/ansible/minimal.yml), and `floor`: no tool at all (as root inside
   every robot at once: pull, stop, create, parallel start, verdict files polled; see
   fleetbench.scenarios.floor_steps), the lower bound of any tool on these robots, and
   `floor-ordered`: the same, starting the services in depends_on order.
2. Fan-out: N host sshd targets on 127.0.0.1:3001... (their docker is the host's
   engine); `rosdeploy status`, no-op `rosdeploy apply` and Ansible's no-op run.
Prints the table of medians, checks the targets, writes bench/results/fleet-<date>.json
and the results section of docs/benchmarks.md. Method: docs/benchmarks.md.
Ansible comes from PyPI into bench/.venv-ansible (created on first use).
"""
from __future__ import annotations

import argparse
import os
import shlex
import shutil
import signal
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

import yaml

if TYPE_CHECKING:
    from rosdeploy.model import FleetSpec
    from rosdeploy.sim import SimFleet

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fleetbench import ansible as ans  # noqa: E402
from fleetbench import fanout as fan  # noqa: E402
from fleetbench import report  # noqa: E402
from fleetbench.proc import REPO, BenchError, Timed, check, log  # noqa: E402
from fleetbench.scenarios import (BAD, FIRST, SCENARIOS, SSH_FLOOR, TOOLS, UPGRADE, Measure,  # noqa: E402
                                  SimBench, policy_vars, render_versions)

RESULTS_DIR = REPO / "bench" / "results"
DOCS = REPO / "docs" / "benchmarks.md"
SIM_USER_HOME = "/home/robot"    # the sim inventory logs in as `robot`


def parse_args(argv: Sequence[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=3, help="rounds per scenario (medians are reported)")
    p.add_argument("--robots", type=int, default=3, help="simulated robots to deploy to")
    p.add_argument("--fanout", default="10,25,50,100", help="fan-out target counts; empty to skip")
    p.add_argument("--fanout-port", type=int, default=3001, help="first port of the fan-out sshd targets")
    p.add_argument("--ansible-fanout-runs", type=int, default=1,
                   help="runs of Ansible's fan-out no-op per N (about 5 minutes at N=100 on 2 cores)")
    p.add_argument("--fleet", type=Path, default=REPO / "playbooks" / "demo.yml", help="the demo fleet file")
    p.add_argument("--skip-fleet", action="store_true", help="only the fan-out part")
    p.add_argument("--tools", default="rosdeploy,ansible,ansible-minimal",
                   help="which tools' rounds to run on the sim fleet (ansible: the equal-work playbook "
                        "bench/ansible/deploy.yml; ansible-minimal: bench/ansible/minimal.yml; floor: no tool, "
                        "the switch done by hand inside every robot at once; floor-ordered: the same, "
                        "starting the services in depends_on order)")
    p.add_argument("--scenarios", default=",".join(SCENARIOS),
                   help="which sim fleet scenarios to measure, e.g. noop,upgrade (the ones before the last "
                        "selected still run, untimed, to bring the robots there). A selection writes "
                        "bench/results/fleet-<date>-<scenarios>.json and leaves docs/benchmarks.md alone")
    p.add_argument("--retries", type=int, default=1,
                   help="times a failed round is run again (the failure is kept in the results)")
    p.add_argument("--no-write", action="store_true", help="print only; leave docs/ and bench/results/ alone")
    p.add_argument("--rounds-file", type=Path, metavar="FILE",
                   help="add this run's rounds to FILE (JSON) and report over every round in it: several short "
                        "runs (`--runs 1`, the sim lock held a few minutes each) make one result")
    args = p.parse_args(argv)
    args.sizes = sorted({int(n) for n in args.fanout.split(",") if n.strip()})
    args.tools = [t for t in TOOLS if t in args.tools.split(",")]
    args.scenarios = [s for s in SCENARIOS if s in args.scenarios.split(",")]
    if not args.scenarios:
        p.error(f"--scenarios: choose from {','.join(SCENARIOS)}")
    if args.runs < 1 or args.robots < 1 or any(n < 1 for n in args.sizes):
        p.error("--runs, --robots and every --fanout size must be at least 1")
    return args


# ------------------------------------------------------------- sim fleet

def sim_fleet(robots: int) -> "SimFleet":
    """The running sim fleet (started or grown with `sim.up` when needed; never shrunk)."""
    from rosdeploy import sim
    from rosdeploy.errors import SimError

    try:
        fleet = sim.load()
    except SimError:
        fleet = None
    if fleet is None or len(fleet.robots) < robots:
        log(f"sim up --robots {robots} (builds images on first use, ~3 min)")
        fleet = sim.up(robots=max(robots, len(fleet.robots) if fleet else 0), progress=log)
    return fleet


def health_timeout(raw: dict[str, Any]) -> int:
    from rosdeploy.fleet import parse_duration
    from rosdeploy.model import HealthPolicy

    return int(parse_duration((raw.get("health") or {}).get("timeout", HealthPolicy().timeout)))


def load_spec(fleet_file: Path, inventory: Path) -> "FleetSpec":
    from rosdeploy.project import load_project

    return load_project(str(fleet_file), inventory=str(inventory)).spec


def home_path(deploy_root: str) -> str:
    return SIM_USER_HOME + deploy_root[1:] if deploy_root.startswith("~") else deploy_root


def sim_bench(args: argparse.Namespace, raw: dict[str, Any], work: Path, playbook: Path) -> SimBench:
    fleet = sim_fleet(args.robots)
    robots = fleet.robots[:args.robots]
    spec = load_spec(args.fleet, fleet.inventory)
    render_dir = render_versions(args.fleet, fleet.inventory, work / "render", (FIRST, UPGRADE, BAD))
    root = home_path(str(spec.deploy_root))
    hosts = [ans.InventoryHost(r.name, r.host, r.ssh_port, root) for r in robots]
    inventory = ans.write_inventory(work / "ansible-sim.yml", hosts, user="robot", key_file=fleet.key_file,
                                    known_hosts=fleet.known_hosts)
    services = [s.name for s in spec.services if not s.profiles]
    extra = {"project": spec.project, "services": services, "render_dir": str(render_dir),
             "health_timeout": int(spec.health.timeout), **policy_vars(raw)}
    return SimBench(fleet=args.fleet, inventory=fleet.inventory, robots=tuple(r.name for r in robots),
                    project=spec.project, services=tuple(services),
                    registry_robot=fleet.registry_robot, runner=ans.Ansible(playbook, inventory, work),
                    extra=extra, env={"ROSDEPLOY_RUNS_DIR": str(work / "runs")}, render_dir=render_dir,
                    deploy_root=root,
                    ssh=tuple(ssh_argv(r.host, r.ssh_port, fleet.key_file, fleet.known_hosts) for r in robots))


def ssh_argv(host: str, port: int, key_file: Path, known_hosts: Path) -> tuple[str, ...]:
    """`ssh robot@host true` with the sim's key and known_hosts: the floor of any SSH tool."""
    return ("ssh", "-i", str(key_file), "-p", str(port), "-o", "BatchMode=yes", "-o", "IdentitiesOnly=yes",
            "-o", f"UserKnownHostsFile={known_hosts}", "-o", "StrictHostKeyChecking=yes", f"robot@{host}", "true")


def run_fleet(bench: SimBench, tools: list[str], runs: int, retries: int, discarded: list[dict[str, str]],
              scenarios: Sequence[str] = SCENARIOS) -> dict[str, list[dict[str, Measure]]]:
    rounds: dict[str, list[dict[str, Measure]]] = {tool: [] for tool in tools}
    for number in range(runs):
        order = tools if number % 2 == 0 else tools[::-1]   # spread any drift evenly
        if "noop" in scenarios:
            floor = ssh_floor(bench)
            rounds.setdefault(SSH_FLOOR, []).append({"noop": floor})
            log(f"round {number + 1}/{runs}: parallel `ssh true` floor {floor.seconds:.2f}s")
        for tool in order:
            log(f"round {number + 1}/{runs}: {tool}")
            got = one_round(bench, tool, retries, discarded, scenarios)
            rounds[tool].append(got)
            log("  " + ", ".join(f"{k} {m.seconds:.2f}s" for k, m in got.items()))
    return rounds


def ssh_floor(bench: SimBench) -> Measure:
    """Wall time of `ssh robot true` to every robot at once: what no SSH tool can go below
    (fresh connections, as rosdeploy's apply opens them). Measured in the same run as the
    tools, so the no-op's overhead above it is read on one machine state."""
    import subprocess
    import time

    started = time.monotonic()
    procs = [subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE) for argv in bench.ssh]
    failed = [p.args[-2] for p in procs if p.wait(timeout=60) != 0]
    seconds = time.monotonic() - started
    if failed:
        raise BenchError(f"ssh floor: `ssh true` failed on {failed}")
    return Measure(seconds)


def one_round(bench: SimBench, tool: str, retries: int, discarded: list[dict[str, str]],
              scenarios: Sequence[str]) -> dict[str, Measure]:
    """A round whose result check failed is run again (at most `retries` times) and the
    failure is kept in the results: on a shared machine, another user's tests may reset
    the sim robots in the middle of a round."""
    for attempt in range(retries + 1):
        try:
            return TOOLS[tool](bench, scenarios)
        except BenchError as exc:
            if attempt == retries:
                raise
            discarded.append({"tool": tool, "error": str(exc)[:2000]})
            log(f"  {tool} round failed, running it again: {str(exc).splitlines()[0]}")
    raise AssertionError("unreachable")


# --------------------------------------------------------------- fan-out

def run_fanout(args: argparse.Namespace, raw: dict[str, Any], work: Path, playbook: Path, timeout: int,
               times: dict[str, dict[int, list[Timed]]]) -> None:
    """Fills `times` as it goes, so what was measured survives a later failure."""
    times.update({"status_first": {}, "status": {}, "rosdeploy_noop": {}, "ansible_noop": {}})
    quiet_sim_fleet()
    setup, farm = fan.prepare(work / "fanout", raw, args.sizes, args.fanout_port)
    try:
        farm.start()
        log(f"{len(setup.targets)} sshd targets up on 127.0.0.1:{args.fanout_port}..")
        release = fan.render_identical(setup)
        fan.deploy_first_target(setup)
        log(f"fan-out release {release} deployed to t001 and copied to every target")
        for n in args.sizes:
            for _ in range(args.runs):
                measure(times["status_first"], n, lambda n=n: fan.rosdeploy_status(setup, n, held=False))
                measure(times["status"], n, lambda n=n: fan.rosdeploy_status(setup, n, held=True))
                measure(times["rosdeploy_noop"], n, lambda n=n: fan.rosdeploy_noop(setup, n))
            log(f"  N={n}: status {_secs(times['status_first'][n])} connecting, {_secs(times['status'][n])} "
                f"held, no-op {_secs(times['rosdeploy_noop'][n])}")
        runner = ans.Ansible(playbook, fan.ansible_inventory(setup), work)
        services = [name for name, svc in raw["services"].items() if not svc.get("profiles")]
        extra = fan.ansible_extra(setup, policy_vars(raw), services, timeout)
        fan.ansible_deploy_first_target(setup, runner, extra)
        for n in args.sizes:
            for _ in range(args.ansible_fanout_runs):
                measure(times["ansible_noop"], n, lambda n=n: fan.ansible_noop(setup, runner, extra, n))
            log(f"  N={n}: Ansible no-op {_secs(times['ansible_noop'][n])}")
    finally:
        fan.teardown(farm)


def quiet_sim_fleet() -> None:
    """The fan-out targets are not the sim robots: stop the demo nodes the fleet part left
    running on them (12 ROS processes), so they do not share the 2 cores with the targets."""
    from rosdeploy import sim

    if sim.status().running:
        sim.reset()
        log("sim robots reset: no demo nodes running during the fan-out part")


def measure(series: dict[int, list[Timed]], n: int, command: Callable[[], Timed]) -> None:
    fan.settle()
    series.setdefault(n, []).append(command())


def _secs(runs: list[Timed]) -> str:
    return ", ".join(f"{t.seconds:.2f}s (cpu {t.cpu:.2f}s)" for t in runs)


# ----------------------------------------------------------------- report

def tool_versions(playbook: Path) -> dict[str, str]:
    import rosdeploy

    docker = check(["docker", "version", "--format", "{{.Server.Version}}"], what="docker version").stdout
    compose = check(["docker", "compose", "version", "--short"], what="docker compose version").stdout
    return {"rosdeploy": rosdeploy.__version__, "ansible": ans.version(playbook), "docker": docker.strip(),
            "compose": compose.strip()}


def build_results(args: argparse.Namespace, argv: Sequence[str], rounds: dict[str, list[dict[str, Measure]]],
                  fan_raw: dict[str, dict[int, list[Timed]]], playbook: Path,
                  load_start: tuple[float, ...]) -> dict[str, Any]:
    fleet = report.fleet_section(rounds) if rounds else {}
    fanout = report.fanout_section(fan_raw) if fan_raw else {}
    command = "python bench/fleet_bench.py" + ("" if not argv else " " + shlex.join(argv))
    return {"date": report.now_utc(), "command": command, "machine": report.machine(),
            "versions": tool_versions(playbook),
            "load_average": {"start": [round(x, 2) for x in load_start],
                             "end": [round(x, 2) for x in os.getloadavg()]},
            "config": {"runs": args.runs, "robots": args.robots, "fanout": args.sizes,
                       "ansible_fanout_runs": args.ansible_fanout_runs,
                       "fleet_file": str(args.fleet.resolve().relative_to(REPO)) if args.fleet.resolve()
                       .is_relative_to(REPO) else str(args.fleet)},
            "fleet": fleet, "fanout": fanout}


def kept_rounds(path: Path, rounds: dict[str, list[dict[str, Measure]]], load: tuple[float, ...],
                ) -> tuple[dict[str, list[dict[str, Measure]]], tuple[float, ...]]:
    """The rounds saved in `path` plus this run's (saved back), and the highest 1-minute load
    average any of those runs started at."""
    import dataclasses
    import json

    saved = json.loads(path.read_text()) if path.exists() else {"rounds": {}, "loads": []}
    for tool, series in rounds.items():
        saved["rounds"].setdefault(tool, []).extend(
            {name: dataclasses.asdict(m) for name, m in got.items()} for got in series)
    saved["loads"].append(list(load))
    path.write_text(json.dumps(saved, indent=1))
    every = {tool: [{name: Measure(m["seconds"], tuple(m["steps"]), m["wall_inside"]) for name, m in got.items()}
                    for got in series] for tool, series in saved["rounds"].items()}
    return every, tuple(max(loads) for loads in zip(*saved["loads"], strict=True))


def with_goals(results: dict[str, Any]) -> dict[str, Any]:
    goals = report.goals(results.get("fleet", {}), results.get("fanout", {}))
    return {**results, "goals": [{**g.__dict__, "met": g.met} for g in goals],
            "issue19": report.issue19(results.get("fleet", {}))}


def publish(results: dict[str, Any], write: bool, suffix: str = "") -> None:
    """Print the tables; with `write`, save the JSON, and (unless `suffix` marks a scenario
    selection) replace the docs' latest-run block."""
    print(report.text_table(report.table_rows(results), report.HEADER))
    print()
    for line in report.goal_lines(results):
        print(line)
    issue19 = report.issue19_lines(results)
    if issue19:
        print("\nissue #19, time over the minimal playbook's (lower is better):")
        for line in issue19:
            print(line)
    if results.get("fanout"):
        print("\nfan-out, controller CPU seconds (median):\n"
              + report.text_table(report.fanout_cpu_rows(results), report.CPU_HEADER))
    if results.get("fleet"):
        print("\nrosdeploy, median seconds per robot and step:\n" + report.steps_table(results))
    if any(e.get("floor_steps") or e.get("floor_ordered_steps") for e in results.get("fleet", {}).values()):
        print("\nfloors (no tool), median seconds per robot and phase:\n" + report.floor_steps_table(results))
    if write:
        path = report.save_json(results, RESULTS_DIR, suffix)
        if not suffix:
            report.write_docs(DOCS, report.docs_block(results, str(path.relative_to(REPO))))
        log(f"wrote {path.relative_to(REPO)}" + ("" if suffix else f" and {DOCS.relative_to(REPO)}"))


def stop_on_sigterm(_signum: int, _frame: Any) -> None:
    raise KeyboardInterrupt   # unwinds through every `finally`: sshd targets, containers, user


def byte_compile() -> None:
    """Compile rosdeploy's modules once, as `pip install` does, so both tools run from
    bytecode (pip compiled the Ansible venv). A `pip install -e` checkout under
    PYTHONDONTWRITEBYTECODE=1 would compile its ~40 modules again on every run (~70 ms)."""
    check([sys.executable, "-m", "compileall", "-q", str(REPO / "rosdeploy")], what="byte-compiling rosdeploy")


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parse_args(argv)
    signal.signal(signal.SIGTERM, stop_on_sigterm)
    if not args.skip_fleet and not args.fleet.exists():
        raise BenchError(f"{args.fleet} does not exist (the demo fleet file)")
    load_start = os.getloadavg()     # others' work on a shared machine shows up here
    work = Path(tempfile.mkdtemp(prefix="rdb-", dir="/tmp"))    # short: ControlPath sockets live here
    try:
        playbook = ans.ensure_venv()
        byte_compile()
        raw = yaml.safe_load(args.fleet.read_text())
        rounds, fan_raw, discarded = {}, {}, []
        if not args.skip_fleet:
            rounds = run_fleet(sim_bench(args, raw, work, playbook), args.tools, args.runs, args.retries,
                               discarded, args.scenarios)
        fanout_error = None
        if args.sizes:
            try:
                run_fanout(args, raw, work, playbook, health_timeout(raw), fan_raw)
            except BenchError as exc:      # keep the fleet results and what the fan-out measured
                fanout_error = str(exc)[:3000]
                log(f"fan-out stopped: {fanout_error.splitlines()[0]}")
        fan_raw = {name: series for name, series in fan_raw.items() if series}
        if args.rounds_file:
            rounds, load_start = kept_rounds(args.rounds_file, rounds, load_start)
        results = build_results(args, argv, rounds, fan_raw, playbook, load_start)
        results.update(discarded_rounds=discarded, fanout_error=fanout_error)
        partial = args.scenarios != list(SCENARIOS)
        if not args.no_write and not partial:
            report.carry_over(results, RESULTS_DIR)
        publish(with_goals(results), not args.no_write, suffix="-" + "-".join(args.scenarios) if partial else "")
        if fanout_error:
            return 1
    except BenchError as exc:
        print(f"fleet_bench: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("fleet_bench: interrupted; everything it started was stopped", file=sys.stderr)
        return 130
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
