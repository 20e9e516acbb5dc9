"""Fourth hostile-input audit (issue #18): each case gave a message of several KB, a misleading
message, or was let through. Now: exit 2 from validate, check and render, the file:line, key or
option named, no traceback, nothing written by render.

1. A long value is quoted by its head and its length (errors.shown), never in full.
2. deploy_root and rosdeploy_deploy_root have a length bound (1024, and 255 a name).
3. A UTF-8 byte-order mark: refused at the start of an INI inventory or a vault file (Ansible
   misreads both), accepted in YAML (PyYAML skips it, in Ansible as here).
4. A control character in --limit (a newline split it into two patterns) or --version.
5. A YAML key past 1024 characters is named as such, not as "could not find expected ':'".
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from rosdeploy.errors import SHOWN_CHARS, shown
from test_hostile import cli, edit, lab, refused_everywhere

__all__ = ["lab"]   # the fixture: tests/unit/data/fleet copied, its vault password in place

COMMANDS = ("validate", "check", "render")
BOM = "\ufeff"
LONG = 5000
# One message of a refused long value, plus the lab's own GPU warning: far below the ~5 KB a
# value quoted whole made.
SHORT_OUTPUT = 1500


def refused(capsys: pytest.CaptureFixture, lab: Path, *words: str) -> None:
    refused_everywhere(capsys, lab, *words, commands=COMMANDS)


def refused_option(capsys: pytest.CaptureFixture, lab: Path, *argv: str) -> list[str]:
    """Each command's output for `argv`, after asserting exit 2 and that render wrote nothing."""
    texts = []
    for command in COMMANDS:
        code, text = cli(capsys, lab, command, *argv)
        assert code == 2, (command, text)
        assert not (lab / "out").exists(), f"{command} wrote files"
        texts.append(text)
    return texts


def fleet_text(lab: Path, change: Any) -> None:
    path = lab / "fleet.yml"
    path.write_text(change(path.read_text()))


# ------------------------------------------------------------------ 1. long values quoted short

def test_shown_keeps_short_values_and_cuts_long_ones() -> None:
    assert shown("UTC") == "'UTC'" and shown(None) == "None" and shown([1, 2]) == "[1, 2]"
    long = shown("x" * LONG)
    assert long == repr("x" * SHOWN_CHARS) + f"... ({LONG} characters)"
    assert shown(list(range(LONG))).endswith("characters)") and len(shown(list(range(LONG)))) < 150


def test_shown_does_not_raise_on_an_int_python_cannot_write() -> None:
    assert shown(10 ** 5000) == "a number too long to show"


def test_a_long_window_tz_is_quoted_short(capsys: pytest.CaptureFixture, lab: Path) -> None:
    # The 5,000 characters were quoted whole: a message of 5 KB.
    edit(lab, lambda d: d.update(window={"start": "01:00", "duration": "3h", "tz": "x" * LONG}))
    refused(capsys, lab, "fleet.yml:", "window.tz: 'xxx", f"... ({LONG} characters) is not a time zone name")
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and len(text) < SHORT_OUTPUT, len(text)


@pytest.mark.parametrize("option", ["--version", "--limit"])
def test_a_long_option_value_is_quoted_short(capsys: pytest.CaptureFixture, lab: Path, option: str) -> None:
    for text in refused_option(capsys, lab, option, "v" * LONG):
        assert f"{option}: " in text and f"... ({LONG} characters)" in text, text[:300]
        assert len(text) < SHORT_OUTPUT, len(text)


def test_a_limit_of_many_unmatched_terms_is_one_short_message(capsys: pytest.CaptureFixture, lab: Path) -> None:
    # `t0:t1:...:t999` explained every term in one message: 100 KB.
    for text in refused_option(capsys, lab, "--limit", ":".join(f"t{i}" for i in range(1000))):
        assert "--limit: pattern" in text and "selects no robot" in text and "and 995 more term(s)" in text, text
        assert len(text) < SHORT_OUTPUT, len(text)


# ------------------------------------------------------------------ 2. deploy roots too long

@pytest.mark.parametrize("root, what", [("/opt/" + "/".join(["a" * 200] * 6), "a path of 1210 characters"),
                                        ("~/" + "b" * 300, "a folder name of 300 characters")],
                         ids=["path", "name"])
def test_a_deploy_root_too_long_is_refused(capsys: pytest.CaptureFixture, lab: Path, root: str, what: str) -> None:
    # validate said OK; the robot's first mkdir failed (ENAMETOOLONG), after the images were pulled.
    edit(lab, lambda d: d.update(deploy_root=root))
    refused(capsys, lab, "fleet.yml:", "deploy_root: ", what, "at most 1024 characters")


def test_a_robot_deploy_root_too_long_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    with (lab / "inventory" / "host_vars" / "r1.yml").open("a") as handle:
        handle.write(f"rosdeploy_deploy_root: /opt/{'c' * 2000}\n")
    refused(capsys, lab, "r1.yml:2: rosdeploy_deploy_root: robot 'r1': a path of 2005 characters")


def test_a_deploy_root_of_normal_length_still_passes(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, lambda d: d.update(deploy_root="/opt/" + "a" * 255 + "/rosdeploy"))
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


# ------------------------------------------------------------------ 3. byte-order marks

