"""The remote scripts, run for real by a local sh against a temp dir (no SSH, no robot)."""
from __future__ import annotations

import io
import itertools
import json
import os
import re
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest

from rosdeploy import commands, ready, restarts


def run_local(cmd: commands.Command, home: Path) -> subprocess.CompletedProcess:
    """Run the exact wire string through a login-like shell, as sshd would."""
    env = {"HOME": str(home), "PATH": os.environ["PATH"]}
    return subprocess.run(["sh", "-c", cmd.wire()], input=cmd.stdin, capture_output=True, env=env)


def tarball(files: dict[str, tuple[str, int]]) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tar:
        for name, (content, mode) in files.items():
            data = content.encode()
            info = tarfile.TarInfo(name)
            info.size, info.mode = len(data), mode
            tar.addfile(info, io.BytesIO(data))
    return buf.getvalue()


def test_hostile_values_stay_data_not_code(tmp_path: Path) -> None:
    marker = tmp_path / "pwned"
    evil = f"x; touch {marker}; $(touch {marker}) `touch {marker}`"
    cmd = commands.record("~/rosdeploy", "demo", {"reason": evil, "quote": "it's \"quoted\"\n"})
    assert evil not in cmd.argv[2], "values must never be spliced into the script text"
    assert run_local(cmd, tmp_path).returncode == 0
    assert not marker.exists()
    line = (tmp_path / "rosdeploy/demo/history.jsonl").read_text()
    assert json.loads(line)["reason"] == evil


def test_tilde_root_resolves_to_the_ssh_users_home(tmp_path: Path) -> None:
    out = run_local(commands.state("~/deploy", "demo"), tmp_path)
    sections = commands.parse_sections(out.stdout.decode())
    assert sections["dir"] == f"{tmp_path}/deploy/demo"
    assert not (tmp_path / "deploy").exists(), "state must not create anything"


def test_lock_is_exclusive_and_unlock_needs_the_token(tmp_path: Path) -> None:
    first = run_local(commands.lock("~/r", "demo", {"run": "run-A", "by": "alice@ops"}), tmp_path)
    assert first.returncode == 0 and first.stdout.strip() == b"locked"
    second = run_local(commands.lock("~/r", "demo", {"run": "run-B", "by": "bob@ops"}), tmp_path)
    assert second.returncode == 3
    assert json.loads(second.stdout.decode().replace("held ", "", 1))["by"] == "alice@ops"
    run_local(commands.unlock("~/r", "demo", "run-B"), tmp_path)
    assert (tmp_path / "r/demo/.lock").is_dir(), "another run's token must not release the lock"
    run_local(commands.unlock("~/r", "demo", "run-A"), tmp_path)
    assert not (tmp_path / "r/demo/.lock").exists()


def test_break_lock_takes_a_stale_lock(tmp_path: Path) -> None:
    run_local(commands.lock("~/r", "demo", {"run": "dead"}), tmp_path)
    broke = run_local(commands.lock("~/r", "demo", {"run": "new"}, break_stale=True), tmp_path)
    assert broke.returncode == 0
    assert json.loads((tmp_path / "r/demo/.lock/owner").read_text())["run"] == "new"


def test_a_dead_runs_lock_is_taken_over_and_only_that_lock(tmp_path: Path) -> None:
    run_local(commands.lock("~/r", "demo", {"run": "run-A"}), tmp_path)
    # run-B's lock is not the dead run's: it stays, and the caller learns who holds it
    held = run_local(commands.lock("~/r", "demo", {"run": "run-C"}, dead_run="run-B"), tmp_path)
    assert held.returncode == 3 and b'"run": "run-A"' in held.stdout
    taken = run_local(commands.lock("~/r", "demo", {"run": "run-C"}, dead_run="run-A"), tmp_path)
    assert taken.returncode == 0 and taken.stdout.strip() == b"locked"
    assert json.loads((tmp_path / "r/demo/.lock/owner").read_text())["run"] == "run-C"
    assert not (tmp_path / "r/demo/.lock-break").exists()
    # a second run that also found run-A dead must not remove run-C's lock
    again = run_local(commands.lock("~/r", "demo", {"run": "run-D"}, dead_run="run-A"), tmp_path)
    assert again.returncode == 3 and json.loads((tmp_path / "r/demo/.lock/owner").read_text())["run"] == "run-C"


