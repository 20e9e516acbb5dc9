"""Secrets at rest: whole files encrypted with a password, decrypted in memory only.

rosdeploy's own format is a text file, so it diffs and merges like any other:

    $ROSDEPLOY_VAULT;1;AES256-GCM;scrypt;n=32768,r=8,p=1
    <base64 of salt(16) | nonce(12) | ciphertext+tag, 64 characters a line>

AES-256-GCM authenticates the ciphertext *and* the header line (as associated
data), so a flipped bit or an edited header fails as loudly as a wrong password.
The key comes from scrypt with a random salt per file; its cost parameters live
in the header, so they can be raised later without breaking old files.
n=2**15 costs ~0.1 s and 32 MiB per file: strong against guessing, yet a fleet
with a few vault files still loads in well under a second (each file is
decrypted once, see Vault).

Ansible's `$ANSIBLE_VAULT;1.1;AES256` files (AES-CTR + HMAC-SHA256, PBKDF2 10000)
are read too, and written back in their own format by `vault edit`, so a team's
existing vaults keep working with both tools.
"""
from __future__ import annotations

import base64
import binascii
import contextlib
import hashlib
import os
import subprocess
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, Sequence

# cryptography is imported where a file is sealed or opened (~60 ms at import): `rosdeploy --help`,
# completion and a `validate` of a fleet without vault files never load it.

from rosdeploy.errors import Problem, VaultError, shown
from rosdeploy import yamlsrc

MAGIC = b"$ROSDEPLOY_VAULT;"
ANSIBLE_MAGIC = b"$ANSIBLE_VAULT;"
ENV_PASSWORD_FILE = "ROSDEPLOY_VAULT_PASSWORD_FILE"
ENV_PASSWORD = "ROSDEPLOY_VAULT_PASSWORD"
HOW_TO_GIVE_PASSWORD = (f"pass --vault-password-file FILE, or set {ENV_PASSWORD_FILE} "
                        f"or {ENV_PASSWORD}")

_SALT, _NONCE, _TAG = 16, 12, 16
_LINE = 64


@dataclass(frozen=True)
class ScryptParams:
    n: int = 2 ** 15
    r: int = 8
    p: int = 1

    def header_field(self) -> str:
        return f"n={self.n},r={self.r},p={self.p}"


# A header is attacker-controlled input: refuse costs that would exhaust memory or time.
# scrypt takes 128*n*r bytes and time in p*n*r: allow twice the memory and four times the work of
# what rosdeploy writes (ScryptParams()), so a header cannot make one file cost 16 GB or 20 s.
_MAX_MEMORY = 2 * 128 * ScryptParams().n * ScryptParams().r          # 64 MiB
_DEFAULT_WORK = ScryptParams().p * ScryptParams().n * ScryptParams().r    # ~0.09 s
_MAX_WORK = 4 * _DEFAULT_WORK
# Ansible's key derivation (PBKDF2-SHA256, 10000 rounds) in the same unit: measured ~1/20 of
# rosdeploy's default scrypt; charged as 1/16 so the budget below errs on the short side.
_ANSIBLE_WORK = _DEFAULT_WORK // 16
# The bound above is per header; nothing bounded how many headers (inline `!vault` values, vault
# ids to try on each): 60 values at four times the work took 21 s, 10 values times 6 vault ids 27 s.
# So a Vault (one command) derives at most this much key in all: 256 files or values at rosdeploy's
# cost, ~20 s, a bound on what a hostile file can cost, not a pace: an inventory with a vault file
# per robot (common in Ansible) stays usable up to 256 robots of ours, ~4,000 of Ansible's. A few
# vault files (the README's advice) use a fraction; past it the message says what to do.
MAX_KDF_WORK = 256 * _DEFAULT_WORK
MAX_FILE_BYTES = yamlsrc.MAX_FILE_BYTES   # a vault file is a vars file: the inventory's bound
MAX_PASSWORD_BYTES = 1 << 20     # a password file holds one line
SCRIPT_OUTPUT_LIMIT = MAX_PASSWORD_BYTES
SCRIPT_TIMEOUT = 30.0            # a password manager asks and answers in seconds; a hung one must not hang us
_SHOWN = 60                      # characters of a header quoted in a message


