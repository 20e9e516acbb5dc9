"""Inventory file formats as Ansible picks them (probe T, round 11, defects 1-3).

Ansible tries its yaml plugin on a file with no extension or a `.yml`/`.yaml`/`.json` one, then its
ini plugin; a `.toml` file goes to its toml plugin. Each case was run through
`ansible-inventory -i FILE --list` (ansible-core 2.19) for the expected hosts, groups and vars.
"""
from __future__ import annotations

from pathlib import Path

import pytest

from rosdeploy.errors import InventoryError
from rosdeploy.inventory import load_inventory
from rosdeploy.inventory.known import SCRIPT_EXTS
from test_hostile import cli, lab  # noqa: F401  (lab: the fixture)

YAML_INVENTORY = """\
all:
  children:
    lab:
      hosts:
        r1: {ansible_host: 127.0.0.1, ros_domain_id: 1}
"""
INI_INVENTORY = "[lab]\nr1 ansible_host=127.0.0.1 ros_domain_id=1\n"
TOML_INVENTORY = """\
[lab]
children = ["web"]
vars = { site = "north" }

[lab.hosts]
r1 = { ansible_host = "127.0.0.1", ros_domain_id = 1 }

[web.hosts.r2]
ansible_host = "127.0.0.2"
ros_domain_id = 2
"""


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def problems(path: Path) -> list[str]:
    with pytest.raises(InventoryError) as caught:
        load_inventory(str(path))
    return [str(p) for p in caught.value.problems]


def lab_r1(path: Path) -> None:
    inventory = load_inventory(str(path))
    assert tuple(inventory.groups["lab"].hosts) == ("r1",)
    assert inventory.hosts["r1"].vars["ansible_host"] == "127.0.0.1"
    assert inventory.hosts["r1"].vars["ros_domain_id"] == 1


# ---------------------------------------------------------------- 1. no extension: YAML, then INI


def test_yaml_in_a_file_without_extension_is_read_as_yaml(tmp_path: Path) -> None:
    lab_r1(write(tmp_path, "hosts", YAML_INVENTORY))


def test_ini_in_a_file_without_extension_is_still_ini(tmp_path: Path) -> None:
    lab_r1(write(tmp_path, "hosts", INI_INVENTORY))
    # a bare list of names is a YAML string, not a mapping: INI, as in Ansible
    inventory = load_inventory(str(write(tmp_path, "names", "r1\nr2\n")))
    assert tuple(inventory.groups["ungrouped"].hosts) == ("r1", "r2")


def test_yaml_without_extension_keeps_yaml_checks_at_their_line(tmp_path: Path) -> None:
    found = problems(write(tmp_path, "hosts", YAML_INVENTORY.replace("hosts:", "host:")))
    assert len(found) == 1, found
    assert found[0].startswith(f"{tmp_path / 'hosts'}:4: all.children.lab.host: unknown key") and "'hosts'" in found[0]


def test_file_without_extension_that_neither_reader_reads_says_what_each_said(tmp_path: Path) -> None:
    broken = YAML_INVENTORY.replace("ros_domain_id: 1}", "ros_domain_id: 1") + "    web:\n"
    found = problems(write(tmp_path, "hosts", broken))
    assert found[0] == (f"{tmp_path / 'hosts'}:1: invalid host name 'all:': use letters, digits, '_', '-' and '.' "
                        "(other characters clash with patterns and shells)")     # INI first, as it was
    yaml = found[-1]
    assert yaml.startswith(f"{tmp_path / 'hosts'}:") and ": not YAML either (invalid YAML: " in yaml
    assert "hosts.yml" in yaml and "hosts.ini" in yaml
    assert len(found) > 2 and all("YAML" not in p for p in found[:-1])


def test_ini_file_without_extension_with_a_typo_gets_no_yaml_noise(tmp_path: Path) -> None:
    found = problems(write(tmp_path, "hosts", INI_INVENTORY + "r2 ros_domain_id\n"))
    assert found == [f"{tmp_path / 'hosts'}:3: expected key=value after the host name, got 'ros_domain_id': "
                     "quote values that hold spaces"], found


def test_inventory_directory_with_yaml_hosts_file_validates(lab: Path,  # noqa: F811
                                                             capsys: pytest.CaptureFixture) -> None:
    inventory = lab / "inventory"
    (inventory / "hosts.yml").rename(inventory / "hosts")
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text
    assert "invalid host name" not in text


# ---------------------------------------------------------------- 2. .yml / .json holding INI


@pytest.mark.parametrize("name", ["hosts.yml", "hosts.yaml", "hosts.json"])
def test_ini_text_in_a_yaml_or_json_file_is_read_as_ini_with_a_warning(tmp_path: Path, name: str) -> None:
    path = write(tmp_path, name, INI_INVENTORY)
    lab_r1(path)
    warnings = [str(w) for w in load_inventory(str(path)).warnings]
    kind = "JSON" if name.endswith(".json") else "YAML"
    assert any(f"not {kind} but INI" in w and "hosts.ini" in w for w in warnings), warnings


