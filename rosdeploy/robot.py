"""What a robot looks like right now, parsed from one `state` round trip, and the
pure decisions made from it (which release is previous, is it healthy).

Nothing here talks to a robot: deploy.py runs the commands, this module reads
their output. That keeps every decision unit-testable without SSH.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping

from rosdeploy.commands import parse_containers, parse_sections
from rosdeploy.guard import Guard, parse_guard


@dataclass(frozen=True)
class Container:
    name: str
    service: str
    image: str
    status: str            # created | running | restarting | exited | dead | paused
    health: str | None     # starting | healthy | unhealthy | None (no health check)
    restarts: int
    workdir: str = ""
    id: str = ""                 # from `docker inspect` (not in `docker ps` output)
    test: tuple[str, ...] = ()   # HEALTHCHECK test, e.g. ("CMD", "/opt/check"); () when none
    test_timeout: float = 30.0   # seconds (Docker's default)
    compose: str = ""            # version of the compose that created it (its label)
    hash: str = ""               # io.rosdeploy.hash: what the container runs (rosdeploy.restarts)

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> "Container":
        """From `docker inspect` (health, restarts) or `docker ps` (health in the status text)."""
        health = data.get("health") if "ps_status" not in data else _ps_health(str(data["ps_status"]))
        return cls(name=str(data.get("name", "")).lstrip("/"), service=str(data.get("service") or ""),
                   image=str(data.get("image", "")), status=str(data.get("status", "")),
                   health=health, restarts=int(data.get("restarts") or 0),
                   workdir=str(data.get("workdir") or ""),
                   id=str(data.get("id") or ""), test=tuple(str(a) for a in data.get("test") or ()),
                   test_timeout=(int(data.get("test_timeout") or 0) / 1e9) or 30.0,
                   compose=str(data.get("compose") or ""), hash=str(data.get("hash") or ""))


    @property
    def release(self) -> str:
        """Release id this container was started from (compose records its working dir)."""
        return self.workdir.rstrip("/").rsplit("/", 1)[-1] if "/releases/" in self.workdir else ""


def _ps_health(status: str) -> str | None:
    """'Up 5 minutes (healthy)' -> healthy; '(health: starting)' -> starting; no check -> None."""
    for word in ("unhealthy", "healthy", "starting"):
        if f"({word})" in status or f"(health: {word})" in status:
            return word
    return None


@dataclass(frozen=True)
class RobotState:
    home: str
    dir: str
    current: str | None                 # release id `current` points at
    manifest: Mapping[str, Any] | None
    lock: Mapping[str, Any] | None      # owner of a held lock
    releases: tuple[str, ...]
    history: tuple[Mapping[str, Any], ...]   # oldest first
    docker: str                          # server version, or the error docker printed
    docker_ok: bool
    compose: tuple[str, str] | None      # ("v2", "2.40.3") / ("v1", "1.29.2")
    containers: tuple[Container, ...]
    free_mb: int | None
    runtimes: Mapping[str, Any] | None   # docker runtimes when asked (gpu robots)
    missing_devices: tuple[str, ...]
    kept_manifests: Mapping[str, str] = field(default_factory=dict)   # release -> manifest text (switch state)
    guard: Guard | None = None           # a deploy guard armed (or acting) on the robot
    clock: int | None = None             # the robot's clock (s since the epoch), for the guard's deadline
    boot: str = ""                       # the robot's boot id
    # Installed host-change file -> its sha256 ("?": unreadable); None when the state did not look.
    host_files: Mapping[str, str] | None = None

    @property
    def running_release(self) -> str | None:
        """The release the project's running containers belong to (their compose labels);
        "mixed" when they belong to more than one, None when none runs."""
        releases = {c.release for c in self.containers if c.status in ("running", "restarting")}
        if not releases:
            return None
        return releases.pop() if len(releases) == 1 else "mixed"

    @property
    def flavor(self) -> str | None:
        return self.compose[0] if self.compose else None

    @property
    def running_flavor(self) -> str | None:
        """v1/v2 from the compose that created the project's containers (their label), so a
        quick state can tell it without the ~0.1 CPU-s `docker compose version`."""
        majors = {c.compose.split(".", 1)[0] for c in self.containers if c.compose}
        return {frozenset({"2"}): "v2", frozenset({"1"}): "v1"}.get(frozenset(majors))

    @property
    def recorded_flavor(self) -> str | None:
        """v1/v2 as the history says the current release was last started with: what the
        containers' label would say, without listing them."""
        for entry in reversed(self.history):
            if entry.get("release") == self.current and entry.get("compose") in ("v1", "v2"):
                return str(entry["compose"])
        return None