# --------------------------------------------------------------------- format

def is_encrypted(data: bytes) -> bool:
    return data.startswith(MAGIC) or data.startswith(ANSIBLE_MAGIC)


def encrypt(plaintext: bytes, password: bytes, params: ScryptParams = ScryptParams()) -> bytes:
    header = f"{MAGIC.decode()}1;AES256-GCM;scrypt;{params.header_field()}".encode()
    from cryptography.hazmat.primitives.ciphers.aead import AESGCM

    salt, nonce = os.urandom(_SALT), os.urandom(_NONCE)
    sealed = AESGCM(_scrypt(password, salt, params)).encrypt(nonce, plaintext, header)
    return header + b"\n" + _wrap(base64.b64encode(salt + nonce + sealed), _LINE)


def decrypt(data: bytes, password: bytes, source: str, *, password_source: str = "") -> bytes:
    """Plaintext of a rosdeploy or Ansible vault file; VaultError naming `source` otherwise."""
    from cryptography.exceptions import InvalidTag
    from cryptography.hazmat.primitives.ciphers.aead import AESGCM

    header, body = _split_header(data, source)
    if data.startswith(ANSIBLE_MAGIC):
        return _ansible_decrypt(header, body, password, source, password_source)
    params = _parse_header(header, source)
    raw = _b64(body, source)
    if len(raw) < _SALT + _NONCE + _TAG:
        raise _error(source, "vault file is truncated: restore it from version control")
    salt, nonce, sealed = raw[:_SALT], raw[_SALT:_SALT + _NONCE], raw[_SALT + _NONCE:]
    try:
        return AESGCM(_scrypt(password, salt, params)).decrypt(nonce, sealed, header.encode())
    except InvalidTag:
        raise _wrong_password(source, password_source) from None


def check_header(data: bytes, source: str) -> None:
    """What decrypt() refuses before it needs a password (no header, a damaged or costly one):
    for an inline `!vault` value, checked when its file is read, where its line is known."""
    header, _ = _split_header(data, source)
    if data.startswith(ANSIBLE_MAGIC):
        _check_ansible_header(header, source)
    else:
        _parse_header(header, source)


def kdf_work(data: bytes, source: str) -> int:
    """What deriving the key of `data` costs, in scrypt's p*n*r (see MAX_KDF_WORK); VaultError for
    what decrypt() would refuse before deriving one."""
    header = _header(data, source).strip().decode("ascii")
    if data.startswith(ANSIBLE_MAGIC):
        _check_ansible_header(header, source)
        return _ANSIBLE_WORK
    params = _parse_header(header, source)
    return params.p * params.n * params.r


def _scrypt(password: bytes, salt: bytes, params: ScryptParams) -> bytes:
    from cryptography.hazmat.primitives.kdf.scrypt import Scrypt

    return Scrypt(salt=salt, length=32, n=params.n, r=params.r, p=params.p).derive(password)


# What str.split() took for whitespace in an ASCII body (\x1c-\x1f too): deleted from the body.
_BODY_WHITESPACE = b" \t\n\r\x0b\x0c\x1c\x1d\x1e\x1f"


def _header(data: bytes, source: str) -> bytes:
    """The first line of a vault file, which must be ASCII throughout; the body is not copied."""
    if not is_encrypted(data):
        raise _error(source, "not a vault file (no $ROSDEPLOY_VAULT or $ANSIBLE_VAULT header)")
    if not data.isascii():
        raise _error(source, "vault file holds non-ASCII bytes: it is damaged; restore it "
                             "from version control")
    end = data.find(b"\n")
    return data[:end] if end >= 0 else data