def test_a_take_over_in_progress_keeps_other_breakers_out(tmp_path: Path) -> None:
    run_local(commands.lock("~/r", "demo", {"run": "run-A"}), tmp_path)
    (tmp_path / "r/demo/.lock-break").mkdir()         # another run is taking over right now
    out = run_local(commands.lock("~/r", "demo", {"run": "run-C"}, dead_run="run-A"), tmp_path)
    assert out.returncode == 3 and json.loads((tmp_path / "r/demo/.lock/owner").read_text())["run"] == "run-A"


def test_upload_lands_whole_with_modes_and_leaves_no_temp(tmp_path: Path) -> None:
    data = tarball({"compose.yml": ("services: {}\n", 0o644), ".env": ("TOKEN=s3cret\n", 0o600)})
    assert run_local(commands.upload("~/r", "demo", "1.0.0-abc", data), tmp_path).returncode == 0
    release = tmp_path / "r/demo/releases/1.0.0-abc"
    assert (release / "compose.yml").read_text() == "services: {}\n"
    assert (release / ".env").stat().st_mode & 0o777 == 0o600
    assert [p.name for p in (tmp_path / "r/demo/releases").iterdir()] == ["1.0.0-abc"]


def test_cut_upload_never_becomes_a_release(tmp_path: Path) -> None:
    data = tarball({"compose.yml": ("x" * 5000, 0o644)})[:700]   # connection cut mid-stream
    run_local(commands.upload("~/r", "demo", "1.1.0-def", data), tmp_path)
    assert not (tmp_path / "r/demo/releases/1.1.0-def").exists()


A, B, C, D = (f"{v}-{v * 12}" for v in "abcd")   # release ids: <version>-<12 hex digits>


def test_activate_switches_current_and_prunes_all_but_keep(tmp_path: Path) -> None:
    for i, rel in enumerate([A, B, C, D]):
        run_local(commands.upload("~/r", "demo", rel, tarball({"images.txt": (f"img:{rel}\n", 0o644)})), tmp_path)
        out = run_local(commands.finish("~/r", "demo", rel, {"release": rel, "result": "active"}, keep=3), tmp_path)
        assert out.returncode == 0, out.stderr
        os.utime(tmp_path / f"r/demo/releases/{rel}", (1000 + i, 1000 + i))   # mtime order = activation order
    demo = tmp_path / "r/demo"
    assert os.readlink(demo / "current") == "releases/" + D
    assert sorted(p.name for p in (demo / "releases").iterdir()) == [B, C, D]
    assert [json.loads(line)["release"] for line in (demo / "history.jsonl").read_text().splitlines()] == \
        [A, B, C, D]


def test_rollback_target_is_not_pruned_after_reactivation(tmp_path: Path) -> None:
    for i, rel in enumerate([A, B, C]):
        run_local(commands.upload("~/r", "demo", rel, tarball({"images.txt": ("", 0o644)})), tmp_path)
        os.utime(tmp_path / f"r/demo/releases/{rel}", (1000 + i, 1000 + i))
    run_local(commands.finish("~/r", "demo", A, {"release": A}, keep=3), tmp_path)  # rolled back to A
    run_local(commands.upload("~/r", "demo", D, tarball({"images.txt": ("", 0o644)})), tmp_path)
    run_local(commands.finish("~/r", "demo", D, {"release": D}, keep=3), tmp_path)
    kept = sorted(p.name for p in (tmp_path / "r/demo/releases").iterdir())
    assert A in kept, "the release that ran just before must survive pruning"
    assert kept == [A, C, D]


