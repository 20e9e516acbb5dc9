"""The deploy guard's pure parts (state file, status words, lock owners) and its robot
scripts, run for real by a local sh against a temp dir with a fake `docker`."""
from __future__ import annotations

import json
import os
import subprocess
import time
from dataclasses import replace
from pathlib import Path

import pytest

from rosdeploy import commands, guard
from rosdeploy.owner import Controller, describe, holder_alive
from rosdeploy.robot import Container, parse_state
from rosdeploy.views import status_word

HERE = Controller(boot="b-1", pid_namespace="pid:[1]")
OWNER = {"run": "R1", "by": "ana@laptop", "pid": 4242, "since": "2026-01-01T00:00:00+00:00",
         "boot": "b-1", "pid_namespace": "pid:[1]"}


# ------------------------------------------------------------------ state file

def test_the_state_file_is_read_with_the_last_value_of_a_key_winning() -> None:
    text = ("run=R1\nby=ana@laptop\nmode=finish\ntarget=1.1.0-b\nprevious=1.0.0-a\nphase=prepare\n"
            "deadline=100\nboot=b-1\nphase=start\ndeadline=160\n")
    g = guard.parse_guard(text)
    assert (g.run, g.mode, g.phase, g.deadline, g.previous, g.acting) == \
           ("R1", "finish", "start", 160, "1.0.0-a", False)
    assert g.seconds_left(118) == 42 and g.seconds_left(200) == 0 and g.seconds_left(None) is None


@pytest.mark.parametrize("text", ["", "  \n", "by=x\nmode=revert\n", "garbage without equals"])
def test_no_run_no_guard(text: str) -> None:
    assert guard.parse_guard(text) is None


def test_a_first_deploy_has_no_previous_and_a_bad_deadline_is_unknown() -> None:
    g = guard.parse_guard("run=R\nprevious=\ndeadline=soon\n")
    assert g.previous is None and g.deadline is None


def test_state_text_keeps_one_value_per_line() -> None:
    text = guard.state_text({"run": "R1", "by": "evil\nrun=other", "services": "driver perception"})
    assert guard.parse_guard(text).run == "R1"
    assert "by=evil run=other\n" in text and "services=driver perception\n" in text


@pytest.mark.parametrize("fields,will", [
    ({"phase": "prepare"}, "releases the lock"),
    ({"phase": "start"}, "reverts to 1.0.0-a"),
    ({"phase": "start", "previous": None}, "stops 1.1.0-b"),
    ({"phase": "start", "mode": "finish"}, "gates 1.1.0-b itself"),
])
def test_what_the_guard_will_do(fields: dict, will: str) -> None:
    g = guard.Guard(run="R", by="", mode="revert", phase="start", target="1.1.0-b", previous="1.0.0-a", deadline=1)
    assert replace(g, **fields).will == will


# ------------------------------------------------------------------ status words

def container(release: str, health: str | None = "healthy", status: str = "running",
              service: str = "driver") -> Container:
    return Container(name=f"demo-{service}-1", service=service, image="i", status=status, health=health, restarts=0,
                     workdir=f"/home/robot/rosdeploy/demo/releases/{release}")


def state(current: str | None = "1.0.0-a", running: str | None = "1.0.0-a", guard_text: str = "",
          acting: bool = False, lock: dict | None = None, clock: int = 1000, boot: str = "b-1"):
    sections = {"current": f"releases/{current}" if current else "", "lock": json.dumps(lock) if lock else "",
                "guard-acting" if acting else "guard": guard_text, "clock": str(clock), "boot": boot}
    st = parse_state("".join(f"\n@@{k}\n{v}\n" for k, v in sections.items()) + "\n@@end\n")
    return replace(st, containers=(container(running),) if running else ())


ARMED = ("run=R1\nby=ana@laptop\nmode=revert\nphase=start\ntarget=1.2.0-bad-c\nprevious=1.0.0-a\n"
         "deadline=1042\nboot=b-1\n")