def _split_header(data: bytes, source: str) -> tuple[str, memoryview]:
    """The header line, and the body without whitespace, one copy of it. A 60 MB body split into
    its million lines (then joined, then unhexlified twice) took 382 MB to find a wrong password."""
    header = _header(data, source)
    # The whole file at once, the header's share cut off through a view: partition() copied the body.
    whole = data.translate(None, _BODY_WHITESPACE)
    return header.strip().decode("ascii"), memoryview(whole)[len(header.translate(None, _BODY_WHITESPACE)):]


def _parse_header(header: str, source: str) -> ScryptParams:
    fields = header.split(";")
    if len(fields) != 5 or fields[1] != "1":
        raise _error(source, f"unsupported vault header {_shown(header)}: this rosdeploy reads "
                             "'$ROSDEPLOY_VAULT;1;AES256-GCM;scrypt;n=..,r=..,p=..'; "
                             "a newer rosdeploy may have written it")
    if fields[2] != "AES256-GCM" or fields[3] != "scrypt":
        raise _error(source, f"unsupported cipher {_shown(fields[2])} / key derivation {_shown(fields[3])} "
                             "in the vault header: only AES256-GCM with scrypt is known")
    try:
        items = [item.split("=", 1) for item in fields[4].split(",")]
        values = dict(items)
        if len(values) != len(items) or values.keys() != {"n", "r", "p"}:
            raise ValueError("a field repeated, missing or unknown")   # `n=..,r=..,p=1,n=2` was read, last wins
        params = ScryptParams(n=int(values["n"]), r=int(values["r"]), p=int(values["p"]))
    except ValueError:
        raise _error(source, f"malformed scrypt parameters {_shown(fields[4])} in the vault header: "
                             "expected n=N,r=R,p=P, each once") from None
    _check_params(params, source)
    return params


def _check_params(params: ScryptParams, source: str) -> None:
    power_of_two = params.n > 1 and params.n & (params.n - 1) == 0
    memory, work = 128 * params.n * params.r, params.p * params.n * params.r
    if not power_of_two or min(params.r, params.p) < 1 or memory > _MAX_MEMORY or work > _MAX_WORK:
        raise _error(source, f"scrypt parameters {_shown(params.header_field())} in the vault header are out of "
                             f"range (n a power of two, r and p 1 or more, 128*n*r at most {_MAX_MEMORY >> 20} MiB, "
                             f"p*n*r at most {_MAX_WORK}; rosdeploy writes {ScryptParams().header_field()}): "
                             "the header was edited or damaged; restore the file from version control")


def _shown(text: str) -> str:
    """`text` quoted for a message, cut short: a header is input, maybe thousands of digits."""
    return shown(text, _SHOWN)


def _b64(body: memoryview, source: str) -> bytes:
    try:
        return base64.b64decode(body, validate=True)
    except binascii.Error:
        raise _error(source, "vault body is not valid base64: the file is damaged; restore it "
                             "from version control") from None


def _wrap(data: bytes, width: int) -> bytes:
    return b"".join(data[i:i + width] + b"\n" for i in range(0, len(data), width))


def _wrong_password(source: str, password_source: str) -> VaultError:
    used = f" (the password came from {password_source})" if password_source else ""
    return WrongPassword([Problem(source, None, "", f"cannot decrypt: wrong vault password, or the file was "
                                                    f"modified{used}; check the password source: "
                                                    f"{HOW_TO_GIVE_PASSWORD}, or --vault-id LABEL@FILE")])


def _error(source: str, message: str) -> VaultError:
    return VaultError([Problem(source, None, "", message)])


# --------------------------------------------------------- Ansible's 1.1 / 1.2

def ansible_encrypt(plaintext: bytes, password: bytes, label: str | None = None) -> bytes:
    """Ansible's own format, so `vault edit` of an Ansible vault leaves it readable by Ansible."""
    from cryptography.hazmat.primitives import hashes, hmac, padding
    from cryptography.hazmat.primitives.ciphers import Cipher, algorithms, modes

    salt = os.urandom(32)
    cipher_key, mac_key, iv = _ansible_keys(password, salt)
    padder = padding.PKCS7(128).padder()
    padded = padder.update(plaintext) + padder.finalize()
    encryptor = Cipher(algorithms.AES(cipher_key), modes.CTR(iv)).encryptor()
    ciphertext = encryptor.update(padded) + encryptor.finalize()
    mac = hmac.HMAC(mac_key, hashes.SHA256())
    mac.update(ciphertext)
    inner = b"\n".join(binascii.hexlify(x) for x in (salt, mac.finalize(), ciphertext))
    header = f"$ANSIBLE_VAULT;1.2;AES256;{label}" if label else "$ANSIBLE_VAULT;1.1;AES256"
    return header.encode() + b"\n" + _wrap(binascii.hexlify(inner), 80)


