"""The CLI contract, seventh pass: one JSON document with `ok` and `exit_code` on every outcome,
a lost stdout fails the commands whose product it is, interrupts during connect end at once,
completion offers files and the right words, and messages stay one line each, unmasked where
masking would garble or give a secret away."""
from __future__ import annotations

import dataclasses
import json
import os
import pty
import select
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Callable, Iterator

import pytest
from test_cli import REPO, _env, lab_args, rosdeploy
from test_cli_signals import BlackHole, fleet, interrupted, start


@pytest.fixture
def hole() -> Iterator[BlackHole]:
    listener = BlackHole()
    yield listener
    listener.close()


def one_document(text: str) -> dict:
    """The whole of stdout is one JSON document."""
    return json.loads(text)


# ------------------------------------------------------- 1: --json and a declined confirmation

@pytest.mark.parametrize("command", ["apply", "rollback"])
def test_declining_under_json_prints_one_document_that_says_so(tmp_path: Path, command: str) -> None:
    master, slave = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "rosdeploy", "--json", command, *lab_args(tmp_path)], cwd=REPO,
                            env=_env(), stdin=slave, stdout=subprocess.PIPE, stderr=slave, text=True)
    os.close(slave)
    seen, deadline = b"", time.monotonic() + 60
    while b"[y/N]" not in seen and time.monotonic() < deadline:
        if select.select([master], [], [], 1)[0]:
            seen += os.read(master, 4096)
    os.write(master, b"n\n")
    out, _ = proc.communicate(timeout=60)
    os.close(master)
    doc = one_document(out)
    assert proc.returncode == 5
    assert (doc["ok"], doc["exit_code"], doc["error"]["kind"]) == (False, 5, "declined")


# ------------------------------------------------------- 8: every document has ok and exit_code

def unreachable_fleet(tmp: Path) -> Path:
    return fleet(tmp, {"r1": 1, "r2": 2})


@pytest.mark.parametrize("command", ["status", "plan", "history"])
def test_a_failing_reports_document_has_ok_and_exit_code(tmp_path: Path, command: str) -> None:
    done = run_in(tmp_path, "--json", command, str(unreachable_fleet(tmp_path)))
    doc = one_document(done.stdout)
    assert done.returncode == 3, done.stderr
    assert (doc["ok"], doc["exit_code"]) == (False, 3) and len(doc["robots"]) == 2


@pytest.mark.parametrize("argv", [["--json", "version"], ["--json", "connections"], ["--version", "--json"]])
def test_a_succeeding_document_has_ok_and_exit_code(argv: list[str]) -> None:
    done = rosdeploy(*argv)
    doc = one_document(done.stdout)
    assert done.returncode == 0, done.stderr
    assert (doc["ok"], doc["exit_code"]) == (True, 0)


def test_sim_status_without_a_fleet_says_ok_false(tmp_path: Path) -> None:
    done = rosdeploy("--json", "sim", "status", env={"ROSDEPLOY_SIM_HOME": str(tmp_path / "nosim")})
    doc = one_document(done.stdout)
    assert (done.returncode, doc["ok"], doc["exit_code"]) == (3, False, 3)


def run_in(tmp: Path, *argv: str, **kwargs) -> subprocess.CompletedProcess[str]:
    from test_cli_signals import run
    if "stdout" not in kwargs:
        kwargs.setdefault("capture_output", True)
    return run(tmp, *argv, **kwargs)


# ------------------------------------------------------- 9: a lost stdout fails a printing command

def to_full_disk(tmp: Path, *argv: str) -> subprocess.CompletedProcess[str]:
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full here")
    with open("/dev/full", "w") as full:
        return run_in(tmp, *argv, stdout=full, stderr=subprocess.PIPE)


@pytest.mark.parametrize("argv", [["completion", "bash"], ["completion", "fish"], ["--help"], ["version"],
                                  ["--json", "version"], ["validate", "--help"]])
def test_a_command_whose_product_is_stdout_fails_on_a_full_disk(tmp_path: Path, argv: list[str]) -> None:
    done = to_full_disk(tmp_path, *argv)
    assert done.returncode == 1
    assert "standard output could not be written (No space left on device)" in done.stderr


def test_check_and_vault_view_fail_on_a_full_disk(tmp_path: Path) -> None:
    args = lab_args(tmp_path)
    assert to_full_disk(tmp_path, "--json", "check", *args).returncode == 1
    vault = str(tmp_path / "lab" / "inventory" / "group_vars" / "all" / "vault.yml")
    assert to_full_disk(tmp_path, "vault", "view", vault, *args[1:]).returncode == 1


