"""Synthetic inventories, one per Ansible behaviour rosdeploy must share, against real Ansible."""
from __future__ import annotations

import os
import textwrap
from pathlib import Path
from typing import Any

import pytest

from compat import ansible_list, ask, cli, list_hosts, ours, require_ansible, select

TEMPLATED = {
    "hosts.yml": """\
        web:
          hosts:
            w1: {ansible_host: 10.0.0.1, base: 5, ros_domain_id: 1}
            w2: {ansible_host: 10.0.0.2, base: 7, ros_domain_id: "{{ base - 5 }}"}
          vars:
            ansible_ssh_private_key_file: "{{ inventory_dir }}/../keys/{{ inventory_hostname }}"
            peer: "{{ hostvars['w2']['ansible_host'] }}"
            next: "{{ base + 1 }}"
            names: "{{ group_names | join(',') }}"
            size: "{{ groups['web'] | length }}"
            short: "{{ inventory_hostname_short }}-{{ inventory_file | basename }}"
            nested: {a: "{{ inventory_hostname }}", b: ["{{ base }}", 3]}
            literal: !unsafe "{{ not templated }}"
        """,
}
FOREIGN = {
    "hosts": """\
        [osds]
        osd0 devices="['/dev/sda','/dev/sdb']" gpu=nvidia-orin ansible_user=ceph
        osd1 gpus=2 device=/dev/sdc ros_domain=3
        [robots]
        amr1 ros_domain_id=4 rosdeploy_devices="{'lidar': '/dev/robot/lidar'}" rosdeploy_gpu=true
        """,
    "group_vars/all.yml": """\
        ansible_user:
        config: |
          line one
          line two
        udev: enabled
        """,
}
RANGES = {"hosts": "[amr]\namr[0:11]\n[cam]\ncam[0:10:5]\n[letters]\nnode-[a:c]\n[padded]\nr[01:03]\n"
                   "[mixed]\nx[8:10]\n"}
LEGACY = {
    "hosts.yml": """\
        all:
          hosts:
            both:
              {ansible_host: 10.0.0.1, ansible_ssh_host: 10.0.0.9, ansible_port: 22, ansible_ssh_port: 2222,
               ansible_user: new, ansible_ssh_user: legacy, ansible_private_key_file: /k/a,
               ansible_ssh_private_key_file: /k/b}
            split: {ansible_ssh_host: 10.0.0.8, ansible_user: new}
          children:
            site: {vars: {ansible_ssh_user: from-group}, hosts: {split: {}, plain: {}}}
        """,
}
PATTERNS = {
    "hosts": """\
        [canary]
        c3
        c1
        [canary:children]
        west
        east
        [west]
        w2
        w1
        [east]
        e1
        c1
        [web]
        w1
        e1
        [db]
        d1
        """,
}
SHAPES = {
    "inv/hosts.yml": "web:\n  hosts:\n    w1:\n    w2:\n",
    "inv/hosts.example": "[extra]\nx1\n",
    "inv/hosts.yml.example": "all:\n  hosts:\n    y1:\n",
    "inv/group_vars/web/main.yml": "a: dir\nb: dir\n",
    "inv/group_vars/web.yml": "a: file\nc: file\n",
    "inv/group_vars/all.yml": "dup: 1\ndup: 2\nu: !unsafe '{{ x }}'\n",
    "inv/dynamic.sh": """\
        #!/bin/sh
        if [ "$1" = "--list" ]; then
          echo '{"db": {"hosts": ["d1", "d2"], "vars": {"port": 5432}}, "web": ["w3"],
                 "_meta": {"hostvars": {"d1": {"role": "primary"}}}}'
        else
          echo '{}'
        fi
        """,
}
PATTERN_LIST = ["canary[0]", "canary[1]", "canary[-1]", "canary[1:3]", "canary[0:]", "canary[2:0]",
                "web:db,canary", "canary:&web,db", "web:nomatch", "west:east", "canary:!east", "all[0]",
                "w*:&canary", "~[cw]1", "web,db", "!web", "&web:db"]


