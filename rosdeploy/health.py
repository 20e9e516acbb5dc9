"""The health gate: is the release that was just started really working?

Containers first (cheap, one `docker inspect` per poll): every expected service
running, Docker health `healthy` where the image or compose declares a check,
no restarts. Then, once, the ROS graph: rosdeploy's probe runs inside a
container of the release and checks each expected topic and its rate. The
probe costs ~0.4 CPU-s, so it runs once per gate (plus one retry), never in a
polling loop.
"""
from __future__ import annotations

import json
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Mapping

from rosdeploy import commands
from rosdeploy.model import FleetSpec, HealthPolicy
from rosdeploy.robot import Container, unhealthy_services
from rosdeploy.transport import Transport

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


def read_containers(t: Transport, project: str) -> tuple[Container, ...]:
    result = t.run(commands.containers(project))
    return tuple(Container.from_json(c) for c in commands.parse_containers(result.stdout))


def broken(containers: tuple[Container, ...], expected: tuple[str, ...],
           baseline: Mapping[str, int]) -> tuple[str, str] | None:
    """A failure no amount of waiting fixes: crashed, restarting, restarted, unhealthy."""
    for c in containers:
        if c.service not in expected:
            continue
        if c.status in ("exited", "dead", "restarting"):
            return c.service, f"container {c.name} is {c.status}"
        if c.restarts > baseline.get(c.name, c.restarts):
            return c.service, f"container {c.name} restarted {c.restarts - baseline[c.name]} time(s)"
        if c.health == "unhealthy":
            return c.service, f"container {c.name} health check reports unhealthy"
    return None


def wait_healthy(t: Transport, spec: FleetSpec, policy: HealthPolicy | None = None) -> Verdict:
    """Poll until healthy, broken, or health.timeout. Not interruptible on purpose: once a
    release was started, the gate decides whether it stays or is rolled back.

    The ROS probe starts as soon as the probe container runs, in parallel with waiting
    for Docker health, so its discovery wait overlaps the health-check interval. It
    runs at most twice per gate (a second time only if the first ran before the
    services were healthy).
    """
    policy = policy or spec.health
    expected = expected_services(spec)
    start = time.monotonic()
    deadline = start + policy.timeout
    baseline: dict[str, int] = {}
    probe: Future[Verdict] | None = None
    early = True   # the running probe started before every service was healthy
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="ros-probe") as pool:
        while True:
            containers = read_containers(t, spec.project)
            for c in containers:
                baseline.setdefault(c.name, c.restarts)
            failure = broken(containers, expected, baseline)
            if failure:
                return Verdict(False, failure[1], failure[0], containers=containers)
            waiting = unhealthy_services(containers, expected)
            if probe is None and _probe_can_start(spec, containers):
                early = bool(waiting)
                probe = pool.submit(_probe_graph, t, spec, containers, policy, deadline)
            if not waiting and time.monotonic() - start >= policy.stable:
                verdict = probe.result() if probe else _probe_graph(t, spec, containers, policy, deadline)
                if verdict.ok or not early or time.monotonic() + policy.interval >= deadline:
                    return replace(verdict, containers=containers)
                probe, early = None, False   # probed too early: once more, now that all are healthy
                continue
            if time.monotonic() >= deadline:
                service, why = next(iter(waiting.items()), ("", "not stable"))
                return Verdict(False, f"{service}: {why} after {policy.timeout:g}s (health.timeout)",
                               service or None, containers=containers)
            time.sleep(policy.interval)


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
                 policy: HealthPolicy, deadline: float) -> Verdict:
    topics = topics_spec(spec)
    service = probe_service(spec)
    if not topics or service is None:
        return Verdict(True, "containers healthy (no ROS topics declared)", containers=containers)
    container = next((c for c in containers if c.service == service), None)
    if container is None:
        return Verdict(False, f"no running container of {service} to probe the ROS graph from", service)
    left = max(deadline - time.monotonic(), 2.0)
    arg = {"topics": topics, "discovery_timeout": min(10.0, left), "window": policy.topic_window}
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
            bad.append(f"topic {name} not on the ROS graph (domain {report.get('domain')})")
        elif not t.get("ok"):
            bad.append(f"topic {name} at {t.get('rate', 0):g} Hz, below min_rate {t.get('min_rate'):g} Hz")
    return "; ".join(bad) or "ROS graph probe failed"
