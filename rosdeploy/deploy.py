"""One robot: apply a release or roll back, leaving it either on the new release,
healthy, or exactly as it was.

    state (1 round trip) -> [up to date: done] -> preflight -> lock (+ arm the guard) -> pull
    (old keeps running) -> upload (temp dir + rename) -> up (guard: the gate's deadline)
    -> health gate -> activate (disarms) | roll back -> unlock (disarms)

The guard (guard.py) ends the deploy on the robot by itself if this process goes away
(kill, sleep, lost link) or the robot restarts before activation. Each step that re-arms
it does so in its own round trip: arming costs no extra one.

Every step is timed and kept in the HostResult; nothing here prints (progress
goes to a callback the output layer renders).
"""
from __future__ import annotations

import io
import json
import os
import tarfile
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from typing import TYPE_CHECKING, Any, Callable, Iterator, Mapping

from rosdeploy import __version__, commands, guard, hold, hostchanges, restarts
from rosdeploy.errors import CommandFailed, ConnectError, GuardTookOver, RemoteError
from rosdeploy.health import (PROBE_SOURCE, Poller, Verdict, diagnose, expected_services, probe_service,
                              settled, start_levels, started_containers, topics_spec, wait_healthy)
from rosdeploy.images import pull as image_pull
from rosdeploy.model import FleetSpec, Host, RenderedRelease
from rosdeploy.owner import Controller, dead_run, describe, holder_alive, record, this_controller
from rosdeploy.results import (DEPLOYED, FAILED, LOCKED, ROLLED_BACK, SKIPPED, STOPPED, SWITCHED,
                               UNCHANGED, UNREACHABLE, HostResult, Step)
from rosdeploy.robot import (RobotState, deployed, parse_state, passed_gate, release_services,
                            rollback_target, unhealthy_services)
from rosdeploy.transport import Result, SSHOptions, Transport, connect

if TYPE_CHECKING:
    from rosdeploy.images.supply import Supply

Progress = Callable[[str, str], None]   # (robot, what is happening)

# Test hook (documented in docs/guard.md): seconds the controller pauses after the gate
# passed and before it activates, so a test can kill it exactly there.
PAUSE_BEFORE_ACTIVATE = "ROSDEPLOY_TEST_PAUSE_BEFORE_ACTIVATE"
TOOK_OVER = 6     # exit code of a robot script whose run the guard took over


@dataclass(frozen=True)
class RunContext:
    """What every robot of one run shares. Frozen: many robot threads read it."""

    spec: FleetSpec
    ssh: SSHOptions
    run_id: str
    operator: str
    progress: Progress = lambda host, msg: None
    cancel: threading.Event = field(default_factory=threading.Event)
    lock_wait: float = 0.0
    break_lock: bool = False
    force: bool = False             # --force: switch regardless of readiness gate and window (hold.py)
    controller: Controller = field(default_factory=this_controller)   # this machine, for lock owners
    connect: Callable[[Host, SSHOptions], Transport] = connect
    images: "Supply | None" = None      # pinned digests and routes (rosdeploy.images); None: pull by tag
    host_changes: bool = True                  # udev rules (rosdeploy.hostchanges); --no-host-changes
    become_password: str | None = field(default=None, repr=False)   # --ask-become-pass
    started_at: str = field(default_factory=lambda: now())   # UTC, seconds: an operator's rollback after it brakes
    braked: threading.Event = field(default_factory=threading.Event)   # set by a robot that found one


def now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


