"""Vault files and `!vault` values, both ways between rosdeploy and real ansible-vault."""
from __future__ import annotations

import argparse
import io
import json
from pathlib import Path

import pytest

from compat import REPO, ask, cli, require_ansible
from rosdeploy.cli import vault as vault_cli
from rosdeploy.inventory import load_inventory
from rosdeploy.inventory.templating import raw_vars
from rosdeploy.output import Output
from rosdeploy.vault import Vault, VaultId, view_file

TEXT = "fleet_api_token: s3cret-value\nnested: {a: 1}\n"


@pytest.fixture
def tmp(tmp_path: Path) -> Path:
    require_ansible()
    for label in ("dev", "prod"):
        (tmp_path / f"{label}.pw").write_text(f"{label}-password\n")
    return tmp_path


def rosdeploy_vault(*argv: str) -> str:
    parser = argparse.ArgumentParser()
    vault_cli.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["vault", *argv])
    out = io.StringIO()
    assert args.func(args, Output(stdout=out, stderr=out)) == 0
    return out.getvalue()


def ansible_vault(tmp: Path, *argv: str) -> str:
    done = cli(["ansible-vault", *argv], tmp)
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.mark.parametrize("ids", [["dev"], ["dev", "prod"]])
def test_rosdeploy_writes_what_ansible_vault_reads(tmp: Path, ids: list[str]) -> None:
    path = tmp / "vault.yml"
    path.write_text(TEXT)
    id_args = [arg for label in ids for arg in ("--vault-id", f"{label}@{tmp / f'{label}.pw'}")]
    rosdeploy_vault("encrypt", "--format", "ansible", *id_args, "--encrypt-vault-id", ids[-1], str(path))
    assert ansible_vault(tmp, "view", "--vault-id", f"{ids[-1]}@{tmp / f'{ids[-1]}.pw'}", str(path)) == TEXT


def test_ansible_vault_writes_what_rosdeploy_reads(tmp: Path) -> None:
    files = {}
    for label in ("dev", "prod"):
        files[label] = tmp / f"{label}.yml"
        files[label].write_text(TEXT.replace("s3cret", label))
        ansible_vault(tmp, "encrypt", "--vault-id", f"{label}@{tmp / f'{label}.pw'}", str(files[label]))
    vault = Vault(ids=[VaultId("dev", str(tmp / "dev.pw")), VaultId("prod", str(tmp / "prod.pw"))])
    for label, path in files.items():
        assert view_file(str(path), vault).decode() == TEXT.replace("s3cret", label)


def test_inline_vault_values_both_ways(tmp: Path) -> None:
    inventory = tmp / "inv"
    (inventory / "group_vars").mkdir(parents=True)
    (inventory / "hosts.yml").write_text("all:\n  hosts:\n    r1:\n")
    theirs = ansible_vault(tmp, "encrypt_string", "--vault-id", f"dev@{tmp / 'dev.pw'}", "--name", "from_ansible",
                           "ansible-made")
    ours_text = rosdeploy_vault("encrypt-string", "--format", "ansible", "--vault-id", f"prod@{tmp / 'prod.pw'}",
                                "--name", "from_rosdeploy", "rosdeploy-made")
    (inventory / "group_vars" / "all.yml").write_text(theirs + "\n" + ours_text)
    vault = Vault(ids=[VaultId("dev", str(tmp / "dev.pw")), VaultId("prod", str(tmp / "prod.pw"))])
    r1 = load_inventory(str(inventory), vault).hosts["r1"]
    assert (r1.vars["from_ansible"], r1.vars["from_rosdeploy"]) == ("ansible-made", "rosdeploy-made")
    answer = ask([{"inventory": str(inventory), "template": {"r1": ["from_ansible", "from_rosdeploy"]},
                   "vault": [["dev", "dev-password"], ["prod", "prod-password"]]}], tmp)[0]
    assert answer["templated"]["r1"] == {"from_ansible": "ansible-made", "from_rosdeploy": "rosdeploy-made"}


def test_the_example_inventory_reads_the_same_in_ansible(tmp: Path) -> None:
    example = REPO / "inventory" / "warehouse"
    password = example / ".vault-password-example"
    done = cli(["ansible-inventory", "-i", str(example), "--list", "--vault-password-file", str(password)], tmp)
    assert done.returncode == 0, done.stderr
    theirs = json.loads(done.stdout)["_meta"]["hostvars"]
    loaded = load_inventory(str(example), Vault(password_file=str(password)))
    assert {name: json.loads(json.dumps(dict(raw_vars(host.vars)))) for name, host in loaded.hosts.items()} == theirs
    assert theirs["amr-n1"]["fleet_api_token"] == "demo-4f9c2a7e1b8d4e6fa0c3"
