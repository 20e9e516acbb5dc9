"""Round eleven: leftovers of earlier rounds."""
from __future__ import annotations

from pathlib import Path

import pytest

from test_hostile import cli, edit, lab  # noqa: F401  (lab is a fixture)


@pytest.mark.parametrize("tmpfs, index, words", [
    (["/proc/foo"], 0, "a tmpfs at /proc/foo is in /proc, where the container runtime (runc) refuses a mount"),
    (["/run", "/sys/class/x"], 1, "a tmpfs at /sys/class/x is in /sys, the container's read-only sysfs"),
    (["/sys"], 0, "a mount at /sys would hide the container's sysfs"),
    (["/run/../proc:size=1m"], 0, "a tmpfs at /proc is in /proc"),
])
def test_a_compose_tmpfs_in_proc_or_sys_is_refused_by_every_command(
        capsys: pytest.CaptureFixture, lab: Path, tmpfs: list, index: int, words: str) -> None:  # noqa: F811
    edit(lab, lambda d: d["services"]["driver"].update(compose={"tmpfs": tmpfs}))
    for command in ("validate", "check", "render"):
        code, text = cli(capsys, lab, command)
        assert code == 2 and f"services.driver.compose.tmpfs[{index}]: {words}" in text, (command, text)
        assert "Traceback" not in text
    assert not (lab / "out").exists()


def test_a_compose_tmpfs_elsewhere_still_renders(capsys: pytest.CaptureFixture, lab: Path) -> None:  # noqa: F811
    edit(lab, lambda d: d["services"]["driver"].update(compose={"tmpfs": ["/run/cache:size=1m", "/proc-like"]}))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    assert "/run/cache:size=1m" in next((lab / "out").glob("*/compose.yml")).read_text()
