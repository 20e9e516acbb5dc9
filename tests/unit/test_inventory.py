"""Inventory loading: Ansible's YAML and INI formats, var precedence, strict errors."""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest

from rosdeploy.errors import InventoryError, VaultError
from rosdeploy.inventory import load_inventory
from rosdeploy.model import UdevDevice
from rosdeploy.vault import Vault, ansible_encrypt, encrypt

DATA = Path(__file__).parent / "data" / "inventory"
REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "inventory" / "warehouse"


def write(root: Path, files: dict[str, str | bytes]) -> Path:
    for name, content in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content)
    return root


def problems_of(root: Path, files: dict[str, str | bytes]) -> str:
    """Load an inventory that must fail; the whole message, one problem a line."""
    write(root, files)
    with pytest.raises(InventoryError) as caught:
        load_inventory(str(root))
    return str(caught.value)


ONE_HOST = "all:\n  hosts:\n    r1:\n      ros_domain_id: 1\n"


# ------------------------------------------------------------------ formats


def test_example_warehouse_inventory_loads_with_the_demo_password():
    vault = Vault(password_file=str(EXAMPLE / ".vault-password-example"))
    inventory = load_inventory(str(EXAMPLE), vault)

    assert list(inventory.hosts) == ["amr-n1", "amr-n2", "amr-s1", "amr-s2"]
    n1, s2 = inventory.hosts["amr-n1"], inventory.hosts["amr-s2"]
    assert n1.groups[0] == "all" and {"warehouse", "site_north", "perception"} <= set(n1.groups)
    assert (n1.address, n1.port, n1.user, n1.gpu, n1.network) == ("10.10.1.11", 22, "robot", True, "north")
    assert (s2.gpu, s2.network, s2.ros_domain_id) == (False, "south", 22)
    assert n1.key_file == os.path.expanduser("~/.ssh/rosdeploy_fleet")
    assert n1.devices["lidar"] == "/dev/robot/lidar"
    assert UdevDevice("robot/motor_controller", "tty", "0403", "6001", group="dialout") in n1.udev
    assert n1.vars["fleet_api_token"] in n1.secret_values
    assert "10.10.1.11" not in n1.secret_values
    assert n1.source.endswith("hosts.yml:16")
    assert inventory.groups["warehouse"].hosts == ("amr-n1", "amr-n2", "amr-s1", "amr-s2")
    assert inventory.groups["site_north"].parents == ("warehouse",)


def test_example_without_a_password_says_how_to_give_one(monkeypatch):
    monkeypatch.delenv("ROSDEPLOY_VAULT_PASSWORD", raising=False)
    monkeypatch.delenv("ROSDEPLOY_VAULT_PASSWORD_FILE", raising=False)
    with pytest.raises(VaultError) as caught:
        load_inventory(str(EXAMPLE))
    message = str(caught.value)
    assert "vault.yml" in message and "--vault-password-file" in message


def test_ini_inventory_parses_like_ansible():
    inventory = load_inventory(str(DATA / "ini" / "hosts"))
    hosts = inventory.hosts

    assert list(hosts) == ["bench-1", "amr-a1", "amr-a2", "amr-a3", "amr-b01", "amr-b02"]
    assert hosts["bench-1"].groups == ("all", "ungrouped")
    assert hosts["bench-1"].address == "192.168.5.9"
    a3 = hosts["amr-a3"]
    assert (a3.port, a3.user, a3.gpu, a3.ros_domain_id) == (2222, "field", True, 3)
    assert a3.vars["motto"] == "keep rolling"
    assert hosts["amr-a1"].groups == ("all", "sites", "site_a")
    assert hosts["amr-a1"].network == "shared"            # [sites:vars]
    b01 = hosts["amr-b01"]
    assert b01.network == "b"                             # child [site_b:vars] beats parent [sites:vars]
    assert b01.vars["greeting"] == "hello world"          # quoted value, quotes removed
    assert b01.vars["enabled"] == "true"                  # like Ansible: only True is a bool in INI
    assert b01.vars["retries"] == 7                       # group_vars/site_b/ files, later file wins
    assert b01.vars["dds_profile"] == "lan"
    assert (b01.ros_domain_id, hosts["amr-b02"].ros_domain_id) == (21, 22)  # host_vars, one without extension
    assert hosts["amr-a2"].ros_domain_id == 2                 # host_vars beats the inline var
    assert inventory.groups["sites"].hosts == ("amr-a1", "amr-a2", "amr-a3", "amr-b01", "amr-b02")
    assert a3.source.endswith("hosts:6")


