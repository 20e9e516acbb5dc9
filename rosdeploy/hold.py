"""May this robot switch now? Its maintenance window, then its readiness gate.

Called by deploy.py on a robot that is locked: with the new images pulled, before
anything restarts; or before host changes that drifted on the robot are put back (a
`udevadm trigger` is not for a robot on a mission either). Window first: it costs nothing
(the controller's clock), and a robot outside its window need not be asked whether it is busy.
"""
from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any

from rosdeploy import commands, ready, window
from rosdeploy.errors import RemoteError
from rosdeploy.health import PROBE_SOURCE, probe_service
from rosdeploy.results import BUSY, SKIPPED, WAITING_WINDOW


@dataclass(frozen=True)
class Held:
    outcome: str             # busy | waiting-window | skipped (interrupted while deferred)
    reason: str
    opens: str | None = None


def before_switch(run: Any, state: Any, kept: str = "images pulled, nothing restarted") -> Held | None:
    """`run`: deploy.RobotRun (its transport, spec, host, ctx, step). None: go ahead. `kept`
    ends the reason of a deferral: what the robot keeps meanwhile."""
    if run.ctx.force:
        return None
    closed = _window_closed(run, kept)
    if closed is not None:
        return closed
    policy = ready.host_setting(run.spec, run.host, "ready")
    if policy is None:
        return None
    running = {c.service: c.name for c in state.containers if c.status == "running"}
    probe_in = running.get(probe_service(run.spec) or "")

    def check() -> Any:
        # A deferral may outlast the guard's prepare deadline: each try pushes it out first,
        # so the guard never acts (and drops the lock) under a run that is only waiting.
        if run.armed:
            run.t.check(commands.rearm(run.root, run.spec.project, run.rearm("prepare")), "rearm")
        return ready.check(run.t.run, policy, running, probe_in, PROBE_SOURCE)

    verdict = ready.wait_ready(check, policy,
                               run.ctx.cancel.is_set, lambda msg: run.ctx.progress(run.host.name, msg), run.step)
    if verdict is None:
        return Held(SKIPPED, "interrupted while deferred by the readiness gate; nothing restarted")
    if not verdict.ok:
        return Held(BUSY, f"not ready after {policy.max_wait:g}s (ready.max_wait): {verdict.reason}; {kept}")
    return _window_closed(run, kept)     # the wait may have outlasted the window


def _window_closed(run: Any, kept: str) -> Held | None:
    win = ready.host_setting(run.spec, run.host, "window")
    if win is None:
        return None
    now = datetime.now(timezone.utc)
    opens = window.next_open(win, now)
    if opens <= now:
        return None
    stamp = opens.isoformat(timespec="seconds")
    return Held(WAITING_WINDOW, f"outside its maintenance window ({win.describe()}): opens {stamp}; {kept}",
                opens=stamp)


def app_locks(ctx: Any, host: Any) -> tuple[dict, ...]:
    """For `status`: the robot's held readiness lock files, who holds each and since when (a
    stale one blocks every deploy until someone removes it). No round trip without a lock
    condition; else one, over the connection `status` keeps for the robot."""
    policy = ready.host_setting(ctx.spec, host, "ready")
    paths = policy.lock_paths if policy else ()
    if not paths:
        return ()
    try:
        t = ctx.connect(host, ctx.ssh)
    except RemoteError:
        return ()
    try:
        held = [(p, ready.lock_holder(t.run(ready.lock_command(p)).stdout)) for p in paths]
    except RemoteError:
        return ()
    finally:
        t.close()
    return tuple({"path": p, **h} for p, h in held if h)
