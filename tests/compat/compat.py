"""Running real Ansible beside rosdeploy, and the figures the suite reports.

Ansible is a test dependency (the `test` extra, installed by scripts/host-setup). Without it the
suite skips on a developer's machine but FAILS in CI (CI=true): a compatibility claim that CI never
checks proves nothing.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from rosdeploy.inventory import Inventory, load_inventory
from rosdeploy.inventory.templating import raw_vars

REPO = Path(__file__).resolve().parents[2]
REAL = REPO.parent / "shared" / "ansible-inventories"
SIDE = Path(__file__).with_name("ansible_side.py")
# Counted by the tests, printed at the end of the run (conftest.py) for the README's figure.
FIGURES: dict[str, list[int]] = {"inventories": [0, 0], "patterns": [0, 0]}


def count(kind: str, same: bool) -> None:
    FIGURES[kind][1] += 1
    FIGURES[kind][0] += int(same)


def require_ansible() -> None:
    if shutil.which("ansible-inventory") and shutil.which("ansible"):
        return
    message = "ansible-core is not installed (pip install -e '.[test]')"
    if os.environ.get("CI") == "true":
        pytest.fail(f"{message}: CI must run the Ansible compatibility suite")
    pytest.skip(message)


def real_inventories() -> list[Path]:
    if not REAL.is_dir():
        if os.environ.get("CI") == "true":
            raise RuntimeError(f"{REAL} is missing: CI has ../shared beside the clone")
        return []
    return sorted(p for p in REAL.iterdir() if p.is_dir())


def _env(tmp: Path) -> dict[str, str]:
    # No ansible.cfg of the machine or the user, no cache files in $HOME.
    config = tmp / "ansible.cfg"
    config.touch()
    return {**os.environ, "ANSIBLE_CONFIG": str(config), "ANSIBLE_HOME": str(tmp),
            "ANSIBLE_LOCAL_TEMP": str(tmp), "ANSIBLE_NOCOLOR": "1", "PYTHONWARNINGS": "ignore"}


def cli(args: list[str], tmp: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(args, capture_output=True, text=True, env=_env(tmp), cwd=tmp, timeout=120, check=False)


def ansible_list(inventory: Path, tmp: Path) -> dict[str, Any]:
    """`ansible-inventory --list` as {"groups": {group: set of hosts, descendants included}, "hostvars"}."""
    done = cli(["ansible-inventory", "-i", str(inventory), "--list"], tmp)
    assert done.returncode == 0, done.stderr
    data = json.loads(done.stdout)
    hostvars = data.get("_meta", {}).get("hostvars", {})
    direct = {name: (entry.get("hosts", []), entry.get("children", []))
              for name, entry in data.items() if name != "_meta"}

    def members(name: str, seen: frozenset[str] = frozenset()) -> set[str]:
        hosts, children = direct.get(name, ([], []))
        out = set(hosts)
        for child in children:
            if child not in seen:
                out |= members(child, seen | {name})
        return out

    groups = {name: members(name) for name in direct}
    groups["all"] = groups.get("all", set()) | set(hostvars)
    return {"groups": groups, "hostvars": {h: unwrap(v) for h, v in hostvars.items()}}


def ansible_host(inventory: Path, host: str, tmp: Path) -> dict[str, Any]:
    done = cli(["ansible-inventory", "-i", str(inventory), "--host", host], tmp)
    assert done.returncode == 0, done.stderr
    return unwrap(json.loads(done.stdout))


def list_hosts(inventory: Path, pattern: str, tmp: Path) -> set[str]:
    done = cli(["ansible", "-i", str(inventory), pattern, "--list-hosts"], tmp)
    assert done.returncode == 0, done.stderr
    lines = [line.strip() for line in done.stdout.splitlines()]
    return {line for line in lines[1:] if line}   # first line: "hosts (N):"


def ask(jobs: list[dict[str, Any]], tmp: Path) -> list[dict[str, Any]]:
    """Many questions to Ansible's own API, in one subprocess (see ansible_side.py)."""
    done = subprocess.run([sys.executable, str(SIDE)], input=json.dumps(jobs), capture_output=True, text=True,
                          env=_env(tmp), cwd=tmp, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def unwrap(value: Any) -> Any:
    """`ansible-inventory` prints an `!unsafe` value as {"__ansible_unsafe": text}: compare the text."""
    if isinstance(value, dict):
        if set(value) == {"__ansible_unsafe"}:
            return value["__ansible_unsafe"]
        return {k: unwrap(v) for k, v in value.items()}
    if isinstance(value, list):
        return [unwrap(v) for v in value]
    return value


def ours(inventory: Path) -> tuple[Inventory, dict[str, Any]]:
    """rosdeploy's view in the same shape: raw merged vars (Ansible's --list does not template)."""
    loaded = load_inventory(str(inventory))
    hostvars = {name: json.loads(json.dumps(dict(raw_vars(host.vars)))) for name, host in loaded.hosts.items()}
    groups = {name: set(group.hosts) for name, group in loaded.groups.items()}
    return loaded, {"groups": groups, "hostvars": hostvars}


def select(inventory: Inventory, pattern: str) -> set[str] | None:
    """rosdeploy's selection, None where it refuses the pattern."""
    from rosdeploy.errors import InventoryError
    try:
        return {host.name for host in inventory.select(pattern)}
    except InventoryError:
        return None
