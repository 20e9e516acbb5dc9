"""The Ansible side: its own venv, an inventory from the template, timed playbook runs.

Every run gets a fresh ControlPath directory, so a run pays its SSH connection
setup once per host (as rosdeploy does every run), and the ControlPersist masters
it leaves are closed right after it (`ssh -O exit`), not left to time out.
"""
from __future__ import annotations

import json
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import jinja2

from fleetbench.proc import BenchError, Timed, check, log, timed

BENCH = Path(__file__).resolve().parents[1]
ANSIBLE_DIR = BENCH / "ansible"
VENV = BENCH / ".venv-ansible"
REQUIREMENT = "ansible-core~=2.19.0"


@dataclass(frozen=True)
class InventoryHost:
    name: str
    address: str
    port: int
    deploy_root: str


def ensure_venv() -> Path:
    """bench/.venv-ansible with ansible-core from PyPI; returns ansible-playbook's path."""
    playbook = VENV / "bin" / "ansible-playbook"
    if not playbook.exists():
        log(f"installing {REQUIREMENT} into {VENV}")
        check([sys.executable, "-m", "venv", str(VENV)], what="creating the Ansible venv")
        check([str(VENV / "bin" / "pip"), "install", "-q", REQUIREMENT], what="pip install ansible-core",
              timeout=900)
    return playbook


def version(playbook: Path) -> str:
    first = check([str(playbook), "--version"], what="ansible-playbook --version").stdout.splitlines()[0]
    return first.replace("ansible-playbook ", "").strip("[] ").replace("core ", "")


def write_inventory(path: Path, hosts: Sequence[InventoryHost], *, user: str, key_file: Path,
                    known_hosts: Path, groups: Mapping[str, Sequence[str]] | None = None) -> Path:
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(ANSIBLE_DIR), undefined=jinja2.StrictUndefined,
                             trim_blocks=True, lstrip_blocks=True, keep_trailing_newline=True)
    text = env.get_template("inventory.yml.j2").render(hosts=hosts, user=user, key_file=key_file,
                                                       known_hosts=known_hosts, groups=groups or {})
    path.write_text(text)
    return path


class Ansible:
    """ansible-playbook with bench/ansible/ansible.cfg and a per-run ControlPath dir."""

    def __init__(self, playbook_bin: Path, inventory: Path, work: Path) -> None:
        self.bin = playbook_bin
        self.inventory = inventory
        self.work = work

    def play(self, extra: Mapping[str, Any], *, forks: int, limit: str | None = None,
             playbook: str = "deploy.yml") -> Timed:
        control_dir = Path(tempfile.mkdtemp(prefix="cp-", dir=self.work))
        argv = [str(self.bin), "-i", str(self.inventory), str(ANSIBLE_DIR / playbook), "-f", str(forks),
                "-e", json.dumps(dict(extra))]
        if limit:
            argv += ["-l", limit]
        env = {"ANSIBLE_CONFIG": str(ANSIBLE_DIR / "ansible.cfg"),
               "ANSIBLE_SSH_CONTROL_PATH_DIR": str(control_dir),
               "ANSIBLE_LOCAL_TEMP": str(self.work / "ansible-tmp"),
               "ANSIBLE_NOCOLOR": "1"}
        try:
            return timed(argv, env=env)
        finally:
            close_masters(control_dir)


def close_masters(control_dir: Path) -> None:
    """End the ControlPersist masters a run left (one socket per host)."""
    for socket_path in sorted(control_dir.glob("*")):
        timed(["ssh", "-o", f"ControlPath={socket_path}", "-O", "exit", "bench-master"], timeout=30)
    shutil.rmtree(control_dir, ignore_errors=True)


def failed_hosts(result: Timed) -> list[str]:
    """Hosts the PLAY RECAP reports with failures or unreachable (for error messages)."""
    bad = []
    for line in result.stdout.splitlines():
        if ": ok=" in line and ("failed=0" not in line or "unreachable=0" not in line):
            bad.append(line.split(":", 1)[0].strip())
    return bad


def require(result: Timed, codes: Sequence[int], what: str) -> Timed:
    if result.code not in codes:
        fatal = [line[:1500] for line in result.stdout.splitlines() if line.startswith("fatal:")][:3]
        raise BenchError(f"{what}: ansible-playbook exit {result.code} (failed: {failed_hosts(result)}):\n"
                         + "\n".join(fatal) + f"\n{result.tail(12)}")
    return result
