"""What real Ansible makes of inventories: run in ONE subprocess for many questions (ansible-core API).

stdin: a JSON list of jobs {"inventory": PATH, "patterns": [...], "template": {host: [var, ...]},
"connection": [host, ...], "vault": [[label, password], ...]}; stdout: one JSON result per job, in order:

    {"patterns": {pattern: [hosts] | {"error": text}},
     "templated": {host: {var: value | {"error": text}}},
     "connection": {host: {"address", "port", "user", "key_file"}},
     "group_order": {group: [hosts in Ansible's order for group[n]]}}

Each CLI run (`ansible-inventory`, `ansible`) costs about a second; the API answers hundreds of
questions in that time. The suite still runs the real CLIs, on fewer questions.
"""
from __future__ import annotations

import json
import sys
import warnings
from typing import Any

warnings.simplefilter("ignore")

from ansible.parsing.dataloader import DataLoader  # noqa: E402
from ansible.parsing.vault import VaultSecret, VaultSecretsContext  # noqa: E402
from ansible.inventory.manager import InventoryManager  # noqa: E402
from ansible.playbook.play_context import PlayContext  # noqa: E402
from ansible.plugins.loader import connection_loader  # noqa: E402
from ansible.template import Templar  # noqa: E402
from ansible.utils.display import Display  # noqa: E402
from ansible.vars.hostvars import HostVars  # noqa: E402
from ansible.vars.manager import VariableManager  # noqa: E402

Display().verbosity = -1


def plain(value: Any) -> Any:
    """Ansible's tagged values as plain JSON values."""
    return json.loads(json.dumps(value, default=str))


def run(job: dict[str, Any]) -> dict[str, Any]:
    loader = DataLoader()
    loader.set_vault_secrets(_secrets(job))
    inventory = InventoryManager(loader=loader, sources=[job["inventory"]])
    manager = VariableManager(loader=loader, inventory=inventory)
    out: dict[str, Any] = {"patterns": {}, "templated": {}, "connection": {}}
    for pattern in job.get("patterns", []):
        try:
            out["patterns"][pattern] = [h.name for h in inventory.get_hosts(pattern)]
        except Exception as exc:  # noqa: BLE001 - any refusal is an answer here
            out["patterns"][pattern] = {"error": str(exc)}
    for host, names in job.get("template", {}).items():
        variables = manager.get_vars(host=inventory.get_host(host))
        variables["hostvars"] = HostVars(inventory=inventory, variable_manager=manager, loader=loader)
        templar = Templar(loader=loader, variables=variables)
        found: dict[str, Any] = {}
        for name in names:
            try:
                found[name] = plain(templar.template(variables[name]))
            except Exception as exc:  # noqa: BLE001
                found[name] = {"error": str(exc)}
        out["templated"][host] = found
    for host in job.get("connection", []):
        variables = manager.get_vars(host=inventory.get_host(host))
        ssh = connection_loader.get("ssh", PlayContext(), None)
        ssh.set_options(var_options=variables)
        out["connection"][host] = plain({"address": ssh.get_option("host"), "port": ssh.get_option("port"),
                                         "user": ssh.get_option("remote_user"),
                                         "key_file": ssh.get_option("private_key_file")})
    out["group_order"] = {name: [h.name for h in group.get_hosts()] for name, group in inventory.groups.items()}
    return out


def _secrets(job: dict[str, Any]) -> list[tuple[str, VaultSecret]]:
    return [(label, VaultSecret(password.encode())) for label, password in job.get("vault", [])]


def main() -> None:
    jobs = json.load(sys.stdin)
    # Inline `!vault` values are decrypted through a process-wide context, set once (as the CLIs do).
    VaultSecretsContext.initialize(VaultSecretsContext([s for job in jobs for s in _secrets(job)]))
    json.dump([run(job) for job in jobs], sys.stdout)


if __name__ == "__main__":
    main()