def parse_state(stdout: str) -> RobotState:
    s = parse_sections(stdout)
    current = s.get("current", "").strip()
    docker = s.get("docker", "").strip()
    compose = s.get("compose", "").split()
    disk = s.get("disk", "").strip()
    return RobotState(
        home=s.get("home", ""), dir=s.get("dir", ""),
        current=current.rsplit("/", 1)[-1] or None,
        manifest=_json(s.get("manifest")), lock=_json(s.get("lock")),
        releases=tuple(r for r in s.get("releases", "").split() if r),
        history=tuple(h for h in (_json(line) for line in s.get("history", "").splitlines()) if h),
        docker=docker, docker_ok=bool(docker) and docker[0].isdigit(),
        compose=(compose[0], compose[1] if len(compose) > 1 else "") if compose else None,
        containers=tuple(Container.from_json(c) for c in parse_containers(s.get("containers", ""))),
        free_mb=int(disk) if disk.isdigit() else None,
        runtimes=_json(s.get("gpu")),
        missing_devices=tuple(line.split(" ", 1)[1] for line in s.get("devices", "").splitlines()
                              if line.startswith("missing ")),
        kept_manifests={name.split(" ", 1)[1]: text for name, text in s.items() if name.startswith("manifest ")},
        guard=parse_guard(s.get("guard-acting"), acting=True) or parse_guard(s.get("guard")),
        clock=int(s["clock"]) if s.get("clock", "").strip().isdigit() else None,
        boot=s.get("boot", "").strip(),
        host_files=_host_files(s["hostfiles"]) if "hostfiles" in s else None)


def _host_files(text: str) -> dict[str, str]:
    pairs = (line.split(" ", 1) for line in text.splitlines() if " " in line)
    return {path: digest for digest, path in pairs}


def _json(text: str | None) -> Any:
    if not text or not text.strip():
        return None
    try:
        return json.loads(text)
    except ValueError:
        return None


# ---------------------------------------------------------------- decisions

def unhealthy_services(containers: Iterable[Container], expected: Iterable[str]) -> dict[str, str]:
    """Service -> why it is not healthy right now; empty when all expected services are fine.

    'starting' counts as not healthy: a no-op must not claim a robot is fine
    while its services are still coming up.
    """
    by_service = {c.service: c for c in containers}
    problems: dict[str, str] = {}
    for name in expected:
        c = by_service.get(name)
        if c is None:
            problems[name] = "no container"
        elif c.status != "running":
            problems[name] = f"container {c.status}"
        elif c.health not in (None, "healthy"):
            problems[name] = f"health {c.health}"
    return problems


def release_services(manifest_text: str) -> tuple[str, ...] | None:
    """The services a kept release runs, as its manifest recorded them when it was deployed;
    None when it did not (deployed by an older rosdeploy) or the manifest is unreadable."""
    try:
        services = json.loads(manifest_text).get("services")
    except (ValueError, AttributeError):
        return None
    if not isinstance(services, list) or not all(isinstance(s, str) for s in services):
        return None
    return tuple(services)


def previous_release(state: RobotState) -> str | None:
    """The release to go back to: the newest one that was active before the current one,
    skipping releases an operator or rosdeploy already rolled back from (unless they
    were successfully activated again later), and releases no longer on the robot."""
    bad: set[str] = set()
    active: list[str] = []
    for entry in state.history:
        release = entry.get("release")
        if entry.get("result") == "active" and release:
            bad.discard(release)
            active.append(release)
        rolled_from = entry.get("rolled_back_from")
        if rolled_from:
            bad.add(rolled_from)
    for release in reversed(active):
        if release != state.current and release not in bad and release in state.releases:
            return release
    return None


def passed_gate(state: RobotState, release: str) -> bool:
    """Was this release ever activated on the robot, i.e. did it pass the whole health gate?"""
    return any(e.get("release") == release and e.get("result") == "active" for e in state.history)


def rollback_target(state: RobotState, to_version: str | None, to_release: str | None) -> str | None:
    """The kept release a rollback goes to: an exact release id, the newest of a version,
    or the previous release; None when the robot does not have it."""
    if to_release:
        return to_release if to_release in state.releases else None
    return release_for_version(state, to_version) if to_version else previous_release(state)


def release_for_version(state: RobotState, version: str) -> str | None:
    """Newest kept release of a version (release ids are `<version>-<digest12>`)."""
    matches = [r for r in state.releases if r.rsplit("-", 1)[0] == version]
    if not matches:
        return None
    activated = [e.get("release") for e in state.history if e.get("result") == "active"]
    return max(matches, key=lambda r: max((i for i, a in enumerate(activated) if a == r), default=-1))
