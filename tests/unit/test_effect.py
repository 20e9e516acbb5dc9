"""Issue 17 in pure code: per-service hashes, per-robot files, GPU reservation (host changes: test_hostchanges.py)."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from rosdeploy import restarts
from rosdeploy.errors import FleetSpecError, RenderError
from rosdeploy.fleet import load_fleet
from rosdeploy.model import Host
from rosdeploy.render import Renderer

FLEET = {
    "project": "demo", "inventory": "./inventory", "registry": "registry.local:5000", "version": "1.0.0",
    "files": {"params": {"template": "params/{{ inventory_hostname }}.yaml", "target": "/config/params.yaml"},
              "calib": {"var": "camera_calibration", "target": "/config/camera.yaml"}},
    "services": {"driver": {"image": "demo/driver", "files": ["params"]},
                 "perception": {"image": "demo/perception", "files": ["calib"]}},
}


def host(name: str, **vars: object) -> Host:
    return Host(name=name, groups=("all",), vars={"camera_calibration": {"fx": 1.5}, **vars},
                address="10.0.0.1", ros_domain_id=7, source="inventory/hosts.yml:2")


@pytest.fixture
def repo(tmp_path: Path) -> Path:
    (tmp_path / "inventory").mkdir()
    (tmp_path / "inventory" / "hosts.yml").write_text("all: {}\n")
    (tmp_path / "params").mkdir()
    for name in ("r1", "r2"):
        (tmp_path / "params" / f"{name}.yaml").write_text("speed: {{ max_speed | default(1.0) }}\nname: "
                                                           "{{ inventory_hostname }}\n")
    return tmp_path


def write(repo: Path, data: dict) -> Path:
    path = repo / "fleet.yml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def compose(release) -> dict:
    return yaml.safe_load(release.file("compose.yml").content)


def test_files_render_per_robot_and_mount_read_only_where_named(repo: Path) -> None:
    renderer = Renderer(load_fleet(write(repo, FLEET)))
    r1, r2 = renderer.render(host("r1", max_speed=2)), renderer.render(host("r2"))
    assert r1.file("files/params").content == "speed: 2\nname: r1\n"
    assert r2.file("files/params").content == "speed: 1.0\nname: r2\n"
    assert yaml.safe_load(r1.file("files/calib").content) == {"fx": 1.5}
    driver = compose(r1)["services"]["driver"]
    mount = next(v for v in driver["volumes"] if v.endswith(":/config/params.yaml:ro"))
    stored = mount.split(":")[0].removeprefix("../../")
    assert r1.file(stored).content == r1.file("files/params").content
    assert not any("/config/camera.yaml" in v for v in driver["volumes"])
    assert any(v.endswith(":/config/camera.yaml:ro") for v in compose(r1)["services"]["perception"]["volumes"])
    assert r1.digest != renderer.render(host("r1", max_speed=3)).digest


def test_a_changed_params_file_changes_only_the_hash_of_services_that_mount_it(repo: Path) -> None:
    renderer = Renderer(load_fleet(write(repo, FLEET)))
    before = restarts.release_hashes(renderer.render(host("r1", max_speed=2)))
    after = restarts.release_hashes(renderer.render(host("r1", max_speed=3)))
    assert restarts.will_restart(after, before) == ("driver",)
    assert restarts.will_restart(before, before) == ()


def test_an_image_upgrade_changes_only_that_service_hash(repo: Path) -> None:
    data = {**FLEET, "services": {**FLEET["services"], "driver": {**FLEET["services"]["driver"], "tag": "1.0.0"}}}
    old = restarts.release_hashes(Renderer(load_fleet(write(repo, data))).render(host("r1")))
    new = restarts.release_hashes(Renderer(load_fleet(write(repo, data), version="1.1.0")).render(host("r1")))
    assert restarts.will_restart(new, old) == ("perception",)


@pytest.mark.parametrize("source,words", [
    ("../secrets.yaml", ["without `..`"]), ("/etc/passwd", ["inside the fleet repo"]),
    ("params/$(id).yaml", ["inside the fleet repo"])])
def test_file_sources_may_not_leave_the_repo(repo: Path, source: str, words: list[str]) -> None:
    data = {**FLEET, "files": {**FLEET["files"], "params": {"copy": source, "target": "/p.yaml"}}}
    with pytest.raises(FleetSpecError) as info:
        load_fleet(write(repo, data))
    [problem] = info.value.problems
    assert problem.key == "files.params.copy" and problem.line, problem
    assert all(w in problem.message for w in words), problem.message


def test_a_rendered_path_leaving_the_repo_or_missing_is_a_render_error(repo: Path) -> None:
    (repo / "params" / "link.yaml").symlink_to("/etc/hostname")
    data = {**FLEET, "files": {**FLEET["files"], "params": {"copy": "params/{{ which }}.yaml", "target": "/p.yaml"}}}
    renderer = Renderer(load_fleet(write(repo, data)))
    for which, words in (("link", "leads out of"), ("nope", "does not exist"), ("../inventory/hosts", "without `..`")):
        with pytest.raises(RenderError) as info:
            renderer.render(host("r1", which=which))
        assert any(words in p.message and p.key == "files.params.copy" and p.line for p in info.value.problems), \
            info.value.problems


def test_unknown_file_names_and_bad_targets_name_their_key(repo: Path) -> None:
    data = {**FLEET, "files": {**FLEET["files"], "calib": {"var": "camera_calibration", "target": "/ros_log/x"}},
            "services": {**FLEET["services"], "driver": {"image": "demo/driver", "files": ["parms"]}}}
    with pytest.raises(FleetSpecError) as info:
        load_fleet(write(repo, data))
    found = {p.key: p.message for p in info.value.problems}
    assert "did you mean 'params'?" in found["services.driver.files[0]"]
    assert "rosdeploy mounts /ros_log" in found["files.calib.target"]


def test_a_missing_inventory_var_names_the_robot(repo: Path) -> None:
    renderer = Renderer(load_fleet(write(repo, FLEET)))
    bare = Host(name="r2", groups=("all",), vars={}, address="10.0.0.2", ros_domain_id=8, source="inv:3")
    with pytest.raises(RenderError) as info:
        renderer.render(bare)
    assert any("camera_calibration" in p.message and "'r2'" in p.message for p in info.value.problems)


def test_an_undefined_inventory_var_that_reads_empty_is_refused_not_written(repo: Path) -> None:
    # Inventory templates use StrictUndefined; a lenient Undefined (another loader, a plugin) must
    # still not become an empty file on the robot, nor reach the YAML dumper.
    import jinja2
    renderer = Renderer(load_fleet(write(repo, FLEET)))
    with pytest.raises(RenderError) as info:
        renderer.render(host("r1", camera_calibration=jinja2.Undefined(name="camera_calibration")))
    assert any("camera_calibration" in p.message and "undefined" in p.message and p.key == "files.calib.var"
               for p in info.value.problems), info.value.problems