def test_the_issue_s_example_a_killed_controller_is_interrupted_with_the_guard_s_countdown() -> None:
    word, reason = status_word(state(running="1.2.0-bad-c", guard_text=ARMED, lock=OWNER), {}, lock_alive=False)
    assert word == "INTERRUPTED"
    assert reason.startswith("1.2.0-bad running, 1.0.0 active; run R1 by ana@laptop")
    assert reason.endswith("guard reverts to 1.0.0-a in 42 s")


def test_a_live_controller_is_deploying() -> None:
    assert status_word(state(running="1.2.0-bad-c", guard_text=ARMED, lock=OWNER), {}, True)[0] == "DEPLOYING"


def test_a_guard_that_acts_is_recovering() -> None:
    word, reason = status_word(state(guard_text=ARMED + "reason=controller lost\n", acting=True), {}, None)
    assert word == "RECOVERING" and "controller lost" in reason


def test_a_guard_armed_before_the_robot_restarted_means_interrupted() -> None:
    word, reason = status_word(state(guard_text=ARMED, lock=OWNER, boot="b-2"), {}, None)
    assert word == "INTERRUPTED" and "robot restarted mid-deploy" in reason


def test_containers_of_a_release_that_was_never_activated_are_ungated_not_healthy() -> None:
    word, reason = status_word(state(current=None, running="1.1.0-b"), {}, None)
    assert word == "UNGATED" and reason.startswith("1.1.0 running, nothing active")


def test_running_something_other_than_current_is_a_mismatch() -> None:
    assert status_word(state(running="1.1.0-b"), {}, None)[0] == "MISMATCH"


@pytest.mark.parametrize("alive,word", [(False, "INTERRUPTED"), (True, "DEPLOYING"), (None, "LOCKED")])
def test_a_lock_without_a_guard(alive: bool | None, word: str) -> None:
    got, reason = status_word(state(lock=OWNER), {}, alive)
    assert got == word and "ana@laptop (run R1, pid 4242, since 2026-01-01T00:00:00+00:00)" in reason


def test_plain_states() -> None:
    assert status_word(state(), {}, None) == ("healthy", "")
    assert status_word(state(current=None, running=None), {}, None) == ("not deployed", "")
    assert status_word(state(), {"driver": "health starting"}, None) == ("UNHEALTHY", "driver: health starting")


def test_the_running_release_comes_from_the_containers_labels() -> None:
    st = state(running="1.1.0-b")
    assert st.running_release == "1.1.0-b"
    mixed = replace(st, containers=st.containers + (container("1.0.0-a", service="perception"),))
    assert mixed.running_release == "mixed"
    assert replace(st, containers=(container("1.1.0-b", status="exited"),)).running_release is None


# ------------------------------------------------------------------ lock owners

def test_lock_owner_alive_only_when_this_system_can_tell() -> None:
    assert holder_alive(OWNER, HERE, alive=lambda pid: pid == 4242) is True
    assert holder_alive(OWNER, HERE, alive=lambda pid: False) is False
    assert holder_alive({**OWNER, "boot": "other"}, HERE, alive=lambda pid: False) is None
    assert holder_alive({"run": "R1"}, HERE) is None and holder_alive(None, HERE) is None


def test_lock_owner_for_people() -> None:
    assert describe(json.dumps(OWNER)) == "ana@laptop (run R1, pid 4242, since 2026-01-01T00:00:00+00:00)"
    assert describe("not json") == "not json"


# ------------------------------------------------------------------ robot scripts

def fake_docker(tmp_path: Path) -> dict:
    """`docker` logs its argv; `ps` lists nothing; `run` succeeds (the guard's container)."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "docker").write_text('#!/bin/sh\necho "$*" >> "$DOCKER_LOG"\n')
    (bin_dir / "docker").chmod(0o755)
    return {"HOME": str(tmp_path), "PATH": f"{bin_dir}:{os.environ['PATH']}",
            "DOCKER_LOG": str(tmp_path / "docker.log")}


def sh(cmd: commands.Command, env: dict) -> subprocess.CompletedProcess:
    return subprocess.run(["sh", "-c", cmd.wire()], input=cmd.stdin, capture_output=True, env=env, text=True)


FILES = ("GUARD", "UP", "FINISH", "PROBE", "SRC", "{}")


def arm(env: dict, run: str = "R1", seconds: int = 30) -> subprocess.CompletedProcess:
    state = guard.state_text({"run": run, "by": "ana", "target": "1.1.0-b"})
    args = commands.arm_args(state, seconds, FILES, ("img:1",))
    return sh(commands.lock("~/r", "demo", {"run": run}, guard=args), env)


def wait_started(tmp_path: Path, seconds: float = 5) -> None:
    """Until the guard's `docker run` was called (its `container` file is written before it)."""
    log = tmp_path / "docker.log"
    end = time.monotonic() + seconds
    while not (log.exists() and "\nrun " in "\n" + log.read_text()) and time.monotonic() < end:
        time.sleep(0.05)


