"""The command line under signals and broken output: Ctrl-C, SIGTERM and SIGHUP stop a command with
exit 130 and one --json document; an output that cannot be written (a reader that left, a full disk,
a closed stream) neither changes the exit code nor stops the work; a run record that cannot be saved
leaves the rollout's own result.

The robots never answer: a closed port on 127.0.0.1, or a "black hole" (a local socket that accepts
and never speaks, so ssh waits for its banner until connect_timeout).
"""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path
from typing import Iterator

import pytest

REPO = Path(__file__).resolve().parents[2]


class BlackHole:
    """A TCP listener on 127.0.0.1 that accepts and never writes; `reached` once a robot connected."""

    def __init__(self) -> None:
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(64)
        self.port = self.sock.getsockname()[1]
        self.reached = threading.Event()
        self.held: list[socket.socket] = []
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.held.append(conn)
            self.reached.set()

    def close(self) -> None:
        self.sock.close()
        for conn in self.held:
            conn.close()


@pytest.fixture
def hole() -> Iterator[BlackHole]:
    listener = BlackHole()
    yield listener
    listener.close()


def fleet(tmp: Path, robots: dict[str, int], connect_timeout: str = "2s") -> Path:
    """A fleet file of robots on 127.0.0.1 at the given ports, and the state folders in `tmp`."""
    (tmp / "inv").mkdir(exist_ok=True)
    (tmp / "kh").touch()
    hosts = "".join(f"        {name}: {{ansible_host: 127.0.0.1, ansible_port: {port}, ros_domain_id: {11 + i}, "
                    f"ansible_user: nobody}}\n" for i, (name, port) in enumerate(robots.items()))
    (tmp / "inv" / "hosts.yml").write_text("all:\n  children:\n    amr:\n      hosts:\n" + hosts)
    path = tmp / "fleet.yml"
    path.write_text(textwrap.dedent(f"""\
        project: probe
        inventory: inv
        registry: 127.0.0.1:1
        version: "1.0.0"
        ssh: {{known_hosts: kh, connect_timeout: {connect_timeout}, command_timeout: 30s, persist: 0}}
        services:
          driver: {{image: demo/driver, restart: always, user: "1000:1000", healthcheck: image}}
        rollout: {{waves: [1, "100%"]}}
        """))
    return path


def env(tmp: Path, **extra: str) -> dict[str, str]:
    values = {k: v for k, v in os.environ.items() if not k.startswith("ROSDEPLOY_")}
    values["PYTHONPATH"] = str(REPO) + os.pathsep + values.get("PYTHONPATH", "")
    values.update(ROSDEPLOY_RUNS_DIR=str(tmp / "runs"), ROSDEPLOY_PENDING_DIR=str(tmp / "pending"),
                  ROSDEPLOY_CONTROL_DIR=str(tmp / "control"))
    values.update(extra)
    return values


def start(tmp: Path, *argv: str, **kwargs) -> subprocess.Popen[str]:
    kwargs.setdefault("stdout", subprocess.PIPE)
    kwargs.setdefault("stderr", subprocess.PIPE)
    return subprocess.Popen([sys.executable, "-m", "rosdeploy", *argv], cwd=tmp, env=kwargs.pop("env", env(tmp)),
                            text=True, **kwargs)


def run(tmp: Path, *argv: str, **kwargs) -> subprocess.CompletedProcess[str]:
    kwargs.setdefault("timeout", 60)
    return subprocess.run([sys.executable, "-m", "rosdeploy", *argv], cwd=tmp, env=kwargs.pop("env", env(tmp)),
                          text=True, **kwargs)


def closed_pipe() -> int:
    """The write end of a pipe whose reader already left (`| head` once head is done)."""
    read, write = os.pipe()
    os.close(read)
    return write


