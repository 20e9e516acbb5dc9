"""Deploying to the simulated fleet: real sshd, real Docker engines, real registry, real ROS 2 nodes.

Every test asserts what the robots really run (docker inspect over SSH), not
only what rosdeploy says.
"""
from __future__ import annotations

import contextlib
import json
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Iterator

import pytest
import yaml

from rosdeploy import owner
from rosdeploy import sim as simulator
from rosdeploy.errors import EXIT_ABORTED, EXIT_OK, EXIT_PARTIAL
from robots import RobotShell, all_healthy, identity, rosdeploy, shells, versions, write_fleet, write_inventory
from robots import apply as deploy
from conftest import connect

pytestmark = pytest.mark.integration




def test_first_deploy_noop_and_single_robot_upgrade(fleet, fleet_file: Path) -> None:
    robots = shells(fleet)
    # A robot whose login environment sets ROS_DOMAIN_ID (ROS's setup guides put it in
    # /etc/environment or ~/.bashrc): Compose prefers the shell's value to .env's for ${VAR}.
    with login_env(fleet, "robot1", "export ROS_DOMAIN_ID=99 RMW_IMPLEMENTATION=rmw_nonexistent_cpp"):
        first = deploy(fleet_file)
        assert first.code == EXIT_OK, first.stderr
    env = robots["robot1"].run("cat /home/robot/rosdeploy/demo/current/.env")
    want = {line for line in env.splitlines() if line.startswith(("ROS_DOMAIN_ID=", "RMW_IMPLEMENTATION="))}
    assert len(want) == 2 and "ROS_DOMAIN_ID=99" not in want, env
    driver = robots["robot1"].containers()["driver"]["id"]
    running = set(json.loads(robots["robot1"].run(f"docker inspect --format '{{{{json .Config.Env}}}}' {driver}")))
    assert want <= running, (want, running)
    for name, shell in robots.items():
        assert first.host(name)["outcome"] == "deployed"
        assert versions(shell) == {"driver": "1.0.0", "perception": "1.0.0"}
        assert all_healthy(shell)
        assert shell.current() == first.host(name)["new_release"]
    manifest = json.loads(robots["robot1"].run("cat /home/robot/rosdeploy/demo/current/manifest.json"))
    assert sorted(manifest["images"]) == [f"registry.local:5000/demo/{s}:1.0.0" for s in ("driver", "perception")]
    assert all(i["id"].startswith("sha256:") and i["repo_digests"] for i in manifest["images"].values())
    assert manifest["services"] == ["driver", "perception"]
    before = {name: shell.containers() for name, shell in robots.items()}

    again = deploy(fleet_file)
    assert again.code == EXIT_OK
    assert {h["outcome"] for h in again.doc["hosts"]} == {"unchanged"}
    for name, shell in robots.items():
        now = shell.containers()
        assert {s: (c["id"], c["started"], c["restarts"]) for s, c in now.items()} == \
               {s: (c["id"], c["started"], c["restarts"]) for s, c in before[name].items()}, "no-op restarted"

    upgrade = deploy(fleet_file, "--limit", "robot2", "--version", "1.1.0")
    assert upgrade.code == EXIT_OK, upgrade.stderr
    assert [h["host"] for h in upgrade.doc["hosts"]] == ["robot2"]
    assert versions(robots["robot2"]) == {"driver": "1.1.0", "perception": "1.1.0"}
    for name in ("robot1", "robot3"):
        assert robots[name].containers()["driver"]["id"] == before[name]["driver"]["id"]

    status = rosdeploy("--json", "status", fleet_file)
    by_host = {r["host"]: r for r in status.doc["robots"]}
    assert by_host["robot2"]["version"] == "1.1.0" and by_host["robot2"]["drift"] is True
    assert by_host["robot1"]["version"] == "1.0.0" and by_host["robot1"]["healthy"]
    assert status.code == EXIT_PARTIAL, "drift is reported in the exit code"


@contextlib.contextmanager
def login_env(fleet, name: str, line: str) -> Iterator[None]:
    """`line` first in the robot user's ~/.bashrc (bash reads it for an SSH command), for the block."""
    shell = RobotShell(fleet, name)
    shell.run(f"cp -p /home/robot/.bashrc /home/robot/.bashrc.orig && sed -i 1i{shlex.quote(line)} /home/robot/.bashrc")
    try:
        client = connect(fleet, name)
        try:
            _, out, _ = client.exec_command("sh -c 'echo $ROS_DOMAIN_ID'", timeout=30)
            assert out.read().decode().strip() == "99", "the robot user's SSH commands must see the line"
        finally:
            client.close()
        yield
    finally:
        shell.run("mv /home/robot/.bashrc.orig /home/robot/.bashrc")