def test_the_lock_arms_the_guard_and_starts_its_container(tmp_path: Path) -> None:
    env = fake_docker(tmp_path)
    out = arm(env)
    assert out.returncode == 0 and out.stdout.strip() == "locked", out.stderr
    g = tmp_path / "r/demo/.guard"
    state = guard.parse_guard((g / "state").read_text())
    assert (state.run, state.phase, state.target) == ("R1", "prepare", "1.1.0-b")
    assert abs(state.deadline - (time.time() + 30)) < 5
    assert (g / "guard.sh").read_text() == "GUARD\n" and (g / "probe.json").read_text() == "{}\n"
    wait_started(tmp_path)
    run = next(c for c in (tmp_path / "docker.log").read_text().splitlines() if c.startswith("run "))
    for part in ("--restart always", "--network none", "-v /:/host", "--entrypoint chroot img:1",
                 f"/host /bin/sh {g}/guard.sh {g} rosdeploy-guard-demo"):
        assert part in run
    assert "com.docker.compose" not in run


def test_rearm_disarm_and_a_guard_that_took_over(tmp_path: Path) -> None:
    env = fake_docker(tmp_path)
    arm(env)
    g = tmp_path / "r/demo/.guard"
    wait_started(tmp_path)
    out = sh(commands.record("~/r", "demo", {"event": "x"}, commands.rearm_arg("R1", 90)), env)
    assert out.returncode == 0, out.stderr
    assert guard.parse_guard((g / "state").read_text()).phase == "start"
    (tmp_path / "r/demo/releases/1.1.0-b").mkdir(parents=True)
    done = sh(commands.finish("~/r", "demo", "1.1.0-b", {"release": "1.1.0-b"}, 3, guard_run="R1"), env)
    assert done.returncode == 0, done.stderr
    assert not (g / "state").exists() and os.readlink(tmp_path / "r/demo/current") == "releases/1.1.0-b"
    sh(commands.unlock("~/r", "demo", "R1"), env)
    # Armed again, then the guard takes over: activation must not switch, the lock stays the guard's
    arm(env, run="R2")
    (g / "state").rename(g / "acting")
    (g / ".claim").mkdir()
    late = sh(commands.finish("~/r", "demo", "1.1.0-b", {"release": "1.1.0-b"}, 3, guard_run="R2"), env)
    assert late.returncode == 6 and "took this run over" in late.stderr
    sh(commands.unlock("~/r", "demo", "R2"), env)
    assert (tmp_path / "r/demo/.lock").exists()
    other = sh(commands.lock("~/r", "demo", {"run": "R3"}, break_stale=True,
                             guard=commands.arm_args("run=R3\n", 30, FILES, ())), env)
    assert other.returncode == 3 and "the deploy guard" in other.stdout


def test_unlock_disarms_the_run_s_guard(tmp_path: Path) -> None:
    env = fake_docker(tmp_path)
    arm(env)
    sh(commands.unlock("~/r", "demo", "R1"), env)
    assert not (tmp_path / "r/demo/.guard/state").exists() and not (tmp_path / "r/demo/.lock").exists()