def test_pruning_leaves_names_that_are_not_releases_and_splits_none(tmp_path: Path) -> None:
    # an operator's `cp -a X "X copy"`: split on its space, the prune deleted X itself
    first, second = "1.0.0-" + "a" * 12, "1.1.0-" + "b" * 12
    for i, rel in enumerate([first, second]):
        run_local(commands.upload("~/r", "demo", rel, tarball({"images.txt": ("", 0o644)})), tmp_path)
        os.utime(tmp_path / f"r/demo/releases/{rel}", (1000 + i, 1000 + i))
    copy = tmp_path / f"r/demo/releases/{first} copy"
    copy.mkdir()
    os.utime(copy, (10, 10))
    out = run_local(commands.finish("~/r", "demo", first, {"release": first}, keep=2), tmp_path)
    assert out.returncode == 0, out.stderr
    assert sorted(p.name for p in (tmp_path / "r/demo/releases").iterdir()) == [first, f"{first} copy", second]


def test_a_record_after_a_line_cut_short_starts_a_line_of_its_own(tmp_path: Path) -> None:
    history = tmp_path / "r/demo/history.jsonl"
    history.parent.mkdir(parents=True)
    history.write_text('{"release": "1.0.0-aaaaaaaaaaaa", "result": "act')       # a power loss mid-write
    run_local(commands.record("~/r", "demo", {"event": "deploy", "result": "failed"}), tmp_path)
    run_local(commands.record("~/r", "demo", {"event": "rollback", "result": "active"}), tmp_path)
    lines = history.read_text().splitlines()
    assert lines[0].endswith('"act') and [json.loads(x)["event"] for x in lines[1:]] == ["deploy", "rollback"]


def test_state_reports_missing_devices(tmp_path: Path) -> None:
    present = tmp_path / "ttyUSB0"
    present.write_text("")
    out = run_local(commands.state("~/r", "demo", (str(present), "/dev/robot/nope")), tmp_path)
    sections = commands.parse_sections(out.stdout.decode())
    assert sections["devices"] == "missing /dev/robot/nope"


@pytest.mark.parametrize("builder", [
    lambda: commands.up("~/r", "p; rm -rf /", "1.0.0-x", "v2"),
    lambda: commands.pull(("registry/img:1.0.0; reboot",)),
    lambda: commands.lock("~/r", "demo", {"by": "$(reboot)"}),
])
def test_every_builder_passes_values_as_arguments(builder) -> None:
    cmd = builder()
    assert cmd.argv[:2] == ("sh", "-c") and cmd.argv[3] == commands.PROG
    script_text = cmd.argv[2]
    assert "reboot" not in script_text and "rm -rf /" not in script_text


def test_upload_prepares_log_dirs_a_non_root_container_can_write(tmp_path: Path) -> None:
    data = tarball({"compose.yml": ("services: {}\n", 0o644)})
    run_local(commands.upload("~/r", "demo", "1.0.0-abc", data, ("driver", "perception")), tmp_path)
    for service in ("driver", "perception"):
        mode = (tmp_path / f"r/demo/logs/{service}").stat().st_mode & 0o7777
        assert mode == 0o1777


def test_locked_state_takes_the_lock_then_reads_the_state_under_it(tmp_path: Path) -> None:
    env, log = fake_docker(tmp_path)                       # a docker that logs any call
    releases = tmp_path / "r/demo/releases"
    (releases / "1.0.0-x/manifest.json").write_text('{"services": ["driver"]}\n')
    (releases / "1.1.0-y").mkdir()                         # a release without a manifest
    (tmp_path / "r/demo/current").symlink_to("releases/1.1.0-y")
    (tmp_path / "r/demo/history.jsonl").write_text('{"release": "1.1.0-y", "compose": "v2"}\n')
    cmd = commands.locked_state("~/r", "demo", {"run": "run-A"})
    out = subprocess.run(["sh", "-c", cmd.wire()], capture_output=True, env=env, text=True)
    assert out.returncode == 0 and out.stdout.split("\n@@", 1)[0].strip() == "locked"
    sections = commands.parse_sections(out.stdout)
    assert sections["current"].endswith("releases/1.1.0-y")
    assert json.loads(sections["lock"])["run"] == "run-A"              # read under the lock it took
    assert json.loads(sections["manifest 1.0.0-x"]) == {"services": ["driver"]}
    assert "manifest 1.1.0-y" not in sections and "containers" not in sections
    assert not log.exists(), "a rollback's first round trip starts no docker CLI"
    # another run holding the lock: exit 3, its owner first, and the state all the same
    held = subprocess.run(["sh", "-c", commands.locked_state("~/r", "demo", {"run": "run-B"}).wire()],
                          capture_output=True, env=env, text=True)
    assert held.returncode == 3
    assert json.loads(held.stdout.split("\n@@", 1)[0].replace("held ", "", 1))["run"] == "run-A"
    assert commands.parse_sections(held.stdout)["current"].endswith("releases/1.1.0-y")



