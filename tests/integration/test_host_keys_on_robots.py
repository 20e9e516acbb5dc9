"""Host-key checking against a robot's real sshd: a name listed with two keys of one type.

OpenSSH accepts a robot that offers any key listed for its name. paramiko keeps one key per
type and name (the last), so a known_hosts that lists a robot's old and new key, in that
order or the other, was refused as "HOST KEY CHANGED": a false alarm on a working robot.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from rosdeploy.commands import Command
from rosdeploy.errors import HostKeyError
from rosdeploy.model import Host
from rosdeploy.sim import SimFleet
from rosdeploy.transport import SSHOptions, connect

ROBOT = "robot3"


def other_key(folder: Path, kind: str) -> str:
    """A public key of `kind` the robot does not have, as its known_hosts text."""
    path = folder / f"other-{kind}"
    subprocess.run(["ssh-keygen", "-q", "-t", kind, "-N", "", "-f", str(path)], check=True)
    kind_name, blob = path.with_suffix(".pub").read_text().split()[:2]
    return f"{kind_name} {blob}"


def robot_lines(sim_fleet: SimFleet) -> tuple[str, list[str]]:
    """The robot's known_hosts name and its real lines."""
    robot = sim_fleet.robot(ROBOT)
    name = f"[{robot.host}]:{robot.ssh_port}"
    lines = [line for line in sim_fleet.known_hosts.read_text().splitlines() if line.split(" ", 1)[0] == name]
    assert lines, f"the sim's known_hosts lists {name}"
    return name, lines


def run_true(sim_fleet: SimFleet, known: Path) -> None:
    robot = sim_fleet.robot(ROBOT)
    host = Host(name=ROBOT, groups=("all",), vars={}, address=robot.host, port=robot.ssh_port, user="robot",
                key_file=str(sim_fleet.key_file))
    transport = connect(host, SSHOptions(known_hosts=str(known)))
    try:
        assert transport.run(Command(("true",))).ok
    finally:
        transport.close()


@pytest.mark.parametrize("old_first", [True, False], ids=["old-key-first", "old-key-last"])
def test_a_robot_listed_with_an_old_and_its_real_key_connects(sim_fleet: SimFleet, tmp_path: Path,
                                                               old_first: bool) -> None:
    name, real = robot_lines(sim_fleet)
    kind = real[0].split()[1]
    old = [f"{name} {other_key(tmp_path, 'ed25519' if 'ed25519' in kind else 'rsa')}"]
    assert old[0].split()[1] == kind, "the old key has the real key's type"
    known = tmp_path / "known_hosts"
    known.write_text("\n".join(old + real if old_first else real + old) + "\n")
    run_true(sim_fleet, known)


def test_a_robot_whose_listed_keys_are_all_other_keys_is_refused_as_changed(sim_fleet: SimFleet,
                                                                           tmp_path: Path) -> None:
    name, real = robot_lines(sim_fleet)
    kind = "ed25519" if "ed25519" in real[0].split()[1] else "rsa"
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    known = tmp_path / "known_hosts"
    known.write_text(f"{name} {other_key(tmp_path / 'a', kind)}\n{name} {other_key(tmp_path / 'b', kind)}\n")
    with pytest.raises(HostKeyError) as caught:
        run_true(sim_fleet, known)
    assert "HOST KEY CHANGED" in str(caught.value) and ROBOT in str(caught.value)
