"""Vault: the file format, Ansible compatibility, password sources, cache, file and CLI operations."""
from __future__ import annotations

import argparse
import base64
import binascii
import hashlib
import hmac
import io
import os
import stat
import sys
from pathlib import Path

import pytest
from cryptography.hazmat.primitives.ciphers import Cipher, algorithms, modes

from rosdeploy import vault as vaultlib
from rosdeploy.cli import vault as vault_cli
from rosdeploy.errors import VaultError
from rosdeploy.output import Output
from rosdeploy.vault import (ScryptParams, Vault, ansible_encrypt, decrypt, decrypt_file, edit_file, encrypt,
                             encrypt_file, is_encrypted, view_file)

FAST = ScryptParams(n=2 ** 10)   # the format is the same; tests need not pay for real scrypt costs
SECRET = b"fleet_api_token: abc123\n"


# ------------------------------------------------------------------ format


def test_round_trip_and_text_format():
    sealed = encrypt(SECRET, b"pw")
    lines = sealed.decode("ascii").splitlines()
    assert lines[0] == "$ROSDEPLOY_VAULT;1;AES256-GCM;scrypt;n=32768,r=8,p=1"
    assert all(len(line) <= 64 for line in lines[1:])
    assert is_encrypted(sealed) and not is_encrypted(SECRET)
    assert decrypt(sealed, b"pw", "x.yml") == SECRET
    assert encrypt(SECRET, b"pw") != sealed        # a fresh salt and nonce every time


def test_parameters_in_the_header_are_honoured():
    sealed = encrypt(SECRET, b"pw", FAST)
    assert b"n=1024,r=8,p=1" in sealed.splitlines()[0]
    assert decrypt(sealed, b"pw", "x.yml") == SECRET


def test_wrong_password_names_the_file_and_the_password_source():
    with pytest.raises(VaultError) as caught:
        decrypt(encrypt(SECRET, b"pw", FAST), b"nope", "group_vars/all/vault.yml")
    message = str(caught.value)
    assert message.startswith("group_vars/all/vault.yml:")
    assert "wrong vault password" in message and "--vault-password-file" in message


def flip_body_byte(sealed: bytes, index: int) -> bytes:
    header, body = sealed.split(b"\n", 1)
    raw = bytearray(base64.b64decode(b"".join(body.split())))
    raw[index] ^= 0x01
    return header + b"\n" + base64.b64encode(bytes(raw)) + b"\n"


@pytest.mark.parametrize("index", [0, 16, 30, -1])   # salt, nonce, ciphertext, tag
def test_tampered_ciphertext_is_refused(index):
    with pytest.raises(VaultError, match="wrong vault password, or the file was modified"):
        decrypt(flip_body_byte(encrypt(SECRET, b"pw", FAST), index), b"pw", "x.yml")


def test_edited_header_is_refused():
    sealed = encrypt(SECRET, b"pw", FAST)
    edited = sealed.replace(b"r=8,p=1", b"r=8,p=2", 1)
    with pytest.raises(VaultError, match="wrong vault password, or the file was modified"):
        decrypt(edited, b"pw", "x.yml")


@pytest.mark.parametrize("header, words", [
    ("$ROSDEPLOY_VAULT;2;AES256-GCM;scrypt;n=1024,r=8,p=1", "unsupported vault header"),
    ("$ROSDEPLOY_VAULT;1;AES256-GCM;scrypt", "unsupported vault header"),
    ("$ROSDEPLOY_VAULT;1;CHACHA20;scrypt;n=1024,r=8,p=1", "unsupported cipher"),
    ("$ROSDEPLOY_VAULT;1;AES256-GCM;scrypt;n=1024,r=8", "malformed scrypt parameters"),
    ("$ROSDEPLOY_VAULT;1;AES256-GCM;scrypt;n=1000,r=8,p=1", "out of range"),
    ("$ROSDEPLOY_VAULT;1;AES256-GCM;scrypt;n=1099511627776,r=8,p=1", "out of range"),
    ("$ANSIBLE_VAULT;1.0;AES", "unsupported Ansible vault header"),
])
def test_header_errors(header, words):
    body = encrypt(SECRET, b"pw", FAST).split(b"\n", 1)[1]
    with pytest.raises(VaultError, match=words) as caught:
        decrypt(header.encode() + b"\n" + body, b"pw", "v.yml")
    assert str(caught.value).startswith("v.yml:")


