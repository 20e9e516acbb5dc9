"""The health gate: is the release that was just started really working?

Containers first (cheap, one `docker inspect` per poll): every expected service
running, healthy where the image or compose declares a check (Docker's verdict, or
the check itself run by rosdeploy while Docker still says `starting`), no restarts.
Then, once, the ROS graph: rosdeploy's probe runs inside a container of the release and
checks each expected topic and its rate. The probe costs ~0.4 CPU-s, so it runs once per
gate (plus one retry), never in a polling loop.
"""
from __future__ import annotations

import json
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Mapping, TypeVar

from rosdeploy import commands
from rosdeploy.model import FleetSpec, HealthPolicy
from rosdeploy.robot import Container, unhealthy_services
from rosdeploy.transport import Transport

FAST_POLL = 0.5       # s between polls while services usually come up
WATCHED_POLL = 1.0    # s between polls while every service waited for is being watched
OWN_TEST_EVERY = 1.0  # s between one-shot runs of a container's own health test
WATCH_EVERY = 0.25    # s between tries of a watched test (inside the container)
WATCH_WINDOW = 10.0   # s one watch loops before it ends and the next poll starts another
FAST_WINDOW = 15.0   # s after a start during which the gate polls fast
# s a new release's services may stay `starting` before the ROS probe looks for their topics
# (a good demo node passes its own check in ~2.5 s here, so a healthy start costs no probe)
EARLY_LOOK_AFTER = 3.0
# s the early look listens at least, however late it begins: the probe's own DDS participant
# needs a moment to discover publishers that are there
LOOK_AT_LEAST = 2.0
T = TypeVar("T")
PROBE_SOURCE = (Path(__file__).parent / "ros_probe.py").read_text(encoding="utf-8")


@dataclass(frozen=True)
class Verdict:
    ok: bool
    reason: str = ""
    service: str | None = None
    probe: Mapping | None = None
    containers: tuple[Container, ...] = field(default_factory=tuple)


def expected_services(spec: FleetSpec) -> tuple[str, ...]:
    """Services `up` starts: those outside compose profiles (profiles are opt-in tools)."""
    return tuple(s.name for s in spec.services if not s.profiles)


def read_containers(t: Transport, project: str, names: tuple[str, ...] = ()) -> tuple[Container, ...]:
    return _containers(commands.parse_containers(t.run(commands.containers(project, names)).stdout))


def started_containers(up_output: str) -> tuple[Container, ...] | None:
    """What `up` read of the project's containers right after starting them."""
    listed = commands.started_containers(up_output)
    return None if listed is None else _containers(listed)


def _containers(listed: tuple[dict, ...]) -> tuple[Container, ...]:
    return tuple(Container.from_json(c) for c in listed)


def start_levels(spec: FleetSpec) -> tuple[tuple[str, ...], ...]:
    """Expected services in start order: each level depends only on earlier levels.
    The fleet file is checked for cycles, so every service lands in a level."""
    expected = expected_services(spec)
    deps = {s.name: {d for d in s.depends_on if d in expected} for s in spec.services if s.name in expected}
    levels: list[tuple[str, ...]] = []
    placed: set[str] = set()
    while len(placed) < len(expected):
        level = tuple(n for n in expected if n not in placed and deps[n] <= placed)
        if not level:   # unreachable for a checked fleet file; start the rest together
            level = tuple(n for n in expected if n not in placed)
        levels.append(level)
        placed.update(level)
    return tuple(levels)


def broken(containers: tuple[Container, ...], expected: tuple[str, ...],
           baseline: Mapping[str, int]) -> tuple[str, str] | None:
    """A failure no amount of waiting fixes: crashed, restarting, restarted, unhealthy."""
    for c in containers:
        if c.service not in expected:
            continue
        if c.status in ("exited", "dead", "restarting"):
            return c.service, f"container {c.name} is {c.status}"
        since = baseline.get(c.id or c.name, c.restarts)
        if c.restarts > since:
            return c.service, f"container {c.name} restarted {c.restarts - since} time(s)"
        if c.health == "unhealthy":
            return c.service, f"container {c.name} health check reports unhealthy"
    return None


