"""What rosdeploy renders takes effect on the robot (issue 17), checked on the robots themselves.

Restart only what changed, per-robot files, the fake GPU runtime, host changes (udev rules)
with the right privileges, and log rotation that runs without rosdeploy.
"""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from rosdeploy.errors import EXIT_OK
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
