"""The inventory's public values: groups and the whole inventory."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from rosdeploy import patterns
from rosdeploy.errors import Problem
from rosdeploy.model import Host


@dataclass(frozen=True)
class Group:
    name: str
    hosts: tuple[str, ...]       # every host in the group or a descendant group, in Ansible's order
    children: tuple[str, ...]
    parents: tuple[str, ...]
    vars: Mapping[str, Any]      # the group's own vars: inline, then its group_vars files
    source: str                  # "file:line" where it was first declared


@dataclass(frozen=True)
class Inventory:
    path: str
    hosts: Mapping[str, Host]    # declaration order
    groups: Mapping[str, Group]
    warnings: tuple[Problem, ...] = ()   # what Ansible would accept but is worth saying (another tool's vars)

    def select(self, pattern: str | None, warnings: list[Problem] | None = None) -> tuple[Host, ...]:
        """Hosts an Ansible pattern (`--limit`) selects, inventory order; None → all.

        A term that matches nothing is a warning appended to `warnings` (as in Ansible)."""
        members = {name: group.hosts for name, group in self.groups.items()}
        names = patterns.select(pattern, tuple(self.hosts), members, warnings=warnings)
        return tuple(self.hosts[name] for name in names)