def test_same_vars_and_groups_as_ansible_itself():
    """Golden output of `ansible-inventory --list` on a tricky mixed INI/YAML directory
    (priorities, ranges with steps and letters, ports, literal values, group_vars/NAME/)."""
    golden = json.loads((DATA / "ansible_golden.json").read_text())
    inventory = load_inventory(str(DATA / "ansible_golden"))
    assert {name: dict(host.vars) for name, host in inventory.hosts.items()} == golden["hostvars"]
    assert {name: sorted(group.hosts) for name, group in inventory.groups.items()} == golden["groups"]


def test_directory_reads_every_inventory_file_and_skips_the_rest(tmp_path):
    write(tmp_path, {
        "10-north.yml": "site_north:\n  hosts:\n    n1:\n      ros_domain_id: 1\n",
        "20-south": "[site_south]\ns1 ros_domain_id=2\n",
        "README.md": "not an inventory",
        ".vault-pass": "secret",
        "group_vars/all.yml": "ansible_user: robot\n",
    })
    inventory = load_inventory(str(tmp_path))
    assert list(inventory.hosts) == ["n1", "s1"]
    assert {h.user for h in inventory.hosts.values()} == {"robot"}


def test_a_symlink_loop_in_an_inventory_directory_is_read_once(tmp_path):
    write(tmp_path, {"hosts.yml": ONE_HOST})
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "up").symlink_to(tmp_path)        # sub/up/sub/up/... forever
    (tmp_path / "again").symlink_to(tmp_path / "sub")
    inventory = load_inventory(str(tmp_path))
    assert list(inventory.hosts) == ["r1"]


def test_a_directory_that_is_no_inventory_is_refused_before_anything_runs(tmp_path):
    write(tmp_path, {"hosts.yml": ONE_HOST})
    marker = tmp_path / "ran"
    script = tmp_path / "inventory.py"
    script.write_text(f"#!/bin/sh\ntouch {marker}\necho '{{}}'\n")
    script.chmod(0o755)
    junk = tmp_path / "junk"
    junk.mkdir()
    for i in range(5001):
        (junk / f"f{i}.txt").touch()
    message = problems_of(tmp_path, {})
    assert str(tmp_path) in message and "more than 5000 entries" in message and "inventory:" in message
    assert not marker.exists()


def chain(depth: int, closing: str) -> str:
    """all > g0 > g1 > ... > g<depth>, each child declared at the top level (no YAML nesting)."""
    groups = "".join(f"    g{i}:\n      children:\n        g{i + 1}: {{}}\n" for i in range(depth))
    return f"all:\n  children:\n{groups}    g{depth}:\n{closing}"


def test_a_long_chain_of_groups_loads_without_recursion(tmp_path):
    write(tmp_path, {"hosts.yml": chain(900, "      hosts: {r1: {ros_domain_id: 1}}\n")})
    inventory = load_inventory(str(tmp_path))
    assert {"g0", "g450", "g900"} <= set(inventory.hosts["r1"].groups)


def test_groups_nested_past_the_bound_are_refused_by_name(tmp_path):
    message = problems_of(tmp_path, {"hosts.yml": chain(5000, "      hosts: {r1: {ros_domain_id: 1}}\n")})
    assert "group 'g1000' is nested more than 1000 groups" in message and "hosts.yml:" in message


def test_a_long_group_cycle_is_one_short_line(tmp_path):
    message = problems_of(tmp_path, {"hosts.yml": chain(3000, "      children: {g0: {}}\n")})
    assert "group cycle g0 -> g1 -> g2 -> g3 -> ... (2994 more) -> g2998 -> g2999 -> g3000 -> g0" in message
    assert len(message.splitlines()) == 1 and len(message) < 400