class RobotRun:
    """The work on one robot during one run: its transport, its timed steps."""

    def __init__(self, ctx: RunContext, host: Host) -> None:
        self.ctx = ctx
        self.spec = ctx.spec
        self.host = host
        self._t: Transport | None = None
        self.steps: list[Step] = []
        self.started = time.monotonic()
        self.locked = False
        self.doing = ""                       # the step under way, for "connection lost during <step>"
        self.lost = False                     # the connection dropped: send nothing more
        self.armed: guard.Guard | None = None  # this run's guard, as armed
        self.guard_at: float | None = None    # when it acts (monotonic), as last (re)armed
        self.rolling_back: dict | None = None  # a rollback's guard lines, once its target is known

    # ------------------------------------------------------------ plumbing
    @contextmanager
    def step(self, name: str) -> Iterator[None]:
        self.ctx.progress(self.host.name, name)
        began = time.monotonic()
        self.doing = name
        try:
            yield
        except Exception as exc:
            if isinstance(exc, ConnectError):
                self.lost = True
            self.steps.append(Step(name, time.monotonic() - began, False, str(exc)))
            raise
        self.steps.append(Step(name, time.monotonic() - began))

    def result(self, outcome: str, **kw: object) -> HostResult:
        self.ctx.progress(self.host.name, outcome)     # the last word on this robot's progress
        return HostResult(host=self.host.name, outcome=outcome, steps=tuple(self.steps),
                          seconds=time.monotonic() - self.started, **kw)  # type: ignore[arg-type]

    def open(self) -> None:
        with self.step("connect"):
            self.t = self.ctx.connect(self.host, self.ctx.ssh)
            if hasattr(self.t, "reconnect"):
                self.t.reconnect = False    # lost mid-deploy: the robot is its guard's, not a new connection's

    @property
    def t(self) -> Transport:
        """The robot's connection, from open() on."""
        if self._t is None:
            raise RuntimeError(f"{self.host.name}: a command before the connection (open() first)")
        return self._t

    @t.setter
    def t(self, transport: Transport) -> None:
        self._t = transport

    def close(self) -> None:
        if self._t is not None:
            # A lost connection leaves the robot to its guard: reconnecting to unlock (which
            # disarms) would take away the only thing that ends the deploy there.
            if self.locked and not (self.lost and self.armed):
                self.unlock()
            self.t.close()

    # ------------------------------------------------------------ the guard
    @property
    def guarded(self) -> bool:
        return self.spec.rollback.guard != "off"

    def guard_arm(self, state: RobotState, release: RenderedRelease) -> tuple[str, ...]:
        """The lock's arguments that arm the guard for this deploy (nothing when it is off)."""
        if not self.guarded:
            return ()
        fields = {"run": self.ctx.run_id, "by": self.ctx.operator, "mode": self.spec.rollback.guard,
                  "project": self.spec.project, "target": release.release_id, "previous": state.current or "",
                  "flavor": state.flavor or "v2", "services": " ".join(expected_services(self.spec)),
                  "gate": int(self.spec.health.timeout), "stable": int(round(self.spec.health.stable)),
                  "keep": self.spec.rollback.keep_releases, "probe": probe_service(self.spec) or "",
                  "margin": int(self.spec.rollback.guard_margin)}
        files = (guard.GUARD_SCRIPT, commands.UP_SCRIPT, commands.FINISH_SCRIPT, commands.ROS_PROBE_SCRIPT,
                 PROBE_SOURCE, guard.probe_spec(topics_spec(self.spec), self.spec.health.topic_window,
                                                 self.spec.health.topics_within))
        self.armed = guard.Guard(run=self.ctx.run_id, by=self.ctx.operator, mode=self.spec.rollback.guard,
                                 phase="prepare", target=release.release_id, previous=state.current,
                                 deadline=None)
        return commands.arm_args(guard.state_text(fields), self._deadline("prepare"), files, release.images)

    def _deadline(self, phase: str) -> float:
        """Seconds from now until the guard acts: a step's own time limit plus the margin."""
        limit = self.spec.command_timeout if phase == "prepare" else self.spec.health.timeout
        seconds = limit + self.spec.rollback.guard_margin
        self.guard_at = time.monotonic() + seconds
        if self.armed is not None:
            self.armed = replace(self.armed, phase=phase)
        return seconds

    def rearm(self, phase: str) -> str:
        """The argument that gives the guard its next deadline ("" when none is armed)."""
        if self.armed and self.rolling_back is not None:
            return self.rollback_rearm(phase)
        return commands.rearm_arg(self.ctx.run_id, self._deadline(phase)) if self.armed else ""

    def rollback_arm(self) -> tuple[str, ...]:
        """The lock+state's arguments that arm a rollback's guard, before its target is known:
        until the switch re-arms it (rollback_rearm) it can only release the lock."""
        if not self.guarded:
            return ()
        fields = {"run": self.ctx.run_id, "by": self.ctx.operator, "mode": guard.ROLLBACK,
                  "project": self.spec.project, "gate": int(self.spec.health.timeout), "stable": 0,
                  "keep": self.spec.rollback.keep_releases, "probe": "",
                  "margin": int(self.spec.rollback.guard_margin)}
        # the switch needs only up.sh and finish.sh: no probe files on the brake's wire
        files = (guard.GUARD_SCRIPT, commands.UP_SCRIPT, commands.FINISH_SCRIPT, "", "", "")
        self.armed = guard.Guard(run=self.ctx.run_id, by=self.ctx.operator, mode=guard.ROLLBACK,
                                 phase="prepare", target="", previous=None, deadline=None)
        return commands.arm_args(guard.state_text(fields), self._deadline("prepare"), files, ())

    def rollback_to(self, state: RobotState, target: str, flavor: str, services: tuple[str, ...] | None) -> None:
        """The rollback's target is known: the `up` that switches re-arms its guard with it."""
        gated = passed_gate(state, target)
        self.rolling_back = {"target": target, "previous": state.current or "", "flavor": flavor,
                             "gated": "yes" if gated else "no",
                             "services": " ".join(services if services is not None else expected_services(self.spec))}
        if self.armed is not None:
            self.armed = replace(self.armed, target=target, previous=state.current, gated=gated)

    def rollback_rearm(self, phase: str) -> str:
        """The rollback's deadline from its switch on (guard.rollback_deadline), with its target."""
        seconds = guard.rollback_deadline(self.spec.command_timeout, self.spec.health.timeout,
                                          self.spec.rollback.guard_margin)
        self.guard_at = time.monotonic() + seconds
        if self.armed is not None:
            self.armed = replace(self.armed, phase=phase)
        return guard.rearm_text(self.ctx.run_id, seconds, self.rolling_back or {})

    def guard_note(self) -> str:
        """What the guard on this robot will do, and when: for a run that lost the robot."""
        if not self.armed or self.guard_at is None:
            return ""
        left = max(0, round(self.guard_at - time.monotonic()))
        when = datetime.fromtimestamp(time.time() + left, timezone.utc).strftime("%H:%M:%S UTC")
        return f"; the guard on the robot {self.armed.will} in ~{left} s (at {when})"

    @property
    def root(self) -> str:
        return str(self.host.vars.get("rosdeploy_deploy_root") or self.spec.deploy_root)

    @property
    def compose_pref(self) -> str:
        return str(self.host.vars.get("rosdeploy_compose", "auto"))

    def required_paths(self) -> tuple[str, ...]:
        """What must exist on the robot before a release may start: its devices and the
        sources of its bind mounts (Docker would create a missing one as an empty root dir)."""
        devices = set(hostchanges.mapped_devices(self.spec, self.host))
        return tuple(sorted(devices | set(mount_sources(self.spec))))

    def wants_gpu(self) -> bool:
        return self.host.gpu and any(s.gpu for s in self.spec.services)

    def read_state(self, full: bool = True, step: str | None = None) -> RobotState:
        with self.step(step or ("state" if full else "check")):
            out = self.t.run(commands.state(self.root, self.spec.project, self.required_paths(),
                                            self.compose_pref, self.wants_gpu(), full=full))
        return parse_state(out.stdout)

    def lock(self, arm: tuple[str, ...] = (), expect: str | None = None) -> str | None:
        """Take the robot's lock (and arm the guard under it); None when taken, else who holds it.
        `expect`: the `current` link the caller decided on; MOVED when another run switched the
        robot since (the lock is not held then)."""
        holder = self._lock(lambda owner, dead: commands.lock(self.root, self.spec.project, owner,
                                                               self.ctx.break_lock, dead, arm, expect), "lock")[0]
        if holder is not None:
            self.armed = None
        return holder

    def lock_and_read(self, arm: tuple[str, ...] = ()) -> tuple[str | None, RobotState]:
        """The lock and, read under it, the state a rollback needs, in one round trip
        (`arm`: and the rollback's guard, see rollback_arm)."""
        holder, out = self._lock(lambda owner, dead: commands.locked_state(self.root, self.spec.project, owner,
                                                                           self.ctx.break_lock, dead, arm),
                                 "lock+state")
        if holder is not None:
            self.armed = None
        return holder, parse_state(out.stdout)

    def _lock(self, command: Callable[[dict, str], commands.Command], step: str) -> tuple[str | None, Result]:
        """Run a lock command until it takes the lock (holder None) or lock_wait ends. A lock
        left by a run of this machine that is certainly dead is taken over, and the steps say so."""
        owner = record(self.ctx.run_id, self.ctx.operator, now(), self.ctx.controller, os.getpid())
        deadline = time.monotonic() + self.ctx.lock_wait
        dead: tuple[str, str] | None = None     # (run, why): a holder this machine knows is gone
        tried: set[str] = set()                 # dead runs named once already
        with self.step(step):
            while True:
                out = self.t.run(command(owner, dead[0] if dead else ""))
                if out.ok:
                    self.locked = True
                    break
                if out.exited == 4 and out.stdout.strip() == "moved":
                    return MOVED, out
                if out.exited != 3:
                    raise CommandFailed(self.host.name, out, step)
                answer = out.stdout.split("\n@@", 1)[0]   # a locked_state's sections follow
                holder = answer.replace("held ", "", 1).strip() or out.stderr.strip()
                dead = dead_run(holder, self.ctx.controller)
                if dead and dead[0] not in tried:
                    tried.add(dead[0])          # at once again, removing that run's lock
                    continue
                dead = None
                if time.monotonic() >= deadline or self.ctx.cancel.is_set():
                    return holder, out
                time.sleep(1.0)
        if dead:
            detail = f"run {dead[0]}: {dead[1]}"
            self.ctx.progress(self.host.name, f"took over the lock of a dead run ({detail})")
            self.steps.append(Step("took over a dead run's lock", 0.0, detail=detail))
        return None, out

    def unlock(self) -> None:
        try:
            self.t.run(commands.unlock(self.root, self.spec.project, self.ctx.run_id))
            self.locked = False
        except RemoteError:
            pass   # connection gone: the lock names this run, `--break-lock` clears it

    def kept_services(self, release: str) -> tuple[str, ...] | None:
        """What a kept release runs, from its own manifest: going back to a release that lacks
        a service the fleet file has now must not wait for that service."""
        out = self.t.run(commands.manifest(self.root, self.spec.project, release))
        return release_services(out.stdout) if out.ok else None

    def start(self, release: str, flavor: str, together: bool = False,
              services: tuple[str, ...] | None = None) -> Verdict:
        """Start the release, then the health gate; a failed `up` is diagnosed the same way.

        A new release starts level by level in `depends_on` order, each level as soon as
        the one before passes its health checks. `together`: going back to a release that
        already passed the gate on this robot. Every service starts at once (Docker's
        restart policies start it that way after every reboot, ignoring depends_on), and
        the gate is the brake's: running and passing health checks (see wait_healthy).
        `services`: what a kept release runs when it is not what the fleet file has now; such a
        release starts the compose way (its own depends_on), not by the fleet file's levels.
        """
        foreign = services is not None and set(services) != set(expected_services(self.spec))
        # a new release: the guard takes the gate's deadline; a rollback's switch: its own
        rearm = self.rearm("start") if not together or self.rolling_back is not None else ""
        levels = ((),) if together or foreign else start_levels(self.spec)
        began = time.monotonic()
        deadline = began + self.spec.health.timeout
        poller = Poller(self.t, self.spec, watch=True)
        with self.step(f"start {release}"):
            for i, level in enumerate(levels):
                if i:
                    ready = wait_healthy(self.t, self.spec, since=began, deadline=deadline, checks_only=True,
                                         poller=poller, services=sum(levels[:i], ()), fail_fast=True)
                    if not ready.ok:
                        return ready
                names = level if len(levels) > 1 else ()   # one level: compose's own `up`
                out = self.t.run(commands.up(self.root, self.spec.project, release, flavor, names,
                                             together=together, timeout=self.spec.command_timeout,
                                             rearm=rearm if i == 0 else ""))
                if not out.ok:
                    lines = (out.stdout + out.stderr).strip().splitlines()
                    return diagnose(self.t, self.spec, "compose up failed: " + (lines[-1] if lines else "no output"))
                poller.seed(started_containers(out.stdout))
        with self.step("health"):
            return wait_healthy(self.t, self.spec, since=began, deadline=deadline, checks_only=together,
                                poller=poller, services=services, fail_fast=not together)

    def history(self, entry: dict, rearm: bool = False) -> None:
        """`rearm`: this run goes on with its own rollback; the guard waits for that too."""
        self.t.run(commands.record(self.root, self.spec.project, self.entry(entry),
                                   self.rearm("start") if rearm else ""))

    def entry(self, fields: dict) -> dict:
        return {"time": now(), "by": self.ctx.operator, "run": self.ctx.run_id, **fields}

    def activate(self, release: str, fields: dict) -> None:
        """Switch `current`; the same round trip disarms this run's guard."""
        pause = float(os.environ.get(PAUSE_BEFORE_ACTIVATE) or 0)
        if pause > 0:
            self.ctx.progress(self.host.name, f"pausing {pause:g}s before activate ({PAUSE_BEFORE_ACTIVATE})")
            time.sleep(pause)
        with self.step("activate"):
            out = self.t.run(commands.finish(self.root, self.spec.project, release, self.entry(fields),
                                             self.spec.rollback.keep_releases,
                                             self.ctx.run_id if self.armed else ""))
            if out.exited == TOOK_OVER:
                self.locked = False        # the guard releases it
                raise GuardTookOver(self.host.name, f"not activated: {out.stderr.strip()}")
            if not out.ok:
                raise CommandFailed(self.host.name, out, "activate")
            self.armed = None

    def logs_of(self, verdict: Verdict) -> dict[str, str]:
        """Last log lines of the failing service (or of every service not running right)."""
        names = {c.service: c.name for c in verdict.containers}
        wanted = [verdict.service] if verdict.service in names else list(names)
        out = {}
        for service in wanted:
            res = self.t.run(commands.logs(names[service], 30))
            out[service] = (res.stdout + res.stderr).strip()[-4000:]
        return out


