"""Read-only looks at robots: status, plan, history. Nothing here changes a robot."""
from __future__ import annotations

import difflib
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Mapping

from rosdeploy import commands, hold, hostchanges, restarts
from rosdeploy.deploy import RobotRun, RunContext, preflight
from rosdeploy.errors import RemoteError
from rosdeploy.health import expected_services, settled
from rosdeploy.model import Host, RenderedRelease
from rosdeploy.commands import parse_sections
from rosdeploy.owner import describe, holder_alive
from rosdeploy.results import version_of
from rosdeploy.robot import UNKNOWN_OWNER, RobotState, deployed, unhealthy_services


@dataclass(frozen=True)
class RobotStatus:
    host: str
    reachable: bool
    error: str = ""
    release: str | None = None
    version: str | None = None
    digest: str | None = None
    drift: bool | None = None             # deployed != what the fleet file renders now, or host_drift
    host_drift: tuple[str, ...] = ()      # installed host-change files that differ from the release's
    healthy: bool = False
    problems: Mapping[str, str] = field(default_factory=dict)   # service -> why not healthy
    services: tuple[Mapping[str, Any], ...] = ()
    deployed_by: str | None = None
    deployed_at: str | None = None
    lock: Mapping[str, Any] | None = None
    app_lock: tuple[Mapping[str, Any], ...] = ()     # held lock files of the readiness gate (ready.py)
    pending: Mapping[str, Any] | None = None         # the controller's pending entry (pending.py)
    images: Mapping[str, Any] = field(default_factory=dict)   # ref -> the digest deployed (manifest `pins`)
    lock_alive: bool | None = None        # the lock's run still runs (None: cannot tell from here)
    running_release: str | None = None    # what the running containers belong to (their labels)
    active: bool | None = None            # running_release is the activated one (`current`)
    guard: Mapping[str, Any] | None = None   # an armed or acting deploy guard
    guard_in: int | None = None           # seconds until it acts
    state: str = ""                       # one word: healthy, UNHEALTHY, INTERRUPTED, DEPLOYING...
    reason: str = ""                      # why, when the word is not enough


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
    alive = holder_alive(state.lock, ctx.controller)
    word, reason = status_word(state, problems, alive)
    if state.current and state.manifest is None:
        reason = "; ".join(filter(None, [reason, "current/manifest.json is missing or unreadable"]))
    guard = state.guard
    drift = None if release is None or not state.current else not deployed(state, release)
    host_drift = hostchanges.drift(state.host_files, release, ctx.spec.project) if release and drift is False else ()
    if host_drift:
        drift = True
        reason = "; ".join(filter(None, [reason, "host changes differ on the robot (" + ", ".join(host_drift)
                                          + "): `apply` puts them back"]))
    return RobotStatus(
        host.name, True, release=state.current, version=_text(manifest, "version"),
        digest=_text(manifest, "digest"), drift=drift, host_drift=host_drift,
        healthy=word == "healthy", problems=problems,
        lock_alive=alive, running_release=state.running_release,
        active=None if state.running_release is None else state.running_release == state.current,
        guard=None if guard is None else asdict(guard), guard_in=guard.seconds_left(state.clock) if guard else None,
        state=word, reason=reason,
        services=tuple({"service": c.service, "status": c.status, "health": c.health, "restarts": c.restarts,
                        "image": c.image} for c in state.containers),
        deployed_by=_text(manifest, "deployed_by"), deployed_at=_text(manifest, "deployed_at"),
        lock=state.lock, app_lock=hold.app_locks(ctx, host), images=_mapping(manifest, "pins"))


def _text(manifest: Mapping[str, Any], key: str) -> str | None:
    """A manifest field shown as text; None when the robot's manifest holds something else there."""
    value = manifest.get(key)
    return value if isinstance(value, str) else None


def _mapping(manifest: Mapping[str, Any], key: str) -> Mapping[str, Any]:
    value = manifest.get(key)
    return value if isinstance(value, dict) else {}


def _guard_runs(status: str | None) -> bool:
    """The guard's container as dockerd reports it; None: not asked (an older state script)."""
    return status is None or status in ("running", "restarting", "created")


