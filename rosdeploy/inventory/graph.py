"""The group graph: Ansible's fix-ups, cycles, depth, priority and ancestors."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

from rosdeploy.errors import shown
from rosdeploy.inventory.draft import Draft, GroupDraft, Origin
from rosdeploy.inventory.hostvars import BadValue, to_int
from rosdeploy.yamlsrc import Doc


# Far deeper than any real fleet's group tree; past it, every group's ancestor set makes
# memory grow with the square of the depth.
MAX_DEPTH = 1000


class _TooDeep(Exception):
    def __init__(self, group: str) -> None:
        super().__init__(group)
        self.group = group


@dataclass(frozen=True)
class Graph:
    """Parents, depth and ancestors of every group, computed once for all hosts."""

    parents: Mapping[str, tuple[str, ...]]
    order: Mapping[str, tuple[int, int, str]]     # Ansible's sort key: depth, priority, name
    ancestors: Mapping[str, frozenset[str]]       # the group itself included

    @staticmethod
    def build(draft: Draft) -> "Graph | None":
        """None when the groups form a cycle or nest too deep (reported in draft.problems)."""
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
        try:
            for name in draft.groups:
                _walk_up(name, frozen, depth, ancestors)
        except _TooDeep as deep:
            draft.problems.append(Origin(Doc(draft.groups[deep.group].source, None)).problem(
                (), f"group {shown(deep.group)} is nested more than {MAX_DEPTH} groups below `all`: flatten the "
                    "group tree (each group's vars and ancestors grow with its depth)"))
            return None
        order = {name: (depth[name], _priority(draft.groups[name], draft), name) for name in draft.groups}
        return Graph(frozen, order, ancestors)


def _reconcile(draft: Draft) -> None:
    """Ansible's fix-ups: orphan groups go under `all`; hosts in no other group are `ungrouped`.

    Ansible tests a host's groups with their ancestors: a host listed under `ungrouped` leaves it
    when any other group holds it, and also when `ungrouped` itself sits under another group; it
    then belongs to no group, not even `all`'s hosts (only its own name selects it)."""
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
    listed = dict(ungrouped)
    nested = "ungrouped" in has_parent and _nested_ungrouped(draft)
    for host, groups in member_of.items():
        if groups - {"all", "ungrouped"} or (nested and host in listed):
            ungrouped.pop(host, None)
        elif host not in listed:
            ungrouped[host] = None


def _nested_ungrouped(draft: Draft) -> bool:
    """Whether a group other than `all` holds `ungrouped`, each such edge warned about at its line."""
    found = False
    for name, group in draft.groups.items():
        origin = group.children.get("ungrouped") if name not in ("all", "ungrouped") else None
        if origin is not None:
            found = True
            draft.warnings.append(origin.problem((), f"group {shown(name)} holds `ungrouped`, Ansible's implicit "
                                                     "group of the hosts in no other group: nested, it should not be. "
                                                     "As in Ansible, the hosts listed under `ungrouped` then belong "
                                                     f"to no group (not {shown(name)}, not `all`: only their own "
                                                     f"name selects them), and hosts in no group join {shown(name)}; "
                                                     "put the hosts in a group of their own instead",
                                                 severity="warning"))
    return found


def _report_cycles(draft: Draft) -> bool:
    """Depth-first, with an explicit stack: a chain of thousands of groups is a valid inventory
    (or an attack), and must not meet Python's recursion limit."""
    done: set[str] = set()
    found = False
    for root in draft.groups:
        if root in done:
            continue
        path, on_path = [root], {root: 0}
        stack = [iter(draft.groups[root].children.items())]
        while stack:
            step = next(stack[-1], None)
            if step is None:
                stack.pop()
                finished = path.pop()
                del on_path[finished]
                done.add(finished)
                continue
            child, origin = step
            if child in on_path or child == "all":
                cycle = _chain(path[on_path[child]:] + [child]) if child in on_path else f"{path[-1]} -> all"
                draft.problems.append(origin.problem((), f"group cycle {cycle}: a group cannot contain "
                                                         "itself (or `all`); remove this children entry"))
                found = True
            elif child not in done:
                on_path[child] = len(path)
                path.append(child)
                stack.append(iter(draft.groups[child].children.items()))
    return found


def _chain(names: list[str]) -> str:
    """`a -> b -> c`; a long cycle keeps its ends, so one message stays one readable line."""
    if len(names) > 9:
        names = [*names[:4], f"... ({len(names) - 8} more)", *names[-4:]]
    return " -> ".join(names)


def _walk_up(name: str, parents: Mapping[str, tuple[str, ...]], depth: dict[str, int],
             ancestors: dict[str, frozenset[str]]) -> None:
    """Depth and ancestors of `name` and every group above it, parents first (iteratively, as above)."""
    stack = [name]
    while stack:
        group = stack[-1]
        if group in depth:
            stack.pop()
            continue
        waiting = [p for p in parents[group] if p not in depth]
        if waiting:
            stack.extend(waiting)
            continue
        stack.pop()
        # Ansible's depth is the longest path from `all`: a group is deeper than every parent.
        depth[group] = 1 + max((depth[p] for p in parents[group]), default=-1)
        if depth[group] > MAX_DEPTH:
            raise _TooDeep(group)
        ancestors[group] = frozenset({group}).union(*(ancestors[p] for p in parents[group]))


def _priority(group: GroupDraft, draft: Draft) -> int:
    # Only inline vars set it, as in Ansible (group_vars files are read too late to reorder).
    for layer in reversed(group.inline):
        if "ansible_group_priority" in layer.vars:
            value = layer.vars["ansible_group_priority"]
            try:
                return to_int(value, "an integer, e.g. 10")
            except BadValue as bad:
                # YAML's spelling, as the file has it: `got true`, not Python's `got True`
                message = bad.message if value is not None and not isinstance(value, bool) else \
                    f"must be an integer, e.g. 10, got {_YAML_WORDS[value]}"
                draft.problems.append(layer.origin.problem(("ansible_group_priority",), message))
    return 1


_YAML_WORDS = {True: "true", False: "false", None: "null"}