# ------------------------------------------------------------------ apply

def preflight(state: RobotState, run: RobotRun, free_needed: int) -> list[str]:
    """Why this robot cannot take the release; empty when it can. Changes nothing."""
    problems = []
    if not state.docker_ok:
        problems.append(f"Docker engine not usable as {run.host.user or 'the SSH user'}: {state.docker or 'no answer'}"
                        " (is dockerd running, and is the user in the `docker` group?)")
    if state.compose is None:
        problems.append("neither `docker compose` (v2) nor `docker-compose` (v1) is installed on the robot")
    if state.free_mb is not None and state.free_mb < free_needed:
        problems.append(f"only {state.free_mb} MB free under {run.root}; the release needs "
                        f"{free_needed} MB (preflight.min_free_disk_mb)")
    by_path = {path: name for name, path in run.host.devices.items()}
    mounts = mount_sources(run.spec)
    later = hostchanges.made_by_rules(run.host) if run.ctx.host_changes else frozenset()
    for path in state.missing_devices:
        if path in later:
            continue     # its udev rule may create it: checked after the rules are installed and triggered
        if path in by_path or path not in mounts:
            problems.append(f"device {path} (`devices.{by_path.get(path, '?')}` in the inventory) is missing "
                            "on the robot: plug it in / check its udev rule, or fix the inventory")
        else:
            problems.append(f"{path} (`services.{mounts[path]}.volumes` in the fleet file) does not exist on "
                            "the robot: create it there (maps, calibration...) or fix the mount")
    if run.wants_gpu() and "nvidia" not in (state.runtimes or {}):
        problems.append("robot has gpu: true but its Docker engine has no `nvidia` runtime: "
                        "install the NVIDIA Container Toolkit")
    return problems