@pytest.mark.parametrize("entry, count", [("r[1:9999999999]", 9999999999), ("r[a:z][a:z][a:z][a:z]", 26 ** 4),
                                          ("r[1:99999][1:99999:2]", 99999 * 50000)])
def test_a_host_range_past_the_bound_is_refused_before_it_expands(tmp_path, entry, count):
    message = problems_of(tmp_path, {"hosts": f"[lab]\n{entry} ros_domain_id=1\n"})
    assert f"hosts:2: invalid host range {entry!r}: it names {count} hosts, more than 20000" in message


def test_ranges_together_past_the_bound_are_refused(tmp_path):
    lines = "".join(f"{p}[1:8000]\n" for p in "abc")
    message = problems_of(tmp_path, {"hosts": f"[lab]\n{lines}"})
    assert "hosts:4: host range 'c[1:8000]' takes this inventory past 20000 hosts" in message


def test_yaml_hosts_may_be_null_and_ranges_expand(tmp_path):
    write(tmp_path, {"hosts.yml": "all:\n  vars:\n    ros_domain_id: 3\n  children:\n    empty:\n"
                                  "    fleet:\n      hosts:\n        amr-[01:03]:\n        spare:\n"})
    inventory = load_inventory(str(tmp_path / "hosts.yml"))
    assert list(inventory.hosts) == ["amr-01", "amr-02", "amr-03", "spare"]
    assert inventory.groups["empty"].hosts == ()


def test_precedence_each_level_overrides_the_one_below():
    host = load_inventory(str(DATA / "precedence")).hosts["h1"]
    expected = ["all_inline", "parent_inline", "child_inline", "all_file", "parent_file", "child_file",
                "host_inline", "host_file"]
    assert [host.vars[f"v{level}"] for level in range(1, 9)] == expected
    assert host.vars["sibling"] == "beta"     # equal depth: alphabetical, later wins
    assert host.groups == ("all", "alpha", "beta", "parent", "child")


def test_group_priority_reorders_groups_of_equal_depth(tmp_path):
    write(tmp_path, {"hosts.yml": "all:\n  children:\n"
                                  "    alpha:\n      vars: {x: alpha, ansible_group_priority: 10}\n"
                                  "      hosts: {r1: {ros_domain_id: 1}}\n"
                                  "    beta:\n      vars: {x: beta}\n      hosts: {r1: }\n"})
    assert load_inventory(str(tmp_path)).hosts["r1"].vars["x"] == "alpha"


def test_vault_encrypted_host_vars_are_secret(tmp_path):
    sealed = encrypt(b"ros_domain_id: 4\napi_token: s3cr3t-token\nnested: {key: deep-secret}\n", b"pw")
    write(tmp_path, {"hosts.yml": "all:\n  hosts:\n    r1:\n      note: public\n", "host_vars/r1.yml": sealed})
    host = load_inventory(str(tmp_path), Vault(b"pw")).hosts["r1"]
    assert host.ros_domain_id == 4
    assert host.secret_values == frozenset({"s3cr3t-token", "deep-secret"})


def test_inline_vault_values_like_ansible_encrypt_string(tmp_path):
    def tagged(sealed: bytes, indent: int = 2) -> str:
        return "!vault |\n" + "".join(f"{' ' * indent}{line}\n" for line in sealed.decode().splitlines())

    write(tmp_path, {"hosts.yml": ONE_HOST, "group_vars/all.yml":
                     "api_user: fleet\n"
                     f"api_token: {tagged(ansible_encrypt(b'tok-ansible', b'pw'))}"
                     f"db:\n  password: {tagged(encrypt(b'tok-rosdeploy', b'pw'), 4)}"})
    host = load_inventory(str(tmp_path), Vault(b"pw")).hosts["r1"]
    assert host.vars["api_token"] == "tok-ansible" and host.vars["db"] == {"password": "tok-rosdeploy"}
    assert host.secret_values == frozenset({"tok-ansible", "tok-rosdeploy"})


def test_select_uses_patterns_and_keeps_inventory_order():
    inventory = load_inventory(str(DATA / "ini"))
    names = [h.name for h in inventory.select("site_b:amr-a1:!amr-b02")]
    assert names == ["amr-a1", "amr-b01"]
    assert len(inventory.select(None)) == 6
    with pytest.raises(InventoryError, match="site_c"):
        inventory.select("site_c")