def test_a_reader_that_left_is_not_a_failure(tmp_path: Path) -> None:
    read, write = os.pipe()
    os.close(read)
    done = run_in(tmp_path, "completion", "bash", stdout=write, stderr=subprocess.PIPE)
    os.close(write)
    assert done.returncode == 0 and "could not be written" not in done.stderr


# ------------------------------------------------------- 4: an interrupt while robots are connecting

@pytest.mark.parametrize(("command", "robots"), [("apply", 1), ("apply", 2), ("rollback", 2)])
def test_an_interrupt_while_connecting_ends_the_run_at_once(tmp_path: Path, hole: BlackHole, command: str,
                                                            robots: int) -> None:
    # 2 robots: apply's pre-check of a rollout in waves; connect_timeout 40 s was waited out in full
    path = fleet(tmp_path, {f"b{i}": hole.port for i in range(robots)}, connect_timeout="40s")
    proc = start(tmp_path, "--json", command, str(path), "--yes")
    code, out, err, took = interrupted(proc, hole, signal.SIGTERM)
    doc = one_document(out)
    assert (code, doc["exit_code"], doc["interrupted"]) == (130, 130, True), err
    assert took < 3, took
    assert {h["outcome"] for h in doc["hosts"]} == {"skipped"}, doc["hosts"]
    assert "unreachable" not in json.dumps(doc["hosts"])
    assert (tmp_path / "runs" / doc["run_id"] / "result.json").is_file()


class Link:
    def close(self) -> None:
        pass


@dataclasses.dataclass(frozen=True)
class FakeContext:
    cancel: threading.Event
    connect: Callable[..., Link]
    progress: Callable[[str, str], None] = lambda host, step: None


def test_an_interrupt_abandons_workers_connecting_and_awaits_those_that_reached_their_robot() -> None:
    from rosdeploy.results import HostResult
    from rosdeploy.rollout import Reached, parallel

    cancel, never = threading.Event(), threading.Event()
    reach = Reached(FakeContext(cancel, _robots(never)))    # type: ignore[arg-type]
    switched: list[str] = []

    def work(host: SimpleNamespace) -> HostResult:
        reach.ctx.connect(host, None)
        time.sleep(1.5)             # reached: locked and mid-switch, whatever the interrupt says
        switched.append(host.name)
        return HostResult(host.name, "deployed")

    main = threading.main_thread().ident
    threading.Timer(0.5, lambda: signal.pthread_kill(main, signal.SIGINT)).start()   # type: ignore[arg-type]
    began = time.monotonic()
    try:
        results = parallel([SimpleNamespace(name="near"), SimpleNamespace(name="far")], work, 2,  # type: ignore[list-item]
                           cancel.set, reach.abandon)
    finally:
        never.set()
    assert time.monotonic() - began < 3
    assert switched == ["near"] and cancel.is_set()
    assert [(r.host, r.outcome) for r in results] == [("near", "deployed"), ("far", "skipped")]


def _robots(never: threading.Event) -> Callable[..., Link]:
    """A connect that answers at once for `near`, and not until the test ends for `far`."""
    def connect(host: SimpleNamespace, options: object) -> Link:
        if host.name == "far":
            never.wait(30)
        return Link()
    return connect


# ------------------------------------------------------- 2, 3: completion offers files, and the right words

def tab(tmp: Path, shell: str, line: str) -> list[str]:
    """What TAB offers after `line` in the real shell, in a folder holding fleet.yml and sub/."""
    import shutil
    if not shutil.which(shell):
        pytest.skip(f"no {shell} here")
    (tmp / "sub").mkdir(exist_ok=True)
    (tmp / "fleet.yml").touch()
    script = tmp / f"rosdeploy.{shell}"
    script.write_text(rosdeploy("completion", shell).stdout)
    if shell == "bash":
        words = line.split(" ")
        code = (f"source /usr/share/bash-completion/bash_completion 2>/dev/null; source {script}; "
                f"COMP_WORDS=({line} ''); COMP_WORDS=(\"${{COMP_WORDS[@]:0:{len(words)}}}\"); "
                f"COMP_CWORD={len(words) - 1}; COMP_LINE='{line}'; COMP_POINT={len(line)}; _shtab_rosdeploy; "
                'printf "%s\\n" "${COMPREPLY[@]}"')
        argv = ["bash", "-c", code]
    elif shell == "zsh":    # _files is what zsh offers files with: the argument's spec must call it
        return [line for line in script.read_text().splitlines() if "_files" in line]
    else:
        argv = ["fish", "-c", f"source {script}; complete -C '{line}'"]
    done = subprocess.run(argv, cwd=tmp, capture_output=True, text=True, timeout=30)
    return [w.split("\t")[0] for w in done.stdout.splitlines() if w]