def mount_sources(spec: FleetSpec) -> dict[str, str]:
    """Robot path -> the first service that bind-mounts it."""
    sources: dict[str, str] = {}
    for svc in spec.services:
        for volume in svc.volumes:
            sources.setdefault(volume.split(":")[0], svc.name)
    return sources


def up_to_date(state: RobotState, release: RenderedRelease, spec: FleetSpec) -> bool:
    if not deployed(state, release):      # the id, and the manifest as status reads it
        return False
    # A container an earlier release started and this one left alone carries this release's hash.
    wanted = restarts.release_hashes(release)
    on_release = [c for c in state.containers
                  if c.release in ("", release.release_id) or (c.hash and c.hash == wanted.get(c.service))]
    return not unhealthy_services(on_release, expected_services(spec))


def apply_host(ctx: RunContext, host: Host, release: RenderedRelease) -> HostResult:
    run = RobotRun(ctx, host)
    if ctx.cancel.is_set():
        return run.result(SKIPPED, new_release=release.release_id, reason="interrupted before this robot started")
    try:
        run.open()
        return _apply(run, release)
    except ConnectError as exc:
        run.lost = True
        if run.locked:    # it got as far as the lock: say where it was lost, and what happens now
            return run.result(UNREACHABLE, new_release=release.release_id,
                              reason=f"connection lost during {run.doing}{run.guard_note()} ({exc.detail})")
        return run.result(UNREACHABLE, new_release=release.release_id, reason=str(exc))
    except RemoteError as exc:
        return run.result(FAILED, new_release=release.release_id, reason=str(exc))
    finally:
        run.close()