def test_bad_release_rolls_back_every_robot_to_what_it_ran(fleet, fleet_file: Path) -> None:
    assert deploy(fleet_file).code == EXIT_OK
    robots = shells(fleet)
    was = {name: shell.current() for name, shell in robots.items()}

    bad = deploy(fleet_file, "--version", "1.2.0-bad", "--waves", "100%")
    assert bad.code == EXIT_ABORTED, bad.stderr
    for name, shell in robots.items():
        result = bad.host(name)
        assert result["outcome"] == "rolled-back", result
        assert result["failed_service"] in ("driver", "perception")
        assert result["logs"], "the failing service's logs are reported"
        assert shell.current() == was[name]
        assert versions(shell) == {"driver": "1.0.0", "perception": "1.0.0"}
        assert all_healthy(shell)
        events = [(h["event"], h["result"]) for h in shell.history()]
        assert events[-2:] == [("deploy", "failed"), ("auto-rollback", "active")]


def test_canary_stops_a_bad_release(fleet, fleet_file: Path) -> None:
    assert deploy(fleet_file).code == EXIT_OK
    robots = shells(fleet)
    before = {name: shell.containers()["driver"]["id"] for name, shell in robots.items()}
    bad = deploy(fleet_file, "--version", "1.2.0-bad", "--waves", "1,100%")
    assert bad.code == EXIT_ABORTED
    assert bad.host("robot1")["outcome"] == "rolled-back"
    assert {bad.host(n)["outcome"] for n in ("robot2", "robot3")} == {"skipped"}
    for name in ("robot2", "robot3"):
        assert robots[name].containers()["driver"]["id"] == before[name], "the rest of the fleet never changed"


def test_emergency_rollback_works_with_the_registry_down(fleet, fleet_file: Path) -> None:
    assert deploy(fleet_file).code == EXIT_OK
    assert deploy(fleet_file, "--version", "1.1.0").code == EXIT_OK
    simulator.stop_registry()
    try:
        back = rosdeploy("--json", "rollback", fleet_file, "--yes")
    finally:
        simulator.start_registry()
    assert back.code == EXIT_OK, back.stderr
    for name, shell in shells(fleet).items():
        assert back.host(name)["outcome"] == "switched"
        assert versions(shell) == {"driver": "1.0.0", "perception": "1.0.0"}
        assert all_healthy(shell)
        assert shell.history()[-1]["event"] == "rollback"


def test_rollback_judges_the_kept_release_by_its_own_services(fleet, tmp_path: Path, fleet_file: Path) -> None:
    """1.1.0 adds a service; going back to 1.0.0 must not wait for it (it is not in 1.0.0)."""
    assert deploy(fleet_file, "--limit", "robot1").code == EXIT_OK
    services = yaml.safe_load(fleet_file.read_text())["services"]
    extra = {**services["perception"], "depends_on": ["driver"], "topics": []}
    (tmp_path / "grown").mkdir()
    grown = write_fleet(tmp_path / "grown", write_inventory(fleet, tmp_path), services={"perception_b": extra})
    up = deploy(grown, "--limit", "robot1", "--version", "1.1.0")
    assert up.code == EXIT_OK, up.stderr
    shell = RobotShell(fleet, "robot1")
    assert set(shell.containers()) == {"driver", "perception", "perception_b"}

    back = rosdeploy("--json", "rollback", grown, "--yes", "--limit", "robot1")
    assert back.code == EXIT_OK, back.stderr
    assert back.host("robot1")["outcome"] == "switched", back.host("robot1")
    assert back.host("robot1")["seconds"] < 30, "judged by 1.0.0's services, not waiting for perception_b"
    assert versions(shell) == {"driver": "1.0.0", "perception": "1.0.0"} and all_healthy(shell)


def test_a_bind_mount_needs_its_robot_directory_and_is_mounted_read_only(fleet, tmp_path: Path) -> None:
    simulator.robot_exec("robot1", ["rm", "-rf", "/home/robot/maps"])
    fleet_file = write_fleet(tmp_path, write_inventory(fleet, tmp_path))
    doc = yaml.safe_load(fleet_file.read_text())
    doc["services"]["driver"]["volumes"] = ["/home/robot/maps:/maps:ro"]
    fleet_file.write_text(yaml.safe_dump(doc, sort_keys=False))

    missing = deploy(fleet_file, "--limit", "robot1")
    reason = missing.host("robot1")["reason"]
    assert missing.host("robot1")["outcome"] == "failed"
    assert "/home/robot/maps" in reason and "services.driver.volumes" in reason, reason
    shell = RobotShell(fleet, "robot1")
    assert shell.containers() == {}, "preflight stopped it before anything changed"

    simulator.robot_exec("robot1",
                         ["sh", "-c", "mkdir -p /home/robot/maps && echo warehouse-7 > /home/robot/maps/map.yaml"])
    mounted = deploy(fleet_file, "--limit", "robot1")
    assert mounted.code == EXIT_OK, mounted.stderr
    assert shell.run("docker exec demo-driver-1 cat /maps/map.yaml").strip() == "warehouse-7"
    assert shell.run("docker exec demo-driver-1 sh -c 'touch /maps/x 2>/dev/null || echo read-only'").strip() == \
        "read-only"