def test_the_guard_releases_a_lock_left_before_anything_started(tmp_path: Path) -> None:
    """Phase prepare, deadline passed: nothing to undo; a history line, the lock released,
    its container removed."""
    env = fake_docker(tmp_path)
    args = commands.arm_args(guard.state_text({"run": "R1", "by": "ana", "project": "demo", "target": "1.1.0-b",
                                               "previous": "1.0.0-a", "flavor": "v2"}), 0, FILES, ())
    assert sh(commands.lock("~/r", "demo", {"run": "R1"}, guard=args), env).returncode == 0
    g = tmp_path / "r/demo/.guard"
    out = subprocess.run(["sh", "-c", guard.GUARD_SCRIPT, "guard", str(g), "rosdeploy-guard-demo"], env=env,
                         capture_output=True, text=True, timeout=20)
    assert out.returncode == 0, out.stderr
    entry = json.loads((tmp_path / "r/demo/history.jsonl").read_text().splitlines()[-1])
    assert (entry["event"], entry["result"], entry["release"], entry["run"]) == \
           ("guard-rollback", "unchanged", "1.0.0-a", "R1")
    assert entry["reason"].startswith("controller lost")
    assert not (tmp_path / "r/demo/.lock").exists() and not (g / "state").exists() and not (g / "acting").exists()
    assert "rm -f rosdeploy-guard-demo" in (tmp_path / "docker.log").read_text()


# ------------------------------------------------------------------ the controller's side

class Recorder:
    """A transport that records each command's label and answers with a fixed exit code."""

    def __init__(self, exited: int = 0, stderr: str = "") -> None:
        self.calls: list[commands.Command] = []
        self.exited, self.stderr = exited, stderr

    def run(self, command: commands.Command):
        from rosdeploy.transport import Result
        self.calls.append(command)
        return Result(command.label, "", self.stderr, self.exited, 0.0)

    def close(self) -> None:
        pass


def robot_run(transport: Recorder, guard_mode: str = "revert"):
    import threading

    from rosdeploy import deploy
    from rosdeploy.model import FleetSpec, Host, RollbackPolicy, Service
    spec = FleetSpec(path="f", project="demo", inventory="i", registry="r", version="1",
                     services=(Service("driver", "img", "1"),), rollback=RollbackPolicy(guard=guard_mode))
    ctx = deploy.RunContext(spec=spec, ssh=None, run_id="run-1", operator="me", cancel=threading.Event())
    run = deploy.RobotRun(ctx, Host(name="r1", groups=("all",), vars={}, address="h"))
    run.t = transport
    return run


def release():
    from rosdeploy.model import RenderedFile, RenderedRelease
    return RenderedRelease("r1", "demo", "1.1.0", (RenderedFile("compose.yml", "x"),), ("img:1.1.0",))


def test_arming_sends_the_state_the_guard_needs() -> None:
    run = robot_run(Recorder())
    args = run.guard_arm(parse_state("\n@@current\nreleases/1.0.0-a\n@@end\n"), release())
    state = guard.parse_guard(args[0])
    assert (state.run, state.mode, state.target, state.previous) == ("run-1", "revert", release().release_id, "1.0.0-a")
    assert int(args[1]) == 600 + 30           # before the start: the pull's timeout + the margin
    assert args[2] == guard.GUARD_SCRIPT and args[3] == commands.UP_SCRIPT and args[-1] == "img:1.1.0"
    assert run.rearm("start") == "run-1 120"  # from the start: health.timeout + the margin
    assert "reverts to 1.0.0-a in ~120 s" in run.guard_note()
    assert robot_run(Recorder(), "off").guard_arm(parse_state(""), release()) == ()


def test_a_run_that_lost_its_robot_leaves_the_lock_to_the_guard() -> None:
    transport = Recorder()
    run = robot_run(transport)
    run.guard_arm(parse_state(""), release())
    run.locked, run.lost = True, True
    run.close()
    assert transport.calls == []              # no unlock: unlocking would disarm the guard
    run.lost = False
    run.close()
    assert [c.label.split()[0] for c in transport.calls] == ["unlock"]


def test_activation_after_the_guard_took_over_fails_and_switches_nothing() -> None:
    from rosdeploy.errors import GuardTookOver
    run = robot_run(Recorder(exited=6, stderr="the deploy guard on the robot took this run over"))
    run.guard_arm(parse_state(""), release())
    with pytest.raises(GuardTookOver, match="took this run over"):
        run.activate("1.1.0-x", {"event": "deploy"})
    assert run.t.calls[0].argv[-1] == "run-1" and not run.locked


