"""Probe P's vault and inventory bounds (round 10): key derivations per command, malformed scrypt
headers, a symbolic link loop as the inventory, an Ansible vault's memory, the host bound."""
from __future__ import annotations

import tracemalloc
from pathlib import Path

import pytest

from rosdeploy import vault
from rosdeploy.errors import InputError, VaultError
from rosdeploy.inventory import load_inventory, ranges
from rosdeploy.vault import ScryptParams, Vault, VaultId

PASSWORD = b"hunter2"
COSTLY = ScryptParams(n=2 ** 16, r=8, p=2)    # the reproducer's header: 4x rosdeploy's work, within the cap


@pytest.fixture
def cheap_scrypt(monkeypatch: pytest.MonkeyPatch) -> list[ScryptParams]:
    """scrypt at a trivial cost whatever the header says, counting each derivation: the budget reads
    the header's cost, so the reproducer's shape runs in milliseconds."""
    real = vault._scrypt
    calls: list[ScryptParams] = []

    def fake(password: bytes, salt: bytes, params: ScryptParams) -> bytes:
        calls.append(params)
        return real(password, salt, ScryptParams(n=16, r=8, p=1))

    monkeypatch.setattr(vault, "_scrypt", fake)
    return calls


def inventory_with_values(root: Path, count: int, params: ScryptParams = COSTLY) -> Path:
    """hosts.ini with one robot, and group_vars/all.yml holding `count` inline `!vault` values."""
    (root / "group_vars").mkdir(parents=True)
    (root / "hosts.ini").write_text("[robots]\nr1 ansible_host=10.0.0.1 ros_domain_id=5\n")
    lines = []
    for index in range(count):
        sealed = vault.encrypt(f"v{index}".encode(), PASSWORD, params).decode()
        lines.append(f"s{index}: !vault |\n" + "".join(f"  {line}\n" for line in sealed.splitlines()))
    (root / "group_vars" / "all.yml").write_text("".join(lines))
    return root


def six_ids(root: Path) -> list[VaultId]:
    """Five wrong passwords, then the right one: the reproducer's --vault-id order."""
    ids = []
    for label in "abcdef":
        (root / f"pw-{label}").write_bytes(PASSWORD if label == "f" else f"wrong-{label}".encode())
        ids.append(VaultId(label, str(root / f"pw-{label}")))
    return ids


# ------------------------------------------------------- 1. key derivations per command

def test_values_are_tried_first_with_the_id_that_opened_the_last_one(tmp_path: Path,
                                                                     cheap_scrypt: list[ScryptParams]) -> None:
    """10 values x 6 ids were 60 derivations (27 s at the reproducer's cost): the right id is
    learned from the first value, so 6 + 9, within the budget, and every value is read."""
    root = inventory_with_values(tmp_path / "inv", 10)
    cheap_scrypt.clear()     # the encryptions above
    inventory = load_inventory(str(root), Vault(ids=six_ids(tmp_path)))
    assert len(cheap_scrypt) == 15
    assert inventory.hosts["r1"].vars["s9"] == "v9"


def test_many_costly_values_are_refused_at_the_budget_naming_the_line(tmp_path: Path,
                                                                      cheap_scrypt: list[ScryptParams]) -> None:
    """70 values at 4x the work (25 s with the right password): refused at the value that would
    cross the budget (256 default derivations: the 65th here), at its file:line, with what to do."""
    root = inventory_with_values(tmp_path / "inv", 70)
    cheap_scrypt.clear()
    with pytest.raises(InputError) as caught:
        load_inventory(str(root), Vault(PASSWORD))
    message = str(caught.value)
    assert len(cheap_scrypt) == vault.MAX_KDF_WORK // (COSTLY.n * COSTLY.r * COSTLY.p) == 64
    line = 1 + 64 * (1 + len(vault.encrypt(b"v0", PASSWORD, COSTLY).splitlines()))
    assert f"group_vars/all.yml:{line}: " in message and "key-derivation budget" in message
    assert "vault-encrypted vars files" in message and len(message.splitlines()) == 1


def test_values_at_rosdeploys_cost_fit_the_budget(tmp_path: Path, cheap_scrypt: list[ScryptParams]) -> None:
    """What `encrypt-string` writes: 256 values in one command are read."""
    root = inventory_with_values(tmp_path / "inv", 256, ScryptParams())
    assert load_inventory(str(root), Vault(PASSWORD)).hosts["r1"].vars["s255"] == "v255"


def test_ansible_values_cost_a_sixteenth(monkeypatch: pytest.MonkeyPatch) -> None:
    """Ansible's PBKDF2 is ~1/20 of rosdeploy's scrypt: 16 of its files where one of ours (the
    budget cut to two of ours, so that 33 PBKDF2 runs show it)."""
    monkeypatch.setattr(vault, "MAX_KDF_WORK", 2 * vault._DEFAULT_WORK)
    keeper = Vault(PASSWORD)
    sealed = [vault.ansible_encrypt(f"v{i}".encode(), PASSWORD) for i in range(33)]
    assert [keeper.decrypt(each, "f") for each in sealed[:32]][-1] == b"v31"
    with pytest.raises(VaultError, match="key-derivation budget"):
        keeper.decrypt(sealed[32], "f")