@pytest.mark.parametrize("data, words", [
    (b"$ROSDEPLOY_VAULT;1;AES256-GCM;scrypt;n=1024,r=8,p=1\n!!!notbase64\n", "not valid base64"),
    (b"$ROSDEPLOY_VAULT;1;AES256-GCM;scrypt;n=1024,r=8,p=1\nAAAA\n", "truncated"),
    (b"$ROSDEPLOY_VAULT;1;AES256-GCM;scrypt;n=1024,r=8,p=1\n\xff\xfe\n", "non-ASCII"),
    (b"plain: yaml\n", "not a vault file"),
    (b"$ANSIBLE_VAULT;1.1;AES256\nzz\n", "malformed"),
])
def test_damaged_files(data, words):
    with pytest.raises(VaultError, match=words):
        decrypt(data, b"pw", "v.yml")


# ------------------------------------------------------------------ Ansible's format


def ansible_vault_by_the_spec(plaintext: bytes, password: bytes) -> bytes:
    """An independent writer of Ansible's 1.1 format (hashlib/hmac, not the code under test)."""
    salt = os.urandom(32)
    key = hashlib.pbkdf2_hmac("sha256", password, salt, 10000, 80)
    pad = 16 - len(plaintext) % 16
    encryptor = Cipher(algorithms.AES(key[:32]), modes.CTR(key[64:])).encryptor()
    ciphertext = encryptor.update(plaintext + bytes([pad]) * pad) + encryptor.finalize()
    mac = hmac.new(key[32:64], ciphertext, hashlib.sha256).digest()
    body = binascii.hexlify(b"\n".join(binascii.hexlify(x) for x in (salt, mac, ciphertext)))
    return b"$ANSIBLE_VAULT;1.1;AES256\n" + b"\n".join(body[i:i + 80] for i in range(0, len(body), 80)) + b"\n"


def test_reads_ansible_vault_files():
    data = ansible_vault_by_the_spec(SECRET, b"ansible-pw")
    assert is_encrypted(data)
    assert decrypt(data, b"ansible-pw", "a.yml") == SECRET
    with pytest.raises(VaultError, match="wrong vault password"):
        decrypt(data, b"other", "a.yml")


def test_writes_ansible_format_with_its_label():
    data = ansible_encrypt(SECRET, b"pw", label="prod")
    assert data.startswith(b"$ANSIBLE_VAULT;1.2;AES256;prod\n")
    assert vaultlib.ansible_label(data) == "prod"
    assert decrypt(data, b"pw", "a.yml") == SECRET


# ------------------------------------------------------------------ password sources and cache


@pytest.fixture
def sealed() -> bytes:
    return encrypt(SECRET, b"right", FAST)


def test_password_file_comes_first_and_is_stripped(tmp_path, sealed):
    (tmp_path / "pw").write_text("right\n")
    env = {vaultlib.ENV_PASSWORD_FILE: "/nonexistent", vaultlib.ENV_PASSWORD: "wrong"}
    vault = Vault(password_file=str(tmp_path / "pw"), env=env, prompt=lambda _: "wrong")
    assert vault.decrypt(sealed, "v.yml") == SECRET
    assert vault.password_source.startswith("--vault-password-file")


