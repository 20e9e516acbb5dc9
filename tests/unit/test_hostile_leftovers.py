"""Leftovers of the hostile-input audit (issue #18): a clean exit 2 at file:line, nothing written.

1. A `volumes:` entry at the container path of one of the service's `files:` (two mounts, one path).
2. An inline `!vault` value in an inventory vars file that cannot be opened (no header, a wrong
   password, a damaged body) is located at the line of its key, not only in its file.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from rosdeploy.cli import main
from rosdeploy.vault import ansible_encrypt, encrypt

DATA = Path(__file__).resolve().parent / "data" / "fleet"
PASSWORD = b"unit-test-password"          # tests/unit/data/fleet/inventory/.vault-password
INLINE_SECRET = "inline-secret-5c0e91"
DRIVER_END = "    topics: [/joint_states]\n"
CAMERA_FILE = "files:\n  camera: {var: camera_calibration, target: /config/camera.yaml}\n"


@pytest.fixture
def lab(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A private copy of tests/unit/data/fleet; only its password file opens its vault."""
    for name in ("ROSDEPLOY_VAULT_PASSWORD", "ROSDEPLOY_VAULT_PASSWORD_FILE"):
        monkeypatch.delenv(name, raising=False)
    return Path(shutil.copytree(DATA, tmp_path / "lab"))


def run(capsys: pytest.CaptureFixture, lab: Path, command: str, *argv: str) -> tuple[int, str]:
    """One command on the lab; render writes to lab/out unless `argv` says where."""
    extra = ["--out", str(lab / "out")] if command == "render" and "--out" not in argv else []
    extra += argv
    password = str(lab / "inventory" / ".vault-password")
    code = main([command, str(lab / "fleet.yml"), "--vault-password-file", password, *extra])
    captured = capsys.readouterr()
    text = captured.out + captured.err
    assert "Traceback" not in text and "internal error" not in text, text
    return code, text


def refused(capsys: pytest.CaptureFixture, lab: Path, *expected: str) -> None:
    """Exit 2 from validate and render, each naming `expected`; render wrote nothing."""
    for command in ("validate", "render"):
        code, text = run(capsys, lab, command)
        assert code == 2, text
        for part in expected:
            assert part in text, text
    assert not (lab / "out").exists()


def line_of(path: Path, text: str) -> int:
    return path.read_text().splitlines().index(text) + 1


# ------------------------------------------------------- 1. volumes at a files target

def with_volumes(lab: Path, *mounts: str, files: str = "[camera]") -> Path:
    fleet = lab / "fleet.yml"
    volumes = "".join(f"      - {m}\n" for m in mounts)
    driver = f"{DRIVER_END}    volumes:\n{volumes}    files: {files}\n"
    fleet.write_text(fleet.read_text().replace(DRIVER_END, driver, 1) + CAMERA_FILE)
    with (lab / "inventory" / "group_vars" / "all" / "vars.yml").open("a") as handle:
        handle.write("camera_calibration: {fx: 600.0, fy: 600.0}\n")
    return fleet


@pytest.mark.parametrize("container", ["/config/camera.yaml", "/config/./camera.yaml", "/config/camera.yaml/",
                                       "/./config/camera.yaml"])
def test_a_volume_at_a_files_target_is_refused_at_its_line(capsys: pytest.CaptureFixture, lab: Path,
                                                           container: str) -> None:
    fleet = with_volumes(lab, "/data/maps:/maps:ro", f"/data/cal:{container}:ro")
    line = line_of(fleet, f"      - /data/cal:{container}:ro")
    refused(capsys, lab, f"fleet.yml:{line}: services.driver.volumes[1]: /config/camera.yaml is also the target "
                         "of files.camera", "one container path takes one mount")


def test_a_volume_is_refused_only_where_the_service_mounts_the_file(capsys: pytest.CaptureFixture,
                                                                    lab: Path) -> None:
    fleet = with_volumes(lab, "/data/cal:/config/camera.yaml:ro", files="[]")   # bridge could mount it: not driver
    fleet.write_text(fleet.read_text().replace("    depends_on: [driver]\n",
                                               "    depends_on: [driver]\n    files: [camera]\n"))
    code, text = run(capsys, lab, "validate")
    assert code == 0, text


