"""A robot's release area as the field leaves it, read and acted on by the real tool.

- A rollback to a release that never passed its gate here, failing it now, is not activated:
  the release the rollback left starts again (it was activated, `current` switched to the
  failed target, and status said MISMATCH).
- An operator's copy `releases/<id> copy` is not a release: pruning split its name on the
  space and deleted the real one (there: the release the robot had just switched to).
- A run of failed deploys pushed the release to go back to out of the 50 history lines the
  controller reads: "no previous release" while it was kept.
- A history file cut mid-line by a power loss glued the next record onto the cut line, so
  that record was lost.
"""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from rosdeploy.errors import EXIT_OK
from robots import RobotShell, all_healthy, rosdeploy, versions, write_fleet, write_inventory
from robots import apply as deploy

pytestmark = pytest.mark.integration

DIR = "/home/robot/rosdeploy/demo"


def history(shell: RobotShell) -> list[dict]:
    """The history's objects; a line that is no JSON object is kept as None (it must be seen)."""
    out = []
    for line in shell.run(f"cat {DIR}/history.jsonl").splitlines():
        try:
            value = json.loads(line)
        except ValueError:
            value = None
        out.append(value if isinstance(value, dict) else None)
    return out


def test_a_rollback_to_a_release_that_never_passed_its_gate_goes_back(fleet, fleet_file: Path) -> None:
    assert deploy(fleet_file, "--limit", "robot3").code == EXIT_OK
    shell = RobotShell(fleet, "robot3")
    good = shell.current()
    bad = deploy(fleet_file, "--limit", "robot3", "--version", "1.2.0-bad")
    assert bad.host("robot3")["outcome"] == "rolled-back", bad.host("robot3")
    assert shell.current() == good

    back = rosdeploy("--json", "rollback", fleet_file, "--yes", "--limit", "robot3", "--to", "1.2.0-bad")
    result = back.host("robot3")
    assert back.code != EXIT_OK and result["outcome"] == "failed", result
    assert "never passed its gate on this robot" in result["reason"] and f"back on {good}" in result["reason"]
    assert shell.current() == good, "the failed target was not activated"
    assert versions(shell) == {"driver": "1.0.0", "perception": "1.0.0"} and all_healthy(shell)
    last = history(shell)[-2:]
    assert [(e["event"], e["result"]) for e in last] == [("rollback", "failed"), ("auto-rollback", "active")]
    seen = rosdeploy("--json", "status", fleet_file, "--limit", "robot3").doc["robots"][0]
    assert seen["state"] == "healthy" and seen["release"] == good, seen
    shell.close()


def test_a_release_area_left_odd_by_people_and_power_cuts_still_rolls_back(fleet, tmp_path: Path) -> None:
    fleet_file = write_fleet(tmp_path, write_inventory(fleet, tmp_path), rollback={"keep_releases": 2})
    assert deploy(fleet_file, "--limit", "robot2").code == EXIT_OK
    shell = RobotShell(fleet, "robot2")
    first = shell.current()
    assert deploy(fleet_file, "--limit", "robot2", "--version", "1.1.0").code == EXIT_OK
    second = shell.current()
    failed = "1.2.0-bad-" + "f" * 12
    lines = [json.dumps({"event": "deploy", "release": failed, "result": "failed", "by": "ci", "time": "t"}),
             json.dumps({"event": "auto-rollback", "release": second, "rolled_back_from": failed,
                         "result": "active", "by": "ci", "time": "t"})] * 30
    text = "\n".join(lines)
    shell.run(f"cd {DIR} && cp -a releases/{first} 'releases/{first} copy' && touch -d 2020-01-01 "
              f"'releases/{first} copy' && printf '%s' '{text[:-40]}' >> history.jsonl && chown -R robot {DIR}")

    back = rosdeploy("--json", "rollback", fleet_file, "--yes", "--limit", "robot2")
    assert back.code == EXIT_OK, back.host("robot2")
    assert back.host("robot2")["outcome"] == "switched" and back.host("robot2")["new_release"] == first
    assert shell.current() == first and all_healthy(shell)
    kept = set(shell.run(f"ls {DIR}/releases").splitlines())
    assert {first, second, f"{first} copy"} <= kept, kept
    entries = history(shell)
    assert entries[-2] is None, "the cut line stays a line of its own"
    assert entries[-1] and entries[-1]["event"] == "rollback" and entries[-1]["release"] == first
    seen = rosdeploy("--json", "status", fleet_file, "--limit", "robot2").doc["robots"][0]
    assert seen["state"] == "healthy" and seen["release"] == first, seen
    shell.close()
