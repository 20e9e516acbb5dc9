"""compose_data (what the checks read) equals the built-in compose.yml parsed back, for every shape."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import yaml

from rosdeploy.compose_env import interpolate, parse_env
from rosdeploy.model import HealthCheck
from rosdeploy.project import load_project
from rosdeploy.render import Renderer
from test_render import FULL, FULL_HOST, NASTY, make_host, make_service, make_spec

REPO = Path(__file__).resolve().parents[2]

SHAPES = {
    "full": (FULL, FULL_HOST),
    "full-no-gpu": (FULL, dataclasses.replace(FULL_HOST, gpu=False)),
    "bridge": (dataclasses.replace(FULL, network_mode="bridge"), FULL_HOST),
    "cyclonedds": (dataclasses.replace(FULL, rmw="cyclonedds", shm_size="1g"), FULL_HOST),
    "nasty-values": (make_spec(make_service(
        environment={"A": NASTY, "B": "$HOME", "yes": "no", "K.x-1": "1e3"}, command=(NASTY, "$x", "~"),
        healthcheck=HealthCheck(("CMD-SHELL", NASTY), interval="1500ms"), user="a$b", memory="1g", cpus=2.0,
        volumes=("/opt/$x:/data:ro",), privileged=True, profiles=("dev",),
        extra={"cap_add": ["SYS_NICE"], "ulimits": {"rtprio": 99}, "x-note": "cost $5 ${X}"})),
        make_host(vars={"x": 1})),
    "interpolated-extra": (make_spec(make_service(extra={"hostname": "${HOSTNAME:-r}"}, compose_interpolate=True)),
                           make_host()),
    "no-command-no-health": (make_spec(make_service(command=None, healthcheck=None, memory=None, cpus=None)),
                             make_host()),
}


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_compose_data_is_the_rendered_file_parsed(name: str) -> None:
    spec, host = SHAPES[name]
    release = Renderer(spec).render(host)
    raw, resolved = release.compose_data
    assert raw == yaml.safe_load(release.file("compose.yml").content)
    assert resolved == interpolate(raw, parse_env(release.file(".env").content))


def test_the_shipped_example_too() -> None:
    project = load_project(str(REPO / "playbooks" / "warehouse.yml"),
                           vault_password_file=str(REPO / "inventory" / "warehouse" / ".vault-password-example"))
    renderer = Renderer(project.spec)
    for host in project.targets():
        release = renderer.render(host)
        assert release.compose_data[0] == yaml.safe_load(release.file("compose.yml").content), host.name


def test_a_user_compose_template_is_parsed_back_instead(tmp_path: Path) -> None:
    (tmp_path / "compose.yml.j2").write_text("services: {a: {image: x}}\n")
    release = Renderer(dataclasses.replace(FULL, templates=str(tmp_path))).render(FULL_HOST)
    assert release.compose_data is None
