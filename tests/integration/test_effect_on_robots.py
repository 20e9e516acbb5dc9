"""What rosdeploy renders takes effect on the robot (issue 17), checked on the robots themselves.

Restart only what changed, per-robot files, the fake GPU runtime, host changes (udev rules)
with the right privileges, and log rotation that runs without rosdeploy.
"""
from __future__ import annotations

import time
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest
import yaml

from rosdeploy.errors import EXIT_OK, EXIT_PARTIAL
from rosdeploy.sim import provision, robot_exec
from robots import RobotShell, all_healthy, rosdeploy, versions, write_fleet, write_inventory
from robots import apply as deploy

pytestmark = pytest.mark.integration


def _services(fleet_file: Path) -> dict:
    return yaml.safe_load(fleet_file.read_text())["services"]


def _ids(shell: RobotShell) -> dict[str, tuple[str, str]]:
    return {s: (c["id"], c["started"]) for s, c in shell.containers().items()}


def test_an_upgrade_of_one_image_leaves_the_other_container_untouched(fleet, tmp_path: Path) -> None:
    inventory = write_inventory(fleet, tmp_path)
    driver = _services(write_fleet(tmp_path, inventory))["driver"]
    fleet_file = write_fleet(tmp_path, inventory, services={"driver": {**driver, "tag": "1.0.0"}})
    assert deploy(fleet_file, "--limit", "robot1").code == EXIT_OK
    shell = RobotShell(fleet, "robot1")
    before = _ids(shell)

    plan = rosdeploy("--json", "plan", fleet_file, "--limit", "robot1", "--version", "1.1.0")
    row = plan.doc["robots"][0]
    assert row["restarts"] == ["perception"] and row["keeps"] == ["driver"], row

    up = deploy(fleet_file, "--limit", "robot1", "--version", "1.1.0")
    assert up.code == EXIT_OK, up.stderr
    assert versions(shell) == {"driver": "1.0.0", "perception": "1.1.0"} and all_healthy(shell)
    after = _ids(shell)
    assert after["driver"] == before["driver"], "the driver's container was restarted"
    assert after["perception"][0] != before["perception"][0]

    again = deploy(fleet_file, "--limit", "robot1", "--version", "1.1.0")
    assert again.host("robot1")["outcome"] == "unchanged", "a container an earlier release left alone counts"

    back = rosdeploy("--json", "rollback", fleet_file, "--yes", "--limit", "robot1")
    assert back.code == EXIT_OK, back.stderr
    assert versions(shell) == {"driver": "1.0.0", "perception": "1.0.0"} and all_healthy(shell)
    assert _ids(shell)["driver"][0] == before["driver"][0], "rollback recreates only what differs"


def test_a_changed_params_file_recreates_only_the_services_that_mount_it_on_that_robot(fleet, tmp_path: Path) -> None:
    inventory = write_inventory(fleet, tmp_path)
    (tmp_path / "params").mkdir()
    for name in ("robot1", "robot2"):
        (tmp_path / "params" / f"{name}.yaml").write_text("speed: 1.0\nname: {{ inventory_hostname }}\n")
    perception = _services(write_fleet(tmp_path, inventory))["perception"]
    fleet_file = write_fleet(
        tmp_path, inventory, services={"perception": {**perception, "files": ["params"]}},
        files={"params": {"template": "params/{{ inventory_hostname }}.yaml", "target": "/config/params.yaml"}})
    assert deploy(fleet_file, "--limit", "robot1,robot2").code == EXIT_OK
    shells = {name: RobotShell(fleet, name) for name in ("robot1", "robot2")}
    before = {name: _ids(shell) for name, shell in shells.items()}
    read = "docker exec {} cat /config/params.yaml"
    assert shells["robot1"].run(read.format(before["robot1"]["perception"][0])) == "speed: 1.0\nname: robot1\n"

    (tmp_path / "params" / "robot1.yaml").write_text("speed: 2.5\nname: {{ inventory_hostname }}\n")
    plan = rosdeploy("--json", "plan", fleet_file, "--limit", "robot1")
    diffs = dict(plan.doc["robots"][0]["diffs"])
    assert "+speed: 2.5" in diffs["files/params"] and plan.doc["robots"][0]["restarts"] == ["perception"]
    run = deploy(fleet_file, "--limit", "robot1,robot2")
    assert run.code == EXIT_OK, run.stderr
    assert run.host("robot2")["outcome"] == "unchanged" and _ids(shells["robot2"]) == before["robot2"]
    after = _ids(shells["robot1"])
    assert after["driver"] == before["robot1"]["driver"], "the driver does not mount the params file"
    assert after["perception"][0] != before["robot1"]["perception"][0]
    assert shells["robot1"].run(read.format(after["perception"][0])) == "speed: 2.5\nname: robot1\n"
    assert all_healthy(shells["robot1"])


