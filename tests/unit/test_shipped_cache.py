"""rosdeploy's own templates are compiled once and loaded from ~/.cache/rosdeploy/templates after
(sandbox.ShippedCache); a damaged, foreign or missing cache is never an error."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from rosdeploy import render, sandbox

DATA = Path(__file__).resolve().parent / "data" / "fleet"
# Renders the unit tests' lab fleet in a fresh interpreter; prints how many templates were compiled
# from source, then the digest of every robot's release.
RENDER = r"""
import hashlib, jinja2, sys
compiled = []
real = jinja2.Environment.compile
def counting(self, *args, **kwargs):
    compiled.append(1)
    return real(self, *args, **kwargs)
jinja2.Environment.compile = counting
from rosdeploy.project import deployable, load_project
project = load_project(sys.argv[1] + "/fleet.yml", vault_password_file=sys.argv[1] + "/inventory/.vault-password")
releases, _ = deployable(project, project.targets())
print(len(compiled), hashlib.sha256("".join(r.digest for r in releases.values()).encode()).hexdigest())
"""


def compile_in_child(cache_home: Path) -> tuple[int, str]:
    env = {**os.environ, "XDG_CACHE_HOME": str(cache_home)}
    done = subprocess.run([sys.executable, "-c", RENDER, str(DATA)], env=env, capture_output=True, text=True,
                          check=True)
    count, digest = done.stdout.split()
    return int(count), digest


def test_compiled_once_then_loaded(tmp_path: Path) -> None:
    first, digest = compile_in_child(tmp_path)
    assert first == 6
    folder = tmp_path / "rosdeploy" / "templates"
    assert len(list(folder.iterdir())) == 6 and oct(folder.stat().st_mode & 0o777) == oct(0o700)
    assert all(f.stat().st_mode & 0o077 == 0 for f in folder.iterdir())
    assert compile_in_child(tmp_path) == (0, digest)


def test_a_damaged_entry_is_compiled_again(tmp_path: Path) -> None:
    compile_in_child(tmp_path)
    entries = sorted((tmp_path / "rosdeploy" / "templates").iterdir())
    entries[0].write_bytes(entries[0].read_bytes()[:40])          # cut short inside its header
    entries[1].write_bytes(b"not a cache entry at all")
    entries[2].write_bytes(entries[2].read_bytes()[:-100])         # cut short inside its code
    assert compile_in_child(tmp_path)[0] == 3


def test_a_cache_folder_others_can_write_is_not_used(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert isinstance(sandbox.shipped_cache(), sandbox.ShippedCache)
    (tmp_path / "rosdeploy" / "templates").chmod(0o777)
    assert sandbox.shipped_cache() is None
    assert compile_in_child(tmp_path)[0] == 6                      # and every command still renders


def test_no_cache_where_none_can_be_made(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "file").write_text("")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "file"))   # a file where the folder would go
    assert sandbox.shipped_cache() is None
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/cache")          # never a folder under the cwd
    assert sandbox.shipped_cache() is None
    assert not Path("relative").exists()


def test_templates_a_user_wrote_never_use_it() -> None:
    """The bounded sandbox compiles with its own code generator: code compiled for the shipped
    templates must never stand in for it, even for an override identical to a shipped template."""
    assert render._BUILTIN.bytecode_cache is not None or sandbox.shipped_cache() is None
    assert sandbox.Sandbox().bytecode_cache is None
