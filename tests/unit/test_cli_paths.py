"""Paths on the command line: a NUL byte, an unknown ~user or an --out that cannot be written
is an input error naming the argument, never an internal error."""
from __future__ import annotations

import os
import shutil
import signal
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


@pytest.mark.parametrize("out", ["file", "too-long", "dangling-link"])
def test_render_out_that_cannot_be_written_is_an_input_error(capsys: pytest.CaptureFixture, lab: Path,
                                                             out: str) -> None:
    target = lab / "a-file"
    target.write_text("keep me\n")
    (lab / "dangling-link").symlink_to(lab / "nowhere")
    path = {"file": str(target), "too-long": str(lab / ("x" * 300))}.get(out, str(lab / out))
    code, text = run(capsys, "render", *fleet_args(lab), "--out", path)
    assert code == 2 and "--out" in text and "cannot write there" in text
    assert f"{path}: --out" in text and ".rosdeploy-render" not in text, text   # the user's path, not ours
    assert target.read_text() == "keep me\n" and not (lab / "nowhere").exists()


def test_render_out_with_the_longest_name_a_folder_may_have_is_written(capsys: pytest.CaptureFixture,
                                                                       lab: Path) -> None:
    path = lab / ("x" * 255)
    code, text = run(capsys, "render", *fleet_args(lab), "--out", str(path))
    assert code == 0, text
    assert (path / "r1" / "compose.yml").is_file()
    assert not [p.name for p in lab.iterdir() if p.name.startswith(".rosdeploy-render")]


def test_a_fifo_as_fleet_file_or_in_the_inventory_is_refused_not_waited_on(capsys: pytest.CaptureFixture,
                                                                           lab: Path) -> None:
    # A regression would block in open(): SIGALRM turns that into a failure instead of a stuck suite.
    signal.signal(signal.SIGALRM, _too_slow)
    signal.alarm(20)
    try:
        _fifo_cases(capsys, lab)
    finally:
        signal.alarm(0)


def _too_slow(*_: object) -> None:
    raise AssertionError("rosdeploy waited on a FIFO")


def _fifo_cases(capsys: pytest.CaptureFixture, lab: Path) -> None:
    os.mkfifo(lab / "inventory" / "extra")
    code, text = run(capsys, "validate", *fleet_args(lab))
    assert code == 2 and f"{lab / 'inventory' / 'extra'}: not a regular file" in text
    (lab / "inventory" / "extra").unlink()
    os.mkfifo(lab / "pipe.yml")
    code, text = run(capsys, "validate", str(lab / "pipe.yml"))
    assert code == 2 and "pipe.yml: not a regular file" in text


@pytest.mark.parametrize("line", ["inventory: ~no-such-user-x/inventory", "ssh: {known_hosts: ~no-such-user-x/kh}"])
def test_an_unknown_user_in_a_fleet_path_is_named_at_its_line(capsys: pytest.CaptureFixture, lab: Path,
                                                              line: str) -> None:
    fleet = lab / "fleet.yml"
    kept = [x for x in fleet.read_text().splitlines() if not x.startswith("inventory:")]
    if line.startswith("ssh"):
        kept.insert(2, "inventory: ./inventory")
    fleet.write_text("\n".join([*kept, line]) + "\n")
    code, text = run(capsys, "validate", *fleet_args(lab))
    assert code == 2 and "there is no user 'no-such-user-x'" in text and "fleet.yml:" in text
