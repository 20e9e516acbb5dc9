"""The command line itself: global options anywhere, version, durations, help, exit codes,
--json failures, colour per stream, shell completion, and what start-up imports.

Where the real process matters (a terminal, the environment, sys.modules) the test runs
`python -m rosdeploy` in a subprocess with this checkout first on the path.
"""
from __future__ import annotations

import argparse
import io
import json
import os
import pty
import re
import select
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from rosdeploy import __version__
from rosdeploy.cli import build_parser, main
from rosdeploy.cli.common import EXIT_CODES, UsageError
from rosdeploy.errors import EXIT_DECLINED, EXIT_INPUT, EXIT_INTERNAL, EXIT_PARTIAL, RemoteError
from rosdeploy.output import Output

REPO = Path(__file__).resolve().parents[2]
LAB = Path(__file__).resolve().parent / "data" / "fleet"
SSH_AND_CRYPTO = ("paramiko", "fabric", "invoke", "cryptography")
ESC = "\x1b["


def rosdeploy(*argv: str, env: dict[str, str] | None = None, **kwargs) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "rosdeploy", *argv], cwd=REPO, env=_env(env), text=True,
                          capture_output=True, timeout=60, **kwargs)


def _env(extra: dict[str, str] | None = None) -> dict[str, str]:
    unset = ("NO_COLOR", "FORCE_COLOR", "ROSDEPLOY_VAULT_PASSWORD", "ROSDEPLOY_VAULT_PASSWORD_FILE")
    env = {k: v for k, v in os.environ.items() if k not in unset}
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env.update(extra or {})
    return env