def ansible_label(data: bytes) -> str | None:
    """The vault-id label of a 1.2 Ansible vault file, if any."""
    end = data.find(b"\n")
    fields = (data[:end] if end >= 0 else data).strip().split(b";")   # split() copied the whole body
    return fields[3].decode("ascii", "replace") if len(fields) > 3 else None


def _ansible_decrypt(header: str, body: memoryview, password: bytes, source: str, password_source: str) -> bytes:
    from cryptography.exceptions import InvalidSignature
    from cryptography.hazmat.primitives import hashes, hmac, padding
    from cryptography.hazmat.primitives.ciphers import Cipher, algorithms, modes

    _check_ansible_header(header, source)
    try:
        salt, mac, ciphertext = _ansible_parts(body)
    except (binascii.Error, ValueError):
        raise _error(source, "Ansible vault body is malformed (expected hex): the file is damaged; "
                             "restore it from version control") from None
    cipher_key, mac_key, iv = _ansible_keys(password, salt)
    check = hmac.HMAC(mac_key, hashes.SHA256())
    check.update(ciphertext)
    try:
        check.verify(mac)
    except InvalidSignature:
        raise _wrong_password(source, password_source) from None
    decryptor = Cipher(algorithms.AES(cipher_key), modes.CTR(iv)).decryptor()
    unpadder = padding.PKCS7(128).unpadder()
    try:
        return unpadder.update(decryptor.update(ciphertext) + decryptor.finalize()) + unpadder.finalize()
    except ValueError:
        raise _error(source, "Ansible vault padding is invalid: the file is damaged") from None


def _ansible_parts(body: memoryview) -> tuple[bytes, bytes, bytes]:
    """salt, mac and ciphertext of an Ansible vault body (hex of three hex lines), cut from one
    unhexlified copy through a memoryview: split() copied the ciphertext once more."""
    inner = binascii.unhexlify(body)
    first = inner.index(b"\n")
    second = inner.index(b"\n", first + 1)
    view = memoryview(inner)
    return (binascii.unhexlify(view[:first]), binascii.unhexlify(view[first + 1:second]),
            binascii.unhexlify(view[second + 1:]))


def _check_ansible_header(header: str, source: str) -> None:
    fields = header.split(";")
    if len(fields) < 3 or fields[1] not in ("1.1", "1.2") or fields[2] != "AES256":
        raise _error(source, f"unsupported Ansible vault header {_shown(header)}: only 1.1/1.2 AES256 is "
                             "read; re-encrypt it with `ansible-vault rekey`")


def _ansible_keys(password: bytes, salt: bytes) -> tuple[bytes, bytes, bytes]:
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.kdf.pbkdf2 import PBKDF2HMAC

    derived = PBKDF2HMAC(hashes.SHA256(), length=80, salt=salt, iterations=10000).derive(password)
    return derived[:32], derived[32:64], derived[64:]


# ------------------------------------------------------------- the password

Prompt = Callable[[str], str]


@dataclass(frozen=True)
class VaultId:
    """One `--vault-id label@source`: source is a password file (an executable one is run) or `prompt`."""

    label: str
    source: str

    @staticmethod
    def parse(text: str) -> "VaultId":
        """`label@source`, or just `source` (label `default`), as ansible-vault reads --vault-id."""
        label, at, source = text.partition("@")
        if not at:
            label, source = "default", text
        if not label or not source:
            raise _error("--vault-id", f"{shown(text)} is not LABEL@FILE (or LABEL@prompt, or FILE)")
        return VaultId(label, source)


