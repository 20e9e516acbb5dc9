"""`rosdeploy vault encrypt|decrypt|view|edit FILE`, `vault encrypt-string`: like ansible-vault."""
from __future__ import annotations

import argparse
import getpass
import os
import re
import shlex
import subprocess
import sys
from typing import TYPE_CHECKING

from rosdeploy.cli.common import add_command, path_arg
from rosdeploy.errors import EXIT_INPUT, EXIT_INTERNAL, EXIT_OK, Problem, VaultError, shown
from rosdeploy.output import Output, one_line

if TYPE_CHECKING:
    from rosdeploy import vault as vaultlib
    from rosdeploy.project import Project

# rosdeploy.vault (and the YAML reader it brings, ~17 ms) is imported by the handlers: every
# command, --help and TAB completion included, builds this parser. Its variables' names, for the
# help (test_cli_seventh checks they are the module's):
ENV_PASSWORD_FILE = "ROSDEPLOY_VAULT_PASSWORD_FILE"
ENV_PASSWORD = "ROSDEPLOY_VAULT_PASSWORD"


CODES = (EXIT_OK, EXIT_INPUT, EXIT_INTERNAL)   # a wrong password or a damaged file is an input error
EXAMPLE_FILE = "inventory/warehouse/group_vars/warehouse/vault.yml"     # the example fleet's, in the repo
EXAMPLE_PASSWORD = "inventory/warehouse/.vault-password-example"


def register(sub: argparse._SubParsersAction) -> None:
    parser = add_command(sub, "vault", "encrypt, decrypt, view or edit vault files (secrets at rest)",
                         "Whole files encrypted with AES-256-GCM; a group_vars/host_vars file may be one. "
                         "Ansible's own vault files are read too.", CODES,
                         f"rosdeploy vault view {EXAMPLE_FILE} --vault-password-file {EXAMPLE_PASSWORD}")
    actions = parser.add_subparsers(dest="vault_action", metavar="ACTION", required=True)
    for name, handler, many, text, more in (
            ("encrypt", _encrypt, True, "encrypt files in place (mode 0600)",
             "Encrypt each FILE in place with the vault password, mode 0600; an encrypted file is refused."),
            ("decrypt", _decrypt, True, "decrypt files in place (mode 0600)",
             "Decrypt each FILE in place, mode 0600: the plaintext is on disk afterwards."),
            ("view", _view, False, "print the plaintext of a vault file",
             "Print the plaintext of a vault file on stdout; the file is left as it is."),
            ("edit", _edit, False, "edit a vault file with $EDITOR (created if missing)",
             "Decrypt into a private temporary file, run $VISUAL or $EDITOR (else vi) on it, and encrypt the result "
             "back; a new file is created.")):
        target = EXAMPLE_FILE if name in ("view", "edit") else "group_vars/all/secrets.yml"
        action = add_command(actions, name, text, more, CODES,
                             f"rosdeploy vault {name} {target} --vault-password-file {EXAMPLE_PASSWORD}")
        action.add_argument("files", nargs="+" if many else 1, type=path_arg, metavar="FILE",
                            help="vault file" + ("s" if many else "") + ", e.g. a group_vars file")
        add_vault_options(action)
        if name in ("encrypt", "edit"):
            _format_args(action)
        # encrypt, decrypt, edit: their product is the file; view's is its output (_after_lost_output)
        action.set_defaults(func=handler, acts=name != "view")
    string = add_command(actions, "encrypt-string", "print `NAME: !vault |` to paste into a vars file",
                         "Encrypt one value (from VALUE, else standard input) as an inline `!vault` value, "
                         "like ansible-vault encrypt_string.", CODES,
                         "rosdeploy vault encrypt-string --name fleet_api_token")
    string.add_argument("value", nargs="?", metavar="VALUE",
                        help="the secret; omit it to read standard input (keeps it out of shell history)")
    string.add_argument("--name", required=True, metavar="NAME", help="the variable name, e.g. fleet_api_token")
    add_vault_options(string)
    _format_args(string)
    string.set_defaults(func=_encrypt_string)