def precheck_host(ctx: RunContext, host: Host, release: RenderedRelease) -> tuple[HostResult | None, Transport | None]:
    """The no-op check alone, one round trip, before a rollout in waves plans them.

    Returns the robot's final result when it has one already (UNCHANGED; UNREACHABLE, which
    its wave reports rather than waiting for connect_timeout twice), or else its open
    connection for the rollout to go on with. A command that fails leaves the verdict to the
    robot's wave, which says what failed in its own words."""
    run = RobotRun(ctx, host)
    try:
        run.open()
        done = _unchanged(run, release, run.read_state(full=False))
    except ConnectError as exc:
        run.close()
        return run.result(UNREACHABLE, new_release=release.release_id, reason=str(exc)), None
    except RemoteError:
        run.close()
        return None, None
    if done is not None:
        run.close()
        return done, None
    return None, run.t


def _unchanged(run: RobotRun, release: RenderedRelease, state: RobotState, repair: bool = False,
               ) -> HostResult | None:
    """UNCHANGED when the robot runs this release, healthy and unlocked, its host changes in place.

    Host changes edited or removed on the robot since (a udev rule, the rotation schedule) are
    put back when `repair`, under the lock and restarting nothing; the rollout's pre-check, which
    changes nothing, leaves such a robot to its wave."""
    if state.current == release.release_id:    # just deployed: judge `starting` services the way the gate did
        state = replace(state, containers=settled(run.t, run.spec, state.containers))
    if state.lock is not None or not up_to_date(state, release, run.spec):
        return None
    drifted = hostchanges.drift(state.host_files, release, run.spec.project) if run.ctx.host_changes else ()
    if not drifted:
        return run.result(UNCHANGED, running_release=state.current, reason="already on this release and healthy",
                          old_release=state.current, new_release=release.release_id)
    return _put_back(run, release, state, drifted) if repair else None


def _put_back(run: RobotRun, release: RenderedRelease, state: RobotState, drifted: tuple[str, ...]) -> HostResult:
    """The running release's host changes installed again: the containers are left as they run.
    In the robot's maintenance window and when it is ready, as a switch would be."""
    new, what = release.release_id, ", ".join(drifted)
    base = {"running_release": new, "old_release": new, "new_release": new}
    holder = run.lock()
    if holder is not None:
        return run.result(LOCKED, reason=_locked_by(holder, run.ctx.controller), **base)
    held = hold.before_switch(run, state, f"its host changes that differ on the robot ({what}) are put back "
                                          "then; nothing changed")
    if held is not None:
        run.unlock()
        return run.result(held.outcome, reason=held.reason, opens=held.opens, **base)
    ok = _host_changes(run, new, hostchanges.mapped_devices(run.spec, run.host))
    run.unlock()
    if not ok:
        return run.result(FAILED, reason=f"already on this release and healthy, but its host changes differ on "
                          f"the robot ({what}) and could not be put back: {run.steps[-1].detail}", **base)
    return run.result(UNCHANGED, reason=f"already on this release and healthy; put back its host changes, which "
                      f"differed on the robot: {what}", **base)


