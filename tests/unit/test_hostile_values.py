"""Hostile values (issue 18), through the CLI: refused with exit 2 at the key that carries them,
never an internal error (exit 1) nor a traceback, and nothing written."""
from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

import pytest
import yaml

from test_hostile import DATA, cli, refused_everywhere


@pytest.fixture
def lab(tmp_path: Path) -> Path:
    return Path(shutil.copytree(DATA, tmp_path / "lab"))


def with_file(lab: Path, template: str, host_vars: dict[str, Any] | None = None) -> None:
    """The driver mounts one `files:` entry whose path is `template`; r1 gets `host_vars`."""
    path = lab / "fleet.yml"
    data = yaml.safe_load(path.read_text())
    data["files"] = {"params": {"template": template, "target": "/config/params.yaml"}}
    data["services"]["driver"]["files"] = ["params"]
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    (lab / "params").mkdir(exist_ok=True)
    r1 = lab / "inventory" / "host_vars" / "r1.yml"
    r1.write_text(yaml.safe_dump({**yaml.safe_load(r1.read_text()), **(host_vars or {})}))


def refused(capsys: pytest.CaptureFixture, lab: Path, *words: str) -> None:
    refused_everywhere(capsys, lab, *words, commands=("validate", "render"))


# ------------------------------------------------------------- files: paths

def test_a_file_path_rendering_a_nul_is_refused_at_the_files_key(capsys: pytest.CaptureFixture, lab: Path) -> None:
    # resolve() raised ValueError (embedded null byte): exit 1.
    # the NUL made by templating the var: one written in a vars file is refused as the file is read
    with_file(lab, "params/{{ p }}", {"p": "x{{ '%c' | format(0) }}"})
    refused(capsys, lab, "files.params.template", "NUL byte")


@pytest.mark.parametrize("name, words", [("a" * 5000, "over 4096 bytes"), ("a" * 300, "over 255 bytes"),
                                         ("d/" * 2100 + "x", "over 4096 bytes")], ids=["path", "name", "depth"])
def test_a_file_path_rendering_too_long_is_refused_at_the_files_key(capsys: pytest.CaptureFixture, lab: Path,
                                                                    name: str, words: str) -> None:
    # stat() raised OSError 36 (exit 1 in validate; render blamed --out).
    with_file(lab, "params/{{ p }}", {"p": name})
    refused(capsys, lab, "files.params.template", words)
    assert "--out" not in cli(capsys, lab, "render")[1]     # render blamed the output folder


def test_a_file_source_over_the_limit_is_refused_before_it_is_read(capsys: pytest.CaptureFixture, lab: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    with_file(lab, "params/big.yaml")
    with open(lab / "params" / "big.yaml", "wb") as handle:     # sparse: 3 GB on paper, no disk used
        handle.truncate(3 << 30)

    def no_read(self: Path) -> bytes:
        raise AssertionError("read_bytes() of the whole file")
    monkeypatch.setattr(Path, "read_bytes", no_read)
    refused(capsys, lab, "files.params.template", "over 50 MB")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs fifos")
def test_a_file_source_that_is_a_fifo_is_refused_without_opening_it(capsys: pytest.CaptureFixture,
                                                                     lab: Path) -> None:
    with_file(lab, "params/pipe.yaml")
    os.mkfifo(lab / "params" / "pipe.yaml")
    refused(capsys, lab, "files.params.template", "not a regular file")


def test_a_file_source_in_a_link_loop_is_a_clean_error(capsys: pytest.CaptureFixture, lab: Path) -> None:
    with_file(lab, "params/loop.yaml")
    (lab / "params" / "loop.yaml").symlink_to(lab / "params" / "loop.yaml")
    refused(capsys, lab, "files.params.template")


# ------------------------------------------------------------- --limit

def test_a_huge_limit_subscript_is_a_clean_error(capsys: pytest.CaptureFixture, lab: Path) -> None:
    for subscript in ("9" * 5000, "1:" + "9" * 5000, "9" * 5000 + ":", "-" + "9" * 5000):
        code, text = cli(capsys, lab, "render", "--limit", f"lab[{subscript}]")
        assert code == 2 and "--limit" in text and "past any inventory" in text, text


def test_limit_at_file_selects_its_hosts(capsys: pytest.CaptureFixture, lab: Path, tmp_path: Path) -> None:
    limit = tmp_path / "lim.txt"
    limit.write_text("r2\n")
    code, text = cli(capsys, lab, "render", "--limit", f"@{limit}")
    assert code == 0, text
    assert (lab / "out" / "r2").exists() and not (lab / "out" / "r1").exists()


def test_limit_at_a_missing_file_is_a_clean_error(capsys: pytest.CaptureFixture, lab: Path, tmp_path: Path) -> None:
    code, text = cli(capsys, lab, "validate", "--limit", f"@{tmp_path / 'none.txt'}")
    assert code == 2 and "unable to find limit file" in text, text


# ------------------------------------------------------------- inventory variables

def test_an_upper_case_rosdeploy_variable_gets_a_warning(capsys: pytest.CaptureFixture, lab: Path) -> None:
    r1 = lab / "inventory" / "host_vars" / "r1.yml"
    r1.write_text(r1.read_text() + "ROSDEPLOY_DEVICES: {}\n")
    code, text = cli(capsys, lab, "validate")
    assert code == 0 and "'ROSDEPLOY_DEVICES' is not a variable rosdeploy reads" in text, text
    assert "rosdeploy_devices" in text, text