def interrupted(proc: subprocess.Popen[str], hole: BlackHole, signum: int) -> tuple[int, str, str, float]:
    """Signal `proc` once it is waiting on the black hole; its exit code, output and how long it took."""
    assert hole.reached.wait(30), "no robot connection reached the black hole"
    time.sleep(0.3)
    proc.send_signal(signum)
    sent = time.monotonic()
    try:
        out, err = proc.communicate(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        pytest.fail(f"still running 15 s after signal {signum}")
    return proc.returncode, out, err, time.monotonic() - sent


def one_document(text: str) -> dict:
    return json.loads(text)


# ------------------------------------------------------- 1, 2: Ctrl-C, SIGTERM, SIGHUP

@pytest.mark.parametrize("command", ["status", "plan", "history"])
def test_ctrl_c_stops_a_read_only_command_at_once(tmp_path: Path, hole: BlackHole, command: str) -> None:
    path = fleet(tmp_path, {"b1": hole.port, "b2": hole.port}, connect_timeout="40s")
    proc = start(tmp_path, "--json", command, str(path))
    code, out, err, took = interrupted(proc, hole, signal.SIGINT)
    assert code == 130, err
    assert took < 10
    doc = one_document(out)
    assert (doc["ok"], doc["exit_code"], doc["error"]["kind"]) == (False, 130, "interrupted")


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_and_sighup_stop_a_read_only_command_like_ctrl_c(tmp_path: Path, hole: BlackHole,
                                                                 signum: signal.Signals) -> None:
    path = fleet(tmp_path, {"b1": hole.port}, connect_timeout="40s")
    proc = start(tmp_path, "--json", "status", str(path))
    code, out, err, took = interrupted(proc, hole, signum)
    assert code == 130, err
    doc = one_document(out)
    assert (doc["exit_code"], doc["error"]["kind"]) == (130, "interrupted")
    assert signal.Signals(signum).name in doc["error"]["message"]
    assert "Traceback" not in err


def test_sigterm_during_apply_brings_robots_to_a_safe_point_and_saves_the_run(tmp_path: Path,
                                                                               hole: BlackHole) -> None:
    path = fleet(tmp_path, {"b1": hole.port, "b2": hole.port}, connect_timeout="3s")
    proc = start(tmp_path, "--json", "apply", str(path), "--yes")
    code, out, err, _ = interrupted(proc, hole, signal.SIGTERM)
    assert code == 130, err
    doc = one_document(out)
    assert doc["interrupted"] is True
    assert (tmp_path / "runs" / doc["run_id"] / "result.json").is_file()


def test_sigterm_during_rollback_says_it_was_interrupted(tmp_path: Path, hole: BlackHole) -> None:
    # the brake's robots finished, but the run exited 0 or 3 as if nothing had stopped it
    path = fleet(tmp_path, {"b1": hole.port, "b2": hole.port}, connect_timeout="3s")
    proc = start(tmp_path, "--json", "rollback", str(path), "--yes", "--forks", "1")
    code, out, err, _ = interrupted(proc, hole, signal.SIGTERM)
    assert code == 130, err
    doc = one_document(out)
    assert doc["interrupted"] is True
    assert doc["hosts"][1]["outcome"] == "skipped", doc["hosts"]


def test_sigterm_while_the_parser_is_built_still_exits_130(tmp_path: Path) -> None:
    """A handler installed before anything else: SIGTERM as early as can be is still 130."""
    script = ("import os, signal, sys; from rosdeploy import cli; real = cli.build_parser\n"
              "def late():\n    os.kill(os.getpid(), signal.SIGTERM); return real()\n"
              "cli.build_parser = late; sys.exit(cli.main(['--json', 'version']))")
    done = subprocess.run([sys.executable, "-c", script], env=env(tmp_path), capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 130, done.stderr
    assert one_document(done.stdout)["error"]["kind"] == "interrupted"


# ------------------------------------------------------- 4, 5: output that cannot be written

def test_a_closed_pipe_keeps_plans_exit_code(tmp_path: Path) -> None:
    path = fleet(tmp_path, {"r1": 1, "r2": 2})
    done = run(tmp_path, "plan", str(path), stdout=closed_pipe(), stderr=subprocess.PIPE)
    assert done.returncode == 3, done.stderr
    assert "Traceback" not in done.stderr and "internal error" not in done.stderr


def test_a_piped_apply_whose_reader_left_finishes_and_keeps_its_records(tmp_path: Path) -> None:
    path = fleet(tmp_path, {"r1": 1, "r2": 2})
    done = run(tmp_path, "apply", str(path), "--yes", stdout=closed_pipe(), stderr=subprocess.PIPE)
    assert done.returncode == 4, done.stderr       # r1, the canary, unreachable: max_fail 0 stops the rollout
    records = list((tmp_path / "runs").glob("*/result.json"))
    assert len(records) == 1
    assert json.loads(records[0].read_text())["aborted"] is True
    assert list((tmp_path / "pending").glob("*.json"))


def test_an_error_document_that_cannot_be_written_keeps_the_input_error(tmp_path: Path) -> None:
    done = run(tmp_path, "--json", "validate", str(tmp_path / "missing.yml"), stdout=closed_pipe(),
               stderr=subprocess.PIPE)
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr


def test_a_full_disk_on_stdout_is_not_an_internal_error(tmp_path: Path) -> None:
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full here")
    path = fleet(tmp_path, {"r1": 1})
    with open("/dev/full", "w") as full:
        done = run(tmp_path, "plan", str(path), stdout=full, stderr=subprocess.PIPE)
    assert done.returncode == 3, done.stderr
    assert "internal error" not in done.stderr and "Traceback" not in done.stderr
    assert "standard output could not be written" in done.stderr


@pytest.mark.parametrize(("words", "redirect", "code"), [
    # `version >&-` printed nothing and exited 0; its output is its product: 1 (test_cli_seventh, defect 9)
    ("version", ">&-", 1), ('validate "$1"', "2>&-", 2), ('validate "$1"', ">&- 2>&-", 2)])
def test_closed_streams_keep_the_exit_code(tmp_path: Path, words: str, redirect: str, code: int) -> None:
    command = f'exec "$0" -m rosdeploy {words} {redirect}'
    done = subprocess.run(["sh", "-c", command, sys.executable, str(tmp_path / "missing.yml")], cwd=tmp_path,
                          env=env(tmp_path), capture_output=True, text=True, timeout=60)
    assert done.returncode == code, done.stderr
    assert "internal error" not in done.stderr


# ------------------------------------------------------- 6: records that cannot be written

def test_a_run_record_that_cannot_be_written_keeps_the_rollouts_result(tmp_path: Path) -> None:
    path = fleet(tmp_path, {"r1": 1, "r2": 2})
    (tmp_path / "runs").write_text("a file, not a folder")
    done = run(tmp_path, "--json", "apply", str(path), "--yes", capture_output=True)
    assert done.returncode == 4, done.stderr
    assert one_document(done.stdout)["aborted"] is True
    assert "could not write the run record" in done.stderr and str(tmp_path / "runs") in done.stderr
    assert "internal error" not in done.stderr


def test_a_pending_record_that_cannot_be_written_keeps_the_rollouts_result(tmp_path: Path) -> None:
    path = fleet(tmp_path, {"r1": 1, "r2": 2})
    (tmp_path / "pending").write_text("a file, not a folder")
    done = run(tmp_path, "apply", str(path), "--yes", capture_output=True)
    assert done.returncode == 4, done.stderr
    assert "could not write the pending record" in done.stderr and str(tmp_path / "pending") in done.stderr
    assert list((tmp_path / "runs").glob("*/result.json"))


# ------------------------------------------------------- 3: forked children end with their parent

@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="reads /proc")
def test_forked_children_end_when_their_parent_is_killed(tmp_path: Path) -> None:
    """SIGKILL leaves no handler to run: the children must still not go on working."""
    pids = tmp_path / "pids"
    script = textwrap.dedent(f"""\
        import os, sys, time
        from rosdeploy import forked
        forked.MIN_ITEMS = 4
        forked.os.sched_getaffinity = lambda pid: {{0, 1, 2}}
        def slow(n):
            with open({str(pids)!r}, "a") as f:
                f.write(f"{{os.getpid()}}\\n")
            time.sleep(0.05)
            return n
        list(forked.mapped(slow, list(range(2000))))
        """)
    proc = subprocess.Popen([sys.executable, "-c", script], env=env(tmp_path))
    deadline = time.monotonic() + 30
    while len(_children(pids, proc.pid)) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    children = _children(pids, proc.pid)
    assert len(children) >= 2, "the script forked no children"
    proc.kill()
    proc.wait()
    deadline = time.monotonic() + 5
    while any(_alive(pid) for pid in children) and time.monotonic() < deadline:
        time.sleep(0.05)
    alive = [pid for pid in children if _alive(pid)]
    for pid in alive:
        os.kill(pid, signal.SIGKILL)
    assert not alive


def _children(pids: Path, parent: int) -> set[int]:
    seen = {int(p) for p in pids.read_text().split()} if pids.exists() else set()
    return seen - {parent}


def _alive(pid: int) -> bool:
    """Running (a zombie waiting for init to reap it counts as ended)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


# ------------------------------------------------------- 8: vault edit with an unusable $EDITOR

@pytest.mark.parametrize("editor", ['"', " ", "'vi"])
def test_vault_edit_refuses_an_editor_it_cannot_parse_before_decrypting(tmp_path: Path, editor: str) -> None:
    secret, password = tmp_path / "vault.yml", tmp_path / "pw"
    secret.write_text("token: s3cr3t-value\n")
    password.write_text("pw\n")
    assert run(tmp_path, "vault", "encrypt", "--vault-password-file", str(password), str(secret),
               capture_output=True).returncode == 0
    before = secret.read_bytes()
    values = env(tmp_path, EDITOR=editor)
    values.pop("VISUAL", None)
    done = run(tmp_path, "vault", "edit", "--vault-password-file", str(password), str(secret), env=values,
               capture_output=True, stdin=subprocess.DEVNULL)
    assert done.returncode == 2, done.stderr
    assert "$EDITOR" in done.stderr and "internal error" not in done.stderr
    assert secret.read_bytes() == before


# ------------------------------------------------------- 9: render --out over a conflicting folder

def test_render_checks_every_conflict_before_moving_anything(tmp_path: Path) -> None:
    path = fleet(tmp_path, {"r1": 1, "r2": 2, "r3": 3})
    out = tmp_path / "out"
    assert run(tmp_path, "render", str(path), "--out", str(out), capture_output=True).returncode == 0
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    (out / "r2" / "compose.yml").unlink()
    (out / "r2" / "compose.yml").mkdir()
    del before[out / "r2" / "compose.yml"]
    path.write_text(path.read_text().replace('"1.0.0"', '"1.0.1"'))
    done = run(tmp_path, "render", str(path), "--out", str(out), capture_output=True)
    assert done.returncode == 2, done.stderr
    assert str(out / "r2" / "compose.yml") in done.stderr and ".rosdeploy-render-" not in done.stderr
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before   # nothing touched
    assert not [p for p in out.iterdir() if p.name.startswith(".rosdeploy-render-")]


# ------------------------------------------------------- 10: a FIFO as --from-bundle

def test_a_fifo_as_bundle_is_refused_not_waited_on(tmp_path: Path) -> None:
    path = fleet(tmp_path, {"r1": 1})
    os.mkfifo(tmp_path / "bundle.tar")
    try:
        done = run(tmp_path, "apply", str(path), "--yes", "--from-bundle", str(tmp_path / "bundle.tar"),
                   capture_output=True, timeout=20)
    except subprocess.TimeoutExpired:
        pytest.fail("apply --from-bundle FIFO waited for a writer")
    assert done.returncode == 2, done.stderr
    assert "not a regular file" in done.stderr


# ------------------------------------------------------- 11: counts as the fleet file takes them

def test_counts_on_the_command_line_are_the_fleet_files() -> None:
    import argparse

    from rosdeploy.cli.common import fail_limit, positive_int, waves
    assert fail_limit("1234567890") == 1234567890
    assert waves("1,1234567890") == (1, 1234567890)
    assert positive_int("10") == 10
    for word in ("\u0665", "1_0", "+5", " 5", "0", "2147483648"):
        with pytest.raises(argparse.ArgumentTypeError, match="whole number from 1 to"):
            positive_int(word)
    for word in ("\u0665", "1_0"):
        with pytest.raises(argparse.ArgumentTypeError, match="robot count"):
            fail_limit(word)
        with pytest.raises(argparse.ArgumentTypeError, match="robot count"):
            waves(word)


# ------------------------------------------------------- 12: a relative control folder

@pytest.mark.parametrize("setting", [{"ROSDEPLOY_CONTROL_DIR": "relative/x"}, {"HOME": "relative"}])
def test_a_relative_control_folder_is_refused_not_made_here(tmp_path: Path, setting: dict[str, str]) -> None:
    values = env(tmp_path, **setting)
    if "HOME" in setting:
        values.pop("ROSDEPLOY_CONTROL_DIR")
        values.pop("XDG_RUNTIME_DIR", None)
    work = tmp_path / "work"
    work.mkdir()
    done = run(work, "connections", env=values, capture_output=True)
    assert done.returncode == 0, done.stderr
    assert list(work.iterdir()) == []
    assert "relative path" in done.stdout + done.stderr