def brake_pulled(state: RobotState, since: str) -> Mapping[str, Any] | None:
    """The newest operator rollback (`rosdeploy rollback`, another run's fleet rollback) recorded on
    the robot after `since`: the emergency brake pulled during this rollout, which its later waves
    must not undo."""
    began = _when(since)
    for entry in reversed(state.history):
        if entry.get("event") == "rollback":
            at = _when(entry.get("time"))
            return entry if began is not None and at is not None and at > began else None
    return None


def _when(text: Any) -> datetime | None:
    try:
        return datetime.fromisoformat(text) if isinstance(text, str) else None
    except ValueError:
        return None


def _braked(entry: Mapping[str, Any]) -> str:
    who = describe({"run": entry.get("run"), "by": entry.get("by"), "since": entry.get("time")})
    return (f"an emergency rollback by {who} switched this robot to {entry.get('release')} after this rollout "
            "began: it is not deployed and the rollout stops here; run apply again to deploy")


def _locked_by(holder: str, here: Controller | None = None) -> str:
    """Who holds the lock, and what to do: --break-lock only for a lock this machine cannot prove
    is a live run's (breaking a live run's lock lets two runs switch the robot at once)."""
    try:
        owner = json.loads(holder)
    except ValueError:
        owner = None
    if here is not None and holder_alive(owner, here) is True:
        return f"locked by {describe(holder)}, a run still going on this machine: wait for it to end"
    return f"locked by {describe(holder)} (wait, or clear a stale lock with --break-lock)"


def _apply(run: RobotRun, release: RenderedRelease) -> HostResult:
    state = run.read_state(full=False)
    if run.ctx.cancel.is_set():
        return run.result(SKIPPED, running_release=state.current, reason="interrupted before this robot started",
                          old_release=state.current, new_release=release.release_id)
    for _ in range(MOVED_TRIES):
        base = {"old_release": state.current, "new_release": release.release_id}
        brake = brake_pulled(state, run.ctx.started_at)
        if brake is not None:
            run.ctx.braked.set()     # the rollout starts no more waves, and takes nothing back itself
            return run.result(SKIPPED, running_release=state.current, reason=_braked(brake), **base)
        done = _unchanged(run, release, state, repair=True)
        if done is not None:
            return done
        state = run.read_state(full=True)    # the preflight facts, only when something will change
        base["old_release"] = state.current
        problems = preflight(state, run, run.spec.min_free_disk_mb)
        if run.ctx.host_changes:
            problems += hostchanges.preflight(run.t, run.root, run.spec.project, run.host, release,
                                              run.ctx.become_password, state.missing_devices)
        if problems:
            return run.result(FAILED, running_release=state.current, reason="preflight: " + "; ".join(problems),
                              **base)
        holder = run.lock(run.guard_arm(state, release), expect=state.link)
        if holder is None:
            return _switch(run, release, state, base)
        if holder != MOVED:
            return run.result(LOCKED, running_release=state.current, reason=_locked_by(holder, run.ctx.controller),
                              **base)
        # another run switched the robot while this one waited for its lock: decide again on
        # what runs now (going back on failure to what it left, never to what it replaced)
        run.ctx.progress(run.host.name, "another run switched this robot meanwhile: reading its state again")
        state = run.read_state(full=False)
    return run.result(LOCKED, running_release=state.current, reason=f"other runs switched this robot {MOVED_TRIES} "
                      "times while this one waited for its lock; run apply again when they are done", **base)


def _switch(run: RobotRun, release: RenderedRelease, state: RobotState, base: dict) -> HostResult:
    new, old = release.release_id, state.current
    # ---- images (rosdeploy.images: pinned digests, via registry or ssh) ----
    with run.step("pull"):
        if run.ctx.images is not None:
            pulled = image_pull.pull(run, release)
        else:
            pulled = run.t.run(commands.pull(release.images, timeout=run.spec.command_timeout))
    if not pulled.ok:
        why = image_pull.failure(pulled, run) if run.ctx.images is not None else \
            "pull failed, nothing changed: " + _pull_errors(pulled.stdout, run.spec.registry)
        return run.result(FAILED, running_release=old, reason=why, **base)
    # ---- end images ----
    held = hold.before_switch(run, state)      # maintenance window, readiness gate: pulled, nothing restarts
    if held is not None:
        return run.result(held.outcome, running_release=old, reason=held.reason, opens=held.opens, **base)
    with run.step("upload"):
        services = tuple(s.name for s in run.spec.services)
        run.t.check(commands.upload(run.root, run.spec.project, new, _tarball(run, release, pulled.stdout),
                                    services, run.rearm("prepare")), "upload")
        run.t.check(restarts.link_store(run.root, run.spec.project, new), "upload")
    if run.ctx.cancel.is_set():
        return run.result(SKIPPED, running_release=old, reason="interrupted before switching", **base)
    if not _host_changes(run, new, hostchanges.mapped_devices(run.spec, run.host)):
        why = run.steps[-1].detail
        if old in state.releases:
            _host_changes(run, old)    # the running release's rules and rotation again
        return run.result(FAILED, running_release=old, reason="host changes failed, nothing restarted: "
                          + why, **base)
    flavor = state.flavor or "v2"
    verdict = run.start(new, flavor)
    if verdict.ok:
        # `compose`: what a later rollback switches with, without listing the containers
        run.activate(new, {"event": "deploy", "release": new, "version": release.version,
                           "digest": release.digest, "from": old, "result": "active", "compose": flavor})
        return run.result(DEPLOYED, running_release=new, reason=verdict.reason, **base)
    return _recover(run, release, state, verdict, base)