def test_the_status_table_shows_the_word_and_why_for_every_robot() -> None:
    import io

    from rosdeploy.cli import report
    from rosdeploy.output import Output
    from rosdeploy.views import RobotStatus
    buf = io.StringIO()
    rows = [RobotStatus("r1", True, release="1.0.0-a", version="1.0.0", state="INTERRUPTED",
                        reason="1.2.0-bad running, 1.0.0 active; guard reverts to 1.0.0-a in 42 s"),
            RobotStatus("r2", False, error="unreachable: no answer")]
    report.status(Output(stdout=buf, stderr=io.StringIO(), color=False), rows)
    lines = buf.getvalue().splitlines()
    assert lines[0].split() == ["ROBOT", "STATE", "VERSION", "DRIFT", "SERVICES", "LAST", "DEPLOY", "WHY"]
    assert "INTERRUPTED" in lines[1] and lines[1].endswith("guard reverts to 1.0.0-a in 42 s")
    assert "UNREACHABLE" in lines[2] and lines[2].endswith("unreachable: no answer")


def test_the_first_up_waits_for_the_lock_s_guard_start_instead_of_starting_a_second(tmp_path: Path) -> None:
    """A second container would take the first one's `started` mark for a restart."""
    env = fake_docker(tmp_path)
    slow = tmp_path / "bin" / "docker"
    slow.write_text('#!/bin/sh\necho "$*" >> "$DOCKER_LOG"\n[ "$1" != run ] || sleep 1\n')
    arm(env)                                               # returns at once; its start takes 1 s
    release = tmp_path / "r/demo/releases/1.1.0-b"
    release.mkdir(parents=True)
    (release / "images.txt").write_text("img:1\n")
    began = time.monotonic()
    out = sh(commands.up("~/r", "demo", "1.1.0-b", "v2", rearm=commands.rearm_arg("R1", 60)), env)
    assert out.returncode == 0, out.stderr
    runs = [c for c in (tmp_path / "docker.log").read_text().splitlines() if c.startswith("run ")]
    assert len(runs) == 1 and not [c for c in (tmp_path / "docker.log").read_text().splitlines()
                                   if c.startswith("rm ")]
    assert (tmp_path / "r/demo/.guard/container").exists() and time.monotonic() - began < 5


def test_a_guard_file_whose_container_is_gone_is_replaced_and_a_start_left_mid_way_bars_nothing(
        tmp_path: Path) -> None:
    # a `container` file that outlived its guard made every later run start none
    env = fake_docker(tmp_path)
    (tmp_path / "bin" / "docker").write_text('#!/bin/sh\necho "$*" >> "$DOCKER_LOG"\n'
                                             '[ "$1" != inspect ] || exit 1\n')     # no such container
    g = tmp_path / "r/demo/.guard"
    (g / ".starting").mkdir(parents=True)            # a start cut by a restart of the robot
    (g / "container").write_text("rosdeploy-guard-demo\n")
    assert arm(env).returncode == 0
    wait_started(tmp_path, 15)        # the left `.starting` is taken over after 10 s
    calls = (tmp_path / "docker.log").read_text().splitlines()
    assert any(c.startswith("inspect rosdeploy-guard-demo") for c in calls)
    assert any(c.startswith("run ") for c in calls), calls
    assert (g / "container").exists() and not (g / ".starting").exists()


def test_status_says_when_no_guard_container_runs_for_a_deploy_cut_off() -> None:
    # it said "guard reverts to … in 0 s" while no guard existed to do it
    cut = replace(state(running="1.2.0-bad-c", guard_text=ARMED, lock=OWNER), guard_container="none")
    word, reason = status_word(cut, {}, lock_alive=False)
    assert word == "INTERRUPTED" and "NO GUARD RUNS on the robot (its container: none)" in reason
    assert "guard reverts" not in reason
    running = replace(cut, guard_container="running")
    assert status_word(running, {}, lock_alive=False)[1].endswith("guard reverts to 1.0.0-a in 42 s")
