"""The deploy guard on the simulated fleet: a deploy whose controller is killed, whose SSH
link is cut, or whose robot restarts, still ends on a release that passed its gate, by
the robot's own means (docs/guard.md has the table of these cases and their outcomes).

Faults are per robot, so the cases run in three lanes at once, one lane per robot, each
case one deploy on its own robot; the controller is a real `rosdeploy apply` process.
After each case the robot's REAL state is read over SSH (as root, host key verified).
"""
from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

from rosdeploy import sim as simulator
from rosdeploy.deploy import PAUSE_BEFORE_ACTIVATE
from robots import REPO, RobotShell, all_healthy, write_fleet, write_inventory

pytestmark = pytest.mark.integration

# health.timeout of the tests' fleet files (s). Measured on the 2-core machine with the three
# lanes running (2026-11-25): 1.1.0 passes its gate in 6-9 s (the guard's own gate included),
# 1.0.0 is healthy again 6 s after the guard's revert starts it; 20 s leaves twice that or more.
GATE = 20
MARGIN = 5           # rollback.guard_margin (the rollback cases' figure below)
COMMAND_TIMEOUT = 20  # ssh.command_timeout: the guard's deadline before the start
IMAGES = ("registry.local:5000/demo/driver:{v}", "registry.local:5000/demo/perception:{v}")


@dataclass(frozen=True)
class Case:
    fault: str          # kill | cut | reboot
    at: str             # the progress step the fault hits: pull, start, health, activate
    version: str        # 1.1.0 | 1.2.0-bad
    mode: str = "revert"
    as_root: bool = False   # SSH as root with Compose v1 (else the docker-group user `robot`, v2)
    stale: bool = False     # a guard's `container` and `.starting` files left with no guard (a lost race, a reboot)

    @property
    def name(self) -> str:
        return (f"{self.fault}@{self.at} {self.version} ({self.mode}{', root, compose v1' if self.as_root else ''}"
                f"{', stale guard files' if self.stale else ''})")

    @property
    def fleet(self) -> str:
        return "root" if self.as_root else self.mode

    @property
    def dir(self) -> str:
        return ("/root" if self.as_root else "/home/robot") + "/rosdeploy/demo"


# Lanes balanced by measured time (2-core machine, GATE 20, MARGIN 5): a case that waits for
# the guard's deadline takes ~37 s, a pull or reboot case ~30 s, the root case ~43 s.
LANES = {
    "robot1": [Case("kill", "start", "1.2.0-bad"), Case("kill", "health", "1.1.0"),
               Case("cut", "health", "1.2.0-bad"), Case("reboot", "health", "1.1.0"),
               Case("kill", "health", "1.2.0-bad", as_root=True)],
    "robot2": [Case("kill", "pull", "1.1.0"), Case("kill", "start", "1.1.0"), Case("kill", "health", "1.2.0-bad"),
               Case("reboot", "start", "1.2.0-bad"), Case("kill", "health", "1.1.0", "finish"),
               Case("kill", "health", "1.2.0-bad", stale=True)],
    "robot3": [Case("kill", "pull", "1.2.0-bad"), Case("kill", "activate", "1.1.0"), Case("cut", "health", "1.1.0"),
               Case("reboot", "start", "1.1.0"), Case("reboot", "health", "1.2.0-bad"),
               Case("kill", "health", "1.2.0-bad", "finish")],
}


def cli(*args: str, env: dict | None = None) -> subprocess.CompletedProcess[str]:
    """The CLI in a process of its own: lanes run at once, and in-process runs share stdout."""
    return subprocess.run([sys.executable, "-m", "rosdeploy", *map(str, args)], capture_output=True, text=True,
                          cwd=REPO, env=env or os.environ.copy(), timeout=300)


def status_of(fleet_file: Path, robot: str) -> dict:
    out = cli("--json", "status", fleet_file, "--limit", robot)
    return json.loads(out.stdout)["robots"][0]


def guard_gone(shell: RobotShell, folder: str) -> bool:
    return shell.run(f"docker ps -aq --filter label=rosdeploy.guard; ls {folder}/.guard/state {folder}/.guard/acting "
                     "2>/dev/null || true").strip() == ""


