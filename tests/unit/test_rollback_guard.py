"""The rollback's guard (docs/guard.md): armed in the rollback's lock+state round trip, re-armed
with its target by the `up` that switches, and, when the controller is gone, completing the
rollback on the robot. The robot scripts run for real (local sh, temp dir, a fake `docker`)."""
from __future__ import annotations

import json
import os
import subprocess
import threading
import time
from dataclasses import replace
from pathlib import Path

from rosdeploy import commands, deploy, guard
from rosdeploy.model import FleetSpec, HealthPolicy, Host, RollbackPolicy, Service
from rosdeploy.robot import parse_state
from rosdeploy.views import status_word

A, B = "1.0.0-aaaaaaaaaaaa", "1.1.0-bbbbbbbbbbbb"    # release ids as rosdeploy makes them (version-digest12)

# `ps` finds one container; `inspect` says it runs, healthy, from $WD (the release dir it was made in)
FAKE_DOCKER = """#!/bin/sh
echo "$*" >> "$DOCKER_LOG"
case $1 in
  ps) echo c1 ;;
  inspect) case "$*" in *RestartCount*) echo "running healthy 0 driver $WD" ;; *) echo "running driver $WD" ;; esac ;;
esac
"""


def robot(tmp_path: Path, running: str) -> dict:
    """A robot dir with A (activated before) and B (current), running `running`."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "docker").write_text(FAKE_DOCKER)
    (bin_dir / "docker").chmod(0o755)
    project = tmp_path / "r/demo"
    for release in (A, B):
        (project / "releases" / release).mkdir(parents=True)
    os.symlink(f"releases/{B}", project / "current")
    return {"HOME": str(tmp_path), "PATH": f"{bin_dir}:{os.environ['PATH']}",
            "DOCKER_LOG": str(tmp_path / "docker.log"), "WD": str(project / "releases" / running)}


def sh(cmd: commands.Command, env: dict) -> subprocess.CompletedProcess:
    return subprocess.run(["sh", "-c", cmd.wire()], input=cmd.stdin, capture_output=True, env=env, text=True)


def robot_run(command_timeout: float = 20, gate: float = 0, margin: float = 8) -> deploy.RobotRun:
    spec = FleetSpec(path="f", project="demo", inventory="i", registry="r", version="1",
                     services=(Service("driver", "img", "1"),), command_timeout=command_timeout,
                     health=HealthPolicy(timeout=gate), rollback=RollbackPolicy(guard_margin=margin))
    ctx = deploy.RunContext(spec=spec, ssh=None, run_id="run-1", operator="ana", cancel=threading.Event())
    return deploy.RobotRun(ctx, Host(name="r1", groups=("all",), vars={}, address="h"))


HISTORY = "".join(json.dumps({"release": r, "result": "active"}) + "\n" for r in (A, B))


def armed_and_switching(tmp_path: Path, env: dict, run: deploy.RobotRun) -> Path:
    """The controller's two round trips up to the switch: lock+state (arms), then `up` (re-arms
    with the target); the switch itself is left to the guard (the fake docker starts nothing)."""
    locked = sh(commands.locked_state("~/r", "demo", {"run": "run-1"}, guard=run.rollback_arm()), env)
    assert locked.returncode == 0 and locked.stdout.startswith("locked"), locked.stderr
    state = replace(parse_state(locked.stdout), history=tuple(json.loads(line) for line in HISTORY.splitlines()))
    run.rollback_to(state, A, "v2", ("driver",))
    up = sh(commands.up("~/r", "demo", A, "v2", together=True, rearm=run.rearm("start")), env)
    assert up.returncode == 0, up.stderr
    return tmp_path / "r/demo/.guard"


def act_now(g: Path, env: dict) -> dict:
    """The guard's deadline passes: run it (as its container would) until it leaves."""
    (g / "state").write_text((g / "state").read_text() + "deadline=0\n")
    out = subprocess.run(["sh", "-c", guard.GUARD_SCRIPT, "guard", str(g), "rosdeploy-guard-demo"], env=env,
                         capture_output=True, text=True, timeout=30)
    assert out.returncode == 0, out.stderr
    return json.loads((g.parent / "history.jsonl").read_text().splitlines()[-1])


