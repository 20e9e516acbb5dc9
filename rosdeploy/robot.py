"""What a robot looks like right now, parsed from one `state` round trip, and the
pure decisions made from it (which release is previous, is it healthy).

Nothing here talks to a robot: deploy.py runs the commands, this module reads
their output. That keeps every decision unit-testable without SSH.
"""
from __future__ import annotations

import json
import posixpath
import re
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping

from rosdeploy.commands import parse_containers, parse_sections
from rosdeploy.fleet import TAG_RE
from rosdeploy.guard import Guard, digits, parse_guard
from rosdeploy.model import RenderedRelease

# What model.RenderedRelease.release_id makes: `<version>-<first 12 hex digits of the digest>`.
# Any other name in releases/ (a copy, a backup, a stray file) is not a release rosdeploy made.
RELEASE_ID_RE = re.compile(TAG_RE.pattern + r"-[0-9a-f]{12}")

# The lock of a `.lock` directory whose owner file is empty, missing or not an owner record: a
# controller killed between `mkdir .lock` and writing the owner leaves one. It is held all the
# same (apply refuses it), so it must never read as "no lock".
UNKNOWN_OWNER: Mapping[str, Any] = {"owner": "unknown"}


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
        test = data.get("test")
        return cls(name=str(data.get("name", "")).lstrip("/"), service=str(data.get("service") or ""),
                   image=str(data.get("image", "")), status=str(data.get("status", "")),
                   health=health, restarts=_count(data.get("restarts")),
                   workdir=str(data.get("workdir") or ""),
                   id=str(data.get("id") or ""), test=tuple(str(a) for a in test) if isinstance(test, list) else (),
                   test_timeout=(_count(data.get("test_timeout")) / 1e9) or 30.0,
                   compose=str(data.get("compose") or ""), hash=str(data.get("hash") or ""))


    @property
    def release(self) -> str:
        """Release id this container was started from (compose records its working dir)."""
        return self.workdir.rstrip("/").rsplit("/", 1)[-1] if "/releases/" in self.workdir else ""


def _count(value: Any) -> int:
    """A count docker reported: an int, or 0 when the robot sent something else."""
    if type(value) is int:
        return max(value, 0)
    return (digits(value) or 0) if isinstance(value, str) else 0


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
    current: str | None                 # release id `current` points at (a kept release rosdeploy made)
    manifest: Mapping[str, Any] | None  # current/manifest.json; None when absent or not a JSON object
    lock: Mapping[str, Any] | None      # owner of a held lock (UNKNOWN_OWNER: held, owner unreadable)
    releases: tuple[str, ...]           # release ids kept in releases/
    history: tuple[Mapping[str, Any], ...]   # oldest first; JSON objects only
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
    # Where `current` points when that is not a release rosdeploy deployed (outside releases/,
    # dangling, a name it never makes); "" otherwise. `current` is None then.
    foreign_current: str = ""
    # Older history lines that still decide a rollback (each kept release's last activation and
    # the last rollback away from it), oldest first: they come before `history`.
    gates: tuple[Mapping[str, Any], ...] = ()
    guard_container: str | None = None   # its docker status ("none": no container); None: not asked
    link: str = ""                       # `current` as readlink printed it: what lock(expect=) compares

    @property
    def gate_history(self) -> tuple[Mapping[str, Any], ...]:
        """What decides "passed its gate" and "previous": the older deciding lines, then the last ones."""
        return self.gates + self.history

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
    """The robot's state; what a robot sends that rosdeploy never writes (corrupt after a power
    loss, or hostile) reads as absent or unreadable, never as an error of the whole command."""
    s = parse_sections(stdout)
    raw = s.get("current", "").rstrip("\n")
    link = raw.strip()
    releases = _releases(s.get("releases"))
    current = _current(link, s.get("dir", "").strip(), releases)
    docker = s.get("docker", "").strip()
    compose = s.get("compose", "").split()
    return RobotState(
        home=s.get("home", ""), dir=s.get("dir", ""),
        current=current, foreign_current=link if link and current is None else "",
        manifest=_object(s.get("manifest")), lock=_lock(s.get("lock"), s.get("lockdir")),
        releases=releases or (),
        history=_objects(s.get("history")), gates=_objects(s.get("gates")),
        guard_container=s["guard-container"].strip() if "guard-container" in s else None,
        docker=docker, docker_ok=bool(docker) and docker[0].isdigit(),
        compose=(compose[0], compose[1] if len(compose) > 1 else "") if compose else None,
        containers=tuple(Container.from_json(c) for c in parse_containers(s.get("containers", ""))
                         if isinstance(c, Mapping)),
        free_mb=digits(s.get("disk")),
        runtimes=_object(s.get("gpu")),
        missing_devices=tuple(line.split(" ", 1)[1] for line in s.get("devices", "").splitlines()
                              if line.startswith("missing ")),
        kept_manifests={name.split(" ", 1)[1]: text for name, text in s.items() if name.startswith("manifest ")},
        guard=parse_guard(s.get("guard-acting"), acting=True) or parse_guard(s.get("guard")),
        clock=digits(s.get("clock")),
        boot=s.get("boot", "").strip(),
        host_files=_host_files(s["hostfiles"]) if "hostfiles" in s else None, link=raw)