def test_relative_paths_resolve_against_the_working_directory_as_in_ansible(tmp_path, monkeypatch):
    write(tmp_path, {"inv/hosts.yml": "all:\n  hosts:\n    r1:\n      ros_domain_id: 1\n"
                                      "      ansible_ssh_private_key_file: keys/fleet\n"
                                      "      rosdeploy_known_hosts: keys/known_hosts\n"
                                      "    r2:\n      ros_domain_id: 2\n"
                                      "      ansible_ssh_private_key_file: '{{ inventory_dir }}/../keys/id'\n"})
    monkeypatch.chdir(tmp_path)
    hosts = load_inventory("inv").hosts
    assert hosts["r1"].key_file == str(tmp_path / "keys" / "fleet")
    assert hosts["r1"].vars["rosdeploy_known_hosts"] == str(tmp_path / "keys" / "known_hosts")
    assert hosts["r2"].key_file == str(tmp_path / "keys" / "id")   # beside the inventory: template it


def test_connection_var_aliases_and_bool_strings(tmp_path):
    write(tmp_path, {"hosts": "r1 ansible_ssh_host=10.0.0.7 ansible_ssh_user=ops ros_domain_id=1 gpu=yes\n"})
    host = load_inventory(str(tmp_path)).hosts["r1"]
    assert (host.address, host.user, host.gpu) == ("10.0.0.7", "ops", True)


def test_five_hundred_hosts_load_fast(tmp_path):
    hosts = "".join(f"        amr-{i:03d}:\n          ros_domain_id: {i % 200}\n" for i in range(500))
    files = {"hosts.yml": "all:\n  children:\n    fleet:\n      hosts:\n" + hosts,
             "group_vars/all.yml": "ansible_user: robot\n",
             "group_vars/fleet.yml": "devices: {lidar: /dev/robot/lidar}\n"}
    files.update({f"host_vars/amr-{i:03d}.yml": f"serial: SN{i}\n" for i in range(0, 500, 5)})
    write(tmp_path, files)
    started = time.perf_counter()
    inventory = load_inventory(str(tmp_path))
    assert len(inventory.hosts) == 500
    assert time.perf_counter() - started < 5  # ~0.3 s here; quadratic merging would blow this


# ------------------------------------------------------------------ bad input: file, line and key named