def test_the_deadlines_prepare_then_the_switch_s_own() -> None:
    run = robot_run(command_timeout=20, gate=30, margin=8)
    args = run.rollback_arm()
    state = guard.parse_guard(args[0])
    assert (state.run, state.mode, state.phase, state.target) == ("run-1", "rollback", "prepare", "")
    assert int(args[1]) == 20 + 8                  # before the switch: a command's timeout + margin
    assert args[2:5] == (guard.GUARD_SCRIPT, commands.UP_SCRIPT, commands.FINISH_SCRIPT)
    run.rollback_to(parse_state(f"\n@@current\nreleases/{B}\n@@end\n"), A, "v1", None)
    first, lines = run.rearm("start").split("\n", 1)
    assert first == "run-1 38"                     # max(command_timeout, health.timeout) + margin
    switched = guard.parse_guard(args[0] + lines)
    assert (switched.target, switched.previous, switched.gated) == (A, B, False)
    assert f"reverts to {B} in ~38 s" in run.guard_note()   # never activated here: no target to finish on
    assert guard.rollback_deadline(600, 90, 30) == 630 and guard.rollback_deadline(20, 90, 30) == 120
    off = robot_run()
    off.spec = replace(off.spec, rollback=RollbackPolicy(guard="off"))
    assert off.rollback_arm() == ()


def test_status_says_an_interrupted_rollback_and_what_its_guard_does() -> None:
    text = f"run=R\nby=ana@laptop\nmode=rollback\nphase=start\ntarget={A}\nprevious={B}\ngated=yes\n" \
           "deadline=142\nboot=b-1\n"
    st = parse_state(f"\n@@current\nreleases/{B}\n@@guard\n" + text + "@@clock\n100\n@@boot\nb-1\n@@end\n")
    word, reason = status_word(st, {}, lock_alive=False)
    assert word == "INTERRUPTED" and reason.endswith(f"guard finishes the rollback to {A} in 42 s")
    rebooted = replace(st, boot="b-2")
    assert "robot restarted mid-rollback" in status_word(rebooted, {}, None)[1]


def test_the_switch_re_arms_the_lock_s_guard_with_its_target(tmp_path: Path) -> None:
    env = robot(tmp_path, running=A)
    g = armed_and_switching(tmp_path, env, robot_run())
    state = guard.parse_guard((g / "state").read_text())
    assert (state.mode, state.phase, state.target, state.previous, state.gated) == \
           ("rollback", "start", A, B, True)
    assert abs(state.deadline - (time.time() + 28)) < 5
    assert (g / "up.sh").read_text() == commands.UP_SCRIPT + "\n"


def test_a_lost_controller_s_rollback_is_completed_without_restarting_what_already_runs(tmp_path: Path) -> None:
    env = robot(tmp_path, running=A)
    g = armed_and_switching(tmp_path, env, robot_run())
    (tmp_path / "docker.log").write_text("")
    entry = act_now(g, env)
    assert (entry["event"], entry["release"], entry["rolled_back_from"], entry["result"], entry["run"]) == \
           ("guard-finished-rollback", A, B, "active", "run-1")
    assert entry["reason"] == "controller lost"
    project = tmp_path / "r/demo"
    assert os.readlink(project / "current") == f"releases/{A}"
    assert not (project / ".lock").exists() and not (g / "state").exists() and not (g / "acting").exists()
    log = (tmp_path / "docker.log").read_text()
    assert "compose -p" not in log and "stop " not in log and "rm -f rosdeploy-guard-demo" in log


def test_a_half_done_switch_is_started_again_the_brake_s_way(tmp_path: Path) -> None:
    env = robot(tmp_path, running=B)      # the old release's container still there
    g = armed_and_switching(tmp_path, env, robot_run())
    (tmp_path / "docker.log").write_text("")
    entry = act_now(g, env)
    log = (tmp_path / "docker.log").read_text()
    assert "compose -p demo -f compose.yml up --no-start --remove-orphans" in log and "start c1" in log
    # the fake still shows the old release: not healthy within the gate, switched all the same (as the brake does)
    assert (entry["event"], entry["result"]) == ("guard-finished-rollback", "unhealthy")
    assert os.readlink(tmp_path / "r/demo/current") == f"releases/{A}"