class WrongPassword(VaultError):
    """The password did not open the file: another vault id may."""


# Every password file a Vault of this process may read, absolute: nothing else rosdeploy reads
# (a release file, the ssh config) may be one of them (see is_password_file).
_PASSWORD_FILES: set[str] = set()
_PASSWORD_FILES_LOCK = threading.Lock()


def is_password_file(path: str | os.PathLike[str]) -> bool:
    """Whether `path` is the same file as a vault password file: one a Vault of this process may
    read, or $ROSDEPLOY_VAULT_PASSWORD_FILE's. Its text unlocks every vault, so it is never
    copied into a release (readable on the robot) nor parsed where an error could quote it."""
    found = _same_file(path)
    if found is None:
        return False
    with _PASSWORD_FILES_LOCK:
        known = set(_PASSWORD_FILES)
    if os.environ.get(ENV_PASSWORD_FILE):
        known.add(os.path.expanduser(os.environ[ENV_PASSWORD_FILE]))
    return any(_same_file(each) == found for each in known)


def _same_file(path: str | os.PathLike[str]) -> tuple[int, int] | None:
    try:
        found = os.stat(path)
    except (OSError, ValueError):
        return None
    return found.st_dev, found.st_ino


class Vault:
    """Vault passwords, each found on first need, and a cache of decrypted files.

    One password (the default sources: password_file, then the environment, then a prompt)
    or several vault ids, as in Ansible: a file is tried with the id its label names first,
    then with every other. Rendering 500 robots reads the same group_vars vault for each of
    them: the cache (keyed by the ciphertext's hash) makes that one key derivation, not 500.
    Key derivation is bounded per Vault (MAX_KDF_WORK). Thread-safe: the rollout renders robots
    from many threads.
    """

    def __init__(self, password: bytes | None = None, *, password_file: str | None = None,
                 env: Mapping[str, str] | None = None, prompt: Prompt | None = None,
                 ids: Sequence[VaultId] = ()) -> None:
        self._given = password
        self._password_file = password_file
        self._env = dict(os.environ if env is None else env)
        self._prompt = prompt
        self._ids = tuple(ids)
        self._passwords: dict[int, tuple[bytes, str]] = {}
        self._cache: dict[bytes, bytes] = {}
        self._kdf_work = 0                 # spent of MAX_KDF_WORK
        self._opened: int | None = None    # the vault id that opened the last file or value
        self._lock = threading.Lock()
        if password is not None:
            self._passwords[0] = (password, "the caller")
        with _PASSWORD_FILES_LOCK:
            _PASSWORD_FILES.update(os.path.abspath(each) for each in self.password_files)

    @property
    def password_source(self) -> str:
        return self._passwords[0][1] if 0 in self._passwords else ""

    @property
    def password_files(self) -> tuple[str, ...]:
        """The password files this vault may read (an inventory must not read them as inventory)."""
        files = [self._password_file, self._env.get(ENV_PASSWORD_FILE)]
        files += [i.source for i in self._ids if i.source != "prompt"]
        return tuple(os.path.expanduser(f) for f in files if f)

    def known_passwords(self) -> tuple[str, ...]:
        """Every password read so far, and the environment's: text for output to mask. A password
        is never a value to print, and an error may quote one (a password file read as inventory
        or as a --limit file)."""
        with self._lock:
            read = [password for password, _ in self._passwords.values()]
        read.append(self._env.get(ENV_PASSWORD, "").rstrip("\r\n").encode())
        return tuple(p.decode("utf-8", "replace") for p in read if p)

    def read_passwords(self) -> tuple[bytes, ...]:
        """The passwords actually read, sorted: secret material for keys that must be stable from
        run to run (render's content addresses of secret files), whatever source gave them."""
        with self._lock:
            return tuple(sorted(password for password, _ in self._passwords.values()))

    @property
    def labels(self) -> tuple[str, ...]:
        """The labels of the vault ids, the first one encrypts; ("default",) without ids."""
        return tuple(i.label for i in self._ids) or ("default",)

    def password(self, needed_by: str, label: str | None = None) -> bytes:
        """The password of `label` (the first id without one), asking its source the first time."""
        index = self.labels.index(label) if label in self.labels else 0
        return self._password(index, needed_by)[0]

    def _password(self, index: int, needed_by: str) -> tuple[bytes, str]:
        with self._lock:
            if index not in self._passwords:
                self._passwords[index] = (self._id_password(self._ids[index], needed_by) if self._ids
                                          else self._find_password(needed_by))
            return self._passwords[index]

    def decrypt(self, data: bytes, source: str) -> bytes:
        key = hashlib.sha256(data).digest()
        with self._lock:
            if key in self._cache:
                return self._cache[key]
        work = kdf_work(data, source)
        tried = []
        for index in self._order(data):
            password, used = self._password(index, source)
            self._spend(work, source)
            try:
                plaintext = decrypt(data, password, source, password_source=used)
                break
            except WrongPassword:
                tried.append(used)
        else:
            raise _wrong_password(source, ", then ".join(tried))
        with self._lock:
            self._cache[key] = plaintext
            self._opened = index
        return plaintext

    def _order(self, data: bytes) -> list[int]:
        """Ansible's order: the id the file's label names first, then every other one; among
        those, the id that opened the last file first. rosdeploy's format and Ansible's 1.1 carry
        no label, and one inventory's values are mostly sealed with one password: 10 values and 6
        ids were 60 key derivations in the ids' order, and are 15 so."""
        label = ansible_label(data) if data.startswith(ANSIBLE_MAGIC) else None
        with self._lock:
            opened = self._opened
        return sorted(range(len(self.labels)), key=lambda i: (self.labels[i] != label, i != opened))

    def _spend(self, work: int, source: str) -> None:
        """Count one key derivation against MAX_KDF_WORK, before it is done; VaultError past it."""
        with self._lock:
            if self._kdf_work + work > MAX_KDF_WORK:
                spent = self._kdf_work
            else:
                self._kdf_work += work
                return
        budget = MAX_KDF_WORK // _DEFAULT_WORK
        raise _error(source, f"decrypting this takes the command past its key-derivation budget ({budget} derivations "
                             f"at rosdeploy's default scrypt cost, ~20 s; {spent / _DEFAULT_WORK:g} spent): too many "
                             "`!vault` values or vault files, costly scrypt headers, or vault ids tried before the "
                             "right one. Keep secrets in a few vault-encrypted vars files (one derivation each) "
                             "rather than many `!vault` values, re-encrypt costly ones with `rosdeploy vault "
                             "encrypt`/`encrypt-string` (default cost), and give the usual --vault-id first")

    def encrypt(self, plaintext: bytes, needed_by: str, *, ansible: bool = False, label: str | None = None) -> bytes:
        """rosdeploy's format, or Ansible's (1.2 with the vault id's label unless it is `default`)."""
        label = label or self.labels[0]
        password = self.password(needed_by, label)   # the first id's when no id has this label
        if ansible:
            return ansible_encrypt(plaintext, password, None if label == "default" else label)
        return encrypt(plaintext, password)

    def read(self, path: str, data: bytes) -> tuple[bytes, bool]:
        """(plaintext, was_encrypted) of a file's bytes."""
        if not is_encrypted(data):
            return data, False
        return self.decrypt(data, path), True

    def _id_password(self, vault_id: VaultId, needed_by: str) -> tuple[bytes, str]:
        if vault_id.source == "prompt":
            typed = self._prompt(f"Vault password ({vault_id.label}): ") if self._prompt else ""
            if not typed:
                raise _error(needed_by, f"--vault-id {vault_id.label}@prompt needs a terminal: give a password "
                                        "file instead")
            return typed.encode(), f"--vault-id {vault_id.label}@prompt"
        given = f"--vault-id {vault_id.label}@{vault_id.source}"
        return read_password_file(vault_id.source, given), given

    def _find_password(self, needed_by: str) -> tuple[bytes, str]:
        if self._given is not None:
            return self._given, "the caller"
        if self._password_file:
            return read_password_file(self._password_file), f"--vault-password-file {self._password_file}"
        if self._env.get(ENV_PASSWORD_FILE):
            path = self._env[ENV_PASSWORD_FILE]
            return read_password_file(path), f"{ENV_PASSWORD_FILE}={path}"
        if self._env.get(ENV_PASSWORD):
            return self._env[ENV_PASSWORD].rstrip("\r\n").encode(), ENV_PASSWORD
        if self._prompt is not None:
            typed = self._prompt("Vault password: ")
            if typed:
                return typed.encode(), "the prompt"
        raise _error(needed_by, f"this file is vault-encrypted and no vault password was given: "
                                f"{HOW_TO_GIVE_PASSWORD}")