def test_registry_down_fails_the_pull_and_changes_nothing(fleet, fleet_file: Path) -> None:
    assert deploy(fleet_file, "--limit", "robot1").code == EXIT_OK
    shell = RobotShell(fleet, "robot1")
    before = identity(shell)
    for node in ("driver", "perception"):   # a robot keeps pulled images: make 1.1.0 need a pull
        simulator.robot_exec("robot1", ["docker", "image", "rm", "-f", f"registry.local:5000/demo/{node}:1.1.0"])
    simulator.stop_registry()
    try:
        run = deploy(fleet_file, "--limit", "robot1", "--version", "1.1.0")
    finally:
        simulator.start_registry()
    assert run.code != EXIT_OK
    assert run.host("robot1")["outcome"] == "failed" and "pull failed" in run.host("robot1")["reason"]
    assert identity(shell) == before and all_healthy(shell)
    assert not any(r.startswith("1.1.0") for r in shell.run("ls /home/robot/rosdeploy/demo/releases").split())


def test_missing_device_fails_preflight_and_keeps_running(fleet, fleet_file: Path) -> None:
    assert deploy(fleet_file, "--limit", "robot3").code == EXIT_OK
    shell = RobotShell(fleet, "robot3")
    before = identity(shell)
    simulator.robot_exec("robot3", ["rm", "-f", "/dev/ttyUSB0"])
    run = deploy(fleet_file, "--limit", "robot3", "--version", "1.1.0")
    assert run.code == EXIT_ABORTED, "one failure exceeds max_fail=0"
    assert run.host("robot3")["outcome"] == "failed"
    reason = run.host("robot3")["reason"]
    assert "preflight" in reason and "/dev/robot/motor" in reason and "devices.motor" in reason
    assert identity(shell) == before and all_healthy(shell), "the running release keeps running"


def test_changed_host_key_is_refused(fleet, fleet_file: Path) -> None:
    simulator.regenerate_host_key("robot2")
    run = deploy(fleet_file)
    result = run.host("robot2")
    assert result["outcome"] == "unreachable" and "HOST KEY CHANGED" in result["reason"]
    # robot2's key no longer matches known_hosts, so look inside it without SSH
    inside = simulator.robot_exec("robot2", ["docker", "ps", "-aq"])
    assert inside.stdout.strip() == "", "nothing was deployed to the robot with the changed key"
    assert run.host("robot1")["outcome"] == "deployed"


def test_locked_robot_is_not_deployed_twice(fleet, fleet_file: Path) -> None:
    # the owner record padded to 70 MB on its line: status and apply read a bounded head of
    # it (read whole, status took 45 s and overflowed its output, so --break-lock never ran)
    simulator.robot_exec("robot1", ["su", "robot", "-c",
                                    "mkdir -p ~/rosdeploy/demo/.lock && { printf '%s' '{\"by\": \"alice@ops\"}'; "
                                    "head -c 70000000 /dev/zero | tr '\\0' ' '; echo; } "
                                    "> ~/rosdeploy/demo/.lock/owner"])
    run = deploy(fleet_file, "--limit", "robot1")
    assert run.host("robot1")["outcome"] == "locked" and "alice@ops" in run.host("robot1")["reason"]
    assert RobotShell(fleet, "robot1").containers() == {}
    status = rosdeploy("--json", "status", fleet_file, "--limit", "robot1")
    seen = status.doc["robots"][0]
    assert seen["state"] == "LOCKED" and "alice@ops" in seen["reason"], seen
    broke = deploy(fleet_file, "--limit", "robot1", "--break-lock")
    assert broke.host("robot1")["outcome"] == "deployed"
    # Two controllers: B waits for A's lock. B read robot1 before A switched it, and must start
    # from what A left (its way back on failure, its guard's `previous`), not from what it read.
    shell = RobotShell(fleet, "robot1")
    a = subprocess.Popen([sys.executable, "-m", "rosdeploy", "--json", "apply", str(fleet_file), "--yes", "--limit",
                          "robot1", "--version", "1.1.0"], stdout=subprocess.PIPE, text=True)
    end = time.monotonic() + 30
    while not shell.run("test -d ~/rosdeploy/demo/.lock && echo held || true").strip() and time.monotonic() < end:
        time.sleep(0.1)
    b = deploy(fleet_file, "--limit", "robot1", "--version", "1.0.0", "--lock-wait", "60s")
    a_out, _ = a.communicate(timeout=120)
    a_new = next(h for h in json.loads(a_out)["hosts"] if h["host"] == "robot1")["new_release"]
    assert b.host("robot1")["outcome"] == "deployed" and b.host("robot1")["old_release"] == a_new, b.stdout
    assert shell.history()[-1]["from"] == a_new and shell.current() == broke.host("robot1")["new_release"]


