"""SSH keys of the simulated fleet, all made on the host with ssh-keygen.

Host keys are generated here, not by the robots, so known_hosts holds keys we
know first-hand: a test that trusts it trusts nothing learned over the network.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterable

from rosdeploy.sim.model import SimRobot
from rosdeploy.sim.proc import run


def ensure_keypair(private: Path, comment: str) -> Path:
    """Make an ed25519 key pair at `private` (and .pub) unless one is there."""
    if not (private.exists() and public_of(private).exists()):
        private.parent.mkdir(parents=True, exist_ok=True)
        private.unlink(missing_ok=True)
        public_of(private).unlink(missing_ok=True)
        run(("ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-C", comment, "-f", str(private)),
            what=f"ssh-keygen {private.name}")
    private.chmod(0o600)
    return private


def new_keypair(private: Path, comment: str) -> Path:
    """A fresh key pair, replacing any old one at that path."""
    private.unlink(missing_ok=True)
    public_of(private).unlink(missing_ok=True)
    return ensure_keypair(private, comment)


def public_of(private: Path) -> Path:
    return private.with_name(private.name + ".pub")


def public_key(private: Path) -> str:
    """`ssh-ed25519 AAAA...` without the comment."""
    return " ".join(public_of(private).read_text().split()[:2])


def known_hosts_line(robot: SimRobot, key: str) -> str:
    # OpenSSH (and paramiko) write non-22 ports as [host]:port.
    return f"[{robot.host}]:{robot.ssh_port} {key}"


def known_hosts_text(entries: Iterable[tuple[SimRobot, str]]) -> str:
    return "".join(known_hosts_line(robot, key) + "\n" for robot, key in entries)