def ini_inventory(lab: Path, text: str) -> None:
    (lab / "inventory" / "hosts.yml").unlink()
    (lab / "inventory" / "hosts").write_text(text, encoding="utf-8")


INI = "[lab]\nr1 ansible_host=127.0.0.1 ros_domain_id=1\nr2 ansible_host=127.0.0.2 ros_domain_id=2\n"


def test_an_ini_inventory_with_a_bom_is_refused_at_line_1(capsys: pytest.CaptureFixture, lab: Path) -> None:
    # It said "invalid host name '\ufeff[lab]'", and Ansible reads that line as no section header.
    ini_inventory(lab, BOM + INI)
    refused(capsys, lab, "hosts:1: ", "starts with a byte-order mark", "save it as UTF-8 without BOM")


def test_the_same_ini_inventory_without_a_bom_passes(capsys: pytest.CaptureFixture, lab: Path) -> None:
    ini_inventory(lab, INI)
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


def test_a_vault_file_with_a_bom_is_refused_as_such(capsys: pytest.CaptureFixture, lab: Path) -> None:
    # It said "a vars file must be a mapping": the header was read as a YAML string.
    vault = lab / "inventory" / "group_vars" / "all" / "vault.yml"
    vault.write_bytes(BOM.encode() + vault.read_bytes())
    refused(capsys, lab, "vault.yml:1: ", "byte-order mark (U+FEFF) before its vault header")


@pytest.mark.parametrize("where", ["fleet.yml", "inventory/hosts.yml", "inventory/host_vars/r1.yml"])
def test_yaml_files_with_a_bom_are_read(capsys: pytest.CaptureFixture, lab: Path, where: str) -> None:
    path = lab / where
    path.write_text(BOM + path.read_text(), encoding="utf-8")
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


# ------------------------------------------------------------------ 4. control characters in options

@pytest.mark.parametrize("pattern, shown_as", [("r1\nr2", "'r1\\nr2'"), ("r1\tr2", "'r1\\tr2'"),
                                               ("r1\x1b[0m", "'r1\\x1b[0m'")], ids=["newline", "tab", "escape"])
def test_a_control_character_in_limit_is_refused(capsys: pytest.CaptureFixture, lab: Path, pattern: str,
                                                 shown_as: str) -> None:
    # "r1\nr2" was read as r1:r2, so a pasted list went out unnoticed.
    for text in refused_option(capsys, lab, "--limit", pattern):
        assert f"--limit: pattern {shown_as} holds a control character" in text, text
        assert "separate patterns with `:` or `,`" in text, text


def test_a_control_character_in_version_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    for text in refused_option(capsys, lab, "--version", "1.0.0\n2"):
        assert "--version: version: '1.0.0\\n2' is not a valid image tag" in text, text


# ------------------------------------------------------------------ 5. YAML keys past 1024 characters

KEY = "k" * 1100
LONG_KEY_SAYS = "a key of 1100 characters: YAML allows at most 1024"


@pytest.mark.parametrize("change, line", [
    (lambda text: text + f"{KEY}: 1\n", 23),
    (lambda text: text.replace("  driver:\n", f"  driver:\n    {KEY}: 1\n"), 8),
    (lambda text: text + f'"{KEY}": 1\n', 23),
    (lambda text: text + f"labels: {{a: 1, {KEY}: 1}}\n", 23),
], ids=["top", "nested", "quoted", "flow"])
def test_a_yaml_key_past_1024_characters_is_named(capsys: pytest.CaptureFixture, lab: Path, change: Any,
                                                  line: int) -> None:
    # libyaml's "could not find expected ':'" (or "mapping values are not allowed"): the `:` is there.
    fleet_text(lab, change)
    refused(capsys, lab, f"fleet.yml:{line}: invalid YAML: a key of 1", "use a shorter key")


def test_a_long_key_in_an_inventory_file_is_named(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "inventory" / "host_vars" / "r1.yml").write_text(f"gpu: true\n{KEY}: 1\n")
    refused(capsys, lab, f"r1.yml:2: invalid YAML: {LONG_KEY_SAYS}")


@pytest.mark.parametrize("text, says", [("x: a: b\n", "mapping values are not allowed"),
                                        (f"x: {KEY}: b\n", "mapping values are not allowed"),
                                        (f'x: "{KEY}": b\n', "mapping values are not allowed")],
                         ids=["short", "long-value", "long-quoted-value"])
def test_other_colon_errors_keep_their_message(capsys: pytest.CaptureFixture, lab: Path, text: str,
                                               says: str) -> None:
    fleet_text(lab, lambda old: old + text)
    refused(capsys, lab, "fleet.yml:23: invalid YAML: ", says)



# ----------------------------------------------- a NUL byte in a path on this machine (fuzzing)

@pytest.mark.parametrize("key", ["known_hosts", "config"])
def test_a_nul_byte_in_a_local_path_is_refused_at_its_key(capsys: pytest.CaptureFixture, lab: Path,
                                                          key: str) -> None:
    """ssh.known_hosts: a NUL reached os.stat(), whose ValueError was an internal error (exit 1)."""
    edit(lab, lambda d: d.setdefault("ssh", {}).update({key: "/tmp/a\0b"}))
    refused(capsys, lab, "fleet.yml:", f"ssh.{key}", "NUL byte")