def subcommands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """(path, parser) of every (sub)command, nested ones (sim up, vault view) included."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                yield path + (name,), child
                yield from subcommands(child, path + (name,))


def leaves() -> list[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    return [(path, p) for path, p in subcommands(build_parser())
            if not any(isinstance(a, argparse._SubParsersAction) for a in p._actions)]


@pytest.fixture
def plain_fleet(tmp_path: Path) -> Path:
    """The lab fleet without its vault file or secrets: nothing in it needs cryptography."""
    shutil.copytree(LAB, tmp_path / "lab")
    (tmp_path / "lab" / "inventory" / "group_vars" / "all" / "vault.yml").unlink()
    fleet = tmp_path / "lab" / "fleet.yml"
    data = yaml.safe_load(fleet.read_text())
    for service in data["services"].values():
        service.pop("secrets", None)
    fleet.write_text(yaml.safe_dump(data, sort_keys=False))
    return fleet


def lab_args(tmp_path: Path) -> list[str]:
    shutil.copytree(LAB, tmp_path / "lab", dirs_exist_ok=True)
    return [str(tmp_path / "lab" / "fleet.yml"), "--vault-password-file",
            str(tmp_path / "lab" / "inventory" / ".vault-password")]


# ------------------------------------------------------- global options anywhere

@pytest.mark.parametrize("argv", [
    ["--json", "status", "F"], ["status", "F", "--json"], ["status", "--json", "F"],
    ["sim", "status", "--json"], ["--json", "sim", "status"], ["vault", "view", "x", "--json"],
    ["validate", "F", "--json"], ["--json", "version"], ["history", "F", "--json", "-n", "2"],
])
def test_json_before_or_after_the_command(argv: list[str]) -> None:
    assert build_parser().parse_args(argv).json is True


def test_global_options_default_and_after_the_command() -> None:
    args = build_parser().parse_args(["apply", "F"])
    assert (args.json, args.debug, args.color) == (False, False, "auto")
    args = build_parser().parse_args(["apply", "F", "--debug", "--color", "never"])
    assert (args.debug, args.color) == (True, "never")
    args = build_parser().parse_args(["--color=always", "--debug", "rollback", "F"])
    assert (args.debug, args.color) == (True, "always")


def test_every_command_accepts_the_global_options() -> None:
    for path, parser in leaves():
        options = {o for a in parser._actions for o in a.option_strings}
        assert {"--json", "--debug", "--color"} <= options, path


def test_color_takes_only_its_three_words() -> None:
    with pytest.raises(UsageError, match="invalid choice: 'blue'"):
        build_parser().parse_args(["validate", "F", "--color", "blue"])


# ----------------------------------------------------------------- version

@pytest.mark.parametrize("argv", [["--version"], ["-V"], ["version"]])
def test_version(argv: list[str]) -> None:
    done = rosdeploy(*argv)
    assert (done.returncode, done.stdout.strip()) == (0, f"rosdeploy {__version__}")


@pytest.mark.parametrize("argv", [["version", "--json"], ["--json", "--version"], ["-V", "--json"]])
def test_version_json(argv: list[str]) -> None:
    done = rosdeploy(*argv)
    # every document carries ok and exit_code now (test_cli_seventh, defect 8)
    assert done.returncode == 0 and json.loads(done.stdout) == {"version": __version__, "ok": True, "exit_code": 0}


@pytest.mark.parametrize("argv, option", [(["validate", ""], "FLEET"),
                                          (["validate", "F", "-i", ""], "-i/--inventory")])
def test_an_empty_path_is_refused_naming_the_argument(argv: list[str], option: str) -> None:
    with pytest.raises(UsageError, match=f"argument {option}: an empty path"):
        build_parser().parse_args(argv)


def test_an_internal_error_under_debug_points_at_the_traceback(capsys: pytest.CaptureFixture,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    parser = build_parser()      # validate's handler replaced by a bug
    parser._subparsers._group_actions[0].choices["validate"].set_defaults(func=lambda args, out: 1 / 0)
    monkeypatch.setattr("rosdeploy.cli.build_parser", lambda: parser)
    assert main(["validate", "F", "--debug"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and "ZeroDivisionError" in err and "(the traceback is above)" in err
    assert "run with --debug" not in err


def test_a_commands_version_option_is_still_the_release_version() -> None:
    assert build_parser().parse_args(["apply", "F", "--version", "1.1.0"]).release_version == "1.1.0"


# --------------------------------------------------------------- durations

@pytest.mark.parametrize("text, seconds", [("30s", 30.0), ("2m", 120.0), ("1m30s", 90.0), ("45", 45.0),
                                           ("1.5", 1.5), ("500ms", 0.5)])
def test_pause_and_lock_wait_take_the_fleet_files_durations(text: str, seconds: float) -> None:
    args = build_parser().parse_args(["apply", "F", "--pause", text, "--lock-wait", text])
    assert (args.pause, args.lock_wait) == (seconds, seconds)
    assert build_parser().parse_args(["rollback", "F", "--lock-wait", text]).lock_wait == seconds


@pytest.mark.parametrize("text", ["3x", "-5", "soon", "", "99999999999999999999h", "8785h", "nan", "inf"])
def test_a_bad_duration_is_a_usage_error_that_says_what_to_write(text: str) -> None:
    # 1e23 s used to pass here and overflow the timer between waves: an internal error
    with pytest.raises(UsageError, match=r"--pause: invalid duration .*30s, 2m.*at most 8784h"):
        build_parser().parse_args(["apply", "F", "--pause", text])


def test_waves_and_max_fail_take_what_the_fleet_file_takes() -> None:
    args = build_parser().parse_args(["apply", "F", "--waves", "1, 10%,100%", "--max-fail", "0"])
    assert (args.waves, args.max_fail) == ((1, "10%", "100%"), 0)
    assert build_parser().parse_args(["apply", "F", "--max-fail", "25%"]).max_fail == "25%"
    with pytest.raises(UsageError, match="--waves: waves are cumulative targets and never shrink"):
        build_parser().parse_args(["apply", "F", "--waves", "2,1"])


@pytest.mark.parametrize("option, text", [("--waves", "x"), ("--waves", "1,x"), ("--waves", "0"),
                                          ("--waves", "200%"), ("--waves", "1,,2"), ("--max-fail", "-1"),
                                          ("--max-fail", "lots"), ("--max-fail", "0%"), ("--waves", "²")])
def test_a_bad_wave_or_failure_limit_is_a_usage_error_not_a_crash(option: str, text: str) -> None:
    with pytest.raises(UsageError, match=rf"argument {option}: .*a robot count \(1, 5\) or a percentage"):
        build_parser().parse_args(["apply", "F", option, text])


# -------------------------------------------------------------------- help

def test_every_command_has_a_description_exit_codes_and_an_example() -> None:
    for path, parser in leaves():
        assert parser.description, path
        assert "exit codes:" in parser.epilog and "example:" in parser.epilog, path
        codes = [int(c) for c in re.findall(r"^\s+(\d+)  ", parser.epilog.split("example:")[0], re.M)]
        assert codes and set(codes) <= set(EXIT_CODES), (path, codes)
        assert 0 in codes and EXIT_INPUT in codes, path


def test_every_example_parses_as_the_command_it_illustrates() -> None:
    for path, parser in leaves():
        example = parser.epilog.split("example:\n", 1)[1].strip().split("#")[0]
        words = shlex.split(example.split(">")[0])
        assert words[:1 + len(path)] == ["rosdeploy", *path], (path, example)
        build_parser().parse_args(words[1:])


def test_every_option_with_a_value_has_a_real_metavar() -> None:
    """No argparse default like FORKS or MAX_FAIL: each value says what it is."""
    for path, parser in leaves():
        for action in parser._actions:
            if action.option_strings and action.nargs != 0 and not action.choices:
                assert action.metavar, (path, action.option_strings)
        assert "FORKS" not in parser.format_help() and "MAX_FAIL" not in parser.format_help(), path


def test_the_readme_lists_every_exit_code() -> None:
    readme = (REPO / "README.md").read_text()
    table = readme.split("### Exit codes", 1)[1].split("\n#", 1)[0]
    for code in EXIT_CODES:
        assert re.search(rf"^\| {code} \|", table, re.M), code


def test_help_shows_the_exit_codes() -> None:
    done = rosdeploy("apply", "--help")
    assert done.returncode == 0
    assert f"  {EXIT_DECLINED}  {EXIT_CODES[EXIT_DECLINED]}" in done.stdout
    assert "example:\n  rosdeploy apply" in done.stdout


# ---------------------------------------------------------- declining: exit 5

def answer_on_a_terminal(argv: list[str], answer: str, piped: bool = False) -> tuple[int, str]:
    """Run rosdeploy with a terminal as stdin and stdout (`piped`: stdout a pipe, as in `| tee`,
    and stderr the terminal), answer its question, return (code, text on the terminal + the other)."""
    master, slave = pty.openpty()
    streams = {"stdout": subprocess.PIPE, "stderr": slave} if piped else {"stdout": slave, "stderr": subprocess.PIPE}
    proc = subprocess.Popen([sys.executable, "-m", "rosdeploy", *argv], cwd=REPO, env=_env(),
                            stdin=slave, text=True, **streams)
    os.close(slave)
    seen = b""
    deadline = time.monotonic() + 60
    while b"[y/N]" not in seen and time.monotonic() < deadline:
        if select.select([master], [], [], 1)[0]:
            seen += os.read(master, 4096)
    os.write(master, answer.encode() + b"\n")
    out, err = proc.communicate(timeout=60)
    os.close(master)
    return proc.returncode, seen.decode() + (out if piped else err)


@pytest.mark.parametrize("command", ["apply", "rollback"])
def test_declining_the_confirmation_exits_5_and_does_nothing(tmp_path: Path, command: str) -> None:
    code, text = answer_on_a_terminal([command, *lab_args(tmp_path)], "n")
    assert "[y/N]" in text
    assert code == EXIT_DECLINED != EXIT_INPUT, text
    assert "declined: nothing was done" in text


def test_a_report_piped_to_tee_still_asks_at_the_keyboard_on_stderr(tmp_path: Path) -> None:
    code, text = answer_on_a_terminal(["apply", *lab_args(tmp_path)], "n", piped=True)
    assert "[y/N]" in text and code == EXIT_DECLINED, text     # it used to refuse: "without a terminal"


def test_step_without_a_keyboard_is_refused_rather_than_not_asking(tmp_path: Path) -> None:
    done = rosdeploy("apply", *lab_args(tmp_path), "--yes", "--step", stdin=subprocess.DEVNULL)
    assert done.returncode == EXIT_INPUT and "--step asks before every wave" in done.stderr, done.stderr


def test_without_a_terminal_and_without_yes_it_is_an_input_error(tmp_path: Path) -> None:
    done = rosdeploy("apply", *lab_args(tmp_path), stdin=subprocess.DEVNULL)
    assert done.returncode == EXIT_INPUT
    assert "pass --yes" in done.stderr and "error: : " not in done.stderr


# ------------------------------------------------------------ --json failures

def one_document(text: str) -> dict:
    return json.loads(text)   # raises unless stdout is exactly one JSON document


@pytest.mark.parametrize("argv", [["--json", "status"], ["status", "--json"], ["--json", "bogus"],
                                  ["apply", "F", "--pause", "3x", "--json"], ["--js", "validate", "--bogus"],
                                  ["--json=1", "validate", "F"], ["apply", "F", "--waves", "x", "--json"]])
def test_json_usage_errors_print_one_document(argv: list[str]) -> None:
    done = rosdeploy(*argv)
    doc = one_document(done.stdout)
    assert done.returncode == EXIT_INPUT
    assert doc["ok"] is False and doc["exit_code"] == EXIT_INPUT and doc["error"]["kind"] == "usage"
    assert doc["error"]["message"] in done.stderr
    assert "usage:" not in done.stdout


def test_vault_commands_and_completion_print_one_document_with_json(tmp_path: Path) -> None:
    # they printed their text on stderr and nothing on stdout
    env = {"ROSDEPLOY_VAULT_PASSWORD": "pw-123456"}
    secrets = tmp_path / "s.yml"
    secrets.write_text("k: v\n")
    runs = {"encrypt": ["vault", "encrypt", str(secrets)], "view": ["vault", "view", str(secrets)],
            "decrypt": ["vault", "decrypt", str(secrets)], "string": ["vault", "encrypt-string", "--name", "x", "v1"],
            "completion": ["completion", "bash"]}
    docs = {}
    for name, argv in runs.items():
        done = rosdeploy("--json", *argv, env=env)
        assert done.returncode == 0 and done.stderr == "", (name, done.stderr)
        docs[name] = one_document(done.stdout)
        assert docs[name]["ok"] is True, docs[name]
    assert docs["encrypt"]["encrypted"] == [{"file": str(secrets), "format": "rosdeploy"}]
    assert docs["view"]["plaintext"] == "k: v\n" and docs["decrypt"]["decrypted"] == [str(secrets)]
    assert docs["string"]["yaml"].startswith("x: !vault |") and docs["string"]["name"] == "x"
    assert docs["completion"]["shell"] == "bash" and "complete" in docs["completion"]["script"]
    assert secrets.read_text() == "k: v\n"


@pytest.mark.parametrize("argv, words", [
    (["apply", "F", "--waves", "1,1"], "1 is listed twice; keep one"),      # the fleet file refused it, not --waves
    (["apply", "F", "--forks", "99999999999999999999"], "is not a whole number from 1 to 2147483647"),
    (["sim", "up", "--robots", "91"], "--robots: must be between 1 and 90, not 91"),   # was exit 3
])
def test_option_values_are_checked_as_the_fleet_file_checks_them(argv: list[str], words: str) -> None:
    done = rosdeploy("--json", *argv)
    assert done.returncode == EXIT_INPUT and words in done.stderr, done.stderr
    assert one_document(done.stdout)["exit_code"] == EXIT_INPUT


@pytest.mark.parametrize("argv, blamed", [(["rollback", "F", "--pause", "3s"], "rosdeploy rollback"),
                                          (["vault", "view", "x", "--bogus"], "rosdeploy vault view"),
                                          (["sim", "heal", "robot1", "--for", "2s"], "rosdeploy sim heal")])
def test_a_word_no_command_takes_is_blamed_on_that_command(argv: list[str], blamed: str) -> None:
    with pytest.raises(UsageError) as caught:
        build_parser().parse_args(argv)
    assert caught.value.message.startswith(f"{blamed}: unrecognized arguments: ") and f"`{blamed} --help`" in \
        caught.value.message and caught.value.usage.startswith(f"usage: {blamed} ")


@pytest.mark.parametrize("argv, meant", [(["aply", "F"], "apply"), (["sim", "stauts"], "status"),
                                         (["vault", "veiw", "x"], "view")])
def test_a_mistyped_command_gets_a_suggestion(argv: list[str], meant: str) -> None:
    with pytest.raises(UsageError, match=rf"invalid choice: .*; did you mean '{meant}'\?"):
        build_parser().parse_args(argv)


def test_a_non_utf8_argument_reaches_the_json_as_a_replacement_character() -> None:
    done = rosdeploy("--json", "validate", "/nonexistent/x\udcff.yml")     # the argv byte 0xff
    assert "\\udcff" not in done.stdout and "x\ufffd.yml" in json.loads(done.stdout)["error"]["message"]
    stream = io.StringIO()
    Output(stdout=stream, as_json=True).document({"name": "x\udcff", "ok": "robot \U0001F600"})
    assert json.loads(stream.getvalue()) == {"name": "x\ufffd", "ok": "robot \U0001F600"}, "a real pair stays"


def test_json_after_double_dash_is_a_word_not_the_option() -> None:
    done = rosdeploy("validate", "--bogus", "--", "--json")
    assert done.returncode == EXIT_INPUT and done.stdout == "" and "unrecognized arguments: --bogus" in done.stderr


def test_json_input_error_names_the_file(tmp_path: Path) -> None:
    done = rosdeploy("validate", str(tmp_path / "missing.yml"), "--json")
    doc = one_document(done.stdout)
    assert (done.returncode, doc["error"]["kind"]) == (EXIT_INPUT, "input")
    assert doc["error"]["problems"][0]["file"] == str(tmp_path / "missing.yml")


def test_json_internal_and_remote_errors(capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch) -> None:
    from rosdeploy import cli

    def boom(args: argparse.Namespace, out: Output) -> int:
        raise RuntimeError("a bug")

    monkeypatch.setattr(cli, "cmd_version", boom)
    assert main(["--json", "version"]) == EXIT_INTERNAL
    doc = one_document(capsys.readouterr().out)
    assert doc["error"]["kind"] == "internal" and "a bug" in doc["error"]["message"]

    def unreachable(args: argparse.Namespace, out: Output) -> int:
        raise RemoteError("r1", "connection refused")

    monkeypatch.setattr(cli, "cmd_version", unreachable)
    assert main(["version", "--json"]) == EXIT_PARTIAL
    doc = one_document(capsys.readouterr().out)
    assert (doc["exit_code"], doc["error"]["message"]) == (EXIT_PARTIAL, "r1: connection refused")


def test_a_command_that_already_printed_its_document_gets_no_second_one(
        capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch) -> None:
    from rosdeploy import cli

    def late_failure(args: argparse.Namespace, out: Output) -> int:
        out.document({"robots": []})
        raise RemoteError("r1", "lost on the way out")

    monkeypatch.setattr(cli, "cmd_version", late_failure)
    assert main(["--json", "version"]) == EXIT_PARTIAL
    captured = capsys.readouterr()
    doc = one_document(captured.out)      # the command's document, with the failure added (not a second one)
    assert (doc["robots"], doc["ok"], doc["exit_code"], doc["error"]["kind"]) == ([], False, EXIT_PARTIAL, "error")
    assert "r1: lost on the way out" in captured.err


# ------------------------------------------------------------------ colour

class Stream:
    def __init__(self, tty: bool) -> None:
        self.tty, self.text = tty, ""

    def isatty(self) -> bool:
        return self.tty

    def write(self, text: str) -> None:
        self.text += text

    def flush(self) -> None:
        pass


@pytest.mark.parametrize("out_tty, err_tty", [(True, False), (False, True)])
def test_colour_is_decided_per_stream(monkeypatch: pytest.MonkeyPatch, out_tty: bool, err_tty: bool) -> None:
    monkeypatch.delenv("NO_COLOR", raising=False)
    monkeypatch.delenv("FORCE_COLOR", raising=False)
    out = Output(stdout=Stream(out_tty), stderr=Stream(err_tty))
    out.line(out.paint("table", "bold"))
    out.error("error: bad")
    out.warn("warning: odd")
    assert (ESC in out.stdout.text, ESC in out.stderr.text) == (out_tty, err_tty)


@pytest.mark.parametrize("env, flag, painted", [
    ({}, "auto", False), ({"FORCE_COLOR": "1"}, "auto", True), ({"FORCE_COLOR": "0"}, "auto", False),
    ({"NO_COLOR": "1", "FORCE_COLOR": "1"}, "auto", False), ({"FORCE_COLOR": "1"}, "never", False),
    ({"NO_COLOR": "1"}, "always", True), ({}, "always", True),
])
def test_no_color_force_color_and_the_flag(tmp_path: Path, env: dict, flag: str, painted: bool) -> None:
    """Pipes for both streams (like `check F 2>err`): only FORCE_COLOR or --color always paints."""
    done = rosdeploy("--color", flag, "validate", str(tmp_path / "missing.yml"), env=env)
    assert done.returncode == EXIT_INPUT
    assert (ESC in done.stderr) is painted
    assert ESC not in done.stdout


def test_stderr_to_a_file_stays_plain_while_stdout_is_a_terminal(tmp_path: Path) -> None:
    master, slave = pty.openpty()
    with open(tmp_path / "err", "w") as err:
        proc = subprocess.run([sys.executable, "-m", "rosdeploy", "validate", str(tmp_path / "missing.yml")],
                              cwd=REPO, env=_env(), stdin=subprocess.DEVNULL, stdout=slave, stderr=err, timeout=60)
    os.close(slave)
    os.close(master)
    assert proc.returncode == EXIT_INPUT
    text = (tmp_path / "err").read_text()
    assert "missing.yml" in text and ESC not in text


# -------------------------------------------------------------- completion

@pytest.mark.parametrize("shell, check", [("bash", ["bash", "-n"]), ("zsh", ["zsh", "-n"]),
                                          ("fish", ["fish", "--no-execute"])])
def test_completion_scripts_are_valid_in_their_shell(tmp_path: Path, shell: str, check: list[str]) -> None:
    done = rosdeploy("completion", shell)
    assert done.returncode == 0, done.stderr
    script = tmp_path / f"rosdeploy.{shell}"
    script.write_text(done.stdout)
    syntax = subprocess.run([*check, str(script)], capture_output=True, text=True, timeout=30)
    assert syntax.returncode == 0, syntax.stderr
    for word in ("validate", "rollback", "lock-wait", "vault-password-file"):
        assert word in done.stdout, (shell, word)
    assert "python" not in done.stdout


def completions(tmp_path: Path, shell: str, line: str) -> list[str]:
    """What pressing TAB after `line` offers, in the real shell, with no Python on the PATH."""
    script = tmp_path / f"rosdeploy.{shell}"
    script.write_text(rosdeploy("completion", shell).stdout)
    if shell == "bash":
        words = line.split(" ")
        code = (f"source {shlex.quote(str(script))}; COMP_WORDS=({line}); COMP_CWORD={len(words) - 1}; "
                f"COMP_LINE={shlex.quote(line)}; COMP_POINT={len(line)}; _shtab_rosdeploy; "
                'printf "%s\\n" "${COMPREPLY[@]}"')
        argv = ["bash", "-c", code]
    else:
        argv = ["fish", "-c", f"source {shlex.quote(str(script))}; complete -C {shlex.quote(line)}"]
    done = subprocess.run([shutil.which(argv[0]), *argv[1:]], capture_output=True, text=True, timeout=30,
                          env={"PATH": "/nonexistent", "HOME": str(tmp_path)})
    assert done.returncode == 0, done.stderr
    return [w.split("\t")[0] for w in done.stdout.split()]


@pytest.mark.parametrize("shell", ["bash", "fish"])
def test_tab_completes_commands_options_and_choices_without_python(tmp_path: Path, shell: str) -> None:
    assert "apply" in completions(tmp_path, shell, "rosdeploy ap")
    assert "--lock-wait" in completions(tmp_path, shell, "rosdeploy apply --lock")
    assert "status" in completions(tmp_path, shell, "rosdeploy sim st")
    assert {"auto", "always", "never"} <= set(completions(tmp_path, shell, "rosdeploy apply F --color "))
    assert {"bash", "zsh", "fish"} == set(completions(tmp_path, shell, "rosdeploy completion "))
    assert {"on", "off"} == set(completions(tmp_path, shell, "rosdeploy sim busy robot1 "))


def test_the_readme_install_lines_work_in_an_empty_home(tmp_path: Path) -> None:
    readme = (REPO / "README.md").read_text().split("### Shell completion", 1)[1].split("```sh\n", 1)[1]
    lines = readme.split("```", 1)[0].splitlines()
    stub = tmp_path / "bin" / "rosdeploy"        # the README's `rosdeploy`, this checkout's
    stub.parent.mkdir()
    stub.write_text(f'#!/bin/sh\nPYTHONPATH={REPO} exec {sys.executable} -m rosdeploy "$@"\n')
    stub.chmod(0o755)
    env = {"HOME": str(tmp_path / "home"), "PATH": f"{stub.parent}:/usr/bin:/bin"}
    (tmp_path / "home").mkdir()
    for line in lines:
        done = subprocess.run(["sh", "-c", line], capture_output=True, text=True, timeout=60, env=env)
        assert done.returncode == 0, (line, done.stderr)
    assert len(list((tmp_path / "home").rglob("*rosdeploy*"))) == 3


# ------------------------------------------------------- start-up imports

MODULES_AFTER = """
import contextlib, io, json, runpy, sys
sys.argv = ["rosdeploy", *json.loads(sys.argv[1])]
with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
    try:
        runpy.run_module("rosdeploy", run_name="__main__")
    except SystemExit as exc:
        code = exc.code