@pytest.mark.parametrize("line", ["rosdeploy validate fl", "rosdeploy apply F -i fl",
                                  "rosdeploy plan F --vault-password-file fl", "rosdeploy bundle F --out fl",
                                  "rosdeploy vault view fl", "rosdeploy vault encrypt a fl"])
@pytest.mark.parametrize("shell", ["bash", "fish"])
def test_tab_offers_file_names_for_paths(tmp_path: Path, shell: str, line: str) -> None:
    assert "fleet.yml" in tab(tmp_path, shell, line)


@pytest.mark.parametrize("shell", ["bash", "fish"])
def test_tab_offers_folders_for_render_out(tmp_path: Path, shell: str) -> None:
    assert [w.rstrip("/") for w in tab(tmp_path, shell, "rosdeploy render F -o s")] == ["sub"]


def test_zsh_offers_files_for_fleet_and_folders_for_render_out(tmp_path: Path) -> None:
    specs = "\n".join(tab(tmp_path, "zsh", ""))
    assert ":the fleet file, e.g. playbooks\\/warehouse.yml:_files" in specs
    assert "--vault-password-file" in specs and ":DIR:_files -/" in specs


@pytest.mark.parametrize(("line", "offered"), [
    ("rosdeploy sim status --", {"--json", "--color", "--debug", "--help"}),
    ("rosdeploy sim busy ", set()), ("rosdeploy sim busy robot1 ", {"on", "off"}),
    ("rosdeploy completion bash ", set()), ("rosdeploy completion ", {"bash", "zsh", "fish"}),
    ("rosdeploy --color never sim ", {"up", "down", "status", "cut", "isolate", "heal", "busy", "reboot"}),
])
def test_fish_offers_what_the_position_takes(tmp_path: Path, line: str, offered: set[str]) -> None:
    assert set(tab(tmp_path, "fish", line)) == offered


# ------------------------------------------------------- 10: --help imports no vault, model or YAML

def test_help_imports_neither_the_vault_nor_the_model() -> None:
    code = ("import sys; from rosdeploy.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in sys.modules if m in ('rosdeploy.vault', 'rosdeploy.model', 'yaml', "
            "'rosdeploy.images.refs', 'rosdeploy.yamlsrc')))")
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=_env(), capture_output=True, text=True,
                          timeout=60)
    assert done.stdout.strip().splitlines()[-1] == "[]", done.stderr


def test_the_help_names_the_vaults_own_variables() -> None:
    from rosdeploy import vault
    from rosdeploy.cli import vault as vault_cli
    assert (vault_cli.ENV_PASSWORD_FILE, vault_cli.ENV_PASSWORD) == (vault.ENV_PASSWORD_FILE, vault.ENV_PASSWORD)


# ------------------------------------------------------- 7: the advice for an unreachable robot is whole

@pytest.mark.parametrize("command", ["status", "plan", "history"])
def test_the_advice_for_an_unreachable_robot_is_not_cut(tmp_path: Path, command: str) -> None:
    done = run_in(tmp_path, command, str(unreachable_fleet(tmp_path)))
    assert done.returncode == 3, done.stderr
    assert done.stdout.count("Check its ansible_host and ansible_port") == 2, done.stdout
    assert "UNREACHABLE: r1" not in done.stdout and "r1: unreachable: [127.0.0.1]:1:" in done.stdout


# ------------------------------------------------------- 6: a newline in a file name fakes no line

def test_a_newline_in_a_path_prints_no_line_of_its_own(tmp_path: Path) -> None:
    done = run_in(tmp_path, "validate", "a\nerror: b.yml")
    assert done.returncode == 2
    assert not any(line.startswith("error: b.yml") for line in done.stderr.splitlines()), done.stderr
    assert "a\\nerror: b.yml" in done.stderr


# ------------------------------------------------------- 5: the last --color wins, on a usage error too

def test_the_last_color_wins_on_a_usage_error(tmp_path: Path) -> None:
    assert "\x1b[" not in run_in(tmp_path, "--color", "always", "--color", "never", "bogus").stderr
    assert "\x1b[" in run_in(tmp_path, "--color", "never", "--color", "always", "bogus").stderr


# ------------------------------------------------------- 12: a single-value option given twice

@pytest.mark.parametrize(("argv", "option"), [
    (["apply", "F", "--version", "1", "--version", "2"], "--version"),
    (["status", "F", "-l", "a", "-l", "b"], "--limit"),
    (["rollback", "F", "--to", "1", "--to", "2"], "--to"), (["apply", "F", "--pause", "1", "--pause", "2"], "--pause"),
    (["history", "F", "-n", "10", "-n", "3"], "-n")])
