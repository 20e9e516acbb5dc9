"""Round 11 (probe T): IPv6 hosts in `--limit`, a nested `ungrouped`, did-you-means that repeat
the input, and small inventory divergences, each checked against ansible-core 2.19's results."""
from __future__ import annotations

from pathlib import Path

import pytest

from rosdeploy.errors import InventoryError
from rosdeploy.inventory import load_inventory
from rosdeploy.patterns import select, split
from test_hostile import cli, lab

__all__ = ["lab"]   # the fixture: tests/unit/data/fleet copied, its vault password in place


# ------------------------------------------------------------------ defect 4: IPv6 in patterns

@pytest.mark.parametrize("pattern, terms", [
    # Ansible's split_host_pattern keeps a pattern that parses as one address whole ...
    ("::1", ["::1"]),
    ("fe80::1", ["fe80::1"]),
    ("2001:db8::5", ["2001:db8::5"]),
    ("abc::d", ["abc::d"]),
    ("1:2:3:4:5:6:7:8", ["1:2:3:4:5:6:7:8"]),
    ("fe80::1:22", ["fe80::1:22"]),          # no port without brackets: all address
    ("[::1]:2223", ["[::1]:2223"]),
    ("[fe80::1]:22", ["[fe80::1]:22"]),
    ("fe80::[1:3]", ["fe80::[1:3]"]),          # a range in place of a group
    ("::ffff:1.2.3.4", ["::ffff:1.2.3.4"]),
    ("web[1:3]:22", ["web[1:3]:22"]),
    ("10.0.0.[1:3]:22", ["10.0.0.[1:3]:22"]),
    ("amr-n1:22", ["amr-n1:22"]),
    ("::", ["::"]),
    # ... and splits anything else on ':'
    ("fe80::1:r1", ["fe80", "1", "r1"]),
    ("r1:fe80::1", ["r1", "fe80", "1"]),
    ("::1:r1", ["1", "r1"]),
    ("r1:22:r2", ["r1", "22", "r2"]),
    ("a:b", ["a", "b"]),
    ("lab:!::1", ["lab", "!", "1"]),
    ("1:2:3:4:5:6:7::", ["1", "2", "3", "4", "5", "6", "7"]),   # seven groups beside `::`: not Ansible's
    ("fe80::1%eth0", ["fe80", "1%eth0"]),
    ("web:g", ["web", "g"]),
])
def test_a_pattern_that_is_one_address_is_one_term_as_in_ansible(pattern, terms):
    assert split(pattern) == terms


V6_HOSTS = ("r1", "::1", "fe80::1", "r2")
V6_GROUPS = {"all": V6_HOSTS, "ungrouped": (), "lab": V6_HOSTS}


@pytest.mark.parametrize("pattern, chosen", [("::1", ("::1",)), ("fe80::1", ("fe80::1",)),
                                             ("fe80::1:r1", ("r1",)), ("r1:r2", ("r1", "r2"))])
def test_limit_selects_a_robot_named_by_an_ipv6_address(pattern, chosen):
    assert select(pattern, V6_HOSTS, V6_GROUPS, warnings=[]) == chosen


@pytest.mark.parametrize("pattern, host", [("[::1]:2223", "::1"), ("r2:22", "r2")])
def test_a_host_with_its_port_selects_nothing_but_names_the_host(pattern, host):
    """Ansible matches `[::1]:2223` against host names, which hold no port: nothing. Say which host."""
    with pytest.raises(InventoryError) as raised:
        select(pattern, V6_HOSTS, V6_GROUPS)
    message = str(raised.value)
    assert "without its port" in message and f"did you mean '{host}'?" in message


IPV6_INI = "[lab]\nr1 ansible_host=127.0.0.1 ros_domain_id=1\n[::1]:2223 ros_domain_id=3\nfe80::1 ros_domain_id=4\n"


def with_inventory(lab: Path, files: dict[str, str]) -> None:
    (lab / "inventory" / "hosts.yml").unlink()
    for name, text in files.items():
        (lab / "inventory" / name).write_text(text)


def test_render_limited_to_an_ipv6_robot_renders_it_alone(capsys, lab):
    with_inventory(lab, {"hosts.ini": IPV6_INI})
    code, text = cli(capsys, lab, "render", "-l", "fe80::1")
    assert code == 0, text
    assert sorted(p.name for p in (lab / "out").iterdir() if p.is_dir()) == ["fe80::1"]


# ------------------------------------------------------------------ defect 5: nested ungrouped

UNGROUPED_INI = ("[lab]\nr1 ansible_host=127.0.0.1 ros_domain_id=1\n[ungrouped]\nr2 ansible_host=127.0.0.2 "
                 "ros_domain_id=2\n[site:children]\nungrouped\n")


