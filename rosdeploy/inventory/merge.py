"""Assembling frozen hosts and groups: Ansible's variable precedence, lowest first."""
from __future__ import annotations

import os
from dataclasses import replace
from itertools import chain
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

from rosdeploy.errors import Problem, shown
from rosdeploy.inventory.draft import Draft, GroupDraft, HostDraft, Layer, Origin, split_where
from rosdeploy.inventory.graph import Graph
from rosdeploy.inventory.ranges import plain_odd_groups_warning
from rosdeploy.inventory.hostvars import CONNECTION, PREFIX, BadValue, check_layer, connection_ignored, host_fields
from rosdeploy.inventory.model import Group, Inventory
from rosdeploy.inventory.templating import HostVars, TemplateFailed, raw_vars
from rosdeploy.model import Host, frozen_map


def assemble(draft: Draft, graph: Graph, root: Path, base: Path) -> Inventory:
    for layer in _all_layers(draft):
        errors, warnings = check_layer(layer)
        draft.problems.extend(errors)
        draft.warnings.extend(warnings)
    for name in sorted(draft.hosts.keys() & draft.groups.keys()):
        # Ansible warns too ("Found both group and host with same name"): a pattern selects the host
        file, line = split_where(draft.hosts[name].source)
        draft.warnings.append(Problem(file, line, "", f"{shown(name)} is both a host and a group: `--limit {name}` "
                                      "selects the host only, as in Ansible; rename one", severity="warning"))
    direct = _direct_groups(draft)
    host_groups = {name: _host_groups(direct[name], graph) for name in draft.hosts}
    inline = {name: [_no_priority(layer) for layer in group.inline] for name, group in draft.groups.items()}
    ordered = {name: ansible_order(name, draft) for name in draft.groups}
    hostvars: dict[str, HostVars] = {}
    magic: dict[str, Any] = {"groups": {name: list(hosts) for name, hosts in ordered.items()}, "hostvars": hostvars}
    # every host's vars exist before any is read: `hostvars['b']` in a's vars finds b, wherever b is
    # declared (Ansible's order does not matter there either)
    merged = {name: _host_vars(host, host_groups[name], draft, inline, magic) for name, host in draft.hosts.items()}
    hosts: dict[str, Host] = {}
    for name, host in draft.hosts.items():
        built = _build_host(host, host_groups[name], draft, *merged[name])
        if built is not None:
            hosts[name] = built
    if not draft.hosts and not draft.problems:
        draft.problems.append(Problem(str(base), None, "", "the inventory defines no hosts: add robots "
                                                           "under a group's hosts:"))
    groups = {name: _group(group, inline[name], ordered[name], graph) for name, group in draft.groups.items()}
    plain = plain_odd_groups_warning(draft)
    if plain is not None:
        draft.warnings.append(plain)
    return Inventory(str(root), frozen_map(hosts), frozen_map(groups), _folded(draft.warnings))


def ansible_order(name: str, draft: Draft) -> tuple[str, ...]:
    """A group's hosts in Ansible's order (Group.get_hosts): its own hosts as added, then its
    descendants' level by level, children in the order they were added; `group[0]` indexes this."""
    seen_groups, level, out = {name}, [name], dict.fromkeys(draft.groups[name].hosts)
    while level:
        following = []
        for group in level:
            for child in draft.groups[group].children:
                if child not in seen_groups:
                    seen_groups.add(child)
                    following.append(child)
                    out.update(dict.fromkeys(draft.groups[child].hosts))
        level = following
    return tuple(out)


def _folded(warnings: list[Problem]) -> tuple[Problem, ...]:
    """One warning per place and key: a group var another tool owns is said once, not once per robot."""
    by_place: dict[tuple[str, int | None, str, str], list[Problem]] = {}
    for problem in warnings:
        kind = problem.message.split(":", 1)[-1]
        by_place.setdefault((problem.file, problem.line, problem.key, kind), []).append(problem)
    out = []
    for found in by_place.values():
        first = found[0]
        more = f" (and {len(found) - 1} other robots)" if len(found) > 1 else ""
        out.append(replace(first, message=first.message + more))
    return tuple(out)


def _all_layers(draft: Draft) -> Iterator[Layer]:
    entities: list[GroupDraft | HostDraft] = [*draft.groups.values(), *draft.hosts.values()]
    for entity in entities:
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


def _group(group: GroupDraft, inline: list[Layer], hosts: tuple[str, ...], graph: Graph) -> Group:
    merged, _ = _merge(chain(inline, group.files))
    return Group(group.name, hosts, tuple(group.children), graph.parents[group.name],
                 frozen_map(merged), group.source)


def _merge(layers: Iterable[Layer]) -> tuple[dict[str, Any], dict[str, Origin]]:
    merged: dict[str, Any] = {}
    origins: dict[str, Origin] = {}
    for layer in layers:
        merged.update(layer.vars)
        origins.update(dict.fromkeys(layer.vars, layer.origin))
    return merged, origins


def _no_priority(layer: Layer) -> Layer:
    """A group's inline vars without `ansible_group_priority`: there it is a group setting, not a
    variable, as in Ansible; set in a group_vars file or on a host it is a var like any other."""
    if "ansible_group_priority" not in layer.vars:
        return layer
    return replace(layer, vars={k: v for k, v in layer.vars.items() if k != "ansible_group_priority"})


def _host_layers(host: HostDraft, groups: tuple[str, ...], draft: Draft,
                 inline: dict[str, list[Layer]]) -> list[Layer]:
    """Ansible's precedence, lowest first (see the module docstring); `inline` is each group's
    inline layers as vars (_no_priority)."""
    others = [g for g in groups if g != "all"]
    return [*inline["all"], *chain.from_iterable(inline[g] for g in others),
            *draft.groups["all"].files, *chain.from_iterable(draft.groups[g].files for g in others),
            *host.inline, *host.files]


