"""Read-only looks at robots: status, plan, history. Nothing here changes a robot."""
from __future__ import annotations

import difflib
from dataclasses import dataclass, field, replace
from typing import Any, Mapping

from rosdeploy import commands, hostchanges, restarts
from rosdeploy.deploy import RobotRun, RunContext, preflight
from rosdeploy.errors import RemoteError
from rosdeploy.health import expected_services, settled
from rosdeploy.model import Host, RenderedRelease
from rosdeploy.commands import parse_sections
from rosdeploy.robot import RobotState, unhealthy_services


@dataclass(frozen=True)
class RobotStatus:
    host: str
    reachable: bool
    error: str = ""
    release: str | None = None
    version: str | None = None
    digest: str | None = None
    drift: bool | None = None             # deployed != what the fleet file renders now
    healthy: bool = False
    problems: Mapping[str, str] = field(default_factory=dict)   # service -> why not healthy
    services: tuple[Mapping[str, Any], ...] = ()
    deployed_by: str | None = None
    deployed_at: str | None = None
    lock: Mapping[str, Any] | None = None


def quick_state(ctx: RunContext, host: Host, judge_health: bool = False) -> RobotState | RemoteError:
    """Connect, read the quick state, close: the one round trip status and history need.
    `judge_health`: `starting` containers are judged as the health gate does (see settled)."""
    run = RobotRun(ctx, host)
    try:
        run.open()
        state = run.read_state(full=False)
        if judge_health:
            state = replace(state, containers=settled(run.t, ctx.spec, state.containers))
        return state
    except RemoteError as exc:
        return exc
    finally:
        run.close()


def status_host(ctx: RunContext, host: Host, release: RenderedRelease | None) -> RobotStatus:
    state = quick_state(ctx, host, judge_health=True)
    if isinstance(state, RemoteError):
        return RobotStatus(host.name, False, error=str(state))
    manifest = state.manifest or {}
    problems = unhealthy_services(state.containers, expected_services(ctx.spec)) if state.current else {}
    return RobotStatus(
        host.name, True, release=state.current, version=manifest.get("version"),
        digest=manifest.get("digest"),
        drift=None if release is None or not state.current else manifest.get("digest") != release.digest,
        healthy=bool(state.current) and not problems, problems=problems,
        services=tuple({"service": c.service, "status": c.status, "health": c.health, "restarts": c.restarts,
                        "image": c.image} for c in state.containers),
        deployed_by=manifest.get("deployed_by"), deployed_at=manifest.get("deployed_at"),
        lock=state.lock)


@dataclass(frozen=True)
class RobotPlan:
    host: str
    reachable: bool
    error: str = ""
    current: str | None = None
    new: str | None = None
    up_to_date: bool = False
    diffs: tuple[tuple[str, str], ...] = ()      # (file, unified diff); secrets masked by Output
    pulls: tuple[str, ...] = ()
    preflight: tuple[str, ...] = ()
    restarts: tuple[str, ...] = ()               # services whose containers the switch recreates
    keeps: tuple[str, ...] = ()                  # services whose containers keep running untouched
    host_changes: tuple[str, ...] = ()           # outside the release dir (rosdeploy.hostchanges)


def plan_host(ctx: RunContext, host: Host, release: RenderedRelease) -> RobotPlan:
    run = RobotRun(ctx, host)
    try:
        run.open()
        state = run.read_state()
        names = tuple(f.name for f in release.files)
        current = state.current or ""
        out = run.t.run(commands.release_files(run.root, ctx.spec.project, current, names, release.images))
    except RemoteError as exc:
        return RobotPlan(host.name, False, error=str(exc), new=release.release_id)
    finally:
        run.close()
    sections = parse_sections(out.stdout)
    old_files = [None if sections.get(f"file{i}") == "!!absent!!" else sections.get(f"file{i}", "")
                 for i in range(1, len(names) + 1)]
    diffs = tuple((f.name, _diff(f.name, old, f.content)) for f, old in zip(release.files, old_files)
                  if (old or "").strip() != f.content.strip() and not f.name.startswith(restarts.STORE + "/"))
    recreate = restarts.will_restart(restarts.release_hashes(release),
                                     {c.service: c.hash for c in state.containers if c.status == "running"})
    pulls = tuple(line.split(" ", 1)[1] for line in sections.get("images", "").splitlines()
                  if line.startswith("missing "))
    return RobotPlan(host.name, True, current=state.current, new=release.release_id,
                     up_to_date=state.current == release.release_id, diffs=diffs, pulls=pulls,
                     preflight=tuple(preflight(state, run, ctx.spec.min_free_disk_mb)), restarts=recreate,
                     keeps=tuple(sorted(set(restarts.release_hashes(release)) - set(recreate))),
                     host_changes=hostchanges.describe(release, ctx.spec.project))


def _diff(name: str, old: str | None, new: str) -> str:
    lines = difflib.unified_diff((old or "").splitlines(keepends=True), new.splitlines(keepends=True),
                                 fromfile=f"current/{name}" if old is not None else "/dev/null",
                                 tofile=f"new/{name}")
    return "".join(lines)


def history_host(ctx: RunContext, host: Host) -> tuple[bool, str, tuple[Mapping[str, Any], ...]]:
    """(reachable, error, entries newest first)."""
    state = quick_state(ctx, host)
    if isinstance(state, RemoteError):
        return False, str(state), ()
    return True, "", tuple(reversed(state.history))