def test_locked_state_of_a_robot_with_nothing_deployed_creates_nothing(tmp_path: Path) -> None:
    out = run_local(commands.locked_state("~/r", "demo", {"run": "run-A"}), tmp_path)
    assert out.returncode == 0 and commands.parse_sections(out.stdout.decode())["releases"] == ""
    assert not (tmp_path / "r").exists()


def test_a_lock_that_cannot_be_created_is_an_error_not_held(tmp_path: Path) -> None:
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "demo").write_text("a file where the project dir should be")
    out = run_local(commands.lock("~/r", "demo", {"run": "A"}), tmp_path)
    assert out.returncode not in (0, 3)
    assert b"cannot create" in out.stderr


def fake_docker(tmp_path: Path) -> tuple[dict, Path]:
    """A `docker` on PATH that logs each call's argv (one line) and answers `ps -aq`."""
    bin_dir, log = tmp_path / "bin", tmp_path / "docker.log"
    bin_dir.mkdir()
    (bin_dir / "docker").write_text('#!/bin/sh\necho "$*" >> "$DOCKER_LOG"\n'
                                    'case "$1 $2" in "ps -aq"|"ps -q") echo c1; echo c2;; esac\n'
                                    '[ "$*" != "$DOCKER_FAIL" ] || exit 5\n'
                                    'if [ "$1" = inspect ]; then shift 2; for c in "$@"; do\n'
                                    '  printf \'{"id": "%s", "name": "demo-%s", "status": "running"}\\n\' "$c" "$c"\n'
                                    'done; fi\n')
    (bin_dir / "docker").chmod(0o755)
    env = {"HOME": str(tmp_path), "PATH": f"{bin_dir}:{os.environ['PATH']}", "DOCKER_LOG": str(log)}
    (tmp_path / "r/demo/releases/1.0.0-x").mkdir(parents=True)
    return env, log


LIST_PROJECT = ["ps -aq --filter label=com.docker.compose.project=demo", "inspect c1 c2"]


@pytest.mark.parametrize("kwargs,expected", [
    ({}, ["compose -p demo -f compose.yml up -d --remove-orphans", *LIST_PROJECT]),
    # one call per service, in the caller's order, none waiting on depends_on
    ({"services": ("driver", "perception")},
     ["compose -p demo -f compose.yml up -d --remove-orphans --no-deps driver",
      "compose -p demo -f compose.yml up -d --remove-orphans --no-deps perception", *LIST_PROJECT]),
    # create all, then a `docker start` of every created or stopped container, all at once;
    # those are the project's containers then, so they are inspected without listing again
    ({"together": True},
     ["ps -q --filter label=com.docker.compose.project=demo", "stop c1 c2",
      "compose -p demo -f compose.yml up --no-start --remove-orphans",
      "ps -aq --filter label=com.docker.compose.project=demo --filter status=created --filter status=exited",
      "start c1", "start c2", "inspect c1 c2"]),
])
def test_up_modes_run_these_docker_calls(tmp_path: Path, kwargs: dict, expected: list[str]) -> None:
    env, log = fake_docker(tmp_path)
    cmd = commands.up("~/r", "demo", "1.0.0-x", "v2", **kwargs)
    out = subprocess.run(["sh", "-c", cmd.wire()], capture_output=True, env=env)
    assert out.returncode == 0, out.stderr
    calls = [re.sub(r"^inspect --format .* (c1 c2)$", r"inspect \1", c) for c in log.read_text().splitlines()]
    at = [i for i, c in enumerate(calls) if c.startswith("start ")]    # parallel: in any order
    for i, call in zip(at, sorted(calls[i] for i in at), strict=True):
        calls[i] = call
    assert calls == expected


