"""render --out (rosdeploy.cli.writeout): each robot written where it rendered; what lands, and what does not."""
from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest
import yaml

from rosdeploy.cli import offline, writeout
from rosdeploy.errors import InputError
from rosdeploy.model import RenderedFile, RenderedRelease
from rosdeploy.project import Project, deployable, load_project
from test_forked import forking

__all__ = ["forking"]   # the fixture: children from 4 robots on, 3 processes, whatever the machine


def release(host: str, secret: str = "s3cret") -> RenderedRelease:
    files = (RenderedFile("compose.yml", f"services: {{}}  # {host}\n"), RenderedFile(".env", f"K={secret}\n", 0o600),
             RenderedFile("store/abc/fastdds.xml", "<dds/>\n"))
    return RenderedRelease(host, "p", "1.0.0", files, ())


def renders(*releases: RenderedRelease, then: BaseException | None = None):
    def render(sink):
        for r in releases:
            if sink is not None:
                sink(r)
        if then is not None:
            raise then
        return {r.host: r for r in releases}, []
    return render


def test_every_release_lands_with_its_modes_and_no_staging(tmp_path: Path) -> None:
    root = tmp_path / "out"
    done, _ = offline._render_to(root, renders(release("a"), release("b")))
    assert list(done) == ["a", "b"]
    assert sorted(p.name for p in root.iterdir()) == ["a", "b"]
    assert (root / "a" / "store" / "abc" / "fastdds.xml").read_text() == "<dds/>\n"
    assert stat.S_IMODE((root / "b" / ".env").stat().st_mode) == 0o600
    assert stat.S_IMODE((root / "b" / "compose.yml").stat().st_mode) == 0o644


def test_a_new_out_folder_lands_whole_with_the_mode_mkdir_gives(tmp_path: Path) -> None:
    old = os.umask(0o027)
    try:
        offline._render_to(tmp_path / "new" / "out", renders(release("a"), release("b")))
    finally:
        os.umask(old)
    root = tmp_path / "new" / "out"
    assert stat.S_IMODE(root.stat().st_mode) == 0o750     # not a temp folder's 0700
    assert sorted(p.name for p in root.iterdir()) == ["a", "b"]
    assert [p.name for p in root.parent.iterdir()] == ["out"]     # no staging folder beside it


def test_an_out_folder_made_meanwhile_keeps_its_files_and_gets_the_robots(tmp_path: Path) -> None:
    root = tmp_path / "out"

    def render(sink):
        done = renders(release("a"), release("b"))(sink)
        root.mkdir(exist_ok=True)
        (root / "notes.txt").write_text("mine\n")     # another program, while rosdeploy rendered
        return done
    offline._render_to(root, render)
    assert sorted(p.name for p in root.iterdir()) == ["a", "b", "notes.txt"]
    assert (root / "a" / "compose.yml").is_file() and [p.name for p in tmp_path.iterdir()] == ["out"]


@pytest.mark.parametrize("failure", [InputError([]), KeyboardInterrupt()])
def test_a_run_that_fails_after_some_robots_were_sent_leaves_nothing_and_keeps_its_own_error(
        tmp_path: Path, failure: BaseException) -> None:
    """A refusal stays a refusal and Ctrl-C stays an interrupt, with nothing left on disk."""
    root = tmp_path / "out"
    with pytest.raises(type(failure)):
        offline._render_to(root, renders(release("a"), release("b"), then=failure))
    assert not root.exists() and list(tmp_path.iterdir()) == []


def test_a_file_name_that_leaves_the_robot_folder_is_refused(tmp_path: Path) -> None:
    bad = RenderedRelease("a", "p", "1", (RenderedFile("../../etc/x", "x"),), ())
    with pytest.raises(InputError) as refused:
        offline._render_to(tmp_path / "out", renders(bad))
    assert "leaves the release folder" in str(refused.value.problems[0].message)
    assert not (tmp_path / "out").exists() and not (tmp_path / "etc").exists()


