"""Many lightweight SSH targets on loopback: one host `sshd` per target.

Each target is a separate sshd process (run as root) on 127.0.0.1:<port> with its
own generated host key. Every target logs in as one dedicated user, `rdbench`, with a
client key generated here; like the sim robots' `robot` user it is in the `docker`
group, so its `docker` is the host's engine. A dedicated user rather than root:
root's ~/.bashrc on a developer machine (pyenv init, cargo env...) runs on every SSH
command and would be measured instead of the tools (it cost 0.2 s per command here).
The user has /bin/sh as its shell, a home in the temp dir, and is removed at the end.
No config file is read (`-f /dev/null`), every option is on the command line; no
PAM (`UsePAM no`: key logins only, the account's password is `*`, not locked `!`).
StrictModes is off because the authorized_keys file lives in the temp dir, not in a home.
"""
from __future__ import annotations

import pwd
import shutil
import socket
import subprocess
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from fleetbench.proc import BenchError, check

SSHD = "/usr/sbin/sshd"    # sshd re-execs itself: it must be started by absolute path
PRIVSEP_DIR = Path("/run/sshd")
USER = "rdbench"
USER_MARK = "rosdeploy fleet_bench fan-out target"    # GECOS: tells our user from anybody else's


# ------------------------------------------------------------------ login user

def ensure_user(home: Path) -> str:
    """The targets' login user (re-created if an earlier, killed run left it)."""
    try:
        entry = pwd.getpwnam(USER)
    except KeyError:
        entry = None
    if entry is not None and entry.pw_gecos != USER_MARK:
        raise BenchError(f"a user {USER!r} exists and is not the benchmark's; remove it or rename USER")
    if entry is not None:
        remove_user()
    check(["useradd", "--system", "--no-create-home", "--home-dir", str(home), "--shell", "/bin/sh",
           "--groups", "docker", "--comment", USER_MARK, USER], what=f"useradd {USER}")
    check(["usermod", "-p", "*", USER], what=f"unlocking {USER} for key logins")
    home.mkdir(parents=True, exist_ok=True)
    shutil.chown(home, USER, USER)
    return USER


def remove_user() -> None:
    try:
        if pwd.getpwnam(USER).pw_gecos == USER_MARK:
            check(["userdel", USER], what=f"userdel {USER}")
    except KeyError:
        pass


@dataclass(frozen=True)
class Target:
    name: str      # "t001"
    port: int
    host_key: Path

    @property
    def endpoint(self) -> str:
        return f"[127.0.0.1]:{self.port}"     # as known_hosts names a non-22 port


def keygen(path: Path, comment: str) -> Path:
    check(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-C", comment, "-f", str(path)],
          what=f"ssh-keygen {path.name}")
    return path


def public_key(private: Path) -> str:
    return " ".join(private.with_name(private.name + ".pub").read_text().split()[:2])


def make_targets(work: Path, count: int, base_port: int) -> list[Target]:
    keys = work / "host-keys"
    keys.mkdir(parents=True, exist_ok=True)
    targets = [Target(f"t{i:03d}", base_port + i - 1, keys / f"t{i:03d}") for i in range(1, count + 1)]
    with ThreadPoolExecutor(max_workers=8) as pool:
        list(pool.map(lambda t: keygen(t.host_key, t.name), targets))
    return targets


def write_known_hosts(path: Path, targets: Sequence[Target]) -> Path:
    path.write_text("".join(f"{t.endpoint} {public_key(t.host_key)}\n" for t in targets))
    return path


def sshd_argv(target: Target, authorized_keys: Path) -> list[str]:
    options = {
        "ListenAddress": f"127.0.0.1:{target.port}",
        "UsePAM": "no",
        "PidFile": "none",
        "AuthorizedKeysFile": str(authorized_keys),
        "PermitRootLogin": "no",
        "AllowUsers": USER,
        "PubkeyAuthentication": "yes",
        "PasswordAuthentication": "no",
        "KbdInteractiveAuthentication": "no",
        "StrictModes": "no",
        "UseDNS": "no",
        "MaxStartups": "200:30:400",
        "MaxSessions": "64",
        "Subsystem": "sftp internal-sftp",
        "LogLevel": "ERROR",
    }
    argv = [SSHD, "-D", "-e", "-f", "/dev/null", "-h", str(target.host_key)]
    for key, value in options.items():
        argv += ["-o", f"{key} {value}"]
    return argv


class SshdFarm:
    """Starts one sshd per target; `stop()` ends exactly the processes it started."""

    def __init__(self, work: Path, targets: Sequence[Target], authorized_key: str) -> None:
        self.targets = list(targets)
        self.authorized_keys = work / "authorized_keys"
        self.authorized_keys.write_text(authorized_key + "\n")
        self.authorized_keys.chmod(0o644)      # read with the login user's rights
        self.log = work / "sshd.log"
        self.procs: list[subprocess.Popen] = []

    def start(self, timeout: float = 30.0) -> None:
        busy = [t.port for t in self.targets if _listening(t.port)]
        if busy:
            raise BenchError(f"ports {busy[:5]}... are already in use on 127.0.0.1; stop whatever listens there "
                             "or choose another --fanout-port")
        PRIVSEP_DIR.mkdir(mode=0o755, exist_ok=True)
        with self.log.open("ab") as sink:
            for target in self.targets:
                self.procs.append(subprocess.Popen(sshd_argv(target, self.authorized_keys), stdout=sink,
                                                   stderr=sink, stdin=subprocess.DEVNULL))
        self._wait_greeting(timeout)

    def _wait_greeting(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        for target, proc in zip(self.targets, self.procs, strict=True):
            while not _greets(target.port):
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise BenchError(f"sshd for {target.name} on port {target.port} did not come up "
                                     f"(exit {proc.poll()}); see {self.log}")
                time.sleep(0.05)

    def stop(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.terminate()
        for proc in self.procs:
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)
        self.procs.clear()


def _listening(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.5):
            return True
    except OSError:
        return False


def _greets(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=1) as conn:
            conn.settimeout(1)
            return conn.recv(8).startswith(b"SSH-")
    except OSError:
        return False
