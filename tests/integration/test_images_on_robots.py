"""Images for robots that cannot reach the registry (docs/images.md), on the simulated fleet.

Robots are cut off from the registry with `sim.isolate`; each test checks what the robot's
own engine holds and runs, over SSH. Bytes are what rosdeploy's forwarder sent (the
`images` step), compared with the compressed sizes in the registry's own manifests, read
here with plain HTTP. The rate is measured independently, on the robot's interface.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import pytest

from rosdeploy import sim as simulator
from rosdeploy.errors import EXIT_OK
from robots import REPO, RobotShell, all_healthy, apply, rosdeploy, versions, write_fleet, write_inventory

pytestmark = pytest.mark.integration

REGISTRY = "http://127.0.0.1:5000"
MANIFEST_V2 = "application/vnd.docker.distribution.manifest.v2+json"
NODES = ("driver", "perception")


# ------------------------------------------------------------------ helpers

def manifest(repo: str, ref: str) -> tuple[bytes, str]:
    """(manifest bytes, digest) as the registry holds them."""
    request = urllib.request.Request(f"{REGISTRY}/v2/{repo}/manifests/{ref}", headers={"Accept": MANIFEST_V2})
    with urllib.request.urlopen(request, timeout=10) as response:
        return response.read(), response.headers["Docker-Content-Digest"]


def layers(tag: str) -> dict[str, int]:
    """Compressed layer sizes of both demo images at `tag`, by digest (shared layers once)."""
    found: dict[str, int] = {}
    for node in NODES:
        for layer in json.loads(manifest(f"demo/{node}", tag)[0])["layers"]:
            found[layer["digest"]] = layer["size"]
    return found


def put_manifest(repo: str, tag: str, body: bytes) -> None:
    request = urllib.request.Request(f"{REGISTRY}/v2/{repo}/manifests/{tag}", data=body, method="PUT",
                                     headers={"Content-Type": MANIFEST_V2})
    with urllib.request.urlopen(request, timeout=10) as response:
        assert response.status == 201


def sent(host: dict) -> int:
    """Bytes the forwarder sent to this robot in a run (0: the robot had everything)."""
    details = [s["detail"] for s in host["steps"] if s["name"] == "images"]
    return sum(int(re.search(r"(\d+) bytes sent", d).group(1)) for d in details)


def rx(robot: str) -> int:
    """Bytes received on the robot's network interfaces (loopback excluded): its link."""
    text = simulator.robot_exec(robot, ["cat", "/proc/net/dev"]).stdout
    return sum(int(line.split(":", 1)[1].split()[0]) for line in text.splitlines()[2:]
               if not line.strip().startswith("lo:"))


def robot_sh(robot: str, script: str) -> str:
    result = simulator.robot_exec(robot, ["sh", "-c", script], timeout=300)
    assert result.returncode == 0, result.stderr
    return result.stdout


def remove_images(robot: str, tags: tuple[str, ...] | None) -> None:
    """Drop the demo images of `tags` on a robot (and the layers no other image holds);
    `None`: every image, tagged or not.

    Again while one is left: a previous run's deploy guard may still be starting in the
    background (it runs from a release image, and leaves by itself once it finds itself
    disarmed), holding its image for a moment after the containers were removed; `rmi -f`
    then only untags it, and the image stays, dangling, until the guard is gone."""
    refs = " ".join(f"registry.local:5000/demo/{n}:{t}" for n in NODES for t in tags or ())
    remove = f"docker rmi -f {refs}" if tags is not None else "docker images -aq | xargs -r docker rmi -f"
    left = f"for ref in {refs}; do docker images -q \"$ref\"; done" if tags is not None else "docker images -aq"
    for _ in range(15):
        robot_sh(robot, f"docker ps -aq | xargs -r docker rm -f >/dev/null; {remove} >/dev/null 2>&1; "
                        "docker image prune -f >/dev/null; true")
        if not robot_sh(robot, left).strip():
            return
        time.sleep(1)


def image_ids(shell: RobotShell) -> dict[str, str]:
    out = shell.run("docker inspect --format '{{index .Config.Labels \"com.docker.compose.service\"}} {{.Image}}' "
                    "$(docker ps -q --filter label=com.docker.compose.project=demo)")
    return dict(line.split() for line in out.splitlines())


def ssh_fleet(fleet, tmp_path: Path, ssh: dict | None = None, **images) -> Path:
    extra = {"ssh": ssh} if ssh else {}
    return write_fleet(tmp_path, write_inventory(fleet, tmp_path), images={"via": "ssh", **images}, **extra)


