"""The group graph: Ansible's fix-ups, cycles, depth, priority and ancestors."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

from rosdeploy.inventory.draft import Draft, GroupDraft, Origin
from rosdeploy.inventory.hostvars import BadValue, to_int
from rosdeploy.yamlsrc import Doc


@dataclass(frozen=True)
class Graph:
    """Parents, depth and ancestors of every group, computed once for all hosts."""

    parents: Mapping[str, tuple[str, ...]]
    order: Mapping[str, tuple[int, int, str]]     # Ansible's sort key: depth, priority, name
    ancestors: Mapping[str, frozenset[str]]       # the group itself included

    @staticmethod
    def build(draft: Draft) -> "Graph | None":
        """None when the groups form a cycle (reported in draft.problems)."""
        _reconcile(draft)
        if _report_cycles(draft):
            return None
        parents: dict[str, list[str]] = {name: [] for name in draft.groups}
        for name, group in draft.groups.items():
            for child in group.children:
                parents[child].append(name)
        frozen = {name: tuple(found) for name, found in parents.items()}
        depth: dict[str, int] = {}
        ancestors: dict[str, frozenset[str]] = {}
        for name in draft.groups:
            _walk_up(name, frozen, depth, ancestors)
        order = {name: (depth[name], _priority(draft.groups[name], draft), name) for name in draft.groups}
        return Graph(frozen, order, ancestors)


def _reconcile(draft: Draft) -> None:
    """Ansible's fix-ups: orphan groups go under `all`; hosts in no other group are `ungrouped`."""
    has_parent = {child for group in draft.groups.values() for child in group.children}
    root = draft.groups["all"]
    for name, group in draft.groups.items():
        if name != "all" and name not in has_parent:
            root.children.setdefault(name, Origin(Doc(group.source, None)))
    member_of: dict[str, set[str]] = {name: set() for name in draft.hosts}
    for name, group in draft.groups.items():
        for host in group.hosts:
            member_of[host].add(name)
    ungrouped = draft.groups["ungrouped"].hosts
    for host, groups in member_of.items():
        if groups - {"all", "ungrouped"}:
            ungrouped.pop(host, None)
        else:
            ungrouped[host] = None


def _report_cycles(draft: Draft) -> bool:
    state: dict[str, int] = {}   # 1: on the current path, 2: done
    found = False

    def visit(name: str, path: list[str]) -> None:
        nonlocal found
        state[name] = 1
        for child, origin in draft.groups[name].children.items():
            if state.get(child) == 1 or child == "all":
                cycle = " -> ".join(path[path.index(child):] + [child]) if child in path else f"{name} -> all"
                draft.problems.append(origin.problem((), f"group cycle {cycle}: a group cannot contain "
                                                         "itself (or `all`); remove this children entry"))
                found = True
            elif child not in state:
                visit(child, path + [child])
        state[name] = 2

    for name in draft.groups:
        if name not in state:
            visit(name, [name])
    return found


def _walk_up(name: str, parents: Mapping[str, tuple[str, ...]], depth: dict[str, int],
             ancestors: dict[str, frozenset[str]]) -> None:
    if name in depth:
        return
    for parent in parents[name]:
        _walk_up(parent, parents, depth, ancestors)
    # Ansible's depth is the longest path from `all`: a group is deeper than every parent.
    depth[name] = 1 + max((depth[p] for p in parents[name]), default=-1)
    ancestors[name] = frozenset({name}).union(*(ancestors[p] for p in parents[name]))


def _priority(group: GroupDraft, draft: Draft) -> int:
    # Only inline vars set it, as in Ansible (group_vars files are read too late to reorder).
    for layer in reversed(group.inline):
        if "ansible_group_priority" in layer.vars:
            try:
                return to_int(layer.vars["ansible_group_priority"], "an integer, e.g. 10")
            except BadValue as bad:
                draft.problems.append(layer.origin.problem(("ansible_group_priority",), bad.message))
    return 1


