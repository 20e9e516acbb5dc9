"""Two controllers and one robot: a run that waited for the lock must not switch on the state
it read before another run switched the robot (it would go back, on failure, to a release that
no longer ran, and point `current` away from what runs); and an operator's rollback pulled during
a rollout stops it (its later waves must not undo the brake)."""
from __future__ import annotations

import os
import subprocess
import threading
from pathlib import Path

import pytest

from rosdeploy import commands, deploy
from rosdeploy.model import FleetSpec, Host, RenderedFile, RenderedRelease, RollbackPolicy, Service
from rosdeploy.results import LOCKED
from rosdeploy.transport import Result


def run_local(cmd: commands.Command, home: Path) -> subprocess.CompletedProcess:
    env = {"HOME": str(home), "PATH": os.environ["PATH"]}
    return subprocess.run(["sh", "-c", cmd.wire()], input=cmd.stdin, capture_output=True, env=env, text=True)


def test_the_lock_is_given_back_when_current_moved_since_the_state_was_read(tmp_path: Path) -> None:
    root = tmp_path / "r/demo"
    (root / "releases/1.0.0-aaaaaaaaaaaa").mkdir(parents=True)
    (root / "releases/1.1.0-bbbbbbbbbbbb").mkdir()
    (root / "current").symlink_to("releases/1.0.0-aaaaaaaaaaaa")
    taken = run_local(commands.lock("~/r", "demo", {"run": "A"}, expect="releases/1.0.0-aaaaaaaaaaaa"), tmp_path)
    assert taken.returncode == 0 and taken.stdout.strip() == "locked"
    run_local(commands.unlock("~/r", "demo", "A"), tmp_path)
    (root / "current").unlink()
    (root / "current").symlink_to("releases/1.1.0-bbbbbbbbbbbb")           # another run switched the robot
    moved = run_local(commands.lock("~/r", "demo", {"run": "B"}, expect="releases/1.0.0-aaaaaaaaaaaa"), tmp_path)
    assert moved.returncode == 4 and moved.stdout.strip() == "moved"
    assert not (root / ".lock").exists(), "a stale decision leaves the lock free"
    unchecked = run_local(commands.lock("~/r", "demo", {"run": "C"}), tmp_path)
    assert unchecked.returncode == 0


def test_nothing_deployed_is_expected_as_an_empty_link(tmp_path: Path) -> None:
    assert run_local(commands.lock("~/r", "demo", {"run": "A"}, expect=""), tmp_path).returncode == 0


A, B = "1.0.0-aaaaaaaaaaaa", "1.1.0-bbbbbbbbbbbb"
STATES = {A: f"\n@@dir\n/h/r/demo\n@@current\nreleases/{A}\n@@releases\n{A}\n@@end\n",
          B: f"\n@@dir\n/h/r/demo\n@@current\nreleases/{B}\n@@releases\n{A}\n{B}\n@@end\n"}


class Robot:
    """A transport for one robot that another run switches to 1.1.0-bbbbbbbbbbbb when it gets the lock."""

    def __init__(self, moves: int) -> None:
        self.current, self.moves, self.locks = A, moves, []

    def run(self, command: commands.Command) -> Result:
        kind = command.label.split()[0]
        if kind == "lock":
            expected = command.argv[-1] if command.argv[-2] == "yes" else None
            self.locks.append(expected)
            if self.moves:
                self.moves -= 1
                self.current = B if self.current == A else A
                return Result(command.label, "moved\n", "", 4, 0.0)
            return Result(command.label, "locked\n", "", 0, 0.0)
        return Result(command.label, STATES[self.current] if kind == "state" else "", "", 0, 0.0)

    def close(self) -> None:
        pass


def robot_run(robot: Robot) -> deploy.RobotRun:
    spec = FleetSpec(path="f", project="demo", inventory="i", registry="r", version="1.2.0",
                     services=(Service("driver", "img", "1.2.0"),), rollback=RollbackPolicy(guard="off"))
    ctx = deploy.RunContext(spec=spec, ssh=None, run_id="run-1", operator="me", cancel=threading.Event(),
                            host_changes=False)
    run = deploy.RobotRun(ctx, Host(name="r1", groups=("all",), vars={}, address="h"))
    run.t = robot
    return run


def release() -> RenderedRelease:
    return RenderedRelease("r1", "demo", "1.2.0", (RenderedFile("compose.yml", "x"),), ("img:1.2.0",))


def test_a_run_whose_robot_was_switched_meanwhile_decides_again_on_what_runs_now(monkeypatch) -> None:
    robot = Robot(moves=1)
    seen: list[str | None] = []
    monkeypatch.setattr(deploy, "preflight", lambda state, run, free: [])
    monkeypatch.setattr(deploy, "_switch", lambda run, rel, state, base: seen.append(state.current) or base)
    base = deploy._apply(robot_run(robot), release())
    assert robot.locks == [f"releases/{A}", f"releases/{B}"]   # the second lock expects what runs now
    assert seen == [B], "the switch (and its way back) starts from the release that runs now"
    assert base["old_release"] == B