def test_a_gpu_robot_deploys_with_the_fake_nvidia_runtime_and_one_without_is_refused(fleet, tmp_path: Path) -> None:
    inventory = write_inventory(fleet, tmp_path, gpu=True)
    perception = _services(write_fleet(tmp_path, inventory))["perception"]
    fleet_file = write_fleet(tmp_path, inventory, services={"perception": {**perception, "gpu": True}},
                             rollout={"waves": ["100%"], "max_fail": 1})
    provision.gpu_runtime("robot1")
    try:
        run = deploy(fleet_file, "--limit", "robot1,robot2")
        assert run.host("robot1")["outcome"] == "deployed", run.host("robot1")
        shell = RobotShell(fleet, "robot1")
        assert all_healthy(shell)
        runtime = shell.run("docker inspect --format '{{.HostConfig.Runtime}}' "
                            + shell.containers()["perception"]["id"]).strip()
        assert runtime == "nvidia"
        refused = run.host("robot2")
        assert refused["outcome"] == "failed" and "no `nvidia` runtime" in refused["reason"], refused
        assert RobotShell(fleet, "robot2").containers() == {}, "nothing started on the refused robot"
    finally:
        robot_exec("robot1", ["/usr/local/sbin/robot-ctl", "reset"], check=True)   # no container on the runtime
        provision.gpu_runtime("robot1", present=False)


RULES = "/etc/udev/rules.d/99-rosdeploy-demo.rules"


def _rules(shell: RobotShell) -> str:
    return shell.run(f"cat {RULES} 2>/dev/null || true")


def test_udev_rules_installed_as_root_and_through_sudo_and_restored_by_rollback(fleet, tmp_path: Path) -> None:
    shells = {name: RobotShell(fleet, name) for name in ("robot1", "robot2")}
    for shell in shells.values():
        shell.run(f"rm -f {RULES}")
    root_inv = write_inventory(fleet, tmp_path, ansible_user="root")
    data = yaml.safe_load(root_inv.read_text())
    data["all"]["children"]["sim"]["hosts"]["robot2"]["ansible_user"] = "robot"   # through sudo -n
    root_inv.write_text(yaml.safe_dump(data, sort_keys=False))
    fleet_file = write_fleet(tmp_path, root_inv)
    plan = rosdeploy("--json", "plan", fleet_file, "--limit", "robot1")
    assert "udev rules" in plan.doc["robots"][0]["host_changes"][0]
    first = deploy(fleet_file, "--limit", "robot1,robot2")
    assert first.code == EXIT_OK, first.stderr
    for name, shell in shells.items():
        assert 'ATTRS{idProduct}=="6001"' in _rules(shell) and 'SYMLINK+="robot/motor"' in _rules(shell), name
        step = next(s for s in first.host(name)["steps"] if s["name"] == "host changes")
        assert f"installed {RULES}" in step["detail"] and "no udev on this robot" in step["detail"], step

    data["all"]["vars"]["udev"][0]["product"] = "6015"
    root_inv.write_text(yaml.safe_dump(data, sort_keys=False))
    assert deploy(fleet_file, "--limit", "robot1", "--version", "1.1.0").code == EXIT_OK
    assert 'ATTRS{idProduct}=="6015"' in _rules(shells["robot1"])
    back = rosdeploy("--json", "rollback", fleet_file, "--yes", "--limit", "robot1")
    assert back.code == EXIT_OK, back.stderr
    assert 'ATTRS{idProduct}=="6001"' in _rules(shells["robot1"]), "the rollback restores the kept release's rules"


def test_a_non_root_user_without_sudo_is_refused_in_preflight_and_keeps_running(fleet, tmp_path: Path) -> None:
    inventory = write_inventory(fleet, tmp_path)
    fleet_file = write_fleet(tmp_path, inventory)
    assert deploy(fleet_file, "--limit", "robot3").code == EXIT_OK
    shell = RobotShell(fleet, "robot3")
    before = _ids(shell)
    provision.sudo("robot3", present=False)
    # A host change that differs from what is installed (nothing that differs needs no root).
    fleet_file = write_fleet(tmp_path, inventory, logging={"rotate_every": "2m"})
    try:
        run = deploy(fleet_file, "--limit", "robot3", "--version", "1.1.0")
    finally:
        provision.sudo("robot3")
    result = run.host("robot3")
    assert result["outcome"] == "failed" and result["reason"].startswith("preflight:"), result
    assert all(w in result["reason"] for w in ("need root", "NOPASSWD", "--no-host-changes")), result
    assert _ids(shell) == before and versions(shell) == {"driver": "1.0.0", "perception": "1.0.0"}

    skipped = deploy(fleet_file, "--limit", "robot3", "--version", "1.1.0", "--no-host-changes")
    assert skipped.code == EXIT_OK and "--no-host-changes" in skipped.stderr