class Poller:
    """Container polls for one start of a release: restart baselines, and the services'
    own health tests run by rosdeploy while Docker still says `starting`.

    Docker < 25 runs a HEALTHCHECK first one full `interval` after the start (5 s and
    more is common), and compose's `depends_on: service_healthy` waits for that tick.
    A test that passes when we run it is what Docker would conclude at its next tick,
    so the gate takes it instead of waiting; failures are left to Docker's own retries.

    Polls are what the gate costs the robot (each docker CLI start is ~40 ms of CPU, a
    `docker exec` ~70 ms, on the simulated robots): known containers are inspected by
    name (one CLI start). `watch`: each starting container's test runs in a loop inside
    it (one exec per WATCH_WINDOW, see commands.health_watch), in the background; else
    (a one-shot look, or an image without /bin/sh) one exec per OWN_TEST_EVERY.
    """

    def __init__(self, t: Transport, spec: FleetSpec, watch: bool = False) -> None:
        self.t, self.spec, self.watch = t, spec, watch
        self.baseline: dict[str, int] = {}
        self.names: tuple[str, ...] = ()
        self.passed: set[str] = set()          # container ids whose own test passed
        self.tested: dict[str, float] = {}     # container id -> when its own test last ran
        self.watches: dict[str, Future[int]] = {}
        self.unwatchable: set[str] = set()     # container ids tested one exec at a time
        self.woken = threading.Event()         # a watch ended: poll now, not at the next tick
        self.fresh: tuple[Container, ...] | None = None   # read by `up` just now: the next poll
        self.look: Future[Verdict] | None = None   # the early presence probe (look_for_topics)
        self.started_at: float | None = None       # when the last `up` returned (its containers started)

    def seed(self, containers: tuple[Container, ...] | None) -> None:
        """Containers `up` listed after starting them: the next poll takes them instead of
        reading again, so the health watches begin as soon as `up` returns."""
        self.fresh = containers
        self.started_at = time.monotonic()

    def watching(self, containers: tuple[Container, ...], waiting: Mapping[str, str]) -> bool:
        """Is every service still waited for a container whose watch is running?"""
        by_service = {c.service: c for c in containers}
        running = {k for k, f in self.watches.items() if not f.done()}
        return bool(waiting) and all(s in by_service and (by_service[s].id or by_service[s].name) in running
                                     for s in waiting)

    def nap(self, seconds: float) -> None:
        """Sleep until the next poll, or until a watch ends (its verdict is news)."""
        self.woken.wait(seconds)
        self.woken.clear()

    def poll(self, expected: tuple[str, ...]) -> tuple[tuple[Container, ...], tuple[str, str] | None]:
        containers, self.fresh = self.fresh, None
        if containers is None:
            containers = read_containers(self.t, self.spec.project, self.names)
        if not {c.service for c in containers} >= set(expected) and self.names:
            containers = read_containers(self.t, self.spec.project)   # a service is new or gone
        self.names = tuple(c.name for c in containers)
        for c in containers:   # by id: a recreated container keeps its name, not its count
            self.baseline.setdefault(c.id or c.name, c.restarts)
        failure = broken(containers, expected, self.baseline)
        if failure is None:
            containers = tuple(self._checked(c, expected) for c in containers)
        return containers, failure

    def _checked(self, c: Container, expected: tuple[str, ...]) -> Container:
        if c.health != "starting" or c.status != "running" or c.service not in expected:
            return c
        key = c.id or c.name
        if key not in self.passed and not self._passes(c, key):
            return c
        self.passed.add(key)
        return replace(c, health="healthy")

    def _passes(self, c: Container, key: str) -> bool:
        if self.watch and key not in self.unwatchable:
            return self._watched(c, key)
        now = time.monotonic()
        command = commands.health_test(c.name, c.test, min(c.test_timeout, 10.0))
        if command is None or (key in self.tested and now - self.tested[key] < OWN_TEST_EVERY):
            return False
        self.tested[key] = now
        return self.t.run(command).ok

    def _watched(self, c: Container, key: str) -> bool:
        running = self.watches.get(key)
        if running is not None and not running.done():
            return False
        code = _exit_code(running) if running is not None else 3
        if code == 0:
            return True
        if code != 3:                        # cannot loop in this image: one exec per poll
            self.unwatchable.add(key)
            return self._passes(c, key)
        command = commands.health_watch(c.name, c.test, min(c.test_timeout, 10.0), WATCH_WINDOW, WATCH_EVERY)
        if command is not None:
            self.watches[key] = _in_background(lambda: self.t.run(command).exited, self.woken)
        return False


    def look_for_topics(self, containers: tuple[Container, ...], waiting: Mapping[str, str],
                        since: float, deadline: float) -> Verdict | None:
        """A new release still `starting` EARLY_LOOK_AFTER s after its start: one presence-only
        probe (no rates) for the topics of the services already running. A topic still missing
        `health.topics_within` after its container started (the last `up`, which started it or
        a later level), while its container ran, fails the gate there: Docker's own verdict
        would come only after the image's start period and retries (~20 s for the demo's silent
        1.2.0-bad). One look per start; a failure it cannot pin is left to Docker."""
        if self.look is None:
            now = time.monotonic()
            if waiting and now - since >= EARLY_LOOK_AFTER:
                running = {c.service for c in containers if c.status == "running"}
                # the look begins late on purpose (a healthy start needs none): what it listens
                # is what is left of topics_within, counted from the start, not a fresh wait
                left = self.spec.health.topics_within - (now - (self.started_at or since))
                self.look = _start_look(self.t, self.spec, containers, running, deadline, self.woken,
                                        max(left, LOOK_AT_LEAST))
            return None
        if not self.look.done() or self.look.exception() is not None:
            return None
        verdict = self.look.result()
        return None if verdict.ok or not missing_topics(verdict) else verdict