def _recover(run: RobotRun, release: RenderedRelease, state: RobotState, verdict: Verdict,
             base: dict) -> HostResult:
    new, old = release.release_id, state.current
    logs = run.logs_of(verdict) if verdict.containers else {}
    why = f"health gate failed: {verdict.reason}"
    run.history({"event": "deploy", "release": new, "version": release.version, "from": old,
                 "result": "failed", "reason": verdict.reason}, rearm=True)
    failed = {"failed_service": verdict.service, "logs": logs, **base}
    if not run.spec.rollback.auto:
        return run.result(FAILED, running_release=new, reason=why + " (rollback.auto is off: left running)", **failed)
    back = _back_to(run, state, new, state.flavor or "v2", verdict.reason)
    if back is None:
        return run.result(STOPPED, running_release=None,
                          reason=why + "; no previous release on the robot, so the failed one was stopped", **failed)
    if back.ok:
        return run.result(ROLLED_BACK, running_release=old, reason=why + f"; rolled back to {old}", **failed)
    return run.result(FAILED, running_release=old, reason=why + f"; rollback to {old} is unhealthy too: "
                      + back.reason, **failed)


def _back_to(run: RobotRun, state: RobotState, failed: str, flavor: str, reason: str) -> Verdict | None:
    """Start the release the run left (`current`) again, the brake's way, after `failed` failed its
    gate, and record it; None when there is none to go back to: `failed` is stopped instead."""
    left = state.current
    if left is None or left not in state.releases:
        with run.step("stop failed release"):
            run.t.run(commands.down(run.root, run.spec.project, failed, flavor))
        return None
    back = run.start(left, flavor, together=True, services=run.kept_services(left))
    _host_changes(run, left)   # after the switch: going back must not wait for a round trip more
    run.history({"event": "auto-rollback", "release": left, "rolled_back_from": failed,
                 "result": "active" if back.ok else "unhealthy", "reason": reason, "compose": flavor})
    return back


def _rollback_refused(run: RobotRun, state: RobotState, target: str, flavor: str, verdict: Verdict,
                      base: dict) -> HostResult:
    """A rollback's target that never passed its gate here failed it now: it is not
    activated; the release the rollback left starts again, as the guard does for it."""
    why = f"{target} never passed its gate on this robot and failed it now: {verdict.reason}"
    logs = run.logs_of(verdict) if verdict.containers else {}
    run.history({"event": "rollback", "release": target, "from": state.current, "result": "failed",
                 "reason": verdict.reason, "compose": flavor})
    back = _back_to(run, state, target, flavor, verdict.reason)
    if back is None:
        return run.result(FAILED, reason=why + "; no activated release to go back to, so it was stopped",
                          failed_service=verdict.service, logs=logs, **{**base, "running_release": None})
    again = f"back on {state.current}" if back.ok else f"{state.current} started again but is unhealthy: {back.reason}"
    return run.result(FAILED, reason=f"{why}; {again}", failed_service=verdict.service, logs=logs, **base)


def _host_changes(run: RobotRun, release: str, devices: tuple[str, ...] = ()) -> bool:
    """Install `release`'s host changes (udev rules, log rotation), then check that `devices`
    resolve; a step with the robot's notes either way."""
    if not run.ctx.host_changes:
        return True
    began = time.monotonic()
    ok, notes = hostchanges.install(run.t, run.root, run.spec.project, release, run.host, run.ctx.become_password,
                                    devices)
    if not ok or notes != hostchanges.NOTHING:
        run.steps.append(Step("host changes", time.monotonic() - began, ok, notes))
    return ok


def _pull_errors(stdout: str, registry: str) -> str:
    missing = [line.split(" ", 2) for line in stdout.splitlines() if line.startswith("missing ")]
    detail = "; ".join(f"{m[1]}: {m[2].strip() if len(m) > 2 else ''}".strip() for m in missing)
    return (detail or stdout.strip()[-400:]) + f" (is the registry {registry} reachable from the robot, " \
                                                "and is the tag pushed?)"


def _tarball(run: RobotRun, release: RenderedRelease, pull_output: str) -> bytes:
    """The release dir's content: rendered files + manifest.json + images.txt, modes kept."""
    images = {}
    for line in pull_output.splitlines():
        parts = line.split()
        if parts[:1] == ["ok"] and len(parts) >= 3:
            images[parts[1]] = {"id": parts[2], "repo_digests": parts[3].split(",") if len(parts) > 3 else []}
    manifest = {"project": run.spec.project, "host": run.host.name, "version": release.version,
                "release": release.release_id, "digest": release.digest, "images": images,
                "deployed_by": run.ctx.operator, "deployed_at": now(), "run": run.ctx.run_id,
                "rosdeploy": __version__, "files": [f.name for f in release.files],
                "services": list(expected_services(run.spec)), "pins": image_pull.digests(run, release)}
    extra = [("manifest.json", json.dumps(manifest, indent=2, sort_keys=True) + "\n", 0o644),
             ("images.txt", "".join(f"{i}\n" for i in release.images), 0o644)]
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tar:
        for name, content, mode in [(f.name, f.content, f.mode) for f in release.files] + extra:
            data = content.encode("utf-8")
            info = tarfile.TarInfo(name)
            info.size, info.mode, info.mtime = len(data), mode, int(time.time())
            tar.addfile(info, io.BytesIO(data))
    return buf.getvalue()