def test_a_rollback_lost_before_its_switch_only_releases_the_lock(tmp_path: Path) -> None:
    env = robot(tmp_path, running=B)
    locked = sh(commands.locked_state("~/r", "demo", {"run": "run-1"}, guard=robot_run().rollback_arm()), env)
    assert locked.returncode == 0
    g = tmp_path / "r/demo/.guard"
    assert "@@guard\nrun=run-1\n" in locked.stdout          # the state read under the lock shows it armed
    entry = act_now(g, env)
    assert (entry["event"], entry["release"], entry["result"]) == ("guard-rollback", B, "unchanged")
    assert "before the rollback switched anything" in entry["reason"]
    assert os.readlink(tmp_path / "r/demo/current") == f"releases/{B}" and not (tmp_path / "r/demo/.lock").exists()


def test_a_guard_that_is_acting_keeps_a_rollback_out(tmp_path: Path) -> None:
    env = robot(tmp_path, running=B)
    g = tmp_path / "r/demo/.guard"
    g.mkdir()
    (g / "acting").write_text("run=R0\n")
    (g / ".claim").mkdir()
    out = sh(commands.locked_state("~/r", "demo", {"run": "run-1"}, guard=robot_run().rollback_arm()), env)
    assert out.returncode == 3 and out.stdout.startswith("held") and "the deploy guard" in out.stdout
    assert not (tmp_path / "r/demo/.lock").exists()


def test_a_guard_that_is_acting_keeps_a_deploy_out_with_one_answer(tmp_path: Path) -> None:
    """The deploy's lock gives the lock back when its guard cannot be armed: its answer is only
    `held ...` (it used to print `locked` first, and the holder read as that text)."""
    env = robot(tmp_path, running=B)
    g = tmp_path / "r/demo/.guard"
    g.mkdir()
    (g / "acting").write_text("run=R0\n")
    (g / ".claim").mkdir()
    arm = commands.arm_args("run=run-1\n", 30, ("",) * 6, ())
    out = sh(commands.lock("~/r", "demo", {"run": "run-1"}, guard=arm), env)
    assert out.returncode == 3 and out.stdout.startswith("held {") and "locked" not in out.stdout, out.stdout
    assert not (tmp_path / "r/demo/.lock").exists()
    (g / ".claim").rmdir()
    (g / "acting").unlink()
    taken = sh(commands.lock("~/r", "demo", {"run": "run-1"}, guard=arm), env)
    assert taken.returncode == 0 and taken.stdout == "locked\n", taken.stderr


def test_the_controller_s_activation_disarms_the_rollback_s_guard_and_a_lost_run_leaves_it_armed() -> None:
    from rosdeploy.transport import Result

    class Recorder:
        def __init__(self) -> None:
            self.calls: list[commands.Command] = []

        def run(self, command: commands.Command) -> Result:
            self.calls.append(command)
            return Result(command.label, "", "", 0, 0.0)

        def close(self) -> None:
            pass

    run = robot_run()
    run.t = transport = Recorder()
    run.rollback_arm()
    run.activate(A, {"event": "rollback"})
    assert transport.calls[-1].argv[-1] == "run-1"      # finish.sh disarms this run's guard (strict)
    lost = robot_run()
    lost.t = transport = Recorder()
    lost.rollback_arm()
    lost.locked, lost.lost = True, True
    lost.close()
    assert transport.calls == []                          # no unlock: it would disarm the guard


def test_a_switch_that_lost_dockerd_is_left_to_the_guard_only_when_nothing_of_the_target_runs() -> None:
    from rosdeploy.deploy import _engine_gone
    from rosdeploy.health import Verdict
    from rosdeploy.robot import Container
    gone = "compose up failed: Cannot connect to the Docker daemon at unix:///var/run/docker.sock."
    target = "1.0.0-aaaa"
    old = Container("demo-driver-1", "driver", "x", "running", None, 0, workdir="/r/demo/releases/1.1.0-bbbb")
    new = Container("demo-driver-1", "driver", "x", "running", None, 0, workdir=f"/r/demo/releases/{target}")
    assert _engine_gone(Verdict(False, gone, containers=(old,)), target)
    assert not _engine_gone(Verdict(False, gone, containers=(new,)), target)
    assert not _engine_gone(Verdict(False, "compose up failed: port is already allocated"), target)