# ------------------------------------------------------------------ tests

def test_isolated_robot_via_registry_fails_preflight_naming_the_registry(fleet, fleet_file: Path) -> None:
    remove_images("robot1", ("1.1.0",))
    simulator.isolate("robot1", "registry")
    run = apply(fleet_file, "--limit", "robot1", "--version", "1.1.0")
    reason = run.host("robot1")["reason"]
    assert run.host("robot1")["outcome"] == "failed", reason
    assert reason.startswith("preflight:") and "registry.local:5000" in reason and "via: ssh" in reason
    assert RobotShell(fleet, "robot1").containers() == {}, "nothing started"


def test_isolated_robot_over_ssh_deploy_upgrade_bad_release_and_rollback(fleet, tmp_path: Path) -> None:
    """robot2 keeps only the 1.2.0-bad images (the shared ROS base): what it lacks for 1.0.0 is
    that version's application layers, and an upgrade lacks only 1.1.0's."""
    robot_sh("robot2", "for n in driver perception; do docker pull -q registry.local:5000/demo/$n:1.2.0-bad; done")
    remove_images("robot2", ("1.0.0", "1.1.0"))
    simulator.isolate("robot2", "registry")
    fleet_file = ssh_fleet(fleet, tmp_path)
    shell = RobotShell(fleet, "robot2")

    first = apply(fleet_file, "--limit", "robot2")
    assert first.code == EXIT_OK, first.stdout + first.stderr
    missing = sum(size for digest, size in layers("1.0.0").items() if digest not in layers("1.2.0-bad"))
    assert 0 < sent(first.host("robot2")) <= 1.1 * missing
    assert versions(shell) == {"driver": "1.0.0", "perception": "1.0.0"} and all_healthy(shell)
    pinned = json.loads(shell.run("cat /home/robot/rosdeploy/demo/current/manifest.json"))["pins"]
    for node in NODES:
        ref = f"registry.local:5000/demo/{node}:1.0.0"
        assert pinned[ref]["digest"] == manifest(f"demo/{node}", "1.0.0")[1]
        assert image_ids(shell)[node] == pinned[ref]["image_id"], "the robot runs the pinned bytes"
    assert not shell.run("docker images -q --filter label=io.rosdeploy.stage"), "stage images are removed"

    upgrade = apply(fleet_file, "--limit", "robot2", "--version", "1.1.0")
    assert upgrade.code == EXIT_OK, upgrade.stdout
    changed = sum(size for digest, size in layers("1.1.0").items() if digest not in layers("1.0.0"))
    assert 0 < sent(upgrade.host("robot2")) <= 1.1 * changed + 1_000_000
    assert versions(shell) == {"driver": "1.1.0", "perception": "1.1.0"} and all_healthy(shell)

    bad = apply(fleet_file, "--limit", "robot2", "--version", "1.2.0-bad")
    assert bad.host("robot2")["outcome"] == "rolled-back", bad.host("robot2")["reason"]
    assert versions(shell) == {"driver": "1.1.0", "perception": "1.1.0"} and all_healthy(shell)

    back = rosdeploy("--json", "rollback", fleet_file, "--limit", "robot2", "--yes")
    assert back.code == EXIT_OK and back.host("robot2")["outcome"] == "switched"
    assert versions(shell) == {"driver": "1.0.0", "perception": "1.0.0"} and all_healthy(shell)
    status = rosdeploy("--json", "status", fleet_file, "--limit", "robot2")
    images = status.doc["robots"][0]["images"]
    assert images["registry.local:5000/demo/driver:1.0.0"]["digest"] == manifest("demo/driver", "1.0.0")[1]


