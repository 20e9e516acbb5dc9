"""Inventories written for Ansible: templates (sandboxed), other tools' vars, ranges, legacy names,
dynamic inventories; and hostile input refused cleanly (exit 2, file:key, nothing written)."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from rosdeploy.cli import main
from rosdeploy.errors import InventoryError
from rosdeploy.inventory import load_inventory

DATA = Path(__file__).resolve().parent / "data" / "fleet"
ONE = "all:\n  hosts:\n    r1:\n      ros_domain_id: 1\n"


def write(root: Path, files: dict[str, str]) -> Path:
    for name, content in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(content)
    return root


def refused(root: Path, files: dict[str, str]) -> str:
    write(root, files)
    with pytest.raises(InventoryError) as caught:
        load_inventory(str(root))
    return str(caught.value)


# ------------------------------------------------------------------ templates


def test_templates_see_ansibles_inventory_vars(tmp_path: Path) -> None:
    write(tmp_path, {"hosts.yml": "web:\n  hosts:\n    w1: {port_base: 2200, ros_domain_id: 1}\n"
                                  "    w2: {port_base: 2300, ros_domain_id: 2}\n"
                                  "  vars:\n    ansible_port: '{{ port_base + 1 }}'\n"
                                  "    ansible_host: '{{ inventory_hostname }}.lan'\n"
                                  "    first: \"{{ groups['web'][0] }}\"\n"
                                  "    other: \"{{ hostvars['w2']['ansible_host'] }}\"\n"
                                  "    mine: '{{ group_names }}'\n"})
    w1 = load_inventory(str(tmp_path)).hosts["w1"]
    assert (w1.address, w1.port) == ("w1.lan", 2201)
    assert (w1.vars["first"], w1.vars["other"], w1.vars["mine"]) == ("w1", "w2.lan", ["web"])


def test_unsafe_values_are_never_templated(tmp_path: Path) -> None:
    write(tmp_path, {"hosts.yml": ONE, "group_vars/all.yml": "raw: !unsafe '{{ lipsum }}'\n"})
    assert load_inventory(str(tmp_path)).hosts["r1"].vars["raw"] == "{{ lipsum }}"


@pytest.mark.parametrize("payload", [
    "{{ lipsum.__globals__.os.popen('touch MARKER; echo $ROSDEPLOY_TEST_SECRET').read() }}",
    "{{ cycler.__init__.__globals__.os.system('touch MARKER') }}",
    "{{ ''.__class__.__mro__[1].__subclasses__() }}",
    "{{ range.__init__.__globals__ }}",
    "{{ self._TemplateReference__context.environment }}",
    "{{ lookup('env', 'ROSDEPLOY_TEST_SECRET') }}",
])
def test_a_hostile_template_runs_nothing_and_leaks_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                          payload: str) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("ROSDEPLOY_TEST_SECRET", "s3cr3t-from-env")
    root = write(tmp_path / "inv", {"hosts.yml": ONE, "host_vars/r1.yml": f"x: 1\nansible_host: \"{payload}\"\n"})
    with pytest.raises(InventoryError) as caught:
        load_inventory(str(root))
    message = str(caught.value)
    assert "host_vars/r1.yml:2: ansible_host:" in message and "robot 'r1'" in message
    assert "s3cr3t-from-env" not in message
    assert not list(tmp_path.rglob("MARKER"))


def test_a_template_error_in_a_var_read_later_names_file_and_key(tmp_path: Path) -> None:
    write(tmp_path, {"hosts.yml": ONE, "group_vars/all.yml": "motd: '{{ nope }}'\nloop: '{{ loop }}'\n"})
    host = load_inventory(str(tmp_path)).hosts["r1"]   # lazily: unused vars do not stop a load
    copied = {**host.vars}                              # nor does copying them
    with pytest.raises(InventoryError, match=r"all.yml:1: motd: robot 'r1': cannot template .*nope"):
        str(copied["motd"])
    with pytest.raises(InventoryError, match="recursive loop"):
        str(host.vars["loop"])


@pytest.mark.parametrize("broken", ["{{ 1/0 }}", "{{ [[1] }}", "{{ x | no_such_filter }}", "{{ model }}"])
@pytest.mark.parametrize("use", ["{{ model | default('small') }}", "{{ model | d('small') }}",
                                 "{{ model if model is defined else 'small' }}",
                                 "{{ 'small' if model is undefined else model }}"])
def test_a_broken_var_is_an_error_even_where_a_default_stands_in(
        tmp_path: Path, capsys: pytest.CaptureFixture, broken: str, use: str) -> None:
    """As in Ansible: `default` stands in for a var that is not there, or whose template reads a
    name that is not; a var whose template cannot work (1/0, a syntax error, a filter that does
    not exist, a loop) is an error, never quietly the default."""
    lab = tmp_path / "lab"
    shutil.copytree(DATA, lab)
    (lab / "inventory" / "host_vars" / "r2.yml").write_text(f"model: '{broken}'\n")
    fleet = (lab / "fleet.yml").read_text()
    (lab / "fleet.yml").write_text(fleet.replace("    restart: always\n",
                                                 f"    restart: always\n    environment: {{MODEL: \"{use}\"}}\n"))
    code = main(["render", str(lab / "fleet.yml"), "--vault-password-file",
                 str(lab / "inventory" / ".vault-password"), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "r2.yml:1: model: robot 'r2'" in err, err
    assert "Traceback" not in err and not (tmp_path / "out").exists()


@pytest.mark.parametrize("reads", ["{{ nosuch }}", "{{ nosuch.field }}", "{{ ansible_facts.hostname }}"])
def test_a_var_that_reads_an_undefined_name_takes_the_default(
        tmp_path: Path, capsys: pytest.CaptureFixture, reads: str) -> None:
    lab = tmp_path / "lab"
    shutil.copytree(DATA, lab)
    (lab / "inventory" / "host_vars" / "r2.yml").write_text(f"model: '{reads}'\n")
    fleet = (lab / "fleet.yml").read_text()
    (lab / "fleet.yml").write_text(fleet.replace(
        "    restart: always\n", "    restart: always\n    environment: {MODEL: \"{{ model | default('small') }}\"}\n"))
    code = main(["render", str(lab / "fleet.yml"), "--vault-password-file",
                 str(lab / "inventory" / ".vault-password"), "--out", str(tmp_path / "out")])
    assert code == 0, capsys.readouterr().err
    assert 'MODEL: "small"' in (tmp_path / "out" / "r2" / "compose.yml").read_text()


def test_vars_that_need_a_playbook_fail_only_where_a_fleet_template_uses_them(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    lab = tmp_path / "lab"
    shutil.copytree(DATA, lab)
    extra = "iface: '{{ ansible_default_ipv4.interface }}'\nrepo: '{{ playbook_dir }}/..'\n"
    (lab / "inventory" / "group_vars" / "all" / "other_roles.yml").write_text(extra)
    argv = ["render", str(lab / "fleet.yml"), "--vault-password-file", str(lab / "inventory" / ".vault-password")]
    assert main([*argv, "--out", str(tmp_path / "ok")]) == 0, capsys.readouterr().err   # unused: as in Ansible
    fleet = (lab / "fleet.yml").read_text()
    (lab / "fleet.yml").write_text(fleet.replace("    restart: always\n",
                                                 "    restart: always\n    environment: {IFACE: '{{ iface }}'}\n"))
    code = main([*argv, "--out", str(tmp_path / "used")])
    err = capsys.readouterr().err
    assert code == 2 and "other_roles.yml:1: iface:" in err and "ansible_default_ipv4" in err, err
    assert "Traceback" not in err


def test_multi_line_values_are_fine_where_they_reach_no_env_file(tmp_path: Path) -> None:
    write(tmp_path, {"hosts.yml": ONE, "group_vars/all.yml": "config: |\n  a: 1\n  b: 2\n"})
    assert load_inventory(str(tmp_path)).hosts["r1"].vars["config"] == "a: 1\nb: 2\n"


# ------------------------------------------------------------------ Ansible's shapes


def test_host_ranges_as_ansible_expands_them(tmp_path: Path) -> None:
    write(tmp_path, {"hosts": "[a]\namr[0:11]\n[c]\ncam[0:10:5]\n[p]\nr[08:10]\n"})
    hosts = list(load_inventory(str(tmp_path)).hosts)
    assert hosts[:12] == [f"amr{i}" for i in range(12)]
    assert hosts[12:] == ["cam0", "cam5", "cam10", "r08", "r09", "r10"]


def test_legacy_connection_names_win_as_in_ansible(tmp_path: Path) -> None:
    write(tmp_path, {"hosts.yml": "all:\n  vars: {ansible_ssh_user: legacy, ansible_ssh_port: 2222}\n  hosts:\n"
                                  "    r1: {ansible_host: 10.0.0.1, ansible_ssh_host: 10.0.0.9, ansible_user: new,"
                                  " ansible_port: 22}\n"})
    r1 = load_inventory(str(tmp_path)).hosts["r1"]
    assert (r1.address, r1.user, r1.port) == ("10.0.0.9", "legacy", 2222)


def test_null_user_and_foreign_shapes_load_with_warnings(tmp_path: Path) -> None:
    write(tmp_path, {"hosts": "[osds]\nosd0 devices=\"['/dev/sda']\" gpu=nvidia-orin\n"
                              "r1 rosdeploy_gpu=yes gpu=nvidia-orin ros_domain_id=1\n",
                     "group_vars/all.yml": "ansible_user:\ngpus: 2\n"})
    inventory = load_inventory(str(tmp_path))
    osd0, r1 = inventory.hosts["osd0"], inventory.hosts["r1"]
    assert (osd0.user, osd0.gpu, dict(osd0.devices)) == (None, False, {})
    assert r1.gpu is True   # the prefixed name wins; the short one is another tool's
    said = [str(w) for w in inventory.warnings]
    assert any("hosts:2: devices:" in w and "rosdeploy_devices" in w for w in said)
    assert any("'gpus'" in w and "did you mean 'gpu'" in w for w in said)
    assert not any("r1" in w and "gpu is" in w for w in said)


def test_dynamic_inventory_script_runs_without_a_shell(tmp_path: Path) -> None:
    script = tmp_path / "inv.py"
    script.write_text("#!/usr/bin/env python3\nimport json, sys\n"
                      "print(json.dumps({'robots': {'hosts': ['r1', 'r2'], 'vars': {'ros_domain_id': 3}},"
                      " '_meta': {'hostvars': {'r2': {'ros_domain_id': 4}}}} if sys.argv[1] == '--list' else {}))\n")
    script.chmod(0o755)
    inventory = load_inventory(str(script))
    assert [(h.name, h.ros_domain_id) for h in inventory.hosts.values()] == [("r1", 3), ("r2", 4)]


def test_dynamic_inventory_that_fails_is_refused_clearly(tmp_path: Path) -> None:
    script = tmp_path / "inv.sh"
    script.write_text("#!/bin/sh\necho 'not json'\n")
    script.chmod(0o755)
    with pytest.raises(InventoryError, match=r"inv.sh: dynamic inventory script: .*did not print JSON"):
        load_inventory(str(script))


def test_group_name_with_odd_characters_is_kept_with_a_warning(tmp_path: Path) -> None:
    write(tmp_path, {"hosts": "[site;north]\nr1 ros_domain_id=1\n[site;north:vars]\nx=2\n"})
    inventory = load_inventory(str(tmp_path))
    assert inventory.groups["site;north"].hosts == ("r1",) and inventory.hosts["r1"].vars["x"] == 2
    assert any("'site;north'" in str(w) for w in inventory.warnings)


def test_duplicate_keys_warn_and_keep_the_last(tmp_path: Path) -> None:
    write(tmp_path, {"hosts.yml": ONE, "group_vars/all.yml": "a: 1\na: 2\n"})
    inventory = load_inventory(str(tmp_path))
    assert inventory.hosts["r1"].vars["a"] == 2
    assert any("all.yml:2: a: duplicate key" in str(w) for w in inventory.warnings)


def test_a_host_name_with_a_newline_stays_on_one_line(tmp_path: Path) -> None:
    message = refused(tmp_path, {"hosts.yml": 'all:\n  hosts:\n    "r1\\nERROR: fake":\n'})
    assert len(message.splitlines()) == 1 and "'r1\\nERROR: fake'" in message


# ------------------------------------------------------------------ hostile input, through the CLI


@pytest.mark.parametrize("host_vars, key", [
    ("ros_domain_id: \"\u00b2\"\n", "ros_domain_id"),
    ("ansible_port: \"\u00b9\"\n", "ansible_port"),
    ("devices: {secrets: /etc/shadow}\n", "devices.secrets"),
    ("devices: {root: /}\n", "devices.root"),
    ("rosdeploy_deploy_root: $(id)\n", "rosdeploy_deploy_root"),
    ("rosdeploy_deploy_root: /opt/x/../../etc\n", "rosdeploy_deploy_root"),
    ("rosdeploy_compose: v9\n", "rosdeploy_compose"),
    ("rosdeploy_deploy_rot: /opt/x\n", "rosdeploy_deploy_rot"),
    ("ansible_host: \"{{ lipsum.__globals__.os.popen('id').read() }}\"\n", "ansible_host"),
])
def test_cli_refuses_hostile_inventory_values(tmp_path: Path, capsys: pytest.CaptureFixture,
                                             host_vars: str, key: str) -> None:
    lab = tmp_path / "lab"
    shutil.copytree(DATA, lab)
    robot = next((lab / "inventory" / "host_vars").iterdir())
    robot.write_text(robot.read_text() + host_vars)
    out_dir = tmp_path / "out"
    code = main(["render", str(lab / "fleet.yml"), "--out", str(out_dir), "--vault-password-file",
                 str(lab / "inventory" / ".vault-password")])
    err = capsys.readouterr().err
    assert code == 2, err
    assert f"{robot.name}:" in err and f" {key}:" in err
    assert "Traceback" not in err
    assert not out_dir.exists() or not any(out_dir.iterdir())


def test_a_missing_key_file_names_the_file_and_the_variable(tmp_path: Path) -> None:
    from rosdeploy.errors import ConnectError
    from rosdeploy.transport import SSHOptions, SSHTransport
    write(tmp_path, {"hosts.yml": ONE, "group_vars/all.yml": "x: 1\nansible_ssh_private_key_file: "
                                                            "'{{ inventory_dir }}/keys/none'\n"})
    host = load_inventory(str(tmp_path)).hosts["r1"]
    with pytest.raises(ConnectError) as caught:
        SSHTransport(host, SSHOptions(known_hosts=str(tmp_path / "known_hosts"))).open()
    message = str(caught.value)
    assert str(tmp_path / "keys" / "none") in message and "does not exist" in message
    assert "ansible_ssh_private_key_file (" in message and "all.yml:2)" in message


def test_a_hung_dynamic_inventory_is_stopped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from rosdeploy.inventory import script as script_module
    monkeypatch.setattr(script_module, "TIMEOUT", 0.5)
    script = tmp_path / "slow.sh"
    script.write_text("#!/bin/sh\nsleep 30\n")
    script.chmod(0o755)
    with pytest.raises(InventoryError, match=r"slow.sh --list` did not finish within"):
        load_inventory(str(script))


def test_a_dynamic_inventory_that_prints_without_end_is_stopped(tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """Bounded memory: the output goes to a file whose size is watched, and the script (with what it
    started) is stopped past MAX_OUTPUT, long before TIMEOUT."""
    import time

    from rosdeploy.inventory import script as script_module
    monkeypatch.setattr(script_module, "MAX_OUTPUT", 1 << 20)
    script = tmp_path / "endless.sh"
    marker = tmp_path / "still-running"
    script.write_text(f"#!/bin/sh\n(sleep 2; touch {marker}) &\nyes '{{\"all\": []}}'\n")
    script.chmod(0o755)
    began = time.monotonic()
    with pytest.raises(InventoryError, match=r"endless.sh --list` printed more than 1 MB"):
        load_inventory(str(script))
    assert time.monotonic() - began < 10
    time.sleep(2.5)
    assert not marker.exists(), "what the script started was stopped with it"


def test_fleet_commands_take_vault_ids_and_print_inventory_warnings(tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture) -> None:
    lab = tmp_path / "lab"
    shutil.copytree(DATA, lab)
    robot = next((lab / "inventory" / "host_vars").iterdir())
    (lab / "inventory" / "group_vars" / "all" / "other.yml").write_text("gpus: 2\n")
    password = lab / "inventory" / ".vault-password"
    code = main(["validate", str(lab / "fleet.yml"), "--vault-id", f"lab@{password}",
                 "--limit", f"{robot.stem}:nomatch"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "warning:" in err and "'nomatch' matches no host or group" in err
    assert "other.yml:1: gpus:" in err and "did you mean 'gpu'" in err