def test_a_cached_file_costs_nothing_more(cheap_scrypt: list[ScryptParams]) -> None:
    keeper = Vault(PASSWORD)
    sealed = vault.encrypt(b"x", PASSWORD, COSTLY)
    for _ in range(100):
        assert keeper.decrypt(sealed, "f") == b"x"


# ------------------------------------------------------- 3. a repeated scrypt field

@pytest.mark.parametrize("fields", ["n=32768,r=8,p=1,n=2", "n=32768,r=8,r=8,p=1", "n=32768,r=8,p=1,x=1",
                                    "n=32768,r=8"])
def test_a_scrypt_header_with_a_repeated_or_unknown_field_is_malformed(fields: str) -> None:
    data = f"$ROSDEPLOY_VAULT;1;AES256-GCM;scrypt;{fields}\nAAAA\n".encode()
    with pytest.raises(VaultError, match="malformed scrypt parameters .* expected n=N,r=R,p=P, each once"):
        vault.check_header(data, "f")


def test_a_repeated_field_in_an_inline_value_is_refused_at_its_line(tmp_path: Path) -> None:
    root = inventory_with_values(tmp_path / "inv", 1, ScryptParams(n=16))
    path = root / "group_vars" / "all.yml"
    path.write_text("plain: 1\n" + path.read_text().replace("p=1", "p=1,n=2"))
    with pytest.raises(InputError) as caught:
        load_inventory(str(root), Vault(PASSWORD))
    assert "all.yml:2" in str(caught.value) and "malformed scrypt parameters" in str(caught.value)


# ------------------------------------------------------- 4. a symbolic link loop as the inventory

def test_a_symlink_loop_as_the_inventory_is_named(tmp_path: Path) -> None:
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    with pytest.raises(InputError) as caught:
        load_inventory(str(tmp_path / "a"))
    assert "symbolic link loop" in str(caught.value) and "not found" not in str(caught.value)
    with pytest.raises(InputError, match="inventory not found"):
        load_inventory(str(tmp_path / "missing"))


# ------------------------------------------------------- 5. an Ansible vault's memory

def test_a_large_ansible_vault_with_a_wrong_password_is_not_copied_line_by_line() -> None:
    """The hex body was decoded to text, split into its lines, joined, unhexlified and split
    again: ~6 times the file (382 MB for 60 MB). Now about its size once more, and a half."""
    data = vault.ansible_encrypt(b"k: " + b"x" * (2 << 20), PASSWORD)
    tracemalloc.start()
    try:
        with pytest.raises(VaultError, match="wrong vault password"):
            vault.decrypt(data, b"wrong", "f")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 2.5 * len(data), peak / len(data)
    assert vault.decrypt(data, PASSWORD, "f").endswith(b"xxx")


# ------------------------------------------------------- 2. the host bound

def test_a_range_past_20000_hosts_is_refused_from_its_count(tmp_path: Path) -> None:
    """100,000 hosts took 45 s and 1.7 GB: the bound is 20,000 (4x the issue's 5,000 robots)."""
    assert ranges.MAX_HOSTS == ranges.MAX_RANGE_HOSTS == 20_000
    (tmp_path / "hosts").write_text("[lab]\nr[1:20001] ros_domain_id=1\n")
    with pytest.raises(InputError) as caught:
        load_inventory(str(tmp_path))
    assert "hosts:2: invalid host range 'r[1:20001]': it names 20001 hosts, more than 20000" in str(caught.value)


def test_ranges_past_the_bound_together_are_refused_and_add_no_host(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ranges, "MAX_HOSTS", 1000)     # the same code; a fiftieth of the hosts to build
    (tmp_path / "hosts").write_text("[lab]\na[1:400]\nb[1:400]\na[1:400]\nc[1:400]\nd[1:1]\n")
    with pytest.raises(InputError) as caught:
        load_inventory(str(tmp_path))
    message = str(caught.value)
    assert "hosts:5: host range 'c[1:400]' takes this inventory past 1000 hosts" in message
    assert len(message.splitlines()) == 1


def test_a_dynamic_inventory_past_the_bound_is_refused_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A script's hosts were bounded by its 64 MB of output only (millions of names), and each
    one without `_meta` is asked `--host`: refused at the bound, before any such run."""
    monkeypatch.setattr(ranges, "MAX_HOSTS", 5)
    script = tmp_path / "inv.py"
    script.write_text("#!/bin/sh\nif [ \"$1\" = --host ]; then touch \"$0.asked\"; echo '{}'; exit; fi\n"
                      "echo '{\"a\": [\"r1\", \"r2\", \"r3\"], \"b\": [\"r3\", \"r4\", \"r5\", \"r6\", \"r7\"], "
                      "\"c\": [\"r8\"]}'\n")
    script.chmod(0o755)
    with pytest.raises(InputError) as caught:
        load_inventory(str(script))
    message = str(caught.value)
    assert "names more than 5 hosts" in message and len(message.splitlines()) == 1
    assert not (tmp_path / "inv.py.asked").exists()