def _start_look(t: Transport, spec: FleetSpec, containers: tuple[Container, ...], running: set[str],
                deadline: float, done: threading.Event, within: float) -> Future[Verdict]:
    topics = [{"name": topic.name, "min_rate": None} for s in spec.services
              if s.name in running and not s.profiles for topic in s.topics]
    if not topics or probe_service(spec) not in running:
        return _finished(Verdict(True, "nothing to look for yet"))
    policy = replace(spec.health, topic_window=0.0, topics_within=within)
    return _in_background(lambda: _probe_graph(t, spec, containers, policy, deadline, topics), done)


def _finished(verdict: Verdict) -> Future[Verdict]:
    future: Future[Verdict] = Future()
    future.set_result(verdict)
    return future


def missing_topics(verdict: Verdict) -> list[str]:
    """Topics the probe waited for, the whole discovery wait, and never saw."""
    report = (verdict.probe or {}).get("topics", {})
    return sorted(name for name, t in report.items() if not t.get("present"))


def _in_background(work: Callable[[], T], done: threading.Event) -> Future[T]:
    """A daemon thread: a watch still looping when the run ends must not hold up the exit
    (it stops by itself within WATCH_WINDOW). Sets `done` when it ends."""
    future: Future[T] = Future()

    def target() -> None:
        try:
            future.set_result(work())
        except Exception as exc:     # connection lost: the poll reports it, this falls back
            future.set_exception(exc)
        done.set()
    threading.Thread(target=target, name="health-watch", daemon=True).start()
    return future


def _exit_code(future: Future[int]) -> int:
    return -1 if future.exception() is not None else future.result()


def settled(t: Transport, spec: FleetSpec, containers: tuple[Container, ...]) -> tuple[Container, ...]:
    """Containers as the gate judges them: a `starting` one whose own check passes is healthy.
    No extra round trip unless an expected container is `starting` (just after a deploy,
    before Docker's first tick), so a no-op or `status` then agrees with the gate."""
    expected = expected_services(spec)
    if not any(c.health == "starting" and c.service in expected for c in containers):
        return containers
    return Poller(t, spec).poll(expected)[0]