def make(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))
        if name.endswith(".sh"):
            path.chmod(0o755)
    return root / "inv" if any(name.startswith("inv/") for name in files) else root


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    require_ansible()
    tmp = tmp_path_factory.mktemp("ansible")
    paths = {name: make(tmp_path_factory.mktemp(name), files) for name, files in
             (("templated", TEMPLATED), ("foreign", FOREIGN), ("ranges", RANGES), ("legacy", LEGACY),
              ("patterns", PATTERNS), ("shapes", SHAPES))}
    replies = ask([
        {"inventory": str(paths["templated"]), "template": {h: ["ansible_ssh_private_key_file", "peer", "next",
                                                               "names", "size", "short", "nested", "literal",
                                                               "ros_domain_id"] for h in ("w1", "w2")}},
        {"inventory": str(paths["legacy"]), "connection": ["both", "split", "plain"]},
        {"inventory": str(paths["patterns"]), "patterns": PATTERN_LIST},
    ], tmp)
    return {"tmp": tmp, "paths": paths, "templated": replies[0]["templated"], "connection": replies[1]["connection"],
            "patterns": replies[2]["patterns"]}


@pytest.mark.parametrize("name", ["templated", "foreign", "ranges", "legacy", "patterns", "shapes"])
def test_list_is_ansibles(world: dict[str, Any], name: str) -> None:
    """Hosts, groups and raw vars as `ansible-inventory --list` prints them (it does not template)."""
    theirs = ansible_list(world["paths"][name], world["tmp"])
    _, mine = ours(world["paths"][name])
    assert set(mine["hostvars"]) == theirs["groups"]["all"]
    assert {g: mine["groups"].get(g, set()) for g in theirs["groups"]} == theirs["groups"]
    assert mine["hostvars"] == {h: theirs["hostvars"].get(h, {}) for h in mine["hostvars"]}


def test_templated_values_are_ansibles(world: dict[str, Any]) -> None:
    loaded, _ = ours(world["paths"]["templated"])
    for host, values in world["templated"].items():
        for var, theirs in values.items():
            mine = loaded.hosts[host].vars[var]
            if var == "ansible_ssh_private_key_file":
                mine, theirs = os.path.normpath(mine), os.path.normpath(theirs)
            assert mine == theirs, (host, var)
    w2 = loaded.hosts["w2"]
    assert w2.key_file == os.path.normpath(world["templated"]["w2"]["ansible_ssh_private_key_file"])
    assert w2.ros_domain_id == 2


def test_foreign_vars_load_with_warnings(world: dict[str, Any]) -> None:
    loaded, _ = ours(world["paths"]["foreign"])
    osd0, amr1 = loaded.hosts["osd0"], loaded.hosts["amr1"]
    assert (osd0.devices, osd0.gpu, osd0.user) == ({}, False, "ceph")
    assert (dict(amr1.devices), amr1.gpu, amr1.user) == ({"lidar": "/dev/robot/lidar"}, True, None)
    said = "\n".join(str(w) for w in loaded.warnings)
    assert "devices" in said and "gpu" in said and "rosdeploy_devices" in said


def test_connection_vars_are_the_ones_ansible_uses(world: dict[str, Any]) -> None:
    loaded, _ = ours(world["paths"]["legacy"])
    for host, theirs in world["connection"].items():
        mine = loaded.hosts[host]
        assert mine.address == theirs["address"]
        assert mine.port == (int(theirs["port"]) if theirs["port"] is not None else 22)
        assert mine.user == theirs["user"]
        assert mine.key_file == theirs["key_file"]


def test_patterns_select_ansibles_hosts(world: dict[str, Any]) -> None:
    loaded, _ = ours(world["paths"]["patterns"])
    for pattern, theirs in world["patterns"].items():
        expected = set(theirs) if isinstance(theirs, list) else None
        mine = select(loaded, pattern)
        assert mine == expected or (mine is None and expected == set()), pattern
    assert select(loaded, "canary[0]") == list_hosts(world["paths"]["patterns"], "canary[0]", world["tmp"])
    assert select(loaded, "web:nomatch") == list_hosts(world["paths"]["patterns"], "web:nomatch", world["tmp"])


def test_limit_at_file_selects_ansibles_hosts(world: dict[str, Any]) -> None:
    """`--limit @file`: one pattern a line, blank lines skipped, the other terms applied as well."""
    loaded, _ = ours(world["paths"]["patterns"])
    limit = world["tmp"] / "limit.txt"
    limit.write_text("w1\n\n  east \ncanary[0]\n")
    for pattern in (f"@{limit}", f"@{limit}:!e1", f"web:@{limit}"):
        done = cli(["ansible", "-i", str(world["paths"]["patterns"]), "all", "--limit", pattern, "--list-hosts"],
                   world["tmp"])
        assert done.returncode == 0, done.stderr
        theirs = {line.strip() for line in done.stdout.splitlines()[1:] if line.strip()}
        assert select(loaded, pattern) == theirs, pattern