def test_up_lists_the_started_containers_for_the_gate(tmp_path: Path) -> None:
    env, _ = fake_docker(tmp_path)
    out = subprocess.run(["sh", "-c", commands.up("~/r", "demo", "1.0.0-x", "v2", together=True).wire()],
                         capture_output=True, env=env, text=True)
    listed = commands.started_containers(out.stdout)
    assert [(c["id"], c["name"]) for c in listed] == [("c1", "demo-c1"), ("c2", "demo-c2")]
    assert commands.started_containers("Container demo-driver-1  Started\n") is None   # nothing listed


def test_a_failed_up_lists_nothing_so_its_error_stays_the_last_line(tmp_path: Path) -> None:
    env, log = fake_docker(tmp_path)
    cmd = commands.up("~/r", "demo", "1.0.0-x", "v2", together=True)
    out = subprocess.run(["sh", "-c", cmd.wire()], capture_output=True, text=True,
                         env={**env, "DOCKER_FAIL": "compose -p demo -f compose.yml up --no-start --remove-orphans"})
    assert out.returncode == 5
    assert "@@started" not in out.stdout and not any(c.startswith("inspect") for c in log.read_text().splitlines())


def test_a_container_that_fails_to_start_fails_the_together_start(tmp_path: Path) -> None:
    env, log = fake_docker(tmp_path)
    cmd = commands.up("~/r", "demo", "1.0.0-x", "v2", together=True)
    out = subprocess.run(["sh", "-c", cmd.wire()], capture_output=True, env={**env, "DOCKER_FAIL": "start c2"})
    assert out.returncode == 5
    assert "start c1" in log.read_text().splitlines()     # the others still started


def test_up_of_a_missing_release_changes_nothing(tmp_path: Path) -> None:
    env, log = fake_docker(tmp_path)
    cmd = commands.up("~/r", "demo", "2.0.0-y", "v2", together=True)
    out = subprocess.run(["sh", "-c", cmd.wire()], capture_output=True, env=env)
    assert out.returncode == 4 and b"release 2.0.0-y is not on this robot" in out.stderr
    assert not log.exists()


@pytest.mark.parametrize("test,argv", [
    (("CMD", "/opt/check", "--fast"), ("docker", "exec", "c1", "/opt/check", "--fast")),
    (("CMD-SHELL", "curl -f localhost || exit 1"),
     ("docker", "exec", "c1", "/bin/sh", "-c", "curl -f localhost || exit 1")),
    (("NONE",), None),
    ((), None),
])
def test_health_test_runs_the_containers_own_check(test: tuple, argv: tuple | None) -> None:
    cmd = commands.health_test("c1", test, 3.0)
    assert (cmd.argv if cmd else None) == argv


def _watch_in_container(tmp_path, test: tuple, window: float = 0.3, every: float = 0.05) -> int:
    """health_watch's loop run by a real sh, as `docker exec` would run it in the container."""
    cmd = commands.health_watch("c1", test, 3.0, window, every)
    assert cmd is not None and cmd.argv[:4] == ("docker", "exec", "c1", "/bin/sh")
    return subprocess.run(cmd.argv[3:], cwd=tmp_path, capture_output=True, timeout=10).returncode


def test_health_watch_loops_until_the_check_passes(tmp_path) -> None:
    # passes on the third try: each try appends a line, the check wants three
    check = "echo x >> tries; [ $(wc -l < tries) -ge 3 ]"
    assert _watch_in_container(tmp_path, ("CMD-SHELL", check)) == 0
    assert (tmp_path / "tries").read_text().count("x") == 3


def test_health_watch_gives_up_with_3_after_its_tries(tmp_path) -> None:
    assert _watch_in_container(tmp_path, ("CMD", "sh", "-c", "echo x >> tries; exit 1")) == 3
    assert (tmp_path / "tries").read_text().count("x") == 6      # window 0.3 s / every 0.05 s


def test_health_watch_passes_cmd_arguments_as_they_are(tmp_path) -> None:
    assert _watch_in_container(tmp_path, ("CMD", "test", "a b", "=", "a b")) == 0
    assert commands.health_watch("c1", ("NONE",), 3.0, 1.0, 0.5) is None


