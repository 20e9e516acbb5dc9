"""YAML inventories: `all:` / `children:` / `hosts:` / `vars:`, like Ansible's yaml plugin."""
from __future__ import annotations

from typing import Any

from rosdeploy.errors import shown
from rosdeploy.inventory.draft import Draft, Origin, make_layer
from rosdeploy.inventory.hostvars import CONSUMED_VARS
from rosdeploy.inventory.known import GROUP_KEYS, did_you_mean_hint
from rosdeploy.inventory.ranges import add_hosts, valid_name


def parse_yaml(root: Origin, draft: Draft) -> None:
    doc = root.doc
    if doc.data is None:
        return
    if not isinstance(doc.data, dict):
        draft.problems.append(doc.problem((), "an inventory must be a mapping of group names, "
                                              "starting with `all:`"))
        return
    if "plugin" in doc.data:
        draft.problems.append(doc.problem(("plugin",), "inventory plugins are not supported: "
                                                       "export the hosts to a YAML inventory"))
        return
    for name, entry in doc.data.items():
        if name in GROUP_KEYS:
            draft.problems.append(doc.problem((name,), f"`{name}:` at the top level: put it under "
                                                       "a group, e.g. `all:`"))
            continue
        if _string_key(name, root.child(name), draft, "group"):
            _yaml_group(root.child(name), name, entry, draft)


def _string_key(key: Any, origin: Origin, draft: Draft, what: str) -> bool:
    """A host or group name must be a string, as in Ansible's yaml plugin, which refuses the
    inventory ("Host pattern 1 must be a string. Enclose integers/floats in quotation marks";
    "Invalid group name supplied, expected a string"). str() would turn `~:` into a robot named
    "None" and `yes:` into "True"; `1:` is refused too (Ansible 2.19 does), with the fix: quote it."""
    if isinstance(key, str):
        return True
    if key is None:
        shown, quote = "null (~ or nothing)", "'NAME'"
    elif isinstance(key, bool):
        shown, quote = f"the boolean {str(key).lower()}", "'NAME'"
    elif isinstance(key, (int, float)):
        shown, quote = f"the number {key!r}", f"'{key}'"
    else:
        shown, quote = f"a {type(key).__name__}", "'NAME'"
    draft.problems.append(origin.problem((), f"{what} name is {shown}, not a string: a {what} name must be "
                                             f"a string, as Ansible requires; quote it (e.g. {quote}:)"))
    return False


def _yaml_group(origin: Origin, name: str, entry: Any, draft: Draft) -> bool:
    """Reads one group; False when its name is refused (so no parent may list it)."""
    if not valid_name(name, origin, draft, "group"):
        return False
    draft.group(name, origin.where)
    entry = _as_mapping(origin, entry, f"group {shown(name)} must be a mapping with hosts:, vars: and/or "
                                       "children:", draft)
    for key, value in entry.items():
        sub = origin.child(key)
        if key == "hosts":
            _yaml_hosts(sub, name, value, draft)
        elif key == "vars":
            _yaml_group_vars(sub, name, value, draft)
        elif key == "children":
            _yaml_children(sub, name, value, draft)
        else:
            draft.problems.append(sub.problem((), f"unknown key in group {shown(name)}: a group holds only "
                                                  f"hosts:, vars: and children:{_misplaced_hint(key)}"))
    return True


def _misplaced_hint(key: Any) -> str:
    if str(key) in CONSUMED_VARS or str(key).startswith("ansible_"):
        # The classic slip: a host indented under children:, so it was read as a group.
        return ("; this looks like a variable: put it under vars:, or, if the group above is really a "
                "host, list it under hosts:")
    return did_you_mean_hint(key, GROUP_KEYS)


def _as_mapping(origin: Origin, value: Any, message: str, draft: Draft) -> dict[Any, Any]:
    """`value` if it is a mapping, {} for null (Ansible allows `hosts:` with nothing), else report."""
    if value is None:
        return {}
    if isinstance(value, dict):
        return value
    draft.problems.append(origin.problem((), message))
    return {}


def _yaml_hosts(origin: Origin, group: str, hosts: Any, draft: Draft) -> None:
    hosts = _as_mapping(origin, hosts, "hosts: must be a mapping of host names, each followed by ':' "
                                       "(and its vars, or nothing)", draft)
    for raw, host_vars in hosts.items():
        host_origin = origin.child(raw)
        if not _string_key(raw, host_origin, draft, "host"):
            continue
        host_vars = _as_mapping(host_origin, host_vars, "host vars must be a mapping of name: value "
                                                        "(or nothing after the ':')", draft)
        add_hosts(raw, group, dict(host_vars), host_origin, draft)


def _yaml_group_vars(origin: Origin, group: str, data: Any, draft: Draft) -> None:
    data = _as_mapping(origin, data, "vars: must be a mapping of name: value", draft)
    if data:
        draft.groups[group].inline.append(make_layer(data, origin))


def _yaml_children(origin: Origin, group: str, children: Any, draft: Draft) -> None:
    children = _as_mapping(origin, children, "children: must be a mapping of group names, each followed "
                                             "by ':'", draft)
    for child, entry in children.items():
        child_origin = origin.child(child)
        if not _string_key(child, child_origin, draft, "group"):
            continue
        # listed only once its name is accepted: the graph looks every child up (`"a\nb":` crashed it)
        if _yaml_group(child_origin, child, entry, draft):
            draft.groups[group].children.setdefault(child, child_origin)