# ------------------------------------------------------------- log rotation (item 3), devices (item 2)

CRON, CONF = "/etc/cron.d/rosdeploy-demo", "/etc/logrotate.d/rosdeploy-demo"
PERIOD = 60    # logging.rotate_every: 1m, cron's floor


def _rotation_fleet(fleet, tmp_path: Path, **fleet_changes) -> Path:
    """robot1 as root, robot2 as `robot` (through sudo -n); logs rotate past 1 KB, every minute."""
    inventory = write_inventory(fleet, tmp_path, logrotate_size="1k")
    data = yaml.safe_load(inventory.read_text())
    data["all"]["children"]["sim"]["hosts"]["robot1"]["ansible_user"] = "root"
    inventory.write_text(yaml.safe_dump(data, sort_keys=False))
    return write_fleet(tmp_path, inventory, logging={"rotate_every": "1m"}, **fleet_changes)


def test_ros_logs_are_rotated_by_the_robots_own_schedule_with_rosdeploy_not_running(fleet, tmp_path: Path) -> None:
    fleet_file = _rotation_fleet(fleet, tmp_path)
    plan = rosdeploy("--json", "plan", fleet_file, "--limit", "robot1")
    assert any(f"run by {CRON} (`* * * * *`" in c for c in plan.doc["robots"][0]["host_changes"]), plan.doc
    run = deploy(fleet_file, "--limit", "robot1,robot2")
    assert run.code == EXIT_OK, run.stderr
    homes = {"robot1": "/root", "robot2": "/home/robot"}
    shells = {name: RobotShell(fleet, name) for name in homes}
    logs = {}
    for name, shell in shells.items():
        step = next(s for s in run.host(name)["steps"] if s["name"] == "host changes")
        assert f"installed {CRON}" in step["detail"] and "devices resolve: /dev/robot/motor" in step["detail"], step
        assert shell.run(f"stat -c '%U %a' {CRON} {CONF}").split() == ["root", "644", "root", "644"]
        logs[name] = f"{homes[name]}/rosdeploy/demo/logs/driver/big.log"
        # Past the 1 KB cap, owned by the container user: rosdeploy has exited, only cron is left.
        shell.run(f"head -c 4096 /dev/zero | tr '\\0' x > {logs[name]} && chown 1000:1000 {logs[name]}")
    inodes = {name: shell.run(f"stat -c %i {logs[name]}") for name, shell in shells.items()}
    began = time.monotonic()
    rotated: dict[str, float] = {}
    while len(rotated) < len(shells) and time.monotonic() - began < 3 * PERIOD:
        for name, shell in shells.items():
            if name not in rotated and shell.run(f"test -e {logs[name]}.1.gz && echo yes || true").strip():
                rotated[name] = time.monotonic() - began
        time.sleep(0.5)
    assert set(rotated) == set(shells), f"not rotated within {3 * PERIOD} s: {set(shells) - set(rotated)}"
    assert max(rotated.values()) <= PERIOD + 15, rotated      # one period, plus cron's start and logrotate's run
    for name, shell in shells.items():
        # copytruncate: the same file, emptied in place (a node writing to it keeps its descriptor)
        assert shell.run(f"stat -c '%i %s' {logs[name]}").split() == [inodes[name].strip(), "0"], name
        assert "big.log" in shell.run("cat /var/lib/logrotate/rosdeploy-demo.status"), name


def test_a_rollback_restores_the_previous_rotation_schedule(fleet, tmp_path: Path) -> None:
    fleet_file = _rotation_fleet(fleet, tmp_path)
    assert deploy(fleet_file, "--limit", "robot1").code == EXIT_OK
    shell = RobotShell(fleet, "robot1")
    assert "* * * * * root logrotate" in shell.run(f"cat {CRON}")
    slower = write_fleet(tmp_path, Path(yaml.safe_load(fleet_file.read_text())["inventory"]),
                         logging={"rotate_every": "10m"})
    assert deploy(slower, "--limit", "robot1", "--version", "1.1.0").code == EXIT_OK
    assert "*/10 * * * * root logrotate" in shell.run(f"cat {CRON}")
    back = rosdeploy("--json", "rollback", slower, "--yes", "--limit", "robot1")
    assert back.code == EXIT_OK, back.stderr
    assert "* * * * * root logrotate" in shell.run(f"cat {CRON}"), "the rollback restores the kept release's schedule"
    off = write_fleet(tmp_path, Path(yaml.safe_load(fleet_file.read_text())["inventory"]),
                      logging={"rotate_every": "off"})
    skipped = deploy(off, "--limit", "robot1", "--version", "1.1.0", "--no-host-changes")
    assert skipped.code == EXIT_OK and "--no-host-changes" in skipped.stderr
    assert "* * * * * root logrotate" in shell.run(f"cat {CRON}"), "--no-host-changes leaves the schedule alone"
    assert deploy(off, "--limit", "robot1").code == EXIT_OK      # 1.0.0 again, a release of its own
    assert shell.run(f"ls {CRON} {CONF} 2>/dev/null || true") == "", "rotate_every: off removes the schedule"