def _host_vars(host: HostDraft, groups: tuple[str, ...], draft: Draft, inline: dict[str, list[Layer]],
               magic: dict[str, Any]) -> tuple[HostVars, dict[str, Origin], list[Layer]]:
    """One host's merged vars (templated on first read), registered in `hostvars`."""
    layers = _host_layers(host, groups, draft, inline)
    merged, origins = _merge(layers)
    source_file = os.path.abspath(split_where(host.source)[0])
    hostvars = HostVars(host.name, merged, origins, {
        **magic, "inventory_hostname": host.name, "inventory_hostname_short": host.name.split(".")[0],
        "inventory_file": source_file, "inventory_dir": os.path.dirname(source_file),
        "group_names": sorted(g for g in groups if g != "all")})
    magic["hostvars"][host.name] = hostvars
    return hostvars, origins, layers


def _build_host(host: HostDraft, groups: tuple[str, ...], draft: Draft, hostvars: HostVars,
                origins: dict[str, Origin], layers: list[Layer]) -> Host | None:
    fields, normalised, errors, warnings = host_fields(host.name, _reader(hostvars), origins, hostvars.secret_source)
    errors += _written_from_vault(host.name, hostvars, origins)
    errors += [p for p in _connection_from_vault(host.name, hostvars, origins) if p.key not in {e.key for e in errors}]
    draft.problems.extend(_hide_secrets(hostvars, errors))
    draft.warnings.extend(_hide_secrets(hostvars, warnings + _templated_connection(hostvars, origins)))
    if errors:
        return None
    for key, value in normalised.items():
        hostvars.override(key, value)
    secrets = frozenset().union(*(layer.secrets for layer in layers))
    return Host(name=host.name, groups=groups, vars=hostvars, secret_values=secrets,
                source=host.source, **fields)


MASK_MIN = 4     # as the output's masking and the leak check: shorter values match innocent text
# Host fields rosdeploy writes as they are into files that are not secret: device paths into
# compose.yml, udev entries into the udev rules.
_WRITTEN_AS_IS = ("devices", "udev")


def _written_from_vault(name: str, hostvars: HostVars, origins: dict[str, Origin]) -> list[Problem]:
    problems = []
    for var in (v for short in _WRITTEN_AS_IS for v in (short, PREFIX + short) if v in origins):
        source = hostvars.secret_source(var)
        if source is not None:
            problems.append(origins[var].problem((var,), f"robot {shown(name)}: {var} comes from vault var "
                                                   f"{shown(source)}, and "
                                                   "rosdeploy writes it into files that are not secret (compose.yml, "
                                                   "udev rules): set it in a plain vars file"))
    return problems


_CONNECTION_VARS = tuple(var for names in CONNECTION.values() for var in names)


def _connection_from_vault(name: str, hostvars: HostVars, origins: dict[str, Origin]) -> list[Problem]:
    """How rosdeploy reaches a robot is shown in messages and logs (`plan`: "unreachable: HOST:PORT",
    "SSH key file PATH does not exist"), where masking finds a vault value's own text only: a
    connection var *computed* from a vault var would be shown there (`{{ token|upper }}`, or its
    length in a port). A vault value used as it is stays allowed (it is masked)."""
    problems = []
    for var in (v for v in _CONNECTION_VARS if v in origins):
        try:
            value = hostvars.value(var)    # read, so its template's vault reads are known
        except TemplateFailed:
            continue                       # reported where it is read (host_fields), or unused
        source = hostvars.secret_source(var)
        if source is None or (source in origins and str(value) == str(raw_vars(hostvars)[source])):
            continue
        problems.append(origins[var].problem((var,), f"robot {shown(name)}: {var} is computed from vault var "
                                             f"{shown(source)}, and rosdeploy shows where and how it connects in "
                                             "its messages and logs (plan, status), where only a vault value's own "
                                             f"text is masked: set {var} in a plain vars file, or to the vault "
                                             "value as it is"))
    return problems


def _templated_connection(hostvars: HostVars, origins: dict[str, Origin]) -> list[Problem]:
    """An `ansible_connection` given as a template, judged by what it gives (check_layer skips it):
    one warning at the var for every robot it gives the same value."""
    raw = raw_vars(hostvars).get("ansible_connection")
    if not (isinstance(raw, str) and "{{" in raw and "ansible_connection" in origins):
        return []
    try:
        value = hostvars.value("ansible_connection")
    except TemplateFailed:
        return []                # its own error, where it is read
    why = connection_ignored(value)
    return [origins["ansible_connection"].problem(("ansible_connection",), why, severity="warning")] if why else []


def _hide_secrets(hostvars: HostVars, problems: list[Problem]) -> list[Problem]:
    """A message about a robot's vars quotes no vault value, nor a value computed from one
    (`got '********'`); shorter texts than MASK_MIN would hide innocent words instead."""
    texts = sorted((t for t in hostvars.secret_texts() if len(t) >= MASK_MIN), key=len, reverse=True)
    if not texts or not problems:
        return problems
    return [replace(p, message=_masked(p.message, texts)) for p in problems]


def _masked(message: str, texts: list[str]) -> str:
    for text in texts:
        message = message.replace(text, "********")
    return message


def _reader(hostvars: HostVars) -> Callable[[str], Any]:
    def read(var: str) -> Any:
        try:
            return hostvars.value(var)
        except TemplateFailed as failed:
            raise BadValue(failed.message if failed.key == var else f"{failed.key}: {failed.message}") from None
    return read