def wait_healthy(t: Transport, spec: FleetSpec, policy: HealthPolicy | None = None,
                 since: float | None = None, deadline: float | None = None,
                 checks_only: bool = False, poller: Poller | None = None,
                 services: tuple[str, ...] | None = None, fail_fast: bool = False) -> Verdict:
    """Poll until healthy, broken, or health.timeout. Not interruptible on purpose: once a
    release was started, the gate decides whether it stays or is rolled back.

    `since`: when the release began to start (the stable window and health.timeout count
    from there). The ROS probe starts as soon as the probe container runs, in parallel
    with waiting for health, so its discovery wait overlaps the rest. It runs at most
    twice per gate (a second time only if the first ran before the services were healthy).

    `checks_only`: wait only for running containers that pass their own health checks,
    with no stable window and no ROS probe (those guard a new release as a whole). For a
    start level before the next one (what `service_healthy` means), and for the brake:
    going back to a release that passed the whole gate before on this robot.
    `services`: only these (default: every expected service).
    `fail_fast` (a new release): a declared topic that never appears on the ROS graph while
    its container runs fails the gate when the probe's discovery wait ends, not when Docker
    gives up on the container (see Poller.look_for_topics; the probe of the gate itself
    counts the same way for the services that ran when it began).
    """
    policy = policy or spec.health
    if checks_only:
        policy = replace(policy, stable=0.0)
    expected = services if services is not None else expected_services(spec)
    start = time.monotonic() if since is None else since
    deadline = start + policy.timeout if deadline is None else deadline
    poller = poller or Poller(t, spec, watch=True)
    probe: Future[Verdict] | None = None
    early = True   # the running probe started before every service was healthy
    ran: set[str] = set()   # services running when the probe began
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="ros-probe") as pool:
        while True:
            containers, failure = poller.poll(expected)
            if failure:
                return Verdict(False, failure[1], failure[0], containers=containers)
            waiting = unhealthy_services(containers, expected)
            if probe is None and not checks_only and _probe_can_start(spec, containers):
                early = bool(waiting)
                ran = {c.service for c in containers if c.status == "running"}
                probe = pool.submit(_probe_graph, t, spec, containers, policy, deadline)
            if fail_fast:
                missing = _missing_early(probe, ran, spec) if not checks_only else \
                    poller.look_for_topics(containers, waiting, start, deadline)
                if missing is not None:
                    return replace(missing, reason=_never_appeared(missing, waiting, policy.topics_within),
                                   containers=containers)
            if not waiting and time.monotonic() - start >= policy.stable:
                if checks_only:
                    return Verdict(True, "running and passing health checks", containers=containers)
                verdict = probe.result() if probe else _probe_graph(t, spec, containers, policy, deadline)
                if verdict.ok or not early or time.monotonic() + policy.interval >= deadline:
                    return replace(verdict, containers=containers)
                probe, early = None, False   # probed too early: once more, now that all are healthy
                continue
            if time.monotonic() >= deadline:
                service, why = next(iter(waiting.items()), ("", "not stable"))
                return Verdict(False, f"{service}: {why} after {policy.timeout:g}s (health.timeout)",
                               service or None, containers=containers)
            poller.nap(poll_interval(policy, start, watched=poller.watching(containers, waiting)))


def _missing_early(probe: Future[Verdict] | None, ran: set[str], spec: FleetSpec) -> Verdict | None:
    """The gate's own probe, done before every service was healthy: a failure if a topic of a
    service that ran all along never appeared (a later service's topic may still come)."""
    if probe is None or not probe.done() or probe.exception() is not None:
        return None
    verdict = probe.result()
    owners = {topic.name: s.name for s in spec.services for topic in s.topics}
    if verdict.ok or not any(owners.get(name) in ran for name in missing_topics(verdict)):
        return None
    return verdict


