"""Every real inventory in ../shared/ansible-inventories: rosdeploy against real Ansible.

Per inventory: `ansible-inventory --list` (hosts, groups, every merged var, types included),
`--host` for one host, and the patterns below through Ansible's own InventoryManager (one
process for all of them) plus a few real `ansible PATTERN --list-hosts` runs.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from compat import ansible_host, ansible_list, ask, count, list_hosts, ours, real_inventories, require_ansible, select

INVENTORIES = real_inventories()
IDS = [path.name for path in INVENTORIES]


def patterns_for(groups: dict[str, set[str]], hosts: list[str]) -> list[str]:
    """Patterns of every kind, from the inventory's own names (Ansible's group order matters for [n])."""
    named = sorted(g for g, members in groups.items() if members and g not in ("all", "ungrouped"))
    picked = named[:: max(1, len(named) // 8)][:8]
    out = ["all", "*", "ungrouped", "!ungrouped"]
    for group in picked:
        out += [group, f"{group}[0]", f"{group}[-1]", f"{group}[1:2]", f"{group}[1:]", f"{group}:nomatch"]
    for first, second in zip(picked, picked[1:], strict=False):
        out += [f"{first}:{second}", f"{first}:&{second}", f"{first}:!{second}", f"{first},{second}",
                f"{first}:{second},{hosts[0]}", f"&{first}:{second}"]
    head = re.sub(r"[^A-Za-z]", "", hosts[0])[:2] or hosts[0][:1]
    out += [hosts[0], hosts[-1], f"{hosts[0]},{hosts[-1]}", f"{head}*", f"~{re.escape(head)}", f"*{hosts[-1][-1]}",
            f"all:!{hosts[0]}"]
    return list(dict.fromkeys(out))


@pytest.fixture(scope="module")
def answers(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Ansible's --list of every inventory (one CLI run each) and its answer to every pattern (one process)."""
    require_ansible()
    tmp = tmp_path_factory.mktemp("ansible")
    lists = {path.name: ansible_list(path, tmp) for path in INVENTORIES}
    jobs = [{"inventory": str(path), "patterns": patterns_for(lists[path.name]["groups"],
                                                              sorted(lists[path.name]["hostvars"] or
                                                                     lists[path.name]["groups"]["all"]))}
            for path in INVENTORIES]
    replies = ask(jobs, tmp)
    patterns = {p.name: r["patterns"] for p, r in zip(INVENTORIES, replies, strict=True)}
    return {"tmp": tmp, "lists": lists, "patterns": patterns}


@pytest.mark.parametrize("inventory", INVENTORIES, ids=IDS)
def test_hosts_groups_and_vars_are_ansibles(inventory: Path, answers: dict[str, Any]) -> None:
    theirs = answers["lists"][inventory.name]
    loaded, mine = ours(inventory)
    same_hosts = set(mine["hostvars"]) == theirs["groups"]["all"]
    same_groups = all(mine["groups"].get(g, set()) == members for g, members in theirs["groups"].items())
    extra = {g for g, members in mine["groups"].items() if members and g not in theirs["groups"]}
    # Ansible leaves hosts without vars out of _meta.hostvars.
    same_vars = all(mine["hostvars"][h] == theirs["hostvars"].get(h, {}) for h in mine["hostvars"])
    count("inventories", same_hosts and same_groups and not extra and same_vars)
    assert set(mine["hostvars"]) == theirs["groups"]["all"]
    assert {g: mine["groups"].get(g, set()) for g in theirs["groups"]} == theirs["groups"] and not extra
    assert {h: mine["hostvars"][h] for h in mine["hostvars"]} == \
           {h: theirs["hostvars"].get(h, {}) for h in mine["hostvars"]}


@pytest.mark.parametrize("inventory", INVENTORIES, ids=IDS)
def test_patterns_select_ansibles_hosts(inventory: Path, answers: dict[str, Any]) -> None:
    loaded, _ = ours(inventory)
    differ = {}
    for pattern, theirs in answers["patterns"][inventory.name].items():
        expected = set(theirs) if isinstance(theirs, list) else None
        mine = select(loaded, pattern)
        # Where Ansible selects nothing, rosdeploy refuses the pattern (documented): the same robots.
        same = mine == expected or (mine is None and expected == set())
        count("patterns", same)
        if not same:
            differ[pattern] = (mine, expected)
    assert not differ


def test_the_real_cli_agrees_on_host_and_list_hosts(answers: dict[str, Any]) -> None:
    """A few runs of the real CLIs besides the API: `--host` and `ansible PATTERN --list-hosts`."""
    tmp = answers["tmp"]
    picks = [p for p in INVENTORIES if p.name in ("kolla-multinode", "homelab-dir", "ansible-test-complex-ini",
                                                  "lerobot-swerve")]
    assert picks, "the real inventories are missing"
    for inventory in picks:
        loaded, mine = ours(inventory)
        host = sorted(mine["hostvars"])[0]
        assert mine["hostvars"][host] == ansible_host(inventory, host, tmp)
        pattern = next(p for p, hosts in answers["patterns"][inventory.name].items()
                       if (":&" in p or ":!" in p) and hosts)   # non-empty: rosdeploy refuses an empty one
        assert select(loaded, pattern) == list_hosts(inventory, pattern, tmp)