@pytest.mark.parametrize("files, where, key, words", [
    ({"hosts.yml": "all:\n  hosts:\n    r1: {ros_domain_id: 1\n"}, "hosts.yml:4", "", "invalid YAML"),
    ({"hosts": "[site a]\nr1 ros_domain_id=1\n"}, "hosts:1", "", "invalid section header"),
    ({"hosts": "[site]\nr1 ros_domain_id=1 oops\n"}, "hosts:2", "", "expected key=value"),
    ({"hosts": "[site]\nr1 note='unclosed\n"}, "hosts:2", "", "close the quote"),
    ({"hosts": "[site:vars]\nx=1\n"}, "hosts:1", "site", "never declared"),
    ({"hosts": "[site:children]\nsub\n[site]\nr1 ros_domain_id=1\n"}, "hosts:2", "sub", "never declared"),
    ({"hosts": "[site:kids]\n"}, "hosts:1", "", "unknown section type"),
    ({"hosts.yml": "all:\n  hosts:\n    r1:\n      ros_domain_id: 1\n      ansible_port: ssh\n"},
     "hosts.yml:5", "all.hosts.r1.ansible_port", "port number"),
    ({"hosts.yml": ONE_HOST, "group_vars/all.yml": "rosdeploy_devices: [/dev/ttyUSB0]\n"},
     "all.yml:1", "rosdeploy_devices", "mapping of logical name"),
    ({"hosts.yml": ONE_HOST, "group_vars/all.yml": "devices:\n  lidar: dev/ttyUSB0\n"},
     "all.yml:2", "devices.lidar", "under /dev"),
    ({"hosts.yml": ONE_HOST, "group_vars/all.yml": "devices:\n  lidar: /etc/shadow\n"},
     "all.yml:2", "devices.lidar", "under /dev"),
    ({"hosts.yml": ONE_HOST, "group_vars/all.yml": "rosdeploy_devices:\n  root: /\n"},
     "all.yml:2", "rosdeploy_devices.root", "under /dev"),
    ({"hosts.yml": ONE_HOST, "group_vars/all.yml": "devices:\n  x: /dev/../etc/shadow\n"},
     "all.yml:2", "devices.x", "under /dev"),
    ({"hosts.yml": ONE_HOST, "group_vars/all.yml": "devices:\n  lidar: /dev/tty;reboot\n"},
     "all.yml:2", "devices.lidar", "';'"),
    ({"hosts.yml": ONE_HOST, "group_vars/all.yml": "rosdeploy_gpu: maybe\n"}, "all.yml:1", "rosdeploy_gpu",
     "true or false"),
    ({"hosts.yml": ONE_HOST, "host_vars/r1.yml": "ros_domain_id: 300\n"}, "r1.yml:1", "ros_domain_id", "0-232"),
    ({"hosts.yml": ONE_HOST, "host_vars/r1.yml": "ros_domain_id: '7a'\n"}, "r1.yml:1", "ros_domain_id",
     "integer"),
    ({"hosts.yml": ONE_HOST, "group_vars/all.yml": "ansible_host: 'robot; rm -rf /'\n"},
     "all.yml:1", "ansible_host", "shell metacharacters"),
    ({"hosts.yml": ONE_HOST, "group_vars/all.yml": "ansible_host: -oProxyCommand=x\n"},
     "all.yml:1", "ansible_host", "option"),
    ({"hosts.yml": ONE_HOST, "group_vars/all.yml": "ansible_user: field tech\n"},
     "all.yml:1", "ansible_user", "whitespace"),
    ({"hosts.yml": ONE_HOST, "group_vars/all.yml": "ansible_ssh_private_key_file: /keys/my key\n"},
     "all.yml:1", "ansible_ssh_private_key_file", "whitespace"),
    ({"hosts.yml": ONE_HOST, "group_vars/all.yml": "rosdeploy_ros_network: [a]\n"}, "all.yml:1",
     "rosdeploy_ros_network", "network name"),
    ({"hosts.yml": ONE_HOST, "group_vars/all.yml": "rosdeploy_deploy_rot: /opt/x\n"}, "all.yml:1",
     "rosdeploy_deploy_rot", "did you mean 'rosdeploy_deploy_root'"),
    ({"hosts.yml": ONE_HOST, "host_vars/r1.yml": "rosdeploy_deploy_root: /opt/x/../../etc\n"}, "r1.yml:1",
     "rosdeploy_deploy_root", "without '..'"),
    ({"hosts.yml": ONE_HOST, "host_vars/r1.yml": "rosdeploy_deploy_root: ~/../../etc\n"}, "r1.yml:1",
     "rosdeploy_deploy_root", "without '..'"),
    ({"hosts.yml": ONE_HOST, "host_vars/r1.yml": "rosdeploy_deploy_root: '$(id)'\n"}, "r1.yml:1",
     "rosdeploy_deploy_root", "metacharacters"),
    ({"hosts.yml": ONE_HOST, "host_vars/r1.yml": "rosdeploy_deploy_root: /\n"}, "r1.yml:1",
     "rosdeploy_deploy_root", "absolute path"),
    ({"hosts.yml": ONE_HOST, "host_vars/r1.yml": "rosdeploy_deploy_root: ../../etc\n"}, "r1.yml:1",
     "rosdeploy_deploy_root", "absolute path"),
    ({"hosts.yml": ONE_HOST, "host_vars/r1.yml": "rosdeploy_compose: v9\n"}, "r1.yml:1",
     "rosdeploy_compose", "auto, v1, v2"),
    ({"hosts.yml": ONE_HOST, "host_vars/r1.yml": "ros_domain_id: '\u00b2'\n"}, "r1.yml:1",
     "ros_domain_id", "integer 0-232"),
    ({"hosts.yml": ONE_HOST, "host_vars/r1.yml": "ansible_port: '\u00b9'\n"}, "r1.yml:1",
     "ansible_port", "port number"),
    ({"hosts.yml": "all:\n  host:\n    r1:\n"}, "hosts.yml:2", "all.host", "did you mean 'hosts'"),
    ({"hosts.yml": "all:\n  hosts:\n    - r1\n"}, "hosts.yml:2", "all.hosts", "mapping of host names"),
    ({"hosts.yml": "all:\n  hosts:\n    'r 1':\n"}, "hosts.yml:3", "all.hosts.r 1", "invalid host name"),
    ({"hosts.yml": "all:\n  hosts:\n    r[3:1]:\n"}, "hosts.yml:3", "all.hosts.r[3:1]", "start is after"),
    ({"hosts.yml": ONE_HOST, "group_vars/al.yml": "x: 1\n"}, "al.yml", "", "did you mean 'all'"),
])
def test_bad_input_names_file_line_and_key(tmp_path, files, where, key, words):
    message = problems_of(tmp_path, files)
    assert where in message
    assert f" {key}:" in message if key else True
    assert words in message


