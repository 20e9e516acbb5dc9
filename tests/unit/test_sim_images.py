"""Build-input hashing, the apt-sources mirror reader and the demo release table (pure logic)."""
from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import pytest

from rosdeploy.sim.demo import DEMO_IMAGES, DEMO_TOPICS, demo_image
from rosdeploy.sim.images import IMAGES_DIR, inputs_digest, tag_for, tree_parts, value_parts
from rosdeploy.sim.rootfs import mirror_from_sources


def make_tree(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    return root


def test_digest_is_stable_and_ignores_order() -> None:
    parts = [("a", b"1"), ("b", b"2")]
    assert inputs_digest(parts) == inputs_digest(list(reversed(parts)))
    assert len(inputs_digest(parts)) == 64
    assert tag_for("robot", inputs_digest(parts)) == f"rosdeploy-sim/robot:{inputs_digest(parts)[:12]}"


@pytest.mark.parametrize("change", [
    [("a", b"1"), ("b", b"3")],      # content
    [("a", b"1"), ("c", b"2")],      # name
    [("a", b"12")],                  # moving bytes between inputs
    [("a", b"1"), ("b", b"2"), ("c", b"")],
])
def test_digest_changes_with_any_input(change: list[tuple[str, bytes]]) -> None:
    assert inputs_digest(change) != inputs_digest([("a", b"1"), ("b", b"2")])


def test_tree_parts_see_content_paths_and_the_executable_bit_but_not_caches(tmp_path: Path) -> None:
    root = make_tree(tmp_path / "ctx", {"Dockerfile": "FROM x\n", "pkg/mod.py": "x = 1\n",
                                        "pkg/__pycache__/mod.cpython-311.pyc": "junk"})
    before = inputs_digest(tree_parts(root))
    assert [name for name, _ in tree_parts(root)] == ["Dockerfile:-", "pkg/mod.py:-"]
    (root / "pkg" / "__pycache__" / "mod.cpython-311.pyc").write_text("other junk")
    assert inputs_digest(tree_parts(root)) == before
    os.chmod(root / "Dockerfile", 0o755)
    assert inputs_digest(tree_parts(root)) != before


def test_build_args_take_part_in_the_digest() -> None:
    files = tree_parts(IMAGES_DIR / "demo")
    digests = {inputs_digest(files + value_parts(BASE="b", **image.build_args())) for image in DEMO_IMAGES}
    assert len(digests) == len(DEMO_IMAGES)


def test_every_image_context_is_shipped_with_the_package() -> None:
    for name in ("robot", "ros-base", "demo"):
        assert (IMAGES_DIR / name / "Dockerfile").is_file()
    for script in ("robot/robot-init", "robot/robot-ctl", "demo/healthcheck"):
        assert os.access(IMAGES_DIR / script, os.X_OK), script


SOURCES_DEB822 = """\
Types: deb
URIs: http://mirror.example/debian
Suites: bookworm bookworm-updates
Components: main

Types: deb
URIs: http://mirror.example/debian-security
Suites: bookworm-security
Components: main
"""


def test_mirror_is_read_from_deb822_sources() -> None:
    assert mirror_from_sources([("debian.sources", SOURCES_DEB822)], "bookworm") == "http://mirror.example/debian"
    assert mirror_from_sources([("debian.sources", SOURCES_DEB822)], "bookworm-security") == \
        "http://mirror.example/debian-security"


def test_mirror_is_read_from_one_line_sources_skipping_src_options_and_other_suites() -> None:
    text = ("# deb http://commented.example/debian bookworm main\n"
            "deb-src http://src.example/debian bookworm main\n"
            "deb http://other.example/debian trixie main\n"
            "deb [arch=amd64 signed-by=/k.gpg] http://mirror.example/debian/ bookworm main\n")
    assert mirror_from_sources([("sources.list", text)], "bookworm") == "http://mirror.example/debian"


def test_disabled_deb822_entries_and_missing_suites_give_nothing() -> None:
    disabled = "Enabled: no\n" + SOURCES_DEB822.split("\n\n")[0]
    assert mirror_from_sources([("x.sources", disabled)], "bookworm") is None
    assert mirror_from_sources([("x.sources", SOURCES_DEB822)], "trixie") is None


def test_demo_releases_match_the_node_code_in_the_images(monkeypatch: pytest.MonkeyPatch) -> None:
    spec = importlib.util.spec_from_file_location("demo_nodes_table", IMAGES_DIR / "demo/demo_nodes/__init__.py")
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)     # dataclasses look their module up
    spec.loader.exec_module(module)
    assert module.TOPICS == {node: tuple(topic) for node, topic in DEMO_TOPICS.items()}
    assert {(i.node, i.tag) for i in DEMO_IMAGES} == \
           {(n, t) for n in ("driver", "perception") for t in ("1.0.0", "1.1.0", "1.2.0-bad")}
    assert demo_image("driver", "1.1.0").rate_hz != demo_image("driver", "1.0.0").rate_hz
    assert not demo_image("driver", "1.2.0-bad").healthy and demo_image("perception", "1.0.0").healthy
    assert demo_image("perception", "1.0.0").build_args() == \
        {"NODE": "perception", "VERSION": "1.0.0", "RATE_HZ": "5", "FAULT": ""}
