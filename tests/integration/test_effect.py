"""What rosdeploy renders takes effect on the robot (issue 17), checked on the robots themselves.

Restart only what changed, per-robot files, the fake GPU runtime, host changes (udev rules)
with the right privileges, and log rotation that runs without rosdeploy.
"""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from rosdeploy.errors import EXIT_OK
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