def holds_ansible_vaults(path: str, max_files: int = 2000) -> bool:
    """Whether the inventory around `path` already holds Ansible vault data (whole files or `!vault`).

    The inventory is the nearest directory up from `path` with group_vars/ or host_vars/;
    without one there is no inventory to match, and the answer is False.
    """
    start = Path(path).resolve()
    folder = start if start.is_dir() else start.parent
    root = next((p for p in (folder, *folder.parents) if (p / "group_vars").is_dir() or (p / "host_vars").is_dir()),
                None)
    if root is None:
        return False
    files = (p for p in root.rglob("*") if p.suffix in ("", ".yml", ".yaml", ".json") and p.is_file())
    for count, file in enumerate(files):
        if count >= max_files:
            return False
        try:
            with open(file, "rb") as handle:
                head = handle.read(65536)
        except OSError:
            continue
        if ANSIBLE_MAGIC in head:
            return True
    return False


def read_password_file(path: str, given: str = "") -> bytes:
    """A password file's content; an executable file is run and its stdout used (like Ansible).
    `given`: where the path came from, for the message (default: the option or the variable)."""
    path = os.path.expanduser(path)
    if not os.path.exists(path):
        raise _error(path, f"vault password file not found: check "
                           f"{given or f'--vault-password-file / {ENV_PASSWORD_FILE}'}")
    script = os.path.isfile(path) and os.access(path, os.X_OK)
    raw = _run_password_script(path) if script else _read_file(path, MAX_PASSWORD_BYTES, "a vault password file")
    # Ansible strips surrounding whitespace too, so one password file serves both tools.
    password = raw.strip()
    if not password:
        raise _error(path, "vault password file is empty: put the password on its first line")
    return password