def running_release(shell: RobotShell) -> set[str]:
    labels = shell.run("for c in $(docker ps -q --filter label=com.docker.compose.project=demo); do "
                       "docker inspect --format '{{index .Config.Labels \"com.docker.compose.project.working_dir\"}}' "
                       "$c; done")
    return {line.rstrip("/").rsplit("/", 1)[-1] for line in labels.split()}


class Lane:
    def __init__(self, fleet, robot: str, files: dict[str, Path]) -> None:
        self.fleet, self.robot, self.files = fleet, robot, files
        self.rows: list[tuple[str, str, str]] = []       # (case, outcome, problems)

    def shell(self) -> RobotShell:
        return RobotShell(self.fleet, self.robot)

    def run(self, cases: list[Case]) -> None:
        for case in cases:
            try:
                problems, outcome = self.one(case)
            except Exception as exc:         # one case's failure must not hide the others'
                problems, outcome = [f"{type(exc).__name__}: {exc}"[:600]], "error"
            self.rows.append((case.name, outcome, "; ".join(problems)))

    def one(self, case: Case) -> tuple[list[str], str]:
        problems: list[str] = []
        shell = self.shell()
        if case.as_root:     # the robot's project handed to root and Compose v1: from 1.0.0 again
            shell.run("ids=$(docker ps -aq --filter label=com.docker.compose.project=demo); "
                      "[ -z \"$ids\" ] || docker rm -f $ids >/dev/null")
            base = cli("--json", "apply", self.files["root"], "--yes", "--limit", self.robot)
            assert base.returncode == 0, base.stdout[-2000:]
        home = case.dir.rsplit("/rosdeploy/", 1)[0]
        before = shell.current(home=home)
        if case.stale:       # what a guard that left as it was being started, or a reboot mid-start, leaves
            shell.run(f"mkdir -p {case.dir}/.guard/.starting && echo rosdeploy-guard-demo > {case.dir}/.guard/container"
                      f" && chown -R robot {case.dir}/.guard")
        if case.at == "pull":       # the target's images are pulled again, so the kill lands in the pull
            shell.run("docker rmi " + " ".join(i.format(v=case.version) for i in IMAGES) + " >/dev/null 2>&1 || true")
        shell.close()
        env = dict(os.environ, PYTHONPATH=str(REPO))
        if case.at == "activate":
            env[PAUSE_BEFORE_ACTIVATE] = "60"
        fleet_file = self.files[case.fleet]
        document = tempfile.TemporaryFile(mode="w+")
        ctl = subprocess.Popen([sys.executable, "-m", "rosdeploy", "--json", "apply", str(fleet_file), "--yes",
                                "--limit", self.robot, "--version", case.version],
                               stdout=document, stderr=subprocess.PIPE, text=True, cwd=REPO, env=env)
        progress = self.fault_at(ctl, case)
        seen = None
        if case.fault == "kill":
            ctl.send_signal(signal.SIGKILL)
            ctl.wait()
            seen = status_of(fleet_file, self.robot)
        elif case.fault == "cut":
            out, err = self.ended(ctl, document, GATE + 30, problems)    # the controller notices by itself
            simulator.heal(self.robot)
            seen = status_of(fleet_file, self.robot)
            self.check_report(out, err, problems)
        else:
            out, err = self.ended(ctl, document, 120, problems)          # the robot is back: its guard acts
            seen = status_of(fleet_file, self.robot)
            self.check_report(out, err, problems)
        if seen.get("state") not in ("INTERRUPTED", "RECOVERING"):
            problems.append(f"status said {seen.get('state')!r} ({seen.get('reason')!r}) while interrupted")
        outcome = self.settle(case, before, problems)
        again = cli("--json", "apply", self.files["root" if case.as_root else "revert"], "--yes", "--limit", self.robot)
        if again.returncode != 0:
            problems.append(f"the next apply did not converge: {again.stdout[-400:]} {again.stderr[-400:]}")
        if "Traceback" in progress:
            problems.append("the controller printed a traceback")
        return problems, outcome

    def fault_at(self, ctl: subprocess.Popen, case: Case) -> str:
        """Read the controller's progress until the case's step; then put the fault in.

        `health`: the gate's wait for healthy services. A release whose first start level
        never gets healthy (1.2.0-bad) spends the whole gate inside `start` (the level's
        wait), and never prints `health`: the fault then comes 6 s into `start`."""
        marker = {"pull": " pull", "start": " start ", "health": " health", "activate": "pausing"}[case.at]
        lines: queue.Queue[str] = queue.Queue()
        # "" at the end of its output (a line read has its "\n"): a controller that ended before
        # the step fails the case instead of leaving its lane waiting for ever
        threading.Thread(target=lambda: [*map(lines.put, ctl.stderr), lines.put("")], daemon=True).start()
        seen: list[str] = []
        started = None
        while True:
            wait = None if started is None else max(0.0, started + 6.0 - time.monotonic())
            try:
                line = lines.get(timeout=wait)
            except queue.Empty:
                break                                    # 6 s into the start's health wait
            if not line:
                raise AssertionError(f"the controller ended (exit {ctl.wait()}) before {marker.strip()!r}: "
                                     + "".join(seen)[-400:])
            seen.append(line)
            if marker in line:
                break
            if case.at == "health" and " start " in line:
                started = time.monotonic()
        if case.at in ("start", "health") and marker in seen[-1]:
            time.sleep(1.0)          # well inside the step
        if case.fault == "cut":
            simulator.cut(self.robot)
        elif case.fault == "reboot":
            simulator.reboot(self.robot)
        self.rest = lines
        return "".join(seen)

    def ended(self, ctl: subprocess.Popen, document, timeout: float, problems: list[str]) -> tuple[str, str]:
        """The controller's result document and the rest of its stderr, once it ended by itself."""
        try:
            ctl.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            ctl.kill()
            ctl.wait()
            problems.append(f"the controller did not end by itself within {timeout:g}s of the fault")
        time.sleep(0.5)              # the reader thread takes the last lines
        err = []
        while not self.rest.empty():
            err.append(self.rest.get())
        document.seek(0)
        return document.read(), "".join(err)

    @staticmethod
    def check_report(out: str, err: str, problems: list[str]) -> None:
        if "Traceback" in err or "Error reading SSH protocol banner" in err:
            problems.append("paramiko/traceback text in the controller's output")
        try:
            host = json.loads(out)["hosts"][0]
        except (ValueError, IndexError, KeyError):
            problems.append(f"no result document from the controller: {err[-300:]}")
            return
        # A reboot takes dockerd down before sshd: the switch can fail on the engine first.
        lost = "connection lost during" in host["reason"] or "did not start" in host["reason"]
        if not lost or "guard" not in host["reason"]:
            problems.append(f"the controller's reason does not say where it lost the robot and what the "
                            f"guard does: {host['reason']!r}")

    def settle(self, case: Case, before: str, problems: list[str]) -> str:
        """Wait for the guard to end the deploy, then read the robot's real state."""
        deadline = time.monotonic() + GATE + MARGIN + COMMAND_TIMEOUT + 60
        shell = self.shell()
        while not guard_gone(shell, case.dir) and time.monotonic() < deadline:
            time.sleep(0.5)
        if not guard_gone(shell, case.dir):
            problems.append("the guard did not end the deploy by its deadline")
        home = case.dir.rsplit("/rosdeploy/", 1)[0]
        current = shell.current(home=home)
        history = shell.history(home=home)
        last = history[-1] if history else {}
        if not all_healthy(shell, settle=30):
            problems.append("not healthy")
        if running_release(shell) != {current}:
            problems.append(f"running {running_release(shell)} but current is {current}")
        if not any(e.get("release") == current and e.get("result") == "active" for e in history):
            problems.append(f"current {current} was never activated")
        if shell.run(f"test -e {case.dir}/.lock && echo held || true").strip():
            problems.append("a lock is left")
        want = "guard-finish" if case.mode == "finish" and case.version == "1.1.0" else "guard-rollback"
        if last.get("event") != want:
            problems.append(f"history ends with {last.get('event')!r}, not {want}")
        why = "robot restarted mid-deploy" if case.fault == "reboot" else "controller lost"
        if why not in str(last.get("reason", "")):
            problems.append(f"history's reason {last.get('reason')!r} does not say {why!r}")
        expect = case.version if want == "guard-finish" else None
        if expect and not current.startswith(expect):
            problems.append(f"finish mode should have kept {expect}, runs {current}")
        if not expect and current != before:
            problems.append(f"should be back on {before}, is on {current}")
        shell.close()
        return f"{last.get('event')} -> {current.rsplit('-', 1)[0]} ({last.get('result')}): {last.get('reason')}"


