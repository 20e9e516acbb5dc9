"""Assembling frozen hosts and groups: Ansible's variable precedence, lowest first."""
from __future__ import annotations

from itertools import chain
from pathlib import Path
from typing import Any, Iterable, Iterator

from rosdeploy.errors import Problem
from rosdeploy.inventory.draft import Draft, GroupDraft, HostDraft, Layer, Origin
from rosdeploy.inventory.graph import Graph
from rosdeploy.inventory.hostvars import check_layer, host_fields
from rosdeploy.inventory.model import Group, Inventory
from rosdeploy.model import Host, frozen_map


def assemble(draft: Draft, graph: Graph, root: Path, base: Path) -> Inventory:
    for layer in _all_layers(draft):
        draft.problems.extend(check_layer(layer))
    hosts: dict[str, Host] = {}
    members: dict[str, list[str]] = {name: [] for name in draft.groups}
    direct = _direct_groups(draft)
    for name, host in draft.hosts.items():
        groups = _host_groups(direct[name], graph)
        for group in groups:
            members[group].append(name)
        built = _build_host(host, groups, draft, base)
        if built is not None:
            hosts[name] = built
    if not draft.hosts and not draft.problems:
        draft.problems.append(Problem(str(base), None, "", "the inventory defines no hosts: add robots "
                                                           "under a group's hosts:"))
    groups = {name: _group(group, members[name], graph) for name, group in draft.groups.items()}
    return Inventory(str(root), frozen_map(hosts), frozen_map(groups))


def _all_layers(draft: Draft) -> Iterator[Layer]:
    for entity in chain(draft.groups.values(), draft.hosts.values()):
        yield from entity.inline
        yield from entity.files


def _direct_groups(draft: Draft) -> dict[str, list[str]]:
    """Host -> the groups listing it directly: one pass, not one scan of all groups per host."""
    index: dict[str, list[str]] = {name: [] for name in draft.hosts}
    for group_name, group in draft.groups.items():
        for host in group.hosts:
            index[host].append(group_name)
    return index


def _host_groups(direct: list[str], graph: Graph) -> tuple[str, ...]:
    every = frozenset({"all"}).union(*(graph.ancestors[g] for g in direct))
    return tuple(sorted(every, key=graph.order.__getitem__))


def _group(group: GroupDraft, hosts: list[str], graph: Graph) -> Group:
    merged, _ = _merge(chain(group.inline, group.files))
    return Group(group.name, tuple(hosts), tuple(group.children), graph.parents[group.name],
                 frozen_map(merged), group.source)


def _merge(layers: Iterable[Layer]) -> tuple[dict[str, Any], dict[str, Origin]]:
    merged: dict[str, Any] = {}
    origins: dict[str, Origin] = {}
    for layer in layers:
        merged.update(layer.vars)
        origins.update(dict.fromkeys(layer.vars, layer.origin))
    merged.pop("ansible_group_priority", None)  # a group setting, not a variable (as in Ansible)
    return merged, origins


def _host_layers(host: HostDraft, groups: tuple[str, ...], draft: Draft) -> list[Layer]:
    """Ansible's precedence, lowest first (see the module docstring)."""
    others = [draft.groups[g] for g in groups if g != "all"]
    root = draft.groups["all"]
    return [*root.inline, *chain.from_iterable(g.inline for g in others),
            *root.files, *chain.from_iterable(g.files for g in others),
            *host.inline, *host.files]


def _build_host(host: HostDraft, groups: tuple[str, ...], draft: Draft, base: Path) -> Host | None:
    layers = _host_layers(host, groups, draft)
    merged, origins = _merge(layers)
    fields, problems = host_fields(host, merged, origins, base)
    draft.problems.extend(problems)
    if problems:
        return None
    secrets = frozenset().union(*(layer.secrets for layer in layers))
    return Host(name=host.name, groups=groups, vars=frozen_map(merged), secret_values=secrets,
                source=host.source, **fields)