def add_vault_options(parser: argparse.ArgumentParser) -> None:
    """--vault-password-file and --vault-id (repeatable): for `vault` and for every fleet command."""
    parser.add_argument("--vault-password-file", type=path_arg, metavar="FILE",
                        help=f"file holding the vault password (or set {ENV_PASSWORD_FILE} "
                             f"or {ENV_PASSWORD}); an executable file is run")
    parser.add_argument("--vault-id", dest="vault_ids", action="append", default=[], metavar="LABEL@FILE",
                        help="a vault id as in Ansible: LABEL@FILE, LABEL@prompt or FILE; repeat it for "
                             "files encrypted with different passwords (the first one encrypts)")


def load_masked(args: argparse.Namespace, out: Output, version: str | None) -> Project:
    """The fleet file and inventory of `args`, decrypted with their vault. From here on `out` masks
    every vault password and value, in the error of a load that fails too."""
    from rosdeploy.project import load_project

    vault = vault_from_args(args, getpass.getpass if out.can_ask else None)
    try:
        project = load_project(args.fleet, inventory=args.inventory, version=version, vault=vault)
    finally:
        out.mask(vault.known_passwords())
    out.mask(project.secret_values)
    return project


def vault_from_args(args: argparse.Namespace, prompt: vaultlib.Prompt | None = None) -> vaultlib.Vault:
    """The Vault that add_vault_options' arguments describe (a --vault-password-file is one more id)."""
    from rosdeploy import vault as vaultlib
    ids = [vaultlib.VaultId.parse(text) for text in args.vault_ids]
    if ids and args.vault_password_file:
        ids.append(vaultlib.VaultId("default", args.vault_password_file))
    return vaultlib.Vault(password_file=args.vault_password_file, prompt=prompt, ids=ids)


def _format_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--format", choices=("ansible", "rosdeploy"), dest="vault_format",
                        help="ansible: Ansible's 1.1/1.2 format, which ansible-vault reads (the default inside "
                             "an inventory that already holds Ansible vault data); rosdeploy: AES-256-GCM with "
                             "scrypt (the default otherwise)")
    parser.add_argument("--encrypt-vault-id", metavar="LABEL",
                        help="which --vault-id encrypts (default: the first); its label goes in the header")


def _ansible_format(args: argparse.Namespace, near: str) -> bool:
    from rosdeploy import vault as vaultlib
    if args.vault_format:
        return args.vault_format == "ansible"
    return vaultlib.holds_ansible_vaults(near)


def _encrypt(args: argparse.Namespace, out: Output) -> int:
    from rosdeploy import vault as vaultlib
    vault = _vault(args, args.files[0], new_password=True)
    done = []
    for path in args.files:
        ansible = _ansible_format(args, path)
        vaultlib.encrypt_file(path, vault, ansible_format=ansible, label=args.encrypt_vault_id)
        done.append({"file": path, "format": "ansible" if ansible else "rosdeploy"})
        if not out.as_json:
            out.line(f"encrypted {one_line(path)}" + (" (Ansible's format: ansible-vault reads it)" if ansible else ""))
    return _done(out, {"encrypted": done})


def _encrypt_string(args: argparse.Namespace, out: Output) -> int:
    from rosdeploy import vault as vaultlib
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", args.name):
        raise VaultError([Problem("--name", None, "", f"{shown(args.name)} is not a variable name: use letters, "
                                                      "digits and '_'")])
    value = args.value
    if value is None:
        value = getpass.getpass("Value to encrypt: ") if sys.stdin.isatty() else sys.stdin.read().rstrip("\n")
    if not value:
        raise VaultError([Problem("--name", None, "", "nothing to encrypt: give VALUE or pipe it in")])
    vault = _vault(args, args.name, new_password=True)
    ansible = _ansible_format(args, os.getcwd())
    text = vaultlib.encrypt_string(value, vault, args.name, ansible_format=ansible,
                                   label=args.encrypt_vault_id).rstrip("\n")
    if not out.as_json:
        out.line(text)
    return _done(out, {"name": args.name, "yaml": text + "\n", "format": "ansible" if ansible else "rosdeploy"})