def load(tmp_path: Path, name: str, text: str):
    (tmp_path / name).write_text(text)
    return load_inventory(str(tmp_path))


def names(inventory, pattern: str | None) -> list[str]:
    return [host.name for host in inventory.select(pattern, [])]


def test_hosts_listed_under_a_nested_ungrouped_belong_to_no_group_as_in_ansible(tmp_path):
    """ansible-core: `all` lists r1 only; `site` and `ungrouped` hold no host; `-l r2` finds r2."""
    inventory = load(tmp_path, "hosts.ini", UNGROUPED_INI)
    assert inventory.groups["all"].hosts == ("r1",)
    assert inventory.groups["site"].hosts == () and inventory.groups["ungrouped"].hosts == ()
    assert names(inventory, None) == ["r1"] and names(inventory, "all") == ["r1"]
    assert names(inventory, "r2") == ["r2"] and names(inventory, "*") == ["r1", "r2"]
    assert names(inventory, "all:!r2") == ["r1"]
    assert inventory.hosts["r2"].groups == ("all",)
    for pattern in ("site", "ungrouped"):
        with pytest.raises(InventoryError, match="the groups it names hold no host"):
            inventory.select(pattern, [])


def test_a_nested_ungrouped_is_a_warning_at_its_children_entry(tmp_path):
    inventory = load(tmp_path, "hosts.ini", UNGROUPED_INI)
    found = [w for w in inventory.warnings if "`ungrouped`" in w.message]
    assert len(found) == 1 and found[0].file.endswith("hosts.ini") and found[0].line == 6
    assert "Ansible's implicit group" in found[0].message and "should not be" in found[0].message


def test_a_host_in_no_group_joins_a_nested_ungrouped_and_its_parents(tmp_path):
    """ansible-core: r3 (in `all` only) is added to ungrouped, so site and top hold it; r2, listed
    under ungrouped, is dropped from it."""
    inventory = load(tmp_path, "hosts.yml", """\
all:
  hosts:
    r3: {ansible_host: 127.0.0.3, ros_domain_id: 3}
  children:
    lab: {hosts: {r1: {ansible_host: 127.0.0.1, ros_domain_id: 1}}}
    ungrouped: {hosts: {r2: {ansible_host: 127.0.0.2, ros_domain_id: 2}}}
    top: {children: {site: {children: {ungrouped: }}}}
""")
    assert inventory.groups["all"].hosts == ("r3", "r1")
    for group in ("ungrouped", "site", "top"):
        assert inventory.groups[group].hosts == ("r3",)
    assert set(inventory.hosts["r3"].groups) == {"all", "top", "site", "ungrouped"}
    assert names(inventory, None) == ["r3", "r1"]


def test_ungrouped_under_all_stays_as_it_was(tmp_path):
    inventory = load(tmp_path, "hosts.yml", """\
all:
  children:
    ungrouped: {hosts: {r2: {ansible_host: 127.0.0.2, ros_domain_id: 2}}}
    lab: {hosts: {r1: {ansible_host: 127.0.0.1, ros_domain_id: 1}}}
""")
    assert inventory.groups["ungrouped"].hosts == ("r2",) and names(inventory, None) == ["r2", "r1"]
    assert not [w for w in inventory.warnings if "`ungrouped`" in w.message]


def test_render_leaves_out_a_host_in_no_group_as_ansible_all_does(capsys, lab):
    with_inventory(lab, {"hosts.ini": UNGROUPED_INI})
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    assert sorted(p.name for p in (lab / "out").iterdir() if p.is_dir()) == ["r1"]
    assert "hosts.ini:6" in text and "`ungrouped`" in text


# ------------------------------------------------------------------ defect 7: did-you-mean

ODD_GROUPS = {"all": ("r1", "r2"), "ungrouped": (), "lab": ("r1", "r2"), "g[0]": ("r1",), "~i": ("r1",)}


@pytest.mark.parametrize("pattern, reading", [("g[0]", "item 0 of group 'g'"),
                                              ("~i", "the regular expression 'i'")])
def test_a_group_the_pattern_reads_otherwise_is_named_with_rename(pattern, reading):
    with pytest.raises(InventoryError) as raised:
        select(pattern, ("r1", "r2"), ODD_GROUPS)
    message = str(raised.value)
    assert f"did you mean '{pattern}'" not in message
    assert reading in message and f"group '{pattern}' exists" in message and "rename" in message


def test_an_exclusion_of_such_a_group_says_so_too():
    with pytest.raises(InventoryError) as raised:
        select("lab:!g[0]", ("r1", "r2"), ODD_GROUPS)
    assert "exclusion 'g[0]' reads as item 0 of group 'g'" in str(raised.value)
    assert "did you mean 'g[0]'" not in str(raised.value)


# ------------------------------------------------------------------ defect 8: small divergences