def test_a_volume_beside_a_files_target_still_renders(capsys: pytest.CaptureFixture, lab: Path) -> None:
    with_volumes(lab, "/data/cal:/config/camera.yml:ro", "/data/config:/config:ro")   # a folder above is fine
    code, text = run(capsys, lab, "render")
    assert code == 0, text
    compose = (lab / "out" / "r1" / "compose.yml").read_text()
    assert "/data/cal:/config/camera.yml:ro" in compose and ":/config/camera.yaml:ro" in compose


def test_two_files_at_one_path_written_differently_are_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    # since the fifth round a target must be written plainly, so `/config/./camera.yaml` is refused
    # at its own key before it can clash with /config/camera.yaml
    fleet = with_volumes(lab, "/data/maps:/maps:ro", files="[camera, again]")
    fleet.write_text(fleet.read_text() + "  again: {var: camera_calibration, target: /config/./camera.yaml}\n")
    refused(capsys, lab, "files.again.target: '/config/./camera.yaml' must be an absolute file path in the "
                         "container, written without `.`")
    fleet.write_text(fleet.read_text().replace("/config/./camera.yaml", "/config/camera.yaml"))
    refused(capsys, lab, "services.driver.files[1]: `again` and `camera` both mount at /config/camera.yaml")


# ------------------------------------------------------- 2. inline !vault at its line

def vaulted(text: str) -> str:
    return "!vault |\n" + "".join(f"  {line}\n" for line in text.splitlines())


def with_inline(lab: Path, value: str) -> Path:
    """`extra_token: <value>` in group_vars, on a line of its own after the existing vars."""
    vars_file = lab / "inventory" / "group_vars" / "all" / "vars.yml"
    vars_file.write_text(vars_file.read_text() + "note: public\nextra_token: " + value)
    return vars_file


@pytest.mark.parametrize("body, expected", [
    ("just some text, never encrypted", "rosdeploy vault encrypt-string --name extra_token"),
    (ansible_encrypt(INLINE_SECRET.encode(), b"another-password").decode(), "wrong vault password"),
    (encrypt(INLINE_SECRET.encode(), b"another-password").decode(), "wrong vault password"),
    ("$ANSIBLE_VAULT;1.1;AES256\nzz-not-hex-at-all", "expected hex"),
    ("$ROSDEPLOY_VAULT;1;AES256-GCM;scrypt;n=32768,r=8,p=1\n!!not*base64!!", "not valid base64"),
    ("$ROSDEPLOY_VAULT;1;AES256-GCM;scrypt;n=32768,r=8,p=1\nAAAA", "truncated"),
], ids=["no-header", "ansible-wrong-password", "rosdeploy-wrong-password", "bad-hex", "bad-base64", "truncated"])
def test_an_inline_vault_that_cannot_be_opened_names_its_line(capsys: pytest.CaptureFixture, lab: Path,
                                                              body: str, expected: str) -> None:
    vars_file = with_inline(lab, vaulted(body))
    line = line_of(vars_file, "extra_token: !vault |")
    refused(capsys, lab, f"vars.yml:{line}: extra_token: ", expected)
    code, text = run(capsys, lab, "validate")
    assert INLINE_SECRET not in text and body.splitlines()[-1] not in text   # neither plaintext nor ciphertext


def test_an_inline_vault_with_a_wrong_password_says_how_to_re_encrypt(capsys: pytest.CaptureFixture,
                                                                      lab: Path) -> None:
    with_inline(lab, vaulted(ansible_encrypt(b"x", b"another-password").decode()))
    refused(capsys, lab, "re-encrypt it with `rosdeploy vault encrypt-string --name extra_token`")


def test_an_inline_vault_in_a_list_names_its_item(capsys: pytest.CaptureFixture, lab: Path) -> None:
    vars_file = with_inline(lab, "\n  - plain\n  - !vault |\n    not encrypted\n")
    refused(capsys, lab, f"vars.yml:{line_of(vars_file, '  - !vault |')}: extra_token[1]: ", "encrypt-string")


def test_a_correct_inline_vault_still_decrypts(capsys: pytest.CaptureFixture, lab: Path) -> None:
    with_inline(lab, vaulted(ansible_encrypt(INLINE_SECRET.encode(), PASSWORD).decode()))
    fleet = lab / "fleet.yml"
    fleet.write_text(fleet.read_text().replace("{API_TOKEN: api_token}", "{API_TOKEN: api_token, EXTRA: extra_token}"))
    code, text = run(capsys, lab, "render")
    assert code == 0 and INLINE_SECRET not in text, text
    assert f"EXTRA={INLINE_SECRET}" in (lab / "out" / "r1" / ".env").read_text()