def _run_password_script(path: str) -> bytes:
    """Its stdout, through the dynamic inventory's runner: its own session, stopped (with whatever
    it started) past that runner's time limit or output cap; output to files, read up to our cap."""
    from rosdeploy.inventory import script as runner

    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        try:
            # absolute: a bare `pw` would be looked up on $PATH, not in the current directory
            proc = subprocess.Popen([os.path.abspath(path)], stdout=out, stderr=err, start_new_session=True)
        except OSError as exc:
            raise _error(path, f"the vault password file is executable but could not be run ({exc.strerror}); "
                               "remove its execute bit if it is a plain password file") from exc
        stopped = runner.wait(proc, out.fileno(), err.fileno(), timeout=SCRIPT_TIMEOUT, limit=SCRIPT_OUTPUT_LIMIT)
        if stopped == "time":
            raise _error(path, f"the vault password script did not finish within {SCRIPT_TIMEOUT:g} s: fix it, "
                               "or give a plain password file")
        if stopped == "size" or os.fstat(out.fileno()).st_size > SCRIPT_OUTPUT_LIMIT:
            raise _error(path, f"the vault password script printed more than {SCRIPT_OUTPUT_LIMIT >> 20} MiB: it "
                               "must print the password on one line")
        out.seek(0)
        err.seek(max(0, os.fstat(err.fileno()).st_size - 800))     # only its end is quoted
        stdout, stderr = out.read(), err.read()
    if proc.returncode != 0:
        tail = stderr.decode("utf-8", "replace").strip()[-200:]
        said = f": {tail}" if tail else " and printed nothing on stderr: run it by hand to see why"
        raise _error(path, f"the vault password script exited {proc.returncode}{said}")
    return stdout