def status_word(state: RobotState, problems: Mapping[str, str], lock_alive: bool | None) -> tuple[str, str]:
    """One word for a robot, and the reason when the word alone would hide something: what
    runs against what is activated, a deploy in flight or cut off, its lock, its guard."""
    running, current = state.running_release, state.current
    where = f"{version_of(running) or 'nothing'} running, {version_of(current) or 'nothing'} active"
    guard, lock = state.guard, state.lock or {}
    if guard is not None:
        who = f"run {guard.run} by {guard.by or '?'}"
        if guard.acting:
            return "RECOVERING", f"{where}; {who}: the guard is acting ({guard.reason})"
        left = guard.seconds_left(state.clock)
        when = f"in {left} s" if left is not None else "at its deadline"
        if guard.boot and state.boot and guard.boot != state.boot:
            return "INTERRUPTED", f"{where}; robot restarted mid-{guard.kind} ({who}); the guard {guard.will} now"
        cut_off = lock.get("run") != guard.run or lock_alive is False
        word = "INTERRUPTED" if cut_off else "DEPLOYING"
        gone = " (its process is gone)" if lock_alive is False else ""
        if cut_off and not _guard_runs(state.guard_container):
            return word, (f"{where}; {who}{gone}; NO GUARD RUNS on the robot (its container: "
                          f"{state.guard_container}): nothing acts at the deadline; `apply` ends this deploy")
        return word, f"{where}; {who}{gone}; guard {guard.will} {when}"
    if lock == UNKNOWN_OWNER:
        return "LOCKED", (f"{where}; locked by an unknown owner (its .lock has no readable owner record): if no "
                          "run is going on, `apply --break-lock` clears it")
    if lock:
        who = describe(lock)
        if lock_alive is False:
            return "INTERRUPTED", f"{where}; locked by {who}, whose process is gone: the next apply takes it over"
        return ("DEPLOYING" if lock_alive else "LOCKED"), f"{where}; locked by {who}"
    if state.foreign_current:
        return "FOREIGN", (f"`current` points at {state.foreign_current}, not a release rosdeploy deployed "
                           "here (outside releases/, or gone): `apply` deploys one")
    if running not in (None, current):
        if current is None:
            return "UNGATED", f"{where}: these containers never passed a gate here (not deployed)"
        return "MISMATCH", f"{where}: the running containers are not the activated release"
    if current is None:
        return "not deployed", ""
    if problems:
        return "UNHEALTHY", "; ".join(f"{s}: {why}" for s, why in problems.items())
    return "healthy", ""


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
    images: Mapping[str, str] = field(default_factory=dict)   # ref -> the digest this run would deploy
    guard: str = ""        # what the robot's guard does if this deploy loses its controller, and when
    restarts: tuple[str, ...] = ()               # services whose containers the switch recreates
    keeps: tuple[str, ...] = ()                  # services whose containers keep running untouched
    host_changes: tuple[str, ...] = ()           # outside the release dir (rosdeploy.hostchanges)
    host_drift: tuple[str, ...] = ()             # up to date, but these host-change files differ: put back


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
    diffs = tuple((f.name, _diff(f.name, old, f.content)) for f, old in zip(release.files, old_files, strict=True)
                  if (old or "").strip() != f.content.strip() and not f.name.startswith(restarts.STORE + "/"))
    recreate = restarts.will_restart(restarts.release_hashes(release),
                                     {c.service: c.hash for c in state.containers if c.status == "running"})
    pulls = tuple(line.split(" ", 1)[1] for line in sections.get("images", "").splitlines()
                  if line.startswith("missing "))
    same = deployed(state, release)
    return RobotPlan(host.name, True, current=state.current, new=release.release_id,
                     up_to_date=same, diffs=diffs, pulls=pulls,
                     host_drift=hostchanges.drift(state.host_files, release, ctx.spec.project) if same else (),
                     preflight=tuple(preflight(state, run, ctx.spec.min_free_disk_mb)), restarts=recreate,
                     keeps=tuple(sorted(set(restarts.release_hashes(release)) - set(recreate))),
                     host_changes=hostchanges.describe(release, ctx.spec.project),
                     images={p.ref: p.digest for p in ctx.images.pins_of(release)} if ctx.images else {},
                     guard=guard_plan(ctx.spec, state.current))


def guard_plan(spec, current: str | None) -> str:
    """The guard's deadline and action, as `plan` shows it."""
    policy = spec.rollback
    if policy.guard == "off":
        return "off (rollback.guard): a deploy that loses its controller stays as it was left"
    act = ("runs the gate on the robot, then activates or reverts" if policy.guard == "finish"
           else f"reverts to {current}" if current else "stops the new release")
    return (f"{policy.guard}: if not activated within {spec.health.timeout + policy.guard_margin:g}s of its start "
            f"(health.timeout {spec.health.timeout:g}s + rollback.guard_margin {policy.guard_margin:g}s), "
            f"the robot {act}")


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