def test_a_robot_that_keeps_moving_is_reported_locked_not_switched(monkeypatch) -> None:
    robot = Robot(moves=deploy.MOVED_TRIES)
    monkeypatch.setattr(deploy, "preflight", lambda state, run, free: [])
    monkeypatch.setattr(deploy, "_switch", lambda *a: (_ for _ in ()).throw(AssertionError("no switch")))
    result = deploy._apply(robot_run(robot), release())
    assert result.outcome == LOCKED and "switched this robot" in result.reason
    assert len(robot.locks) == deploy.MOVED_TRIES


def test_a_live_run_of_this_machine_is_never_offered_break_lock() -> None:
    import json

    from rosdeploy import owner
    here = owner.this_controller()
    live = json.dumps(owner.record("run-0", "ops@vm", "2026-11-24T00:00:00+00:00", here, os.getpid()))
    reason = deploy._locked_by(live, here)
    assert "still going on this machine" in reason and "--break-lock" not in reason, reason
    elsewhere = json.dumps({**json.loads(live), "boot": "another-boot"})
    assert "--break-lock" in deploy._locked_by(elsewhere, here)   # this machine cannot tell: the user decides


# ------------------------------------------------------------------ the brake pulled during a rollout

def with_history(state: str, *entries: dict) -> str:
    import json
    lines = "".join(json.dumps(e) + "\n" for e in entries)
    return state.replace("@@end", f"@@history\n{lines}@@end")


def test_only_an_operator_rollback_after_the_rollout_began_is_a_brake() -> None:
    from rosdeploy.robot import parse_state
    since = "2026-11-25T01:00:00+00:00"
    rollback = {"event": "rollback", "release": A, "time": "2026-11-25T01:00:05+00:00", "by": "ana", "run": "R"}
    assert deploy.brake_pulled(parse_state(with_history(STATES[A], rollback)), since) == rollback
    before = {**rollback, "time": "2026-11-25T00:59:59+00:00"}
    assert deploy.brake_pulled(parse_state(with_history(STATES[A], before)), since) is None
    later = {"event": "deploy", "release": A, "time": "2026-11-25T01:00:09+00:00", "result": "active"}
    assert deploy.brake_pulled(parse_state(with_history(STATES[A], rollback, later)), since) == rollback
    guard = {"event": "guard-finished-rollback", "release": A, "time": "2026-11-25T01:00:09+00:00"}
    assert deploy.brake_pulled(parse_state(with_history(STATES[A], guard)), since) is None
    odd = {**rollback, "time": "yesterday"}
    assert deploy.brake_pulled(parse_state(with_history(STATES[A], odd)), since) is None


def test_a_robot_braked_during_the_rollout_is_not_deployed_and_stops_it(monkeypatch) -> None:
    robot = Robot(moves=0)
    run = robot_run(robot)
    since = run.ctx.started_at
    braked_state = {A: with_history(STATES[A], {"event": "rollback", "release": A, "by": "ana@ops", "run": "R9",
                                                 "time": "2099-01-01T00:00:00+00:00"})}
    monkeypatch.setattr(robot, "run", lambda c: Result(c.label, braked_state[A], "", 0, 0.0)
                        if c.label.split()[0] == "state" else pytest.fail(f"nothing else runs: {c.label}"))
    result = deploy._apply(run, release())
    assert result.outcome == "skipped" and "emergency rollback by ana@ops" in result.reason, result.reason
    assert run.ctx.braked.is_set() and since < "2099"


def test_a_braked_rollout_starts_no_more_waves_and_takes_nothing_back(monkeypatch) -> None:
    from rosdeploy import rollout
    from rosdeploy.model import RolloutPolicy
    from rosdeploy.results import DEPLOYED, SKIPPED, HostResult

    def apply_host(ctx, h, rel) -> HostResult:
        if h.name == "r1":
            ctx.braked.set()
            return HostResult(h.name, SKIPPED, reason="an emergency rollback by ana switched this robot")
        return HostResult(h.name, DEPLOYED, "a", "b")

    monkeypatch.setattr(rollout, "apply_host", apply_host)
    monkeypatch.setattr(rollout, "precheck_host", lambda ctx, h, rel: (None, None))
    monkeypatch.setattr(rollout, "rollback_host", lambda *a, **k: pytest.fail("no fleet rollback after a brake"))
    spec = FleetSpec(path="f", project="demo", inventory="i", registry="r", version="1.2.0",
                     services=(Service("driver", "img", "1.2.0"),))
    ctx = deploy.RunContext(spec=spec, ssh=None, run_id="run-1", operator="me", cancel=threading.Event())
    hosts = [Host(name=f"r{i}", groups=("all",), vars={}, address="h") for i in range(4)]
    releases = {h.name: RenderedRelease(h.name, "demo", "1.2.0", (), ()) for h in hosts}
    events: list[tuple[str, dict]] = []
    result = rollout.apply_fleet(ctx, hosts, releases, RolloutPolicy(waves=(2, "100%")),
                                 lambda e, d: events.append((e, d)))
    assert result.aborted and not result.fleet_rollback
    assert [(h.host, h.outcome) for h in result.hosts] == [("r0", "deployed"), ("r1", "skipped"),
                                                          ("r2", "skipped"), ("r3", "skipped")]
    assert "emergency rollback was pulled" in result.hosts[2].reason
    assert ("braked", {"wave": 1, "hosts": ["r1"]}) in events