# --------------------------------------------------------------- rollback

def rollback_host(ctx: RunContext, host: Host, to_version: str | None = None,
                  to_release: str | None = None) -> HostResult:
    """Switch to a kept release without pulling: the previous one, a version, or an exact release id."""
    run = RobotRun(ctx, host)
    if ctx.cancel.is_set():
        return run.result(SKIPPED, reason="interrupted before this robot started: nothing was switched")
    try:
        run.open()
        return _rollback(run, to_version, to_release)
    except ConnectError as exc:
        run.lost = True
        if run.locked:    # say where it was lost, and what the rollback's guard does now
            return run.result(UNREACHABLE, reason=f"connection lost during {run.doing}{run.guard_note()} "
                              f"({exc.detail})")
        return run.result(UNREACHABLE, reason=str(exc))
    except RemoteError as exc:
        return run.result(FAILED, reason=str(exc))
    finally:
        run.close()


MOVED = "\x00moved"   # lock(): another run switched the robot since its state was read (not a holder)
MOVED_TRIES = 3
DAEMON_GONE = "Cannot connect to the Docker daemon"   # the docker CLI's words when dockerd is not there


def _engine_gone(verdict: Verdict, release: str) -> bool:
    """The switch failed because the robot's Docker engine did not answer, and nothing of
    `release` runs."""
    return DAEMON_GONE in verdict.reason and not any(c.status == "running" and c.release == release
                                                     for c in verdict.containers)


def _rollback_flavor(run: RobotRun, state: RobotState) -> str | None:
    """The compose flavour to switch with: as the history recorded it, else as the running
    containers' labels tell it (quick), else the full state's (an emergency skips the
    preflight facts when it can)."""
    def usable(known: str | None) -> bool:
        return known is not None and run.compose_pref in ("auto", known)
    if usable(state.recorded_flavor):
        return state.recorded_flavor
    running = run.read_state(full=False, step="state").running_flavor
    return running if usable(running) else run.read_state().flavor


def _rollback(run: RobotRun, to_version: str | None, to_release: str | None) -> HostResult:
    holder, state = run.lock_and_read(run.rollback_arm())
    target = rollback_target(state, to_version, to_release)
    base = {"old_release": state.current, "new_release": target, "running_release": state.current}
    if holder is not None:
        return run.result(LOCKED, reason=_locked_by(holder, run.ctx.controller), **base)
    if target is None:
        kept = ", ".join(state.releases) or "none"
        what = f"no kept release of version {to_version}" if to_version else "no previous release"
        if run.locked and state.releases:   # the brake was pulled here all the same: a rollout now stops at it
            run.history({"event": "rollback", "release": state.current, "from": state.current, "result": "failed",
                         "reason": what})
        return run.result(FAILED, reason=f"{what} on the robot (kept: {kept})", **base)
    flavor = _rollback_flavor(run, state)
    if flavor is None:
        return run.result(FAILED, reason="no docker compose on the robot", **base)
    manifest = state.kept_manifests.get(target)
    services = release_services(manifest) if manifest is not None else None
    run.rollback_to(state, target, flavor, services)
    gated = passed_gate(state, target)
    verdict = run.start(target, flavor, together=gated, services=services)
    if not verdict.ok and run.armed is not None and _engine_gone(verdict, target):
        # dockerd went away under the switch (the robot is rebooting, or its engine restarts):
        # activating would name a release none of which runs, and the stopped containers of the
        # one left come back with dockerd. The armed guard starts with dockerd, finishes the
        # rollback at once (a reboot) or at its deadline, and releases the lock.
        run.locked = False
        return run.result(FAILED, reason=f"the switch to {target} did not start ({verdict.reason})"
                                         f"{run.guard_note()}", **base)
    if not verdict.ok and not gated:
        return _rollback_refused(run, state, target, flavor, verdict, base)
    _host_changes(run, target)   # the kept release's rules, after the switch (one round trip to it)
    run.activate(target, {"event": "rollback", "release": target, "rolled_back_from": state.current,
                          "result": "active" if verdict.ok else "unhealthy", "reason": "operator rollback",
                          "compose": flavor})
    base["running_release"] = target
    if verdict.ok:
        return run.result(SWITCHED, reason=f"rolled back to {target}", **base)
    return run.result(FAILED, reason=f"switched to {target} but it is unhealthy: {verdict.reason}",
                      failed_service=verdict.service, logs=run.logs_of(verdict), **base)