print(json.dumps({"code": code, "modules": sorted(sys.modules)}))
"""


def imported_by(*argv: str) -> tuple[int, set[str]]:
    done = subprocess.run([sys.executable, "-c", MODULES_AFTER, json.dumps(argv)], cwd=REPO, env=_env(),
                          capture_output=True, text=True, timeout=60)
    report = json.loads(done.stdout)
    return report["code"], {m.split(".")[0] for m in report["modules"]}


@pytest.mark.parametrize("argv", [["--help"], ["apply", "--help"], ["version"], ["completion", "bash"],
                                  ["validate", "--help"]])
def test_help_version_and_completion_import_no_ssh_or_crypto(argv: list[str]) -> None:
    code, modules = imported_by(*argv)
    assert code == 0
    assert not modules & set(SSH_AND_CRYPTO), modules & set(SSH_AND_CRYPTO)


def test_validate_of_a_fleet_without_vault_files_imports_no_ssh_or_crypto(plain_fleet: Path) -> None:
    code, modules = imported_by("validate", str(plain_fleet))
    assert code == 0
    assert "jinja2" in modules          # it did render: the check is not vacuous
    assert not modules & set(SSH_AND_CRYPTO), modules & set(SSH_AND_CRYPTO)


def test_validate_with_vault_files_loads_cryptography_only(tmp_path: Path) -> None:
    code, modules = imported_by("validate", *lab_args(tmp_path))
    assert code == 0
    assert "cryptography" in modules
    assert not modules & {"paramiko", "fabric", "invoke"}


# ------------------------------------------------- README commands as typed

def readme_offline_commands() -> list[tuple[str, dict[str, str]]]:
    """Every `rosdeploy validate|check|render ...` line in the README's shell blocks (not the
    demo's: its inventory is written by `sim up`), with the `export`s above it in its block."""
    text = (REPO / "README.md").read_text()
    found = []
    for block in re.findall(r"```(?:sh|bash|console)?\n(.*?)```", text, re.S):
        exports: dict[str, str] = {}
        for line in (line.split("#")[0].strip() for line in block.splitlines()):
            if line.startswith("export "):
                name, value = line[len("export "):].split("=", 1)
                exports[name] = value
            elif re.match(r"rosdeploy (validate|check|render) ", line) and "demo.yml" not in line:
                found.append((line, dict(exports)))
    return found