UDEV_OK = "  - {symlink: robot/lidar, subsystem: tty, vendor: '10c4', product: 'ea60'}\n"


@pytest.mark.parametrize("entry, key, words", [
    ("  - {symlink: robot/lidar, subsystem: tty, vendor: 10c4x, product: 'ea60'}\n", "udev[0].vendor",
     "4 hex digits"),
    ("  - {symlink: robot/lidar, subsystem: tty, vendor: 0403, product: 'ea60'}\n", "udev[0].vendor",
     "quote it"),
    ("  - {symlink: /dev/robot/lidar, subsystem: tty, vendor: '10c4', product: 'ea60'}\n",
     "udev[0].symlink", "relative to /dev"),
    ("  - {symlink: robot/lidar, subsystem: tty, vendor: '10c4', product: 'ea60', serail: X}\n",
     "udev[0].serail", "did you mean 'serial'"),
    ("  - {symlink: robot/lidar, subsystem: tty, vendor: '10c4'}\n", "udev[0]", "missing product"),
    ("  - {symlink: robot/lidar, subsystem: tty, vendor: '10c4', product: 'ea60', mode: 660}\n",
     "udev[0].mode", "octal mode as a string"),
    (UDEV_OK + UDEV_OK, "udev[1].symlink", "listed twice"),
])
def test_bad_udev_entries(tmp_path, entry, key, words):
    message = problems_of(tmp_path, {"hosts.yml": ONE_HOST, "group_vars/all.yml": "udev:\n" + entry})
    assert "all.yml:" in message and f" {key}:" in message and words in message


def test_udev_entry_is_normalised(tmp_path):
    write(tmp_path, {"hosts.yml": ONE_HOST, "group_vars/all.yml":
                     "udev:\n  - {symlink: robot/cam, subsystem: video4linux, vendor: '046D', product: '0843',"
                     " serial: 'AB12', group: video, mode: '666'}\n"})
    host = load_inventory(str(tmp_path)).hosts["r1"]
    assert host.udev == (UdevDevice("robot/cam", "video4linux", "046d", "0843", "AB12", "video", "0666"),)


def test_missing_domain_id_is_left_to_the_checks_of_the_targeted_robots(tmp_path):
    # Shared inventories hold hosts rosdeploy never deploys to (a `localhost`, a build box):
    # `validate`/`check` refuse a targeted robot without one (rule domain-id-missing).
    write(tmp_path, {"hosts.yml": "all:\n  hosts:\n    r1:\n    r2:\n      ros_domain_id: 2\n"})
    assert "ros_domain_id" not in load_inventory(str(tmp_path)).hosts["r1"].vars


def test_host_indented_as_a_group_gets_a_hint(tmp_path):
    message = problems_of(tmp_path, {"hosts.yml": "all:\n  children:\n    r1:\n      ros_domain_id: 1\n"})
    assert "hosts.yml:4: all.children.r1.ros_domain_id:" in message and "list it under hosts:" in message


def test_group_cycle_is_named(tmp_path):
    message = problems_of(tmp_path, {"hosts": "[a:children]\nb\n[b:children]\na\n[a]\n[b]\nr1 ros_domain_id=1\n"})
    assert "a -> b -> a" in message and "hosts:4" in message