def test_a_deploy_ends_on_a_gated_release_whatever_happens_to_its_controller(fleet, tmp_path: Path) -> None:
    inventory = write_inventory(fleet, tmp_path)
    as_root = write_inventory(fleet, tmp_path, ansible_user="root", rosdeploy_compose="v1")
    files = {}
    for name, mode, hosts in (("revert", "revert", inventory), ("finish", "finish", inventory),
                              ("root", "revert", as_root)):
        folder = tmp_path / name
        folder.mkdir()
        files[name] = write_fleet(folder, hosts, health={"timeout": f"{GATE}s", "stable": "2s"},
                                  rollback={"guard": mode, "guard_margin": f"{MARGIN}s"},
                                  ssh={"command_timeout": f"{COMMAND_TIMEOUT}s"})
    # Every image on every robot first (a pull is not what is tested; `ssh.command_timeout`
    # is short so the guard's deadline before the start is short too)
    pulls = "; ".join(f"docker pull -q {i.format(v=v)} >/dev/null || {{ sleep 2; docker pull -q {i.format(v=v)}; }}"
                      for v in ("1.0.0", "1.1.0", "1.2.0-bad") for i in IMAGES)
    with ThreadPoolExecutor(max_workers=3) as pool:
        list(pool.map(lambda r: simulator.robot_exec(r, ["sh", "-c", pulls], timeout=600), LANES))
    base = cli("--json", "apply", files["revert"], "--yes", "--waves", "100%")
    assert base.returncode == 0, base.stdout[-3000:]
    lanes = [Lane(fleet, robot, files) for robot in LANES]
    with ThreadPoolExecutor(max_workers=len(lanes)) as pool:
        list(pool.map(lambda lane: lane.run(LANES[lane.robot]), lanes))
    rows = [(lane.robot, *row) for lane in lanes for row in lane.rows]
    table = "\n".join(f"| {r} | {c} | {o} | {p or 'ok'} |" for r, c, o, p in rows)
    Path(os.environ.get("ROSDEPLOY_GUARD_TABLE", tmp_path / "guard-cases.md")).write_text(table + "\n")
    failed = [f"{r} {c}: {p}" for r, c, o, p in rows if p]
    assert not failed, "\n" + "\n".join(failed) + "\n\n" + table