def test_the_readme_has_offline_commands_to_run() -> None:
    assert any("warehouse.yml" in c for c, _ in readme_offline_commands())


@pytest.mark.parametrize("command, exports", readme_offline_commands())
def test_readme_offline_commands_work_as_typed(tmp_path: Path, command: str, exports: dict[str, str]) -> None:
    words = [w.replace("/tmp/", f"{tmp_path}/") for w in shlex.split(command)[1:]]
    done = rosdeploy(*words, env=exports)
    assert done.returncode == 0, (command, done.stderr)


def test_a_simulator_failure_exits_3_with_its_error(capsys: pytest.CaptureFixture,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    from rosdeploy import sim
    from rosdeploy.errors import SimError

    def cannot(**kwargs: object) -> None:
        raise SimError("docker info failed: is dockerd running?")

    monkeypatch.setattr(sim, "up", cannot)
    assert main(["sim", "up", "--json"]) == EXIT_PARTIAL == 3
    doc = one_document(capsys.readouterr().out)
    assert doc["error"] == {"kind": "error", "message": "docker info failed: is dockerd running?", "problems": []}
    assert "3  the simulated fleet failed" in build_parser()._subparsers._group_actions[0].choices["sim"].epilog


def test_every_rosdeploy_command_in_the_readme_parses() -> None:
    text = (REPO / "README.md").read_text()
    lines = [line.split("#")[0].split("&& ")[-1].strip()     # `mkdir -p D && rosdeploy ...`: the latter
             for block in re.findall(r"```(?:sh|bash|console)?\n(.*?)```", text, re.S) for line in block.splitlines()]
    commands = [line for line in lines if line.startswith("rosdeploy ")]
    assert len(commands) >= 10
    for command in commands:
        words = shlex.split(command.split(">")[0].split("|")[0])
        build_parser().parse_args(words[1:])      # a UsageError fails the test with the command's problem