def test_health_watch_spaces_a_slow_check_by_its_own_duration(tmp_path) -> None:
    # each try takes ~1 s: with window 2 s every 0.5 s (4 tries) the 1 s try and the 1 s
    # pause after it use up all 4 tries' worth, so it runs once, not 4 times back to back
    check = "echo x >> tries; sleep 1.05; exit 1"
    assert _watch_in_container(tmp_path, ("CMD-SHELL", check), window=2.0, every=0.5) == 3
    assert (tmp_path / "tries").read_text().count("x") == 1


def test_health_watch_counts_a_sub_second_check_by_its_real_duration(tmp_path) -> None:
    # 0.3 s per try, window 2 s every 0.1 s (20 tries): each try and its pause use 4, so
    # it runs 5 times, 0.4 s apart (not spaced by its own duration: it is not whole
    # seconds). A clock in whole seconds calls a try that crosses a second's boundary 1 s
    # long, which here used up the window by the third try at the latest.
    check = "read -r t _ </proc/uptime; echo $t >> tries; sleep 0.3; exit 1"
    assert _watch_in_container(tmp_path, ("CMD-SHELL", check), window=2.0, every=0.1) == 3
    starts = [float(t) for t in (tmp_path / "tries").read_text().split()]
    assert len(starts) == 5
    assert all(0.35 <= b - a < 0.6 for a, b in itertools.pairwise(starts))


ENGINE_API_LIST = [{"Id": "abc", "Names": ["/demo-driver-1"], "Image": "r:5000/demo/driver:1.0.0",
                    "State": "running", "Status": "Up 3 minutes (healthy)",
                    "Labels": {"com.docker.compose.service": "driver", "com.docker.compose.version": "2.40.3",
                               "com.docker.compose.project.working_dir": "/h/r/demo/releases/1.0.0-x"}}]
PS_LINE = {"name": "demo-driver-1", "service": "driver", "image": "r:5000/demo/driver:1.0.0", "status": "running",
           "ps_status": "Up 3 minutes (healthy)", "workdir": "/h/r/demo/releases/1.0.0-x", "compose": "2.40.3"}


def test_the_engine_api_list_parses_to_what_docker_ps_gives() -> None:
    assert commands.parse_containers(json.dumps(ENGINE_API_LIST)) == commands.parse_containers(json.dumps(PS_LINE))


def _state_with(tmp_path: Path, docker_host: str | None, curl_exit: int = 0) -> tuple[list[str], tuple[dict, ...]]:
    """The quick state script with a fake curl and docker on PATH; (tools called, containers read)."""
    import socket
    import tempfile
    tmp_path.mkdir(exist_ok=True)
    env, log = fake_docker(tmp_path)
    sock_path = Path(tempfile.mkdtemp(prefix="rd")) / "docker.sock"   # AF_UNIX paths are short
    server = socket.socket(socket.AF_UNIX)
    server.bind(str(sock_path))
    (tmp_path / "bin" / "curl").write_text(
        f"#!/bin/sh\necho \"curl $*\" >> \"$DOCKER_LOG\"\n[ {curl_exit} = 0 ] || exit {curl_exit}\n"
        f"echo '{json.dumps(ENGINE_API_LIST)}'\n")
    (tmp_path / "bin" / "curl").chmod(0o755)
    if docker_host is not None:
        env["DOCKER_HOST"] = docker_host.replace("SOCK", str(sock_path))
    try:
        out = subprocess.run(["sh", "-c", commands.state("~/r", "demo", full=False).wire()],
                             capture_output=True, env=env, text=True)
    finally:
        server.close()
    calls = [line.split()[0] if line.startswith("curl") else "docker" for line in log.read_text().splitlines()]
    return calls, commands.parse_containers(commands.parse_sections(out.stdout).get("containers", ""))


def test_state_reads_containers_through_the_engine_api_when_the_cli_would_use_the_socket(tmp_path: Path) -> None:
    calls, containers = _state_with(tmp_path, "unix://SOCK")
    assert calls == ["curl"] and containers[0]["service"] == "driver"