def test_env_file_then_env_password_then_prompt(tmp_path, sealed):
    (tmp_path / "pw").write_text("right")
    env_file = Vault(env={vaultlib.ENV_PASSWORD_FILE: str(tmp_path / "pw"), vaultlib.ENV_PASSWORD: "wrong"})
    assert env_file.decrypt(sealed, "v.yml") == SECRET
    assert Vault(env={vaultlib.ENV_PASSWORD: "right"}, prompt=lambda _: "wrong").decrypt(sealed, "v") == SECRET
    assert Vault(env={}, prompt=lambda _: "right").decrypt(sealed, "v.yml") == SECRET


def test_prompt_is_asked_once_and_only_when_needed(sealed):
    asked = []
    vault = Vault(env={}, prompt=lambda text: asked.append(text) or "right")
    assert vault.read("plain.yml", b"a: 1\n") == (b"a: 1\n", False)
    assert asked == []
    vault.decrypt(sealed, "a.yml")
    vault.decrypt(encrypt(b"other", b"right", FAST), "b.yml")
    assert len(asked) == 1


def test_no_password_source_says_how_to_give_one(sealed):
    with pytest.raises(VaultError) as caught:
        Vault(env={}).decrypt(sealed, "group_vars/all/vault.yml")
    message = str(caught.value)
    assert message.startswith("group_vars/all/vault.yml:")
    assert "--vault-password-file" in message and "ROSDEPLOY_VAULT_PASSWORD" in message


def test_each_file_is_decrypted_once(monkeypatch, sealed):
    calls = []
    real = vaultlib._scrypt
    monkeypatch.setattr(vaultlib, "_scrypt", lambda *args: calls.append(1) or real(*args))
    vault = Vault(b"right")
    for _ in range(50):
        assert vault.decrypt(sealed, "v.yml") == SECRET
    assert len(calls) == 1


def test_password_file_problems(tmp_path, sealed):
    (tmp_path / "empty").write_text("\n")
    with pytest.raises(VaultError, match="empty"):
        Vault(password_file=str(tmp_path / "empty")).decrypt(sealed, "v.yml")
    with pytest.raises(VaultError, match="not found"):
        Vault(password_file=str(tmp_path / "missing")).decrypt(sealed, "v.yml")


def test_executable_password_file_is_run(tmp_path, sealed):
    script = tmp_path / "get-password"
    script.write_text(f"#!{sys.executable}\nprint('right')\n")
    script.chmod(0o700)
    assert Vault(password_file=str(script)).decrypt(sealed, "v.yml") == SECRET
    script.write_text(f"#!{sys.executable}\nimport sys; sys.exit('keyring locked')\n")
    with pytest.raises(VaultError, match="exited 1: keyring locked"):
        Vault(password_file=str(script)).decrypt(sealed, "v.yml")
    script.write_text(f"#!{sys.executable}\nimport sys; sys.exit(3)\n")     # says nothing
    with pytest.raises(VaultError, match="exited 3 and printed nothing on stderr: run it by hand"):
        Vault(password_file=str(script)).decrypt(sealed, "v.yml")


def test_an_executable_password_file_named_without_a_folder_is_this_folders(tmp_path, sealed, monkeypatch):
    (tmp_path / "pw").write_text(f"#!{sys.executable}\nprint('right')\n")
    (tmp_path / "pw").chmod(0o700)
    monkeypatch.chdir(tmp_path)       # `--vault-password-file pw` used to be looked up on $PATH
    assert Vault(password_file="pw").decrypt(sealed, "v.yml") == SECRET


# ------------------------------------------------------------------ files in place