def test_a_single_value_option_given_twice_is_refused(tmp_path: Path, argv: list[str], option: str) -> None:
    done = run_in(tmp_path, "--json", *argv)
    doc = one_document(done.stdout)
    assert (done.returncode, doc["error"]["kind"]) == (2, "usage")
    assert option in doc["error"]["message"] and "given twice" in doc["error"]["message"]


def test_an_option_given_once_with_its_default_value_is_no_repeat() -> None:
    from rosdeploy.cli import build_parser
    args = build_parser().parse_args(["apply", "F", "--lock-wait", "0", "-i", "inv", "-l", "a"])
    assert (args.lock_wait, args.inventory, args.limit) == (0.0, "inv", "a")


# ------------------------------------------------------- 13: masking a short password garbles nothing

def test_a_short_wrong_password_is_not_masked_inside_words_and_paths(tmp_path: Path) -> None:
    args = lab_args(tmp_path)
    (tmp_path / "wrongpw").write_text("wrong\n")
    done = run_in(tmp_path, "validate", args[0], "--vault-password-file", str(tmp_path / "wrongpw"))
    assert done.returncode == 2
    assert f"--vault-password-file {tmp_path / 'wrongpw'}" in done.stderr, done.stderr


def test_short_secrets_are_masked_as_whole_words_and_long_ones_anywhere() -> None:
    from rosdeploy.output import MASK, Output
    out = Output()
    out.mask(["pin1", "s3cretvalue"])
    assert out.masked("token: pin1, file pin10/x") == f"token: {MASK}, file pin10/x"
    assert out.masked("xs3cretvaluex") == f"x{MASK}x"


# ------------------------------------------------------- 11: an inventory that is no file or folder

@pytest.mark.parametrize("special", ["/dev/null", "fifo"])
def test_an_inventory_that_exists_but_is_no_file_is_not_called_missing(tmp_path: Path, special: str) -> None:
    path = fleet(tmp_path, {"r1": 1})
    if special == "fifo":
        special = str(tmp_path / "fifo")
        os.mkfifo(special)
    done = run_in(tmp_path, "validate", str(path), "-i", special)
    assert done.returncode == 2
    assert "not a regular file or folder" in done.stderr and "not found" not in done.stderr


# ------------------------------------------------------- 15: an odd lock owner record

@pytest.mark.parametrize(("record", "shown"), [
    ({"by": {"user": "alice"}, "pid": 1}, "an unknown user (pid 1)"),
    ({"by": "bob@ops", "since": 1700000000, "pid": True}, "bob@ops (since 2023-11-14T22:13:20+00:00)"),
    ({"by": "bob@ops", "run": "r1", "pid": 7, "since": "2024-01-01T00:00:00Z"},
     "bob@ops (run r1, pid 7, since 2024-01-01T00:00:00Z)")])
def test_a_lock_owner_is_described_without_raw_structures(record: dict, shown: str) -> None:
    from rosdeploy.owner import describe
    assert describe(json.dumps(record)) == shown


# ------------------------------------------------------- 14: an empty NO_COLOR is ignored, FORCE_COLOR=0 is off

def test_colour_follows_the_documented_environment(tmp_path: Path) -> None:
    def painted(**env: str) -> bool:
        done = rosdeploy("validate", str(tmp_path / "missing.yml"), env=env)
        return "\x1b[" in done.stderr
    assert painted(FORCE_COLOR="1", NO_COLOR="") and not painted(FORCE_COLOR="1", NO_COLOR="1")
    assert not painted(FORCE_COLOR="0")
    readme = (REPO / "README.md").read_text()
    assert "NO_COLOR` (any value)" not in readme and "`FORCE_COLOR=0` means off" in readme


# ------------------------------------------------------- 16: smaller ones

def test_an_unknown_option_without_a_command_is_named() -> None:
    done = rosdeploy("-x")
    assert done.returncode == 2 and "-x" in done.stderr.splitlines()[-1]


def test_the_readme_lists_vault_encrypt_string() -> None:
    table = (REPO / "README.md").read_text().split("## Commands", 1)[1].split("\n\n", 2)[1]
    assert "`rosdeploy vault encrypt-string" in table


def test_a_huge_path_is_not_echoed_whole_in_the_message(tmp_path: Path) -> None:
    done = run_in(tmp_path, "--json", "validate", "a" * 100_000)
    doc = one_document(done.stdout)
    assert done.returncode == 2 and len(done.stdout) < 110_000
    assert "(100000 characters)" in doc["error"]["message"] and len(done.stderr) < 2000