def test_state_falls_back_to_docker_ps(tmp_path: Path) -> None:
    assert _state_with(tmp_path / "a", "unix://SOCK", curl_exit=7)[0] == ["curl", "docker"]   # curl failed
    assert _state_with(tmp_path / "b", "tcp://10.0.0.2:2376")[0] == ["docker"]              # not a local socket
    (tmp_path / "c" / ".docker").mkdir(parents=True)
    (tmp_path / "c" / ".docker" / "config.json").write_text('{"currentContext": "robot-lab"}')
    assert _state_with(tmp_path / "c", "unix://SOCK")[0] == ["docker"]                       # a docker context


def test_manifest_reads_a_kept_release_and_is_empty_for_a_missing_one(tmp_path: Path) -> None:
    release = tmp_path / "r" / "demo" / "releases" / "1.0.0-aaa"
    release.mkdir(parents=True)
    (release / "manifest.json").write_text('{"version": "1.0.0",\n "services": ["driver"]}')
    out = run_local(commands.manifest("~/r", "demo", "1.0.0-aaa"), tmp_path)
    assert out.returncode == 0 and json.loads(out.stdout) == {"version": "1.0.0", "services": ["driver"]}
    gone = run_local(commands.manifest("~/r", "demo", "9.9.9-zzz"), tmp_path)
    assert gone.returncode == 0 and gone.stdout == b""


# ------------------------------------------------------------ the scripts are the files

SHIPPED = Path(commands.__file__).parent           # rosdeploy/


def _script_lines(path: Path) -> list[str]:
    """A script file's own lines as load() sends them: no opening comment block, no
    shellcheck directive, no include."""
    lines = path.read_text(encoding="utf-8").splitlines()
    opening = next((i for i, line in enumerate(lines) if not line.strip()), len(lines))
    return [line for i, line in enumerate(lines)
            if not (i < opening and line.startswith("#")) and not line.lstrip().startswith("# shellcheck ")
            and not re.fullmatch(r"\. \./_[a-z0-9-]+\.sh", line)]


def _includes(path: Path) -> list[str]:
    return re.findall(r"(?m)^\. \./(_[a-z0-9-]+\.sh)$", path.read_text(encoding="utf-8"))


def test_every_shell_file_of_the_package_is_loaded_by_something() -> None:
    import importlib
    import pkgutil

    import rosdeploy
    for module in pkgutil.walk_packages(rosdeploy.__path__, "rosdeploy."):
        # not the demo image's own code (rclpy), nor `python -m rosdeploy` (it runs the CLI)
        if not module.name.startswith("rosdeploy.sim.images") and not module.name.endswith("__main__"):
            importlib.import_module(module.name)
    strings = {value for name, mod in sys.modules.items() if name.startswith("rosdeploy")
               for value in vars(mod).values() if isinstance(value, str)}
    unused = []
    for path in sorted(SHIPPED.rglob("*.sh")):
        if path.parent == commands.SCRIPTS:
            loaded = path.name in commands.LOADED
        else:   # read whole by its module (guard.sh, images/pull.sh)
            loaded = path.read_text(encoding="utf-8") in strings
        if not loaded and "sim/images" not in path.as_posix():
            unused.append(str(path.relative_to(SHIPPED)))
    assert unused == []


@pytest.mark.parametrize("name", sorted(p.name for p in commands.SCRIPTS.glob("*.sh")))
def test_a_script_sends_its_file_and_each_fragment_once(name: str) -> None:
    sent = commands.load(name).splitlines()
    parts, todo = [], [name]          # the file and every fragment it includes, also through another
    while todo:
        part = todo.pop(0)
        if part not in parts:
            parts.append(part)
            todo[:0] = _includes(commands.SCRIPTS / part)
    for part in parts:                # each file's lines, in its order ...
        assert _in_order(_script_lines(commands.SCRIPTS / part), sent), part
    # ... and nothing else, nothing twice
    assert sum(len(_script_lines(commands.SCRIPTS / part)) for part in parts) == len(sent)


def _in_order(needles: list[str], haystack: list[str]) -> bool:
    rest = iter(haystack)
    return all(any(line == other for other in rest) for line in needles)