def load_problems(tmp_path: Path, name: str, text: str) -> str:
    (tmp_path / name).write_text(text)
    with pytest.raises(InventoryError) as raised:
        load_inventory(str(tmp_path))
    return str(raised.value)


def test_an_idna_host_name_is_accepted_as_ansible_does(tmp_path):
    inventory = load(tmp_path, "hosts.ini", "[lab]\nbücher.example ros_domain_id=2\nrë ros_domain_id=3\n")
    assert list(inventory.hosts) == ["bücher.example", "rë"]
    assert names(inventory, "bücher.example") == ["bücher.example"]


@pytest.mark.parametrize("name", ["ｒ1",            # fullwidth: a second spelling of r1 (NFKC)
                                  "r\u0663",        # an Arabic-Indic digit
                                  "bu\u0308cher",   # decomposed: not NFC
                                  "a\u200bb",       # a zero-width space
                                  "rë;x", "-rë", "rë$(id)"])
def test_host_names_a_shell_or_a_resolver_would_misread_stay_refused(tmp_path, name):
    message = load_problems(tmp_path, "hosts.ini", f"[lab]\n{name} ros_domain_id=2\n")
    assert "hosts.ini:2" in message and "host name" in message


GROUPS_INI = "[-lab]\nr1 ros_domain_id=1\n[site-a.b]\nr2 ros_domain_id=2\n[sité]\nr3 ros_domain_id=3\n" \
             "[_ok1]\nr3\n[123]\nr4 ros_domain_id=4\n"


def test_group_names_are_warned_about_as_ansible_warns(tmp_path):
    """ansible-core warns "Invalid characters were found in group names" for `site-a.b`, `-lab`
    and `123`, and not for `sité` or `_ok1` (its rule: word characters, no leading digit)."""
    inventory = load(tmp_path, "hosts.ini", GROUPS_INI)
    warned = {w.line: w.message for w in inventory.warnings if "group name" in w.message}
    # a risky name (a leading '-') on its own; the plain ones in one warning, as Ansible's one line
    assert sorted(warned) == [1, 3]
    assert "'-lab' starts with '-'" in warned[1] and "other than letters" not in warned[1]
    assert "2 group names hold characters Ansible warns about: 'site-a.b', '123'" in warned[3]
    assert "Invalid characters were found in group names" in warned[3]


def test_many_plain_odd_group_names_are_one_warning(tmp_path):
    """kolla's multinode holds 121 such groups (`nova-api`...): one line, as Ansible prints, not 128."""
    sections = "".join(f"[site-{i}]\nr{i} ros_domain_id={i}\n[site-{i}:vars]\nx=1\n" for i in range(1, 31))
    inventory = load(tmp_path, "hosts.ini", sections)
    (warned,) = [w for w in inventory.warnings if "group name" in w.message]
    assert warned.line == 1 and "30 group names" in warned.message and "(and 25 more)" in warned.message
    (tmp_path / "one").mkdir()
    one = load(tmp_path / "one", "one.ini",
               "[site-a]\nr1 ros_domain_id=1\n[b]\nr2 ros_domain_id=2\n[b:children]\nsite-a\n")
    (warned,) = [w for w in one.warnings if "group name" in w.message]
    assert "group name 'site-a' holds '-'" in warned.message


@pytest.mark.parametrize("value, spelled", [("true", "got true"), ("", "got null")])
def test_a_yaml_priority_is_echoed_as_yaml_spells_it(tmp_path, value, spelled):
    message = load_problems(tmp_path, "hosts.yml", f"""\
all:
  children:
    lab: {{hosts: {{r1: {{ansible_host: 127.0.0.1, ros_domain_id: 1}}}}}}
    c: {{vars: {{ansible_group_priority: {value}}}, hosts: {{r1: }}}}
""")
    assert spelled in message and "True" not in message and "None" not in message


def test_ansible_group_priority_from_group_vars_or_a_host_is_a_var(tmp_path):
    """ansible-core: r1 (inline host var) has 9, r2 (group_vars/b.yml) 7; `a`'s inline 5 is no var."""
    (tmp_path / "group_vars").mkdir()
    (tmp_path / "group_vars" / "b.yml").write_text("ansible_group_priority: 7\n")
    inventory = load(tmp_path, "hosts.ini", "[lab]\nr1 ansible_host=127.0.0.1 ros_domain_id=1 "
                                            "ansible_group_priority=9\nr2 ros_domain_id=2\n[a]\nr2\n[a:vars]\n"
                                            "ansible_group_priority=5\n[b]\nr2\n")
    assert inventory.hosts["r1"].vars["ansible_group_priority"] == 9
    assert inventory.hosts["r2"].vars["ansible_group_priority"] == 7
    assert "ansible_group_priority" not in inventory.groups["a"].vars