def test_rate_cap_and_resume_after_the_link_drops(fleet, tmp_path: Path) -> None:
    """A first deploy onto a robot with no images (once, on robot3): capped at 2 MB/s,
    the link cut at about half, then applied again: only what had not arrived whole is sent."""
    remove_images("robot3", None)
    assert not robot_sh("robot3", "docker images -q"), "robot3 must start with no image"
    simulator.isolate("robot3", "registry")
    capped = ssh_fleet(fleet, tmp_path, ssh={"command_timeout": "40s", "connect_timeout": "3s"}, max_rate="2MB/s")
    # A process of its own, as an operator's would be: the next apply sees it gone and takes
    # over the lock its dropped link left on the robot.
    first = subprocess.Popen([sys.executable, "-m", "rosdeploy", "--json", "apply", str(capped), "--yes",
                              "--limit", "robot3"], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             env={**os.environ, "PYTHONPATH": str(REPO)})
    time.sleep(5)                       # connect, state, lock, the first manifests
    before, began = rx("robot3"), time.monotonic()
    time.sleep(22)
    rate = (rx("robot3") - before) / (time.monotonic() - began)
    assert 1.8e6 <= rate <= 2.2e6, f"{rate / 1e6:.2f} MB/s on the robot's link under a 2MB/s cap"
    time.sleep(4)                       # ~31 s at 2 MB/s: about half of the ~124 MB
    simulator.cut("robot3")
    out, err = first.communicate(timeout=120)
    dropped = json.loads(out)["hosts"][0]
    assert dropped["outcome"] in ("unreachable", "failed"), dropped
    simulator.heal("robot3")
    simulator.isolate("robot3", "registry")

    # robot3 only, as the first apply: robot1 and robot2 have every image and were sent nothing
    # (measured), their deploy of 1.0.0 (a canary wave first) only added ~7 s
    again = apply(ssh_fleet(fleet, tmp_path), "--limit", "robot3")
    host = next(h for h in again.doc["hosts"] if h["host"] == "robot3")
    assert host["outcome"] == "deployed", host["reason"]
    missing = layers("1.0.0")
    resent = sent(dropped) + sent(host) - sum(missing.values())
    assert sent(dropped) > 0.3 * sum(missing.values()), "the link dropped after a good part had arrived"
    assert resent <= max(missing.values()), f"re-sent {resent} bytes, more than one layer"
    assert versions(RobotShell(fleet, "robot3")) == {"driver": "1.0.0", "perception": "1.0.0"}


def test_bundle_deploys_to_isolated_robots_with_no_registry(fleet, tmp_path: Path) -> None:
    fleet_file = ssh_fleet(fleet, tmp_path)
    target = tmp_path / "release-1.1.0.tar"
    made = rosdeploy("--json", "bundle", fleet_file, "--version", "1.1.0", "--out", target)
    assert made.code == EXIT_OK, made.stderr
    assert made.doc["images"]["registry.local:5000/demo/driver:1.1.0"]["digest"] == \
        manifest("demo/driver", "1.1.0")[1]
    remove_images("robot1", ("1.1.0",))
    simulator.stop_registry()
    try:
        for robot in ("robot1", "robot2"):
            simulator.isolate(robot, "registry")
        run = apply(fleet_file, "--from-bundle", target, "--limit", "robot1,robot2", "--version", "1.1.0")
        assert run.code == EXIT_OK, run.stdout + run.stderr
        assert sent(run.host("robot1")) > 4_000_000, "robot1's application layers came from the bundle"
    finally:
        simulator.start_registry()
    for robot in ("robot1", "robot2"):
        shell = RobotShell(fleet, robot)
        assert versions(shell) == {"driver": "1.1.0", "perception": "1.1.0"} and all_healthy(shell)


def test_a_tag_moved_during_the_rollout_does_not_reach_later_waves(fleet, tmp_path: Path) -> None:
    fleet_file = write_fleet(tmp_path, write_inventory(fleet, tmp_path), rollout={"waves": [1, "100%"], "pause": "8s"})
    original, _ = manifest("demo/driver", "1.1.0")
    other, other_digest = manifest("demo/driver", "1.0.0")
    canary = RobotShell(fleet, "robot1")
    result: dict = {}
    thread = threading.Thread(target=lambda: result.update(run=apply(fleet_file, "--version", "1.1.0")))
    thread.start()
    try:
        deadline = time.monotonic() + 120
        while not canary.current().startswith("1.1.0") and time.monotonic() < deadline:
            time.sleep(0.3)
        put_manifest("demo/driver", "1.1.0", other)      # someone pushes over 1.1.0 after wave 1
        assert manifest("demo/driver", "1.1.0")[1] == other_digest
        thread.join(timeout=300)
    finally:
        put_manifest("demo/driver", "1.1.0", original)    # the sim's own 1.1.0 again, same digest
    run = result["run"]
    assert run.code == EXIT_OK, run.stdout
    canary_ids = image_ids(canary)
    for robot in ("robot2", "robot3"):
        host = run.host(robot)
        assert host["wave"] == 2
        assert any(s["name"] == "tag moved" for s in host["steps"]), "the run says the tag moved"
        assert image_ids(RobotShell(fleet, robot)) == canary_ids, "wave 2 runs what the canary ran"