# ------------------------------------------------------------- files in place


def encrypt_file(path: str, vault: Vault, ansible_format: bool = False, label: str | None = None) -> None:
    data = _read_file(path)
    if is_encrypted(data):
        raise _error(path, "already vault-encrypted: use `rosdeploy vault edit` to change it")
    write_private(path, vault.encrypt(data, path, ansible=ansible_format, label=label))


def decrypt_file(path: str, vault: Vault) -> None:
    write_private(path, view_file(path, vault))


def view_file(path: str, vault: Vault) -> bytes:
    data = _read_file(path)
    if not is_encrypted(data):
        raise _error(path, "not vault-encrypted (no $ROSDEPLOY_VAULT or $ANSIBLE_VAULT header)")
    return vault.decrypt(data, path)


def edit_file(path: str, vault: Vault, run_editor: Callable[[str], None], ansible_format: bool = False) -> bool:
    """Decrypt to a private temp file, let `run_editor` change it, re-encrypt; True if it changed.

    A missing file is created (in Ansible's format with `ansible_format`). An Ansible
    vault stays an Ansible vault, with its label, so Ansible can still read it. The
    plaintext only ever sits in a 0600 file that is overwritten before it is removed,
    whatever the editor does.
    """
    original = _read_file(path) if os.path.exists(path) else None
    if original is not None and not is_encrypted(original):
        raise _error(path, "not vault-encrypted: run `rosdeploy vault encrypt` on it first")
    plaintext = vault.decrypt(original, path) if original is not None else b""
    fd, temp = tempfile.mkstemp(prefix="rosdeploy-vault-", suffix=Path(path).suffix)
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(plaintext)
        run_editor(temp)
        edited = _read_file(temp)
    finally:
        _shred(temp)
    if original is not None and edited == plaintext:
        return False
    if original is not None:
        ansible = original.startswith(ANSIBLE_MAGIC)
        sealed = vault.encrypt(edited, path, ansible=ansible, label=ansible_label(original) if ansible else None)
    else:
        sealed = vault.encrypt(edited, path, ansible=ansible_format)
    write_private(path, sealed)
    return True


def encrypt_string(value: str, vault: Vault, name: str, ansible_format: bool = False,
                   label: str | None = None) -> str:
    """`name: !vault |` + indented ciphertext, to paste into a vars file (Ansible's encrypt_string)."""
    sealed = vault.encrypt(value.encode("utf-8"), name, ansible=ansible_format, label=label).decode("ascii")
    return f"{name}: !vault |\n" + "".join(f"  {line}\n" for line in sealed.splitlines())


def write_private(path: str, data: bytes) -> None:
    """Replace `path` atomically (temp file + rename in the same directory), mode 0600. A symbolic
    link is followed, as ansible-vault does: replacing the link itself left the file it points to
    in plaintext."""
    real = os.path.realpath(path)
    fd, temp = tempfile.mkstemp(dir=os.path.dirname(real), prefix=f".{os.path.basename(real)}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(temp, 0o600)
        os.replace(temp, real)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(temp)
        raise _error(path, f"cannot write: {exc.strerror}") from exc


def _read_file(path: str, limit: int = MAX_FILE_BYTES, what: str = "a vault file") -> bytes:
    """A regular file of at most `limit` bytes (never a FIFO or /dev/zero: refused before reading)."""
    return yamlsrc.read_bytes(path, limit, what)


def _shred(path: str) -> None:
    # Best effort: overwrite before unlinking so the plaintext is not left in free
    # blocks of a plain filesystem (journaling and SSDs may still keep copies).
    with contextlib.suppress(OSError):
        size = os.path.getsize(path)
        with open(path, "r+b") as handle:
            handle.write(b"\0" * size)
            handle.flush()
            os.fsync(handle.fileno())
    with contextlib.suppress(OSError):
        os.unlink(path)