def _never_appeared(verdict: Verdict, waiting: Mapping[str, str], within: float) -> str:
    names = ", ".join(missing_topics(verdict))
    still = f" (Docker: {'; '.join(f'{s} {why}' for s, why in waiting.items())})" if waiting else ""
    return (f"topic {names}: no publisher on the ROS graph {within:g}s after its container started (health."
            f"topics_within){still}")


def poll_interval(policy: HealthPolicy, since: float, watched: bool = False) -> float:
    """Poll fast while services usually come up (a poll is one `docker inspect`), then
    every `health.interval`, so a slow start does not keep the robot busy. `watched`:
    everything still waited for is a starting container whose watch wakes the gate when
    it passes or the container stops, so the poll only needs to catch Docker's verdicts."""
    if time.monotonic() - since >= FAST_WINDOW:
        return policy.interval
    return min(policy.interval, WATCHED_POLL if watched else FAST_POLL)


def _probe_can_start(spec: FleetSpec, containers: tuple[Container, ...]) -> bool:
    service = probe_service(spec)
    return any(c.service == service and c.status == "running" for c in containers)


def diagnose(t: Transport, spec: FleetSpec, reason: str) -> Verdict:
    """`compose up` itself failed (e.g. a dependency never became healthy): find which
    service is to blame, so the report and the logs name it."""
    containers = read_containers(t, spec.project)
    expected = expected_services(spec)
    failure = broken(containers, expected, {c.name: c.restarts for c in containers})
    if failure is None:
        failure = next(iter(unhealthy_services(containers, expected).items()), None)
    service, why = failure if failure else (None, "")
    detail = f"{reason}; {service}: {why}" if service else reason
    return Verdict(False, detail, service, containers=containers)


def topics_spec(spec: FleetSpec) -> list[dict]:
    return [{"name": t.name, "min_rate": t.min_rate} for s in spec.services if not s.profiles for t in s.topics]


def probe_service(spec: FleetSpec) -> str | None:
    if spec.health.probe_service:
        return spec.health.probe_service
    return next((s.name for s in spec.services if s.topics and not s.profiles), None)


def _probe_graph(t: Transport, spec: FleetSpec, containers: tuple[Container, ...],
                 policy: HealthPolicy, deadline: float, topics: list[dict] | None = None) -> Verdict:
    topics = topics_spec(spec) if topics is None else topics
    service = probe_service(spec)
    if not topics or service is None:
        return Verdict(True, "containers healthy (no ROS topics declared)", containers=containers)
    container = next((c for c in containers if c.service == service), None)
    if container is None:
        return Verdict(False, f"no running container of {service} to probe the ROS graph from", service)
    left = max(deadline - time.monotonic(), 2.0)
    arg = {"topics": topics, "discovery_timeout": min(policy.topics_within, left), "window": policy.topic_window,
           "published": True}
    result = t.run(commands.ros_probe(container.name, PROBE_SOURCE, arg, timeout=left + policy.topic_window + 15))
    report = _last_json(result.stdout)
    if result.ok and report:
        return Verdict(True, "healthy; ROS graph ok", probe=report, containers=containers)
    return Verdict(False, _probe_failure(report, result.stderr), service, probe=report, containers=containers)


def _last_json(text: str) -> dict | None:
    for line in reversed(text.strip().splitlines()):
        try:
            return json.loads(line)
        except ValueError:
            continue
    return None


def _probe_failure(report: dict | None, stderr: str) -> str:
    if not report:
        tail = " ".join(stderr.strip().splitlines()[-3:])
        return f"ROS graph probe could not run: {tail or 'no output'}"
    bad = []
    for name, t in sorted(report.get("topics", {}).items()):
        if not t.get("present"):
            bad.append(f"topic {name} not on the ROS graph (domain {report.get('domain')}): no publisher")
        elif not t.get("ok"):
            bad.append(f"topic {name} at {t.get('rate', 0):g} Hz, below min_rate {t.get('min_rate'):g} Hz")
    return "; ".join(bad) or "ROS graph probe failed"