def test_a_write_failure_is_reported_on_commit_and_not_over_the_runs_own_error(tmp_path: Path) -> None:
    clash = RenderedRelease("a", "p", "1", (RenderedFile("x", "file"), RenderedFile("x/y", "under a file")), ())
    with pytest.raises(InputError) as failed:
        offline._render_to(tmp_path / "out", renders(clash))
    assert "cannot write there" in failed.value.problems[0].message and failed.value.problems[0].key == "--out"
    assert not (tmp_path / "out").exists()
    with pytest.raises(KeyboardInterrupt):
        offline._render_to(tmp_path / "out", renders(clash, then=KeyboardInterrupt()))


# ------------------------------------------- written by the forked children that rendered them

def writers(monkeypatch: pytest.MonkeyPatch, log: Path, fail: str = "", where: str = "") -> None:
    """Log which process writes each robot (O_APPEND: children and this process share the file);
    `fail`: that robot's write fails as on a full disk, in a child only or `anywhere`."""
    real = writeout.write_release
    parent = os.getpid()

    def write_release(folder: str, files: writeout.Files) -> None:
        robot = os.path.basename(folder)
        with open(log, "a") as f:
            f.write(f"{robot} {os.getpid()}\n")
        if robot == fail and (where == "anywhere" or os.getpid() != parent):
            raise OSError(28, "No space left on device", folder)
        real(folder, files)

    monkeypatch.setattr(writeout, "write_release", write_release)


def lab(root: Path, robots: int) -> Project:
    hosts = {f"r{i:02d}": {"ansible_host": f"10.0.0.{i + 1}", "ros_domain_id": i} for i in range(robots)}
    (root / "inventory").mkdir(parents=True)
    (root / "inventory" / "hosts.yml").write_text(yaml.safe_dump({"all": {"hosts": hosts}}))
    (root / "fleet.yml").write_text(yaml.safe_dump({
        "project": "lab", "inventory": "./inventory", "registry": "registry.local:5000", "version": "1.0.0",
        "services": {"driver": {"image": "lab/driver", "environment": {"NAME": "{{ inventory_hostname }}"}}}}))
    return load_project(str(root / "fleet.yml"))


def test_children_write_the_robots_they_rendered(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                 forking: None) -> None:
    project, log, root = lab(tmp_path, 12), tmp_path / "writers.log", tmp_path / "out"
    writers(monkeypatch, log)
    releases, _ = offline._render_to(root, lambda sink: deployable(project, project.targets(), sink))
    by = dict(line.split() for line in log.read_text().splitlines())
    assert sorted(by) == sorted(releases) and len(releases) == 12
    assert len(set(by.values())) == 3 and str(os.getpid()) in by.values()   # this process and two children
    for name, r in releases.items():
        for f in r.files:
            assert (root / name / f.name).read_text() == f.content
    assert [p.name for p in root.iterdir() if p.name.startswith(writeout.STAGE_PREFIX)] == []


def test_a_write_that_fails_in_a_child_is_done_again_here(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                          forking: None) -> None:
    project, log, root = lab(tmp_path, 12), tmp_path / "writers.log", tmp_path / "out"
    writers(monkeypatch, log, fail="r11", where="child")
    releases, _ = offline._render_to(root, lambda sink: deployable(project, project.targets(), sink))
    tries = [line.split()[1] for line in log.read_text().splitlines() if line.startswith("r11 ")]
    assert len(tries) == 2 and tries[-1] == str(os.getpid())
    assert sorted(p.name for p in root.iterdir()) == sorted(releases) and len(releases) == 12


def test_a_write_that_fails_everywhere_is_reported_and_nothing_lands(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch,
                                                                     forking: None) -> None:
    project, log, root = lab(tmp_path, 12), tmp_path / "writers.log", tmp_path / "out"
    writers(monkeypatch, log, fail="r11", where="anywhere")
    with pytest.raises(InputError) as failed:
        offline._render_to(root, lambda sink: deployable(project, project.targets(), sink))
    assert "No space left on device" in failed.value.problems[0].message
    assert failed.value.problems[0].file.endswith("r11") and failed.value.problems[0].key == "--out"
    assert not root.exists()
