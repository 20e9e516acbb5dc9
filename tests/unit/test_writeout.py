"""render --out through the child writer (rosdeploy.cli.writeout): what lands, and what does not."""
from __future__ import annotations

import stat
from pathlib import Path

import pytest

from rosdeploy import forked
from rosdeploy.cli import offline, writeout
from rosdeploy.errors import InputError
from rosdeploy.model import RenderedFile, RenderedRelease


@pytest.fixture(autouse=True, params=["child", "afterwards"])
def way(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Each test both ways: through the child writer, and written after the checks (no fork). The
    child is forced even if an earlier test left a thread behind (can_fork would refuse then)."""
    monkeypatch.setattr(forked, "can_fork", lambda: request.param == "child")
    return request.param


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


def test_every_release_lands_with_its_modes_and_no_staging(tmp_path: Path, way: str,
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    sent: list[str] = []
    real_send = writeout.Writer.send

    def send(self: writeout.Writer, r: RenderedRelease) -> None:
        sent.append(r.host)
        real_send(self, r)

    monkeypatch.setattr(writeout.Writer, "send", send)
    root = tmp_path / "out"
    done, _ = offline._render_to(root, renders(release("a"), release("b")))
    assert list(done) == ["a", "b"]
    assert sorted(p.name for p in root.iterdir()) == ["a", "b"]
    assert (root / "a" / "store" / "abc" / "fastdds.xml").read_text() == "<dds/>\n"
    assert stat.S_IMODE((root / "b" / ".env").stat().st_mode) == 0o600
    assert stat.S_IMODE((root / "b" / "compose.yml").stat().st_mode) == 0o644
    assert sent == (["a", "b"] if way == "child" else [])   # the way this test meant is the way it went


@pytest.mark.parametrize("failure", [InputError([]), KeyboardInterrupt()])
def test_a_run_that_fails_after_some_robots_were_sent_leaves_nothing_and_keeps_its_own_error(
        tmp_path: Path, failure: BaseException) -> None:
    """A refusal stays a refusal and Ctrl-C stays an interrupt, with nothing left on disk."""
    root = tmp_path / "out"
    with pytest.raises(type(failure)):
        offline._render_to(root, renders(release("a"), release("b"), then=failure))
    assert not root.exists()


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