@pytest.mark.parametrize("name", ["hosts.yml", "hosts.json"])
def test_yaml_or_json_file_that_is_not_ini_either_gives_its_own_error_first(tmp_path: Path, name: str) -> None:
    found = problems(write(tmp_path, name, INI_INVENTORY + "[lab\n"))
    assert len(found) == 1, found
    kind = "JSON" if name.endswith(".json") else "YAML"
    assert f": invalid {kind}: " in found[0] and "not INI either" in found[0] and "line 3: " in found[0]


def test_json_syntax_error_is_in_json_words(tmp_path: Path) -> None:
    found = problems(write(tmp_path, "hosts.json", '{"all": {"hosts": {"r1": {}}}}\n[x\n'))
    assert len(found) == 1, found
    assert "document start" not in found[0]     # PyYAML's wording under a JSON label
    assert f"{tmp_path / 'hosts.json'}:2: invalid JSON: Extra data" in found[0]


def test_yaml_list_in_a_yml_file_that_ini_refuses_says_it_is_not_a_mapping(tmp_path: Path) -> None:
    found = problems(write(tmp_path, "hosts.yml", "- {a: 1}\n"))
    assert len(found) == 1 and "not a mapping" in found[0] and "not INI either" in found[0], found


# ---------------------------------------------------------------- 3. TOML


def test_toml_is_not_a_script_extension() -> None:
    assert ".toml" not in SCRIPT_EXTS


def test_toml_inventory_reads_as_ansible_toml_plugin(tmp_path: Path) -> None:
    inventory = load_inventory(str(write(tmp_path, "hosts.toml", TOML_INVENTORY)))
    assert set(inventory.hosts) == {"r1", "r2"}
    assert tuple(inventory.groups["web"].hosts) == ("r2",)
    assert inventory.hosts["r1"].vars["ros_domain_id"] == 1
    assert inventory.hosts["r2"].vars["site"] == "north"      # lab's var, through children
    assert inventory.hosts["r1"].vars["site"] == "north"


def test_toml_inventory_in_a_directory_is_read_not_refused_as_script(tmp_path: Path) -> None:
    folder = tmp_path / "inv"
    folder.mkdir()
    write(folder, "hosts.toml", TOML_INVENTORY)
    assert set(load_inventory(str(folder)).hosts) == {"r1", "r2"}


def test_toml_syntax_error_names_file_and_line(tmp_path: Path) -> None:
    found = problems(write(tmp_path, "hosts.toml", INI_INVENTORY))
    assert found == [f"{tmp_path / 'hosts.toml'}:2: invalid TOML: Expected '=' after a key in a key/value "
                     "pair (column 4)"]


@pytest.mark.parametrize(("text", "key", "words"), [
    ('[lab]\nchildren = "web"\n', "lab.children", "children must be a list of group names"),
    ("lab = 3\n", "lab", "must be a table"),
    ('[lab]\nhosts = ["r1"]\n', "lab.hosts", "hosts must be a table of host names"),
    ('[lab.hosts]\nr1 = "127.0.0.1"\n', "lab.hosts.r1", "a host's vars must be a table"),
])
def test_toml_shape_errors_name_file_and_key_path(tmp_path: Path, text: str, key: str, words: str) -> None:
    found = problems(write(tmp_path, "hosts.toml", text))
    assert any(p.startswith(f"{tmp_path / 'hosts.toml'}: {key}: ") and words in p for p in found), found


def test_toml_inventory_gets_the_yaml_readers_checks(tmp_path: Path) -> None:
    found = problems(write(tmp_path, "hosts.toml", '[lab.host]\nr1 = { ros_domain_id = 1 }\n'))
    assert found == [f"{tmp_path / 'hosts.toml'}: lab.host: unknown key in group 'lab': a group holds only "
                     "hosts:, vars: and children:; did you mean 'hosts'?"], found


def test_toml_bounds(tmp_path: Path) -> None:
    deep = "x = " + "[" * 400 + "]" * 400 + "\n"
    assert any("invalid TOML" in p or "nested" in p for p in problems(write(tmp_path, "deep.toml", deep)))
    big = f"[lab.hosts.r1]\nx = 0x{'f' * 4000}\n"
    assert any("bits" in p for p in problems(write(tmp_path, "big.toml", big)))
    noncharacter = '[lab.hosts.r1]\nx = "\\uFFFF"\n'
    assert any("lab.hosts.r1.x" in p for p in problems(write(tmp_path, "nc.toml", noncharacter)))


def test_toml_lab_inventory_validates(lab: Path, capsys: pytest.CaptureFixture) -> None:  # noqa: F811
    inventory = lab / "inventory"
    (inventory / "hosts.yml").unlink()
    write(inventory, "hosts.toml", '[lab.hosts]\nr1 = { ansible_host = "127.0.0.1", ros_domain_id = 1 }\n'
                                   'r2 = { ansible_host = "127.0.0.2", ros_domain_id = 2 }\n')
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text
    assert "script" not in text
