"""Ansible inventories, read the way Ansible reads them, turned into frozen `Host`s.

A team's existing inventory must work unchanged, so this follows Ansible's own
rules rather than inventing better ones:

* formats: YAML (`all:`/`children:`/`hosts:`/`vars:`), INI (`[g]`, `[g:vars]`,
  `[g:children]`, inline `k=v` parsed with `ast.literal_eval` like Ansible,
  `host[01:03]` ranges, `host:port`) and TOML (Ansible's toml plugin). As Ansible
  tries its plugins: `.toml` is TOML; a file with no extension, or `.yml`, `.yaml`,
  `.json`, is YAML when it holds a mapping, else INI; any other name is INI.
* `-i DIR` reads every inventory file below DIR (hidden files, `group_vars/`,
  `host_vars/` and docs/backups skipped), in sorted order.
* `group_vars/` and `host_vars/` beside the inventory: `NAME`, `NAME.yml`,
  `NAME.yaml`, `NAME.json`, or a directory `NAME/` of such files (sorted).
* precedence, low to high, exactly Ansible's default VARIABLE_PRECEDENCE:
  inline vars of `all` < inline vars of the other groups < group_vars/all <
  group_vars of the other groups < inline host vars < host_vars files. Groups
  are ordered by (depth, ansible_group_priority, name), so a child beats its
  parent and, at equal depth, the alphabetically later group wins. Top-level
  keys replace, nested maps are not merged (Ansible's hash_behaviour=replace).

Stricter than Ansible where silence would deploy the wrong thing: every
problem is collected (file, line, key path, fix) and raised as one
InventoryError; a near-miss of a variable rosdeploy reads (`ros_domian_id`) is
an error, not a new free-form variable.
"""
from __future__ import annotations

from pathlib import Path

from rosdeploy.errors import InventoryError
from rosdeploy.inventory.discovery import Reader, parse_sources
from rosdeploy.inventory.draft import Draft
from rosdeploy.inventory.graph import Graph
from rosdeploy.inventory.hostvars import CONSUMED_VARS, PREFIXED_VARS
from rosdeploy.inventory.merge import assemble
from rosdeploy.inventory.model import Group, Inventory
from rosdeploy.inventory.vars_files import attach_vars_files
from rosdeploy.vault import Vault

__all__ = ["CONSUMED_VARS", "PREFIXED_VARS", "Group", "Inventory", "load_inventory"]


def load_inventory(path: str, vault: Vault | None = None) -> Inventory:
    """Read an inventory file or directory; InventoryError listing every problem found.

    Without a `vault`, vault files are decrypted with the password from the
    environment (ROSDEPLOY_VAULT_PASSWORD[_FILE]) and never with a prompt.
    """
    root = Path(path)
    draft = Draft(str(root))
    reader = Reader(vault or Vault(), draft.warnings)
    base = parse_sources(root, reader, draft)
    attach_vars_files(base, reader, draft)
    graph = Graph.build(draft)
    inventory = assemble(draft, graph, root, base) if graph else None
    if draft.problems or inventory is None:
        raise InventoryError(dict.fromkeys(draft.problems))
    return inventory