def _objects(text: str | None) -> tuple[Mapping[str, Any], ...]:
    """The JSON objects of a section, one a line; anything else is skipped."""
    return tuple(h for h in (_object(line) for line in (text or "").splitlines()) if h is not None)


def _host_files(text: str) -> dict[str, str]:
    pairs = (line.split(" ", 1) for line in text.splitlines() if " " in line)
    return {path: digest for digest, path in pairs}


def _releases(text: str | None) -> tuple[str, ...] | None:
    """The kept releases, one name a line (a name may hold a space); None when not sent."""
    if text is None:
        return None
    return tuple(name for name in text.splitlines() if RELEASE_ID_RE.fullmatch(name))


def _current(link: str, root: str, releases: tuple[str, ...] | None) -> str | None:
    """The release `current` points at: `releases/<id>` (finish.sh writes it relative; a trailing
    slash or the deploy dir's absolute path is the same place). Anything else, or a release that
    is not kept (a dangling link), is not a release rosdeploy deployed. `releases` None: the
    state did not list them (a test's partial state), so only the link's form is checked."""
    path = posixpath.normpath(link) if link else ""
    if root and path.startswith(posixpath.normpath(root) + "/"):
        path = path[len(posixpath.normpath(root)) + 1:]
    parent, _, name = path.partition("/")
    if parent != "releases" or not name or "/" in name:
        return None
    return name if releases is None or name in releases else None


def _lock(owner: str | None, lockdir: str | None) -> Mapping[str, Any] | None:
    """The lock's owner record; UNKNOWN_OWNER when the lock is held by no readable record: its
    owner file is not a JSON object, or (when the state says whether `.lock` exists: the
    `lockdir` section) empty or missing."""
    if owner and owner.strip():
        return _object(owner) or UNKNOWN_OWNER
    return UNKNOWN_OWNER if (lockdir or "").strip() == "yes" else None


def _object(text: str | None) -> Mapping[str, Any] | None:
    """A JSON object; None for anything else (valid JSON that is a list, a string or a number too)."""
    value = _json(text)
    return value if isinstance(value, dict) else None


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
    for entry in state.gate_history:
        release = _text(entry, "release")
        if entry.get("result") == "active" and release:
            bad.discard(release)
            active.append(release)
        rolled_from = _text(entry, "rolled_back_from")
        if rolled_from:
            bad.add(rolled_from)
    for release in reversed(active):
        if release != state.current and release not in bad and release in state.releases:
            return release
    return None


def _text(entry: Mapping[str, Any], key: str) -> str | None:
    """A history entry's field when it is text (an entry from a corrupt or hostile robot may hold anything)."""
    value = entry.get(key)
    return value if isinstance(value, str) else None


def deployed(state: RobotState, release: RenderedRelease) -> bool:
    """`current` is this release: its id, and its manifest's whole digest (the id holds 12 digits
    of it). status, plan and apply's no-op check must agree on it, or a drift never clears; a
    manifest edited or broken on the robot is drift, and apply's upload replaces it whole."""
    return state.current == release.release_id and (state.manifest or {}).get("digest") == release.digest


def passed_gate(state: RobotState, release: str) -> bool:
    """Was this release ever activated on the robot, i.e. did it pass the whole health gate?"""
    return any(e.get("release") == release and e.get("result") == "active" for e in state.gate_history)


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
    activated = [e.get("release") for e in state.gate_history if e.get("result") == "active"]
    return max(matches, key=lambda r: max((i for i, a in enumerate(activated) if a == r), default=-1))
