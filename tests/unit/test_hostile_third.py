"""Third hostile-input audit (issue #18): each case was an internal error (exit 1), a walk of a
whole disk, a message buried under thousands of others, or a value validate let through that
render or the robot then failed on. Now: exit 2, the file:line or key named, no traceback, nothing
written by render.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from rosdeploy.cli import main, offline
from rosdeploy.inventory import discovery
from test_hostile import cli, edit, lab, refused_everywhere

__all__ = ["lab"]   # the fixture: tests/unit/data/fleet copied, its vault password in place

HUGE = "9" * 5000                 # int() refuses it (Python's 4,300-digit bound)
LONG_HEX = "0x" + "f" * 4000      # int() builds it, but str() of it raises


def refused(capsys: pytest.CaptureFixture, lab: Path, *words: str) -> None:
    refused_everywhere(capsys, lab, *words, commands=("validate", "check", "render"))


def ini_inventory(lab: Path, text: str) -> Path:
    (lab / "inventory" / "hosts.yml").unlink()
    (lab / "inventory" / "hosts").write_text(text)
    return lab / "inventory" / "hosts"


def tree(folder: Path, files: int) -> Path:
    folder.mkdir()
    for i in range(files):
        (folder / f"f{i}.py").write_text("x = 1\n")
    return folder


# ------------------------------------------------------------------ integers Python cannot write

@pytest.mark.parametrize("line", [f"r1 ros_domain_id={HUGE}", f"r1 ros_domain_id=[{LONG_HEX}]"])
def test_an_ini_number_too_long_to_write_is_refused_at_its_line(capsys: pytest.CaptureFixture, lab: Path,
                                                                line: str) -> None:
    # ValueError (exceeds the limit for integer string conversion): exit 1 before.
    ini_inventory(lab, f"[lab]\n{line}\nr2 ros_domain_id=2\n")
    refused(capsys, lab, "hosts:2: ros_domain_id: robot 'r1'")


@pytest.mark.parametrize("text, where", [(f"ros_domain_id: {LONG_HEX}\n", "r2.yml:1: ros_domain_id: "),
                                         (f"ros_domain_id: 2\nx: [{LONG_HEX}]\n", "r2.yml:2: x[0]: "),
                                         (f"ros_domain_id: 2\n? {HUGE}\n: 1\n", "r2.yml:2: ")])
def test_a_yaml_number_too_long_to_write_is_refused_at_its_line(capsys: pytest.CaptureFixture, lab: Path,
                                                                text: str, where: str) -> None:
    (lab / "inventory" / "host_vars" / "r2.yml").write_text(text)
    refused(capsys, lab, where)


# ------------------------------------------------------------------ inventory shapes

def test_a_yaml_group_name_with_a_newline_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    # KeyError in the group graph: exit 1 before.
    (lab / "inventory" / "hosts.yml").write_text(
        'all:\n  children:\n    "lab\\nx":\n      hosts: {r1: {ros_domain_id: 1}, r2: {ros_domain_id: 2}}\n')
    refused(capsys, lab, "hosts.yml:3: ", "invalid group name 'lab\\nx'")


def test_an_inventory_folder_too_big_is_one_message(capsys: pytest.CaptureFixture, lab: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    # `-i /` listed a `chmod +x` error for every *.py met before the bound (4,800 lines).
    monkeypatch.setattr(discovery, "MAX_DIR_ENTRIES", 50)
    big = tree(lab / "big", 60)
    code, text = cli(capsys, lab, "validate", "-i", str(big))
    assert code == 2 and "more than 50 entries" in text and "chmod +x" not in text, text
    assert len([line for line in text.splitlines() if line.startswith("error")]) == 1, text


def test_a_link_to_a_big_tree_in_a_vars_folder_is_refused(capsys: pytest.CaptureFixture, lab: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    # group_vars/all/x -> / read every *.yml on the disk (and crashed on EACCES under /proc).
    monkeypatch.setattr(discovery, "MAX_DIR_ENTRIES", 50)   # one bound for every walk
    (lab / "inventory" / "group_vars" / "all" / "disk").symlink_to(tree(lab / "big", 60))
    refused(capsys, lab, "group_vars/all: more than 50 entries under this vars folder")


def test_a_vars_folder_of_no_known_group_is_not_walked(capsys: pytest.CaptureFixture, lab: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(discovery, "MAX_DIR_ENTRIES", 50)   # one bound for every walk
    (lab / "inventory" / "group_vars" / "zzz_other_tool").symlink_to(tree(lab / "big", 60))
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


def test_an_unreadable_vars_folder_is_an_input_error(capsys: pytest.CaptureFixture, lab: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    locked = lab / "inventory" / "group_vars" / "all"
    real_iterdir = Path.iterdir

    def iterdir(self: Path) -> Any:
        if self == locked:
            raise PermissionError(13, "Permission denied", str(self))
        return real_iterdir(self)
    monkeypatch.setattr(Path, "iterdir", iterdir)
    refused(capsys, lab, "group_vars/all: cannot read this vars folder (Permission denied)")


# ------------------------------------------------------------------ fleet values validate let through

def test_a_files_target_name_too_long_is_refused_at_validate(capsys: pytest.CaptureFixture, lab: Path) -> None:
    # validate said OK; render failed writing it and blamed --out.
    (lab / "params.yaml").write_text("a: 1\n")
    edit(lab, lambda d: (d.update(files={"params": {"template": "params.yaml", "target": "/c/" + "a" * 300}}),
                         d["services"]["driver"].update(files=["params"])))
    refused(capsys, lab, "files.params.target: a path of 303 characters")


@pytest.mark.parametrize("change, key", [
    (lambda d: d.update(rollout={"forks": 10**23}), "rollout.forks"),
    (lambda d: d.update(rollback={"keep_releases": 2**63}), "rollback.keep_releases"),
    (lambda d: d.update(logging={"max_file": 10**20}), "logging.max_file"),
    (lambda d: d["services"]["driver"].update(healthcheck={"test": ["CMD", "x"], "retries": 2**40}),
     "services.driver.healthcheck.retries"),
    (lambda d: d["services"]["driver"].update(topics=[{"name": "/a", "min_rate": float("inf")}]),
     "services.driver.topics[0].min_rate"),
    (lambda d: d["services"]["driver"].update(topics=[{"name": "/a", "min_rate": float("nan")}]),
     "services.driver.topics[0].min_rate"),
    (lambda d: d.update(ready={"when": [{"topic": "/a", "field": "d", "at_least": float("nan")}]}),
     "ready.when[0].at_least"),
    (lambda d: d.update(ready={"when": [{"topic": "/a", "field": "__class__.__init__", "is": "x"}]}),
     "ready.when[0].field"),
], ids=["forks", "keep_releases", "max_file", "retries", "min_rate-inf", "min_rate-nan", "at_least-nan",
        "dunder-field"])
def test_values_no_robot_can_use_are_refused(capsys: pytest.CaptureFixture, lab: Path, change: Any,
                                             key: str) -> None:
    edit(lab, change)
    refused(capsys, lab, "fleet.yml:", key)


# ------------------------------------------------------------------ the command line

def test_a_limit_regex_with_a_huge_repeat_is_a_clean_error(capsys: pytest.CaptureFixture, lab: Path) -> None:
    # OverflowError from re.compile: exit 1 before.
    code, text = cli(capsys, lab, "validate", "--limit", "~a{99999999999}")
    assert code == 2 and "--limit: invalid regular expression" in text, text


@pytest.mark.parametrize("out", ["/", "/tmp/.."])
def test_render_refuses_the_filesystem_root(capsys: pytest.CaptureFixture, lab: Path,
                                            monkeypatch: pytest.MonkeyPatch, out: str) -> None:
    # It wrote /r1 and /r2; a robot named `etc` would have merged its files into /etc.
    def no_render(*args: Any) -> Any:
        raise AssertionError("rendered into the filesystem root")
    monkeypatch.setattr(offline, "_render_to", no_render)
    code = main(["render", str(lab / "fleet.yml"), "--vault-password-file",
                 str(lab / "inventory" / ".vault-password"), "--out", out])
    text = capsys.readouterr().err
    assert code == 2 and "--out: the filesystem root" in text and "Traceback" not in text, text


@pytest.mark.parametrize("where", ["inventory", "inventory/out", "inventory/host_vars"])
def test_render_refuses_a_folder_the_inventory_is_read_from(capsys: pytest.CaptureFixture, lab: Path,
                                                           where: str) -> None:
    # robot folders there (compose.yml, .env) would be read as inventory sources by the next run
    before = sorted(str(p) for p in (lab / "inventory").rglob("*"))
    code = main(["render", str(lab / "fleet.yml"), "--vault-password-file",
                 str(lab / "inventory" / ".vault-password"), "--out", str(lab / where)])
    text = capsys.readouterr().err
    assert code == 2 and "which the inventory is read from" in text and "Traceback" not in text, text
    assert sorted(str(p) for p in (lab / "inventory").rglob("*")) == before


def test_render_beside_the_inventory_still_writes(capsys: pytest.CaptureFixture, lab: Path) -> None:
    code = main(["render", str(lab / "fleet.yml"), "--vault-password-file",
                 str(lab / "inventory" / ".vault-password"), "--out", str(lab / "out")])
    assert code == 0, capsys.readouterr().err
    assert any((lab / "out").iterdir())
