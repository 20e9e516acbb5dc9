"""Paths on the command line: a NUL byte, an unknown ~user or an --out that cannot be written
is an input error naming the argument, never an internal error."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from rosdeploy.cli import main

DATA = Path(__file__).resolve().parent / "data" / "fleet"


@pytest.fixture
def lab(tmp_path: Path) -> Path:
    shutil.copytree(DATA, tmp_path / "lab")
    return tmp_path / "lab"


def run(capsys: pytest.CaptureFixture, *argv: str) -> tuple[int, str]:
    code = main(list(argv))
    captured = capsys.readouterr()
    text = captured.out + captured.err
    assert "internal error" not in text and "Traceback" not in text, text
    return code, text


def fleet_args(lab: Path) -> list[str]:
    return [str(lab / "fleet.yml"), "--vault-password-file", str(lab / "inventory" / ".vault-password")]


@pytest.mark.parametrize("where", ["fleet", "-i", "--out", "--vault-password-file"])
def test_a_nul_byte_in_a_path_is_an_argument_error(capsys: pytest.CaptureFixture, lab: Path, where: str) -> None:
    argv = ["render", *fleet_args(lab), "--out", str(lab / "out")]
    bad = "a\0b"
    if where == "fleet":
        argv[1] = bad
    elif where == "-i":
        argv += ["-i", bad]
    else:
        argv[argv.index(where) + 1] = bad
    code, text = run(capsys, *argv)
    assert code == 2 and "NUL byte" in text
    assert not (lab / "out").exists()


def test_an_unknown_user_in_a_tilde_path_is_named(capsys: pytest.CaptureFixture, lab: Path) -> None:
    code, text = run(capsys, "validate", *fleet_args(lab), "-i", "~no-such-user-x/inventory")
    assert code == 2 and "-i/--inventory" in text and "no user 'no-such-user-x'" in text


def test_a_tilde_path_of_the_current_user_still_expands(capsys: pytest.CaptureFixture, lab: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HOME", str(lab))
    code, text = run(capsys, "validate", "~/fleet.yml", "--vault-password-file", "~/inventory/.vault-password")
    assert code == 0, text


@pytest.mark.parametrize("out", ["file", "too-long"])
def test_render_out_that_cannot_be_written_is_an_input_error(capsys: pytest.CaptureFixture, lab: Path,
                                                             out: str) -> None:
    target = lab / "a-file"
    target.write_text("keep me\n")
    path = str(target) if out == "file" else str(lab / ("x" * 300))
    code, text = run(capsys, "render", *fleet_args(lab), "--out", path)
    assert code == 2 and "--out" in text and "cannot write there" in text
    assert target.read_text() == "keep me\n"