def test_the_guards_revert_restores_the_previous_host_changes(fleet, tmp_path: Path) -> None:
    """A deploy that changes the udev rules and the rotation schedule, its controller killed
    in the gate: the guard goes back, rules and schedule included (item 3 of issue 17)."""
    base_inv = write_inventory(fleet, tmp_path)
    data = yaml.safe_load(base_inv.read_text())
    data["all"]["vars"]["udev"][0]["product"] = "6015"
    other_inv = tmp_path / "inventory-other.yml"
    other_inv.write_text(yaml.safe_dump(data, sort_keys=False))
    files = {}
    for name, inventory, every in (("revert", base_inv, "5m"), ("other", other_inv, "10m")):
        (tmp_path / name).mkdir()
        files[name] = write_fleet(tmp_path / name, inventory, health={"timeout": f"{GATE}s", "stable": "2s"},
                                  rollback={"guard": "revert", "guard_margin": f"{MARGIN}s"},
                                  ssh={"command_timeout": f"{COMMAND_TIMEOUT}s"}, logging={"rotate_every": every})
    assert cli("--json", "apply", files["revert"], "--yes", "--limit", "robot2").returncode == 0
    shell = RobotShell(fleet, "robot2")
    host_files = "cat /etc/cron.d/rosdeploy-demo /etc/udev/rules.d/99-rosdeploy-demo.rules"
    before = shell.run(host_files)
    assert "*/5 * * * *" in before and "6001" in before
    case = Case("kill", "health", "1.2.0-bad")
    ctl = subprocess.Popen([sys.executable, "-m", "rosdeploy", "--json", "apply", str(files["other"]), "--yes",
                            "--limit", "robot2", "--version", case.version], stdout=subprocess.DEVNULL,
                           stderr=subprocess.PIPE, text=True, cwd=REPO, env=dict(os.environ, PYTHONPATH=str(REPO)))
    lane = Lane(fleet, "robot2", files)
    lane.fault_at(ctl, case)
    assert "*/10 * * * *" in shell.run(host_files), "the deploy had installed its host changes"
    ctl.send_signal(signal.SIGKILL)
    ctl.wait()
    problems: list[str] = []
    outcome = lane.settle(case, shell.current(), problems)
    assert not problems, outcome + ": " + "; ".join(problems)
    assert shell.run(host_files) == before, "the guard's revert restores the previous rules and schedule"