def _lock_robot1_as(pid: int) -> None:
    """robot1 locked as a run of this machine with this pid would have locked it."""
    held = owner.record("20261122-000000-run000", "ops@this-machine", "2026-11-22T00:00:00+00:00",
                        owner.this_controller(), pid)
    simulator.robot_exec("robot1", ["su", "robot", "-c", "mkdir -p ~/rosdeploy/demo/.lock && printf '%s\\n' "
                                    f"{shlex.quote(json.dumps(held, sort_keys=True))} > ~/rosdeploy/demo/.lock/owner"])


def test_a_lock_left_by_a_dead_run_of_this_machine_is_taken_over(fleet, fleet_file: Path) -> None:
    _lock_robot1_as(os.getpid())                  # a live run of this machine: left alone
    live = deploy(fleet_file, "--limit", "robot1")
    assert live.host("robot1")["outcome"] == "locked" and RobotShell(fleet, "robot1").containers() == {}
    child = subprocess.Popen(["true"])            # a run killed with -9: its pid is gone now
    child.wait()
    _lock_robot1_as(child.pid)
    run = deploy(fleet_file, "--limit", "robot1")
    assert run.code == EXIT_OK, run.stderr
    result = run.host("robot1")
    assert result["outcome"] == "deployed"
    took = [s for s in result["steps"] if s["name"] == "took over a dead run's lock"]
    assert took and f"process {child.pid} on this machine is gone" in took[0]["detail"]
    shell = RobotShell(fleet, "robot1")
    assert shell.run("ls -A ~/rosdeploy/demo | grep -c '^.lock' || true").strip() == "0", "no lock left"


@pytest.mark.parametrize("user,compose,home", [("root", "v2", "/root"), ("robot", "v1", "/home/robot")])
def test_users_and_compose_flavours(fleet, tmp_path: Path, user: str, compose: str, home: str) -> None:
    inventory = write_inventory(fleet, tmp_path, ansible_user=user, rosdeploy_compose=compose)
    fleet_file = write_fleet(tmp_path, inventory)
    run = deploy(fleet_file, "--limit", "robot1")
    assert run.code == EXIT_OK, run.stderr
    shell = RobotShell(fleet, "robot1")
    assert versions(shell) == {"driver": "1.0.0", "perception": "1.0.0"} and all_healthy(shell)
    assert shell.current(home=home) == run.host("robot1")["new_release"]
    env_mode = shell.run(f"stat -c %a {home}/rosdeploy/demo/current/.env").strip()
    assert env_mode == "600"
    made_by = {c["compose"].split(".")[0] for c in shell.containers().values()}
    assert made_by == {compose[1]}, f"containers must be created by Compose {compose}, not {made_by}"


def test_status_holds_its_connections_and_still_sees_a_robot_go_down(fleet, fleet_file: Path) -> None:
    first = rosdeploy("--json", "status", fleet_file)
    names = sorted(r.name for r in fleet.robots)
    assert {r["host"]: r["reachable"] for r in first.doc["robots"]} == {n: True for n in names}
    held = {c["robot"]: c for c in rosdeploy("--json", "connections").doc["connections"]}
    listed = time.monotonic()
    assert sorted(held) == names
    assert held["robot2"]["endpoint"] == f"[127.0.0.1]:{fleet.robot('robot2').ssh_port}"

    again = rosdeploy("--json", "status", fleet_file)
    assert again.doc["robots"] == first.doc["robots"]
    after = {c["robot"]: c for c in rosdeploy("--json", "connections").doc["connections"]}
    since = time.monotonic() - listed
    assert all(after[n]["age"] >= held[n]["age"] + since - 0.2 for n in names), "the same connections"

    container = fleet.robot("robot2").container
    subprocess.run(["docker", "stop", "-t", "1", container], check=True, capture_output=True)
    try:
        down = rosdeploy("--json", "status", fleet_file)
    finally:
        simulator.up(robots=len(fleet.robots), home=fleet.home)
    assert down.code == EXIT_PARTIAL
    rows = {r["host"]: r for r in down.doc["robots"]}
    assert not rows["robot2"]["reachable"] and "unreachable" in rows["robot2"]["error"]
    assert rows["robot1"]["reachable"] and rows["robot3"]["reachable"]

    closed = rosdeploy("--json", "connections", "--close")
    assert closed.doc["keeper"] and closed.doc["closed"] >= 2