@pytest.mark.parametrize("build,name", [
    (lambda: commands.state("~/r", "p"), "state.sh"),
    (lambda: commands.lock("~/r", "p", {"run": "x"}), "lock.sh"),
    (lambda: commands.locked_state("~/r", "p", {"run": "x"}), "locked-state.sh"),
    (lambda: commands.unlock("~/r", "p", "x"), "unlock.sh"),
    (lambda: commands.upload("~/r", "p", "1", b""), "upload.sh"),
    (lambda: commands.rearm("~/r", "p", "x 5"), "rearm.sh"),
    (lambda: commands.pull(("img:1",)), "pull.sh"),
    (lambda: commands.up("~/r", "p", "1", "v2"), "up.sh"),
    (lambda: commands.down("~/r", "p", "1", "v2"), "down.sh"),
    (lambda: commands.containers("p"), "containers.sh"),
    (lambda: commands.ros_probe("c", "print()", {}, 5.0), "ros-probe.sh"),
    (lambda: commands.finish("~/r", "p", "1", {}, 3), "finish.sh"),
    (lambda: commands.record("~/r", "p", {}), "record.sh"),
    (lambda: commands.manifest("~/r", "p", "1"), "manifest.sh"),
    (lambda: commands.release_files("~/r", "p", "1", ("a",), ()), "release-files.sh"),
    (lambda: restarts.link_store("~/r", "p", "1"), "link-store.sh"),
    (lambda: ready.lock_command("~/lock"), "app-lock.sh"),
])
def test_each_builder_sends_its_file_as_it_is_now(build, name: str) -> None:
    argv = build().argv
    assert argv[:2] == ("sh", "-c") and argv[2] == commands.load(name) and argv[3] == commands.PROG


def test_the_health_watch_sends_its_file() -> None:
    cmd = commands.health_watch("c1", ("CMD", "true"), timeout=1.0, window=4.0, every=1.0)
    assert cmd is not None and cmd.argv[4:6] == ("-c", commands.load("health-watch.sh"))
    assert "health-watch.sh" in commands.LOADED


def test_state_sends_the_last_history_lines_and_the_older_ones_a_rollback_needs(tmp_path: Path) -> None:
    # only the last 50 lines went: a run of failed deploys hid the release to go back to
    first, second, bad = "1.0.0-" + "a" * 12, "1.1.0-" + "b" * 12, "1.2.0-" + "c" * 12
    demo = tmp_path / "r/demo"
    for rel in (first, second):
        (demo / "releases" / rel).mkdir(parents=True)
    lines = [{"release": "0.9.0-" + "9" * 12, "result": "active"}, {"release": first, "result": "active"},
             {"release": second, "result": "active"}]
    lines += [{"release": bad, "result": "failed"}, {"release": second, "rolled_back_from": bad,
                                                     "result": "active"}] * 40
    (demo / "history.jsonl").write_text("".join(json.dumps(e) + "\n" for e in lines))
    sections = commands.parse_sections(run_local(commands.state("~/r", "demo", ()), tmp_path).stdout.decode())
    assert [json.loads(x) for x in sections["history"].splitlines()] == lines[-50:]
    assert [json.loads(x) for x in sections["gates"].splitlines()] == [lines[1]], "kept releases' lines only"


def test_the_brake_finishes_its_start_when_its_channel_closes(tmp_path: Path) -> None:
    """The controller (or its link) died while the brake stopped what ran: the channel is gone,
    and compose's first line of output used to kill the script there (SIGPIPE), leaving the
    robot running nothing until the guard's deadline."""
    env, log = fake_docker(tmp_path)
    docker = tmp_path / "bin/docker"
    docker.write_text(docker.read_text().replace(
        '#!/bin/sh\n', '#!/bin/sh\n[ "$1" != stop ] || sleep 0.5\n'
                       '[ "$1" != compose ] || echo " Container demo-driver-1  Created"\n', 1))
    cmd = commands.up("~/r", "demo", "1.0.0-x", "v2", together=True)
    brake = subprocess.Popen(["sh", "-c", cmd.wire()], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    brake.stdout.close()                                   # the channel closes while `docker stop` runs
    brake.stderr.close()
    brake.wait(timeout=20)
    calls = log.read_text().splitlines()
    assert "start c1" in calls and "start c2" in calls, calls
