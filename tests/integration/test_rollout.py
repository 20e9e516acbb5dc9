"""Rolling out across the simulated fleet: waves, failure budget, fleet-level rollback,
unreachable robots. Each test asserts what the robots really run."""
from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rosdeploy import sim as simulator
from rosdeploy.errors import EXIT_ABORTED, EXIT_OK, EXIT_PARTIAL
from robots import RobotShell, all_healthy, apply, rosdeploy, shells, versions

pytestmark = pytest.mark.integration




def test_failure_in_wave_two_returns_wave_one_to_the_old_release(fleet, fleet_file: Path) -> None:
    assert apply(fleet_file).code == EXIT_OK
    robots = shells(fleet)
    old = {name: shell.current() for name, shell in robots.items()}
    simulator.robot_exec("robot3", ["rm", "-f", "/dev/ttyUSB0"])     # robot3 will fail preflight

    run = apply(fleet_file, "--version", "1.1.0", "--waves", "1,100%")
    assert run.code == EXIT_ABORTED, run.stderr
    outcomes = {h["host"]: (h["wave"], h["outcome"]) for h in run.doc["hosts"]}
    assert outcomes == {"robot1": (1, "deployed"), "robot2": (2, "deployed"), "robot3": (2, "failed")}
    back = {h["host"]: h["outcome"] for h in run.doc["fleet_rollback"]}
    assert back == {"robot1": "switched", "robot2": "switched"}
    for name, shell in robots.items():
        assert shell.current() == old[name], f"{name} must be back on the release it ran before the rollout"
        assert versions(shell) == {"driver": "1.0.0", "perception": "1.0.0"}
        assert all_healthy(shell)


@pytest.fixture
def robot2_down(fleet):
    container = fleet.robot("robot2").container
    subprocess.run(["docker", "stop", "-t", "1", container], check=True, capture_output=True)
    yield
    simulator.up(robots=len(fleet.robots), home=fleet.home)   # idempotent: starts robot2 again


def test_unreachable_robot_is_reported_and_the_rest_succeed(fleet, fleet_file: Path, robot2_down) -> None:
    run = apply(fleet_file, "--max-fail", "1")
    assert run.code == EXIT_PARTIAL, run.stderr
    assert run.host("robot2")["outcome"] == "unreachable"
    assert "unreachable" in run.host("robot2")["reason"] and "127.0.0.1]:2202" in run.host("robot2")["reason"]
    for name in ("robot1", "robot3"):
        assert run.host(name)["outcome"] == "deployed"
        shell = RobotShell(fleet, name)
        assert versions(shell) == {"driver": "1.0.0", "perception": "1.0.0"} and all_healthy(shell)


def test_max_fail_one_tolerates_one_failure_and_not_two(fleet, fleet_file: Path) -> None:
    simulator.robot_exec("robot1", ["rm", "-f", "/dev/ttyUSB0"])
    one = apply(fleet_file, "--max-fail", "1", "--waves", "100%")   # max_fail counts per wave
    assert one.code == EXIT_PARTIAL, "one failure within the budget: the rollout completes"
    assert [h["outcome"] for h in one.doc["hosts"]] == ["failed", "deployed", "deployed"]
    assert not one.doc["aborted"] and not one.doc["fleet_rollback"]

    simulator.robot_exec("robot2", ["rm", "-f", "/dev/ttyUSB0"])
    two = apply(fleet_file, "--max-fail", "1", "--waves", "100%", "--version", "1.1.0")
    assert two.code == EXIT_ABORTED, "two failures exceed max_fail=1: the rollout stops"
    assert two.doc["aborted"]
    assert two.host("robot3")["outcome"] == "deployed"
    assert {h["host"]: h["outcome"] for h in two.doc["fleet_rollback"]} == {"robot3": "switched"}
    shell = RobotShell(fleet, "robot3")
    assert versions(shell) == {"driver": "1.0.0", "perception": "1.0.0"} and all_healthy(shell)


def test_a_rollout_in_waves_settles_robots_already_on_the_release_and_canaries_one_that_changes(
        fleet, fleet_file: Path) -> None:
    """Waves are planned over the robots that change: after robot1 took 1.1.0 alone, the canary
    of the fleet-wide 1.1.0 is robot2 (robot1 would prove nothing), and a re-apply is one
    round trip per robot, with no wave at all."""
    assert apply(fleet_file, "--waves", "100%").code == EXIT_OK
    assert apply(fleet_file, "--version", "1.1.0", "--limit", "robot1").code == EXIT_OK

    run = apply(fleet_file, "--version", "1.1.0", "--waves", "1,100%")
    assert run.code == EXIT_OK, run.stderr
    outcomes = {h["host"]: (h["wave"], h["outcome"]) for h in run.doc["hosts"]}
    assert outcomes == {"robot1": (None, "unchanged"), "robot2": (1, "deployed"), "robot3": (2, "deployed")}
    assert "already on this release: robot1" in run.stderr
    for name, shell in shells(fleet).items():
        assert versions(shell) == {"driver": "1.1.0", "perception": "1.1.0"} and all_healthy(shell), name

    again = apply(fleet_file, "--version", "1.1.0", "--waves", "1,100%")
    assert again.code == EXIT_OK, again.stderr
    assert {(h["wave"], h["outcome"]) for h in again.doc["hosts"]} == {(None, "unchanged")}
    for host in again.doc["hosts"]:          # connect and the quick state read (`check`): nothing else ran
        assert [s["name"] for s in host["steps"]] == ["connect", "check"], host
    assert "== wave" not in again.stderr


def test_an_emergency_rollback_during_a_rollout_stops_its_later_waves(fleet, fleet_file: Path) -> None:
    """The brake pulled while a rollout pauses between waves: its later waves must not deploy
    the release again to the robots the operator just took back."""
    assert apply(fleet_file, "--waves", "100%").code == EXIT_OK          # 1.0.0 on every robot
    robots = shells(fleet)
    before = {name: shell.current() for name, shell in robots.items()}
    rollout = subprocess.Popen([sys.executable, "-m", "rosdeploy", "--json", "apply", str(fleet_file), "--yes",
                                "--version", "1.1.0", "--waves", "1,100%", "--pause", "15s"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    end, canary = time.monotonic() + 90, None
    while canary is None and time.monotonic() < end and rollout.poll() is None:
        canary = next((name for name, shell in robots.items() if shell.current() != before[name]), None)
        time.sleep(0.5)
    assert canary is not None, "wave 1 never switched a robot"
    brake = rosdeploy("--json", "rollback", fleet_file, "--yes")      # during the pause before wave 2
    assert brake.host(canary)["outcome"] == "switched", brake.stdout
    out, err = rollout.communicate(timeout=120)
    assert rollout.returncode == EXIT_ABORTED, err[-2000:]
    doc = json.loads(out)
    outcomes = {h["host"]: h["outcome"] for h in doc["hosts"]}
    assert outcomes == {name: "deployed" if name == canary else "skipped" for name in robots}, doc["hosts"]
    assert all("emergency rollback" in h["reason"] for h in doc["hosts"] if h["host"] != canary)
    assert doc["fleet_rollback"] == [], "the operator's rollback took the canary back already"
    for name, shell in robots.items():
        assert shell.current() == before[name] and versions(shell) == {"driver": "1.0.0", "perception": "1.0.0"}