def test_a_run_that_ends_at_once_leaves_no_guard_file_without_its_guard(fleet, tmp_path: Path) -> None:
    """A rollback to a release the robot does not have fails in a fraction of a second, while
    its guard's container is still being started: that guard leaves at once. Its `container`
    file was written after it had left, in 4 of 6 tries, and every later run then trusted the
    file and started no guard at all."""
    inventory = write_inventory(fleet, tmp_path)
    fleet_file = write_fleet(tmp_path, inventory, rollback={"guard": "revert"})
    assert cli("--json", "apply", fleet_file, "--yes", "--limit", "robot1").returncode == 0
    shell = RobotShell(fleet, "robot1")
    folder = "/home/robot/rosdeploy/demo/.guard"
    found = []
    for _ in range(4):
        run = cli("rollback", fleet_file, "--yes", "--limit", "robot1", "--to", "9.9.9")
        assert run.returncode != 0 and "9.9.9" in run.stdout + run.stderr
        end = time.monotonic() + 20
        while shell.run("docker ps -aq --filter label=rosdeploy.guard").strip() and time.monotonic() < end:
            time.sleep(0.5)
        time.sleep(1.0)      # a late writer, if any, has written by now
        found.append(shell.run(f"docker ps -aq --filter label=rosdeploy.guard; ls {folder}/container 2>/dev/null "
                               "|| true").strip())
    shell.close()
    assert found == [""] * 4, f"guard containers or `container` files left: {found}"


# ------------------------------------------------------------------ a rollback that loses its controller

ROLLBACK_FAULTS = {"robot1": "kill", "robot2": "cut", "robot3": "reboot"}   # one robot each, at once
RB_GATE, RB_MARGIN, RB_TIMEOUT = 20, 5, 15     # the guard completes at max(15, 20) + 5 = 25 s after the switch


def wait_old_stopped(robot: str, old: str, problems: list[str]) -> None:
    """Until no container of `old` runs: the rollback's switch stopped them (`together`)."""
    fmt = "{{.Label \"com.docker.compose.project.working_dir\"}}"
    end = time.monotonic() + 60
    while time.monotonic() < end:
        ps = simulator.robot_exec(robot, ["docker", "ps", "--filter", "label=com.docker.compose.project=demo",
                                          "--format", fmt], timeout=30)
        if ps.returncode == 0 and f"/releases/{old}" not in ps.stdout:
            return
    problems.append(f"{old}'s containers never stopped: the rollback did not switch")


def wait_running(robot: str, release: str, seconds: float) -> bool:
    """Until every project container runs from `release` (looked at through docker exec: the
    robot's SSH link may be cut)."""
    fmt = "{{.Label \"com.docker.compose.project.working_dir\"}} {{.State}}"
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        ps = simulator.robot_exec(robot, ["docker", "ps", "-a", "--filter", "label=com.docker.compose.project=demo",
                                          "--format", fmt], timeout=30)
        rows = [line.split() for line in ps.stdout.splitlines() if line.strip()]
        if ps.returncode == 0 and rows and all(d.rstrip("/").endswith(f"/releases/{release}") and state == "running"
                                               for d, state in rows):
            return True
        time.sleep(0.5)
    return False