def test_a_no_op_apply_puts_back_host_changes_edited_on_the_robot_and_status_shows_them(
        fleet, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ROSDEPLOY_PENDING_DIR", str(tmp_path / "pending"))    # the waiting-window record
    fleet_file = _rotation_fleet(fleet, tmp_path)     # robot2 reaches root through sudo -n
    assert deploy(fleet_file, "--limit", "robot2").code == EXIT_OK
    shell = RobotShell(fleet, "robot2")
    before, cron = _ids(shell), shell.run(f"cat {CRON}")
    shell.run(f"echo '# edited by hand' >> {CRON} && rm -f {RULES}")
    looked = rosdeploy("--json", "status", fleet_file, "--limit", "robot2")
    row = looked.doc["robots"][0]
    assert looked.code == EXIT_PARTIAL and row["drift"] is True and set(row["host_drift"]) == {CRON, RULES}, row
    assert "`apply` puts them back" in row["reason"], row
    planned = rosdeploy("--json", "plan", fleet_file, "--limit", "robot2").doc["robots"][0]
    assert planned["up_to_date"] and set(planned["host_drift"]) == {CRON, RULES}, planned

    left = deploy(fleet_file, "--limit", "robot2", "--no-host-changes")
    assert left.host("robot2")["outcome"] == "unchanged" and "edited by hand" in shell.run(f"cat {CRON}")
    opens = datetime.now(timezone.utc) + timedelta(hours=2)     # a udevadm trigger waits for the window too
    closed = deploy(_rotation_fleet(fleet, tmp_path, window={"start": opens.strftime("%H:%M"), "duration": "1h"}),
                    "--limit", "robot2")
    waiting = closed.host("robot2")
    assert closed.code == EXIT_PARTIAL and waiting["outcome"] == "waiting-window", waiting
    assert all(w in waiting["reason"] for w in ("maintenance window", CRON, RULES, "put back then")), waiting
    assert "edited by hand" in shell.run(f"cat {CRON}") and _ids(shell) == before
    fleet_file = _rotation_fleet(fleet, tmp_path)
    fixed = deploy(fleet_file, "--limit", "robot2")
    result = fixed.host("robot2")
    assert fixed.code == EXIT_OK and result["outcome"] == "unchanged", result
    assert all(w in result["reason"] for w in ("put back", CRON, RULES)), result
    assert shell.run(f"cat {CRON}") == cron and 'SYMLINK+="robot/motor"' in _rules(shell)
    assert _ids(shell) == before, "putting host changes back restarts nothing"
    again = rosdeploy("--json", "status", fleet_file, "--limit", "robot2")
    assert again.code == EXIT_OK and again.doc["robots"][0]["drift"] is False, again.doc


def test_a_device_the_new_rules_should_create_is_checked_after_the_trigger(fleet, tmp_path: Path) -> None:
    inventory = write_inventory(fleet, tmp_path)
    driver = _services(write_fleet(tmp_path, inventory))["driver"]
    fleet_file = write_fleet(tmp_path, inventory)
    assert deploy(fleet_file, "--limit", "robot3").code == EXIT_OK
    shell = RobotShell(fleet, "robot3")
    before = _ids(shell)
    data = yaml.safe_load(inventory.read_text())
    data["all"]["vars"]["udev"].append({"symlink": "robot/lidar", "subsystem": "tty", "vendor": "10c4",
                                        "product": "ea60"})
    data["all"]["children"]["sim"]["hosts"]["robot3"]["devices"]["lidar"] = "/dev/robot/lidar"
    inventory.write_text(yaml.safe_dump(data, sort_keys=False))
    with_lidar = write_fleet(tmp_path, inventory,
                             services={"driver": {**driver, "devices": [*driver.get("devices", []), "lidar"]}})
    run = deploy(with_lidar, "--limit", "robot3", "--version", "1.1.0")
    result = run.host("robot3")
    # Preflight let it through (a udev rule creates it); the sim has no udev, so after the
    # install it is still missing: refused before anything restarts, the old rules back.
    assert result["outcome"] == "failed" and "host changes failed, nothing restarted" in result["reason"], result
    assert "/dev/robot/lidar (`devices.lidar`" in result["reason"] and 'SYMLINK+="robot/lidar"' in result["reason"]
    assert _ids(shell) == before and versions(shell) == {"driver": "1.0.0", "perception": "1.0.0"}
    assert "robot/lidar" not in _rules(shell), "the running release's rules are installed again"