def test_every_problem_is_reported_at_once(tmp_path):
    message = problems_of(tmp_path, {
        "hosts.yml": "all:\n  hosts:\n    r1:\n      ansible_port: x\n    r2:\n      ros_domain_id: 999\n",
        "group_vars/all.yml": "rosdeploy_gpus: 1\n",
    })
    lines = message.splitlines()
    assert len(lines) == 3, message   # r1 port, r2 id range, rosdeploy_gpus unknown
    assert any("rosdeploy_gpus" in line and "did you mean 'rosdeploy_gpu'" in line for line in lines)


def test_group_level_problem_is_reported_once_not_per_host(tmp_path):
    hosts = "".join(f"    r{i}:\n      ros_domain_id: {i}\n" for i in range(20))
    message = problems_of(tmp_path, {"hosts.yml": "all:\n  hosts:\n" + hosts,
                                     "group_vars/all.yml": "rosdeploy_gpu: 2\n"})
    assert len(message.splitlines()) == 20   # one per robot, each naming it: the value is rosdeploy's
    assert "robot 'r7'" in message


def test_host_vars_for_dotted_names(tmp_path):
    write(tmp_path, {"hosts": "10.0.0.5\namr.lan\n", "host_vars/10.0.0.5": "ros_domain_id: 5\n",
                     "host_vars/amr.lan.yml": "ros_domain_id: 6\n", "host_vars/README.md": "notes\n"})
    hosts = load_inventory(str(tmp_path)).hosts
    assert (hosts["10.0.0.5"].ros_domain_id, hosts["amr.lan"].ros_domain_id) == (5, 6)


def test_vars_directory_beside_a_vars_file_wins_as_in_ansible(tmp_path):
    write(tmp_path, {"hosts.yml": ONE_HOST, "group_vars/all.yml": "a: 1\n", "group_vars/all/x.yml": "b: 2\n"})
    inventory = load_inventory(str(tmp_path))
    assert dict(inventory.hosts["r1"].vars) == {"ros_domain_id": 1, "b": 2}   # Ansible reads all/ only
    assert any("all.yml" in w.file and "ignored" in w.message for w in inventory.warnings)


def test_symlink_loop_in_group_vars_reads_each_file_once(tmp_path):
    write(tmp_path, {"hosts.yml": ONE_HOST, "group_vars/all/x.yml": "b: 2\n"})
    (tmp_path / "group_vars" / "all" / "loop").symlink_to("..")
    (tmp_path / "group_vars" / "all" / "self").symlink_to(".")
    inventory = load_inventory(str(tmp_path))
    assert inventory.hosts["r1"].vars["b"] == 2
    assert any("symlink loop" in w.message for w in inventory.warnings)


def test_missing_inventory_and_empty_inventory(tmp_path):
    with pytest.raises(InventoryError, match="inventory not found"):
        load_inventory(str(tmp_path / "nope"))
    (tmp_path / "hosts.yml").write_text("all:\n  children:\n    empty:\n")
    with pytest.raises(InventoryError, match="defines no hosts"):
        load_inventory(str(tmp_path))


def test_scripts_are_refused_and_other_names_are_ini(tmp_path):
    message = problems_of(tmp_path, {"hosts.yml": ONE_HOST, "ec2.py": "#!/usr/bin/env python\n"})
    assert "ec2.py" in message and "not executable" in message
    (tmp_path / "ec2.py").unlink()
    write(tmp_path, {"staging.hosts": "[extra]\nx1 ros_domain_id=9\n", "hosts.yml.example": "junk: [\n"})
    assert list(load_inventory(str(tmp_path)).hosts) == ["r1", "x1"]   # any other name is INI, like Ansible


def test_vars_for_groups_and_hosts_of_other_inventories_are_ignored(tmp_path):
    write(tmp_path, {"hosts.yml": "all:\n  children:\n    site_1:\n      hosts: {r1: {ros_domain_id: 1}}\n",
                     "group_vars/staging_only.yml": "x: 1\n", "group_vars/site_2.yml": "x: 1\n",
                     "host_vars/r2.yml": "x: 1\n"})
    assert list(load_inventory(str(tmp_path)).hosts) == ["r1"]