def rollback_case(fleet, fleet_file: Path, robot: str, fault: str) -> tuple[str, str, str, str]:
    """`rosdeploy rollback` on one robot, the fault put in once the old containers stopped."""
    problems: list[str] = []
    shell = RobotShell(fleet, robot)
    left = shell.current()
    target = next(e["release"] for e in reversed(shell.history()) if e.get("result") == "active"
                  and e.get("release") != left)
    shell.close()
    out_file, err_file = tempfile.TemporaryFile(mode="w+"), tempfile.TemporaryFile(mode="w+")
    ctl = subprocess.Popen([sys.executable, "-m", "rosdeploy", "--json", "rollback", str(fleet_file), "--yes",
                            "--limit", robot], stdout=out_file, stderr=err_file, text=True, cwd=REPO,
                           env=dict(os.environ, PYTHONPATH=str(REPO)))
    wait_old_stopped(robot, left, problems)
    if fault == "kill":
        ctl.send_signal(signal.SIGKILL)
    else:
        (simulator.cut if fault == "cut" else simulator.reboot)(robot)
    # the brake finishes its start by itself, its controller or link gone: the robot runs its
    # target long before the guard's deadline (it ran nothing until then, when a closed channel
    # killed the switch after it had stopped the old release)
    if fault != "reboot" and not wait_running(robot, target, RB_TIMEOUT):
        problems.append(f"{target} was not running {RB_TIMEOUT} s after the fault: the switch stopped with its "
                        "controller")
    try:
        ctl.wait(timeout=120)
    except subprocess.TimeoutExpired:
        ctl.kill()
        ctl.wait()
        problems.append("the controller did not end by itself within 120 s of the fault")
    if fault == "cut":
        simulator.heal(robot)
    out_file.seek(0)
    err_file.seek(0)
    if fault != "kill":
        Lane.check_report(out_file.read(), err_file.read(), problems)
    if fault != "reboot":    # after a reboot the guard acts at once: it may be done before we look
        seen = status_of(fleet_file, robot)
        if seen.get("state") not in ("INTERRUPTED", "RECOVERING") or "rollback" not in str(seen.get("reason")):
            problems.append(f"status said {seen.get('state')!r} ({seen.get('reason')!r}) while interrupted")
    shell = RobotShell(fleet, robot)
    end = time.monotonic() + RB_TIMEOUT + RB_GATE + RB_MARGIN + 60
    while not guard_gone(shell, "/home/robot/rosdeploy/demo") and time.monotonic() < end:
        time.sleep(0.5)
    current, history = shell.current(), shell.history()
    last = history[-1] if history else {}
    if not all_healthy(shell, settle=30):
        problems.append("not healthy")
    if current != target or running_release(shell) != {target}:
        problems.append(f"current {current}, running {running_release(shell)}: not the rollback's target {target}")
    why = "robot restarted mid-rollback" if fault == "reboot" else "controller lost"
    if (last.get("event"), last.get("release"), last.get("result")) != ("guard-finished-rollback", target, "active") \
            or why not in str(last.get("reason")):
        problems.append(f"history ends with {last}")
    if shell.run("test -e /home/robot/rosdeploy/demo/.lock && echo held || true").strip():
        problems.append("a lock is left")
    shell.close()
    again = cli("--json", "apply", fleet_file, "--yes", "--limit", robot)
    if again.returncode != 0:
        problems.append(f"the next apply did not converge: {again.stdout[-400:]} {again.stderr[-400:]}")
    outcome = f"{last.get('event')} -> {str(current).rsplit('-', 1)[0]} ({last.get('result')}): {last.get('reason')}"
    return robot, f"{fault}@switch rollback 1.1.0 -> 1.0.0", outcome, "; ".join(problems)


def test_a_rollback_that_loses_its_controller_mid_switch_ends_on_its_target(fleet, tmp_path: Path) -> None:
    fleet_file = write_fleet(tmp_path, write_inventory(fleet, tmp_path),
                             health={"timeout": f"{RB_GATE}s", "stable": "2s"},
                             rollback={"guard": "revert", "guard_margin": f"{RB_MARGIN}s"},
                             ssh={"command_timeout": f"{RB_TIMEOUT}s"})
    for version in ("1.0.0", "1.1.0"):      # 1.0.0 activated before: the rollback's target
        done = cli("--json", "apply", fleet_file, "--yes", "--waves", "100%", "--version", version)
        assert done.returncode == 0, done.stdout[-3000:]
    with ThreadPoolExecutor(max_workers=3) as pool:
        rows = list(pool.map(lambda r: rollback_case(fleet, fleet_file, r, ROLLBACK_FAULTS[r]), ROLLBACK_FAULTS))
    table = "\n".join(f"| {r} | {c} | {o} | {p or 'ok'} |" for r, c, o, p in rows)
    Path(f"{os.environ.get('ROSDEPLOY_GUARD_TABLE', tmp_path / 'guard-cases.md')}.rollback").write_text(table + "\n")
    failed = [f"{r} {c}: {p}" for r, c, o, p in rows if p]
    assert not failed, "\n" + "\n".join(failed) + "\n\n" + table