def mode_of(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_encrypt_and_decrypt_files_in_place(tmp_path):
    path = tmp_path / "vault.yml"
    path.write_bytes(SECRET)
    path.chmod(0o644)
    vault = Vault(b"pw")
    encrypt_file(str(path), vault)
    assert is_encrypted(path.read_bytes()) and mode_of(path) == 0o600
    assert view_file(str(path), vault) == SECRET
    with pytest.raises(VaultError, match="already vault-encrypted"):
        encrypt_file(str(path), vault)
    decrypt_file(str(path), vault)
    assert path.read_bytes() == SECRET and mode_of(path) == 0o600
    with pytest.raises(VaultError, match="not vault-encrypted"):
        view_file(str(path), vault)
    assert [p.name for p in tmp_path.iterdir()] == ["vault.yml"]   # no temp files left


def test_a_link_is_followed_as_ansible_vault_does(tmp_path):
    # the link was replaced by an encrypted copy, and the file it points to stayed plaintext
    shared = tmp_path / "shared"
    shared.mkdir()
    real, link = shared / "secrets.yml", tmp_path / "all.yml"
    real.write_bytes(SECRET)
    link.symlink_to(real)
    vault = Vault(b"pw")
    encrypt_file(str(link), vault)
    assert link.is_symlink() and is_encrypted(real.read_bytes()) and mode_of(real) == 0o600
    decrypt_file(str(link), vault)
    assert link.is_symlink() and real.read_bytes() == SECRET
    assert sorted(p.name for p in shared.iterdir()) == ["secrets.yml"]   # no temp files left


def test_edit_re_encrypts_and_leaves_no_plaintext(tmp_path):
    path = tmp_path / "vault.yml"
    vault = Vault(b"pw")
    seen = []

    def editor(temp: str) -> None:
        seen.append(temp)
        assert mode_of(Path(temp)) == 0o600
        Path(temp).write_bytes(Path(temp).read_bytes() + b"added: 1\n")

    assert edit_file(str(path), vault, editor)          # a missing file is created
    assert edit_file(str(path), vault, editor)
    assert view_file(str(path), vault) == b"added: 1\nadded: 1\n"
    assert not any(os.path.exists(temp) for temp in seen)
    before = path.read_bytes()
    assert not edit_file(str(path), vault, lambda temp: None)
    assert path.read_bytes() == before                  # unchanged: not rewritten


def test_edit_keeps_an_ansible_vault_an_ansible_vault(tmp_path):
    path = tmp_path / "vault.yml"
    path.write_bytes(ansible_encrypt(SECRET, b"pw", label="prod"))
    edit_file(str(path), Vault(b"pw"), lambda temp: Path(temp).write_bytes(b"new: 2\n"))
    assert path.read_bytes().startswith(b"$ANSIBLE_VAULT;1.2;AES256;prod\n")
    assert decrypt(path.read_bytes(), b"pw", "v") == b"new: 2\n"


def test_failed_editor_leaves_the_file_and_removes_the_temp(tmp_path):
    path = tmp_path / "vault.yml"
    path.write_bytes(encrypt(SECRET, b"pw", FAST))
    before, seen = path.read_bytes(), []

    def broken(temp: str) -> None:
        seen.append(temp)
        raise VaultError("editor exited 1")

    with pytest.raises(VaultError):
        edit_file(str(path), Vault(b"pw"), broken)
    assert path.read_bytes() == before and not os.path.exists(seen[0])


# ------------------------------------------------------------------ CLI


def run_cli(*argv: str) -> tuple[int, str]:
    parser = argparse.ArgumentParser()
    vault_cli.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(list(argv))
    stdout = io.StringIO()
    code = args.func(args, Output(stdout=stdout, stderr=stdout))
    return code, stdout.getvalue()


def test_cli_encrypt_view_edit_decrypt(tmp_path, monkeypatch):
    path, password = tmp_path / "vault.yml", tmp_path / "pw"
    path.write_bytes(SECRET)
    password.write_text("pw\n")
    common = ["--vault-password-file", str(password), str(path)]

    assert run_cli("vault", "encrypt", *common) == (0, f"encrypted {path}\n")
    assert is_encrypted(path.read_bytes()) and mode_of(path) == 0o600
    assert run_cli("vault", "view", *common) == (0, SECRET.decode())

    editor = tmp_path / "editor"
    editor.write_text(f"#!{sys.executable}\nimport sys\nopen(sys.argv[1], 'a').write('more: 2\\n')\n")
    editor.chmod(0o700)
    monkeypatch.delenv("VISUAL", raising=False)
    monkeypatch.setenv("EDITOR", str(editor))
    assert run_cli("vault", "edit", *common) == (0, f"saved {path}\n")

    code, _ = run_cli("vault", "decrypt", *common)
    assert code == 0 and path.read_bytes() == SECRET + b"more: 2\n"


def test_cli_without_a_terminal_does_not_prompt(tmp_path, monkeypatch):
    path = tmp_path / "vault.yml"
    path.write_bytes(encrypt(SECRET, b"pw", FAST))
    monkeypatch.setattr(sys, "stdin", io.StringIO())
    monkeypatch.delenv(vaultlib.ENV_PASSWORD, raising=False)
    monkeypatch.delenv(vaultlib.ENV_PASSWORD_FILE, raising=False)
    with pytest.raises(VaultError, match="no vault password was given"):
        run_cli("vault", "view", str(path))


def test_cli_encrypt_string_pastes_into_a_vars_file(tmp_path):
    password = tmp_path / "secrets" / "pw"        # not inside the inventory: it would be read as INI
    password.parent.mkdir()
    password.write_text("pw")
    tmp_path = tmp_path / "inventory"
    tmp_path.mkdir()
    code, text = run_cli("vault", "encrypt-string", "--vault-password-file", str(password),
                         "--name", "fleet_api_token", "s3cret")
    assert code == 0 and text.startswith("fleet_api_token: !vault |\n  $ROSDEPLOY_VAULT;1;")
    (tmp_path / "hosts.yml").write_text("all:\n  hosts:\n    r1:\n      ros_domain_id: 1\n")
    (tmp_path / "group_vars").mkdir()
    (tmp_path / "group_vars" / "all.yml").write_text(text)
    from rosdeploy.inventory import load_inventory
    host = load_inventory(str(tmp_path), Vault(password_file=str(password))).hosts["r1"]
    assert host.vars["fleet_api_token"] == "s3cret" and "s3cret" in host.secret_values


# ------------------------------------------------------------------ vault ids, Ansible's format by default


def password_files(root: Path, **passwords: str) -> dict[str, Path]:
    out = {}
    for label, text in passwords.items():
        out[label] = root / f"{label}.pw"
        out[label].write_text(text + "\n")
    return out


def test_several_vault_ids_open_files_of_different_passwords(tmp_path):
    pw = password_files(tmp_path, dev="dev-pass", prod="prod-pass")
    vault = Vault(ids=[vaultlib.VaultId.parse(f"dev@{pw['dev']}"), vaultlib.VaultId.parse(f"prod@{pw['prod']}")])
    labelled = ansible_encrypt(SECRET, b"prod-pass", "prod")
    unlabelled = encrypt(b"other: 1\n", b"dev-pass", FAST)
    mislabelled = ansible_encrypt(b"x: 1\n", b"dev-pass", "prod")    # the label is a hint, not a rule
    assert vault.decrypt(labelled, "a.yml") == SECRET
    assert vault.decrypt(unlabelled, "b.yml") == b"other: 1\n"
    assert vault.decrypt(mislabelled, "c.yml") == b"x: 1\n"
    with pytest.raises(VaultError, match=r"dev@.*then --vault-id prod@"):
        vault.decrypt(ansible_encrypt(b"y: 1\n", b"nobody's"), "d.yml")


def test_vault_id_forms_and_bad_ones():
    assert vaultlib.VaultId.parse("prod@/k/pw") == vaultlib.VaultId("prod", "/k/pw")
    assert vaultlib.VaultId.parse("/k/pw") == vaultlib.VaultId("default", "/k/pw")
    with pytest.raises(VaultError, match="LABEL@FILE"):
        vaultlib.VaultId.parse("prod@")


def test_a_missing_vault_id_file_names_the_vault_id_not_another_option(tmp_path):
    vault = Vault(ids=[vaultlib.VaultId.parse(f"prod@{tmp_path / 'gone'}")])
    with pytest.raises(VaultError, match=r"not found: check --vault-id prod@.*gone") as caught:
        vault.decrypt(ansible_encrypt(b"y: 1\n", b"pw", "prod"), "d.yml")
    assert "--vault-password-file" not in str(caught.value)


def test_cli_format_ansible_and_the_encrypting_vault_id(tmp_path):
    pw = password_files(tmp_path, dev="dev-pass", prod="prod-pass")
    path = tmp_path / "secret.yml"
    path.write_bytes(SECRET)
    code, _ = run_cli("vault", "encrypt", "--format", "ansible", "--vault-id", f"dev@{pw['dev']}",
                      "--vault-id", f"prod@{pw['prod']}", "--encrypt-vault-id", "prod", str(path))
    assert code == 0 and path.read_bytes().startswith(b"$ANSIBLE_VAULT;1.2;AES256;prod\n")
    assert decrypt(path.read_bytes(), b"prod-pass", "x") == SECRET


def test_ansible_format_is_the_default_in_an_inventory_with_ansible_vaults(tmp_path):
    pw = password_files(tmp_path, default="pw")
    inventory = tmp_path / "inv"
    (inventory / "group_vars" / "all").mkdir(parents=True)
    (inventory / "group_vars" / "all" / "old.yml").write_bytes(ansible_encrypt(b"a: 1\n", b"pw"))
    fresh = inventory / "group_vars" / "all" / "new.yml"
    fresh.write_bytes(SECRET)
    code, out = run_cli("vault", "encrypt", "--vault-password-file", str(pw["default"]), str(fresh))
    assert code == 0 and fresh.read_bytes().startswith(b"$ANSIBLE_VAULT;1.1;AES256\n") and "Ansible" in out
    elsewhere = tmp_path / "loose.yml"
    elsewhere.write_bytes(SECRET)
    run_cli("vault", "encrypt", "--vault-password-file", str(pw["default"]), str(elsewhere))
    assert elsewhere.read_bytes().startswith(b"$ROSDEPLOY_VAULT;")


def test_example_inventory_vault_is_in_ansibles_format():
    example = Path(__file__).resolve().parents[2] / "inventory" / "warehouse"
    data = (example / "group_vars" / "warehouse" / "vault.yml").read_bytes()
    assert data.startswith(b"$ANSIBLE_VAULT;1.1;AES256\n")
    password = (example / ".vault-password-example").read_bytes().strip()
    assert b"fleet_api_token: demo-4f9c2a7e1b8d4e6fa0c3" in decrypt(data, password, "vault.yml")


def test_fleet_commands_can_reuse_the_vault_options(tmp_path):
    """cli.vault.add_vault_options/vault_from_args: what every fleet command adds and reads."""
    pw = password_files(tmp_path, dev="dev-pass", default="pw")
    parser = argparse.ArgumentParser()
    vault_cli.add_vault_options(parser)
    args = parser.parse_args(["--vault-id", f"dev@{pw['dev']}", "--vault-password-file", str(pw["default"])])
    vault = vault_cli.vault_from_args(args)
    assert vault.labels == ("dev", "default")
    assert vault.decrypt(encrypt(SECRET, b"pw", FAST), "a.yml") == SECRET
    assert vault.decrypt(ansible_encrypt(SECRET, b"dev-pass", "dev"), "b.yml") == SECRET
    plain = vault_cli.vault_from_args(parser.parse_args(["--vault-password-file", str(pw["default"])]))
    assert plain.decrypt(encrypt(SECRET, b"pw", FAST), "c.yml") == SECRET