def _decrypt(args: argparse.Namespace, out: Output) -> int:
    from rosdeploy import vault as vaultlib
    vault = _vault(args, args.files[0])
    for path in args.files:
        vaultlib.decrypt_file(path, vault)
        if not out.as_json:
            out.line(f"decrypted {one_line(path)} (plaintext now: keep it out of version control)")
    return _done(out, {"decrypted": list(args.files)})


def _view(args: argparse.Namespace, out: Output) -> int:
    from rosdeploy import vault as vaultlib
    text = vaultlib.view_file(args.files[0], _vault(args, args.files[0])).decode("utf-8", "replace")
    if not out.as_json:
        out.line(text.rstrip("\n"))
    return _done(out, {"file": args.files[0], "plaintext": text})


def _edit(args: argparse.Namespace, out: Output) -> int:
    from rosdeploy import vault as vaultlib
    path = args.files[0]
    editor = _editor(path)     # before anything is decrypted: a bad $EDITOR must not run the plaintext
    vault = _vault(args, path, new_password=not os.path.exists(path))
    changed = vaultlib.edit_file(path, vault, lambda temp: _run_editor(editor, temp, path),
                                 ansible_format=_ansible_format(args, path))
    if not out.as_json:
        out.line(f"saved {one_line(path)}" if changed else f"no changes to {one_line(path)}")
    return _done(out, {"file": path, "changed": changed})


def _done(out: Output, document: dict) -> int:
    """With --json, the one document of a vault command that succeeded (its text went nowhere)."""
    if out.as_json:
        out.document({"ok": True, **document})
    return EXIT_OK


def _vault(args: argparse.Namespace, about: str, new_password: bool = False) -> vaultlib.Vault:
    # No prompt without a terminal: CI must fail with "how to give the password", not hang.
    prompt = None
    if sys.stdin.isatty():
        prompt = _confirmed_prompt(about) if new_password else getpass.getpass
    return vault_from_args(args, prompt)


def _confirmed_prompt(path: str) -> vaultlib.Prompt:
    def ask(_: str) -> str:
        first = getpass.getpass("New vault password: ")
        if first != getpass.getpass("Confirm new vault password: "):
            raise VaultError([Problem(path, None, "", "the two passwords differ: nothing was written; "
                                                      "run the command again")])
        return first
    return ask


def _editor(path: str) -> list[str]:
    """$VISUAL or $EDITOR as a command: `code --wait` is two words. A value of blanks only, or with
    an unclosed quote, is refused: split to nothing, the decrypted file's name would be the command."""
    name = "VISUAL" if os.environ.get("VISUAL") else "EDITOR"
    value = os.environ.get(name) or "vi"
    try:
        editor = shlex.split(value)
    except ValueError as exc:
        raise VaultError([Problem(path, None, "", f"${name} {shown(value)} cannot be parsed ({exc}): "
                                                  "set it to an editor command, e.g. EDITOR=vi")]) from None
    if not editor:
        raise VaultError([Problem(path, None, "", f"${name} is empty ({shown(value)}): set it to an editor "
                                                  "command, e.g. EDITOR=vi")])
    return editor


def _run_editor(editor: list[str], temp: str, path: str) -> None:
    try:
        done = subprocess.run([*editor, temp], check=False)
    except OSError as exc:
        raise VaultError([Problem(path, None, "", f"cannot start the editor {shown(editor[0])} ({exc.strerror}): "
                                                  "set $EDITOR")]) from exc
    if done.returncode != 0:
        raise VaultError([Problem(path, None, "", f"the editor exited {done.returncode}: the vault file "
                                                  "was left unchanged")])
