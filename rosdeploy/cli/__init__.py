"""`rosdeploy` command line: argument parsing and exit codes, no deploy logic.

Each area registers its own subcommands (offline.py, remote.py, sim.py, vault.py); a
handler gets the parsed args and the Output and returns an exit code. Building the parser
imports no SSH or crypto module: the handlers import what their command needs, so `--help`,
`validate` and shell completion start in a blink.
"""
from __future__ import annotations

import argparse
import errno
import os
import signal
import sys
import traceback
from contextlib import contextmanager
from types import FrameType
from typing import Any, Iterator, Sequence, TextIO

from rosdeploy import __version__
from rosdeploy.budget import command_budget
from rosdeploy.cli.common import EXIT_CODES, Parser, UsageError, add_command
from rosdeploy.errors import (EXIT_DECLINED, EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_OK, InputError,
                              Problem, RosdeployError, shown)
from rosdeploy.output import Output


def build_parser() -> Parser:
    from rosdeploy.cli import completion, images, offline, remote, sim, vault

    parser = Parser(
        prog="rosdeploy", root=True,
        description="Declarative deployment of ROS 2 software to robot fleets.",
        epilog="exit codes:\n" + "\n".join(f"  {code:>3}  {text}" for code, text in EXIT_CODES.items())
               + "\n\n`rosdeploy COMMAND --help` shows a command's options, exit codes and an example.")
    parser.add_argument("-V", "--version", action=_ShowVersion, help="print rosdeploy's version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in (offline, remote, sim, vault, images, completion):
        module.register(sub)
    version = add_command(sub, "version", "print rosdeploy's version", "Print rosdeploy's version.",
                          (EXIT_OK, EXIT_INPUT), "rosdeploy version")
    version.set_defaults(func=cmd_version)
    return parser


class _ShowVersion(argparse.Action):
    """`rosdeploy --version`: answered by main() as `rosdeploy version` is, so `--json` holds for it
    too (argparse's own version action prints plain text and exits)."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        raise VersionAsked


class VersionAsked(Exception):
    pass


def cmd_version(args: argparse.Namespace, out: Output) -> int:
    if out.as_json:
        out.document({"version": __version__})
    else:
        out.line(f"rosdeploy {__version__}")
    return EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    with _stopped_by_signals(), _guarded_streams() as streams:
        code, acts = _main(list(sys.argv[1:] if argv is None else argv))
        streams[0].flush()      # what is still buffered (argparse's --help): its failure counts too
    return _after_lost_output(streams, code, acts)


def _main(argv: list[str]) -> tuple[int, bool]:
    """The exit code, and whether the command acts (on robots or files): see _after_lost_output."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:       # --help, printed by argparse
        return (EXIT_OK if exc.code is None else exc.code if isinstance(exc.code, int) else EXIT_INPUT), False
    except VersionAsked:
        out = _early_output(argv)
        return _finish(out, cmd_version(argparse.Namespace(), out)), False
    except UsageError as exc:
        out = _early_output(argv)
        if not out.as_json:
            out.note(exc.usage.rstrip())
        return _finish(out, _fail(out, exc)), False
    except KeyboardInterrupt as exc:    # SIGTERM while the parser was built: nothing was done
        out = _early_output(argv)
        return _finish(out, _fail(out, exc)), False
    out = Output(as_json=args.json, color=args.color, hold=True)
    try:
        with command_budget():
            code = int(args.func(args, out) or 0)
    except Exception as exc:
        if args.debug and not isinstance(exc, RosdeployError):
            traceback.print_exc()
        code = _fail(out, exc, args.debug)
    except KeyboardInterrupt as exc:
        code = _fail(out, exc)
    return _finish(out, code), bool(getattr(args, "acts", False))


def _early_output(argv: Sequence[str]) -> Output:
    """The options were not parsed: read the two that shape the output's form from argv."""
    return Output(as_json=_given(argv, "--json") is not None, color=_given(argv, "--color") or "auto", hold=True)


def _finish(out: Output, code: int) -> int:
    if code != EXIT_OK:     # a command that failed by its exit code, not by raising: the same `error` member
        out.amend({"error": {"kind": _KINDS.get(code, "error"), "message": EXIT_CODES.get(code, f"exit {code}"),
                             "problems": []}}, replace=False)
    out.finish(code)
    return code


# The `error.kind` of an exit code (README, --json), for a document whose command did not say it
_KINDS = {EXIT_INTERNAL: "internal", EXIT_INPUT: "input", EXIT_DECLINED: "declined",
          EXIT_INTERRUPTED: "interrupted"}


class Stopped(KeyboardInterrupt):
    """SIGTERM or SIGHUP (CI cancelling a job, `timeout`, a closed terminal), raised in the main
    thread as Ctrl-C's KeyboardInterrupt is, so both take one path: apply brings its running
    robots to a safe point and releases their locks, a read-only command stops waiting."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signal_name = signal.Signals(signum).name


def _stop(signum: int, frame: FrameType | None) -> None:
    raise Stopped(signum)


@contextmanager
def _stopped_by_signals() -> Iterator[None]:
    """SIGTERM and SIGHUP handled like Ctrl-C while main() runs (their default ends the process
    on the spot: no run record, locks left on the robots, no --json document)."""
    wanted = [getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name)]
    try:
        before = {signum: signal.signal(signum, _stop) for signum in wanted}
    except ValueError:     # not the main thread (main() called from a test's thread): no handlers
        before = {}
    try:
        yield
    finally:
        for signum, handler in before.items():
            signal.signal(signum, handler)


class GuardedStream:
    """stdout or stderr for one run: a write that fails (the reader of a pipe left, a full disk,
    a closed stream) stops the writing on that stream, never the command. `apply F | head` must
    still finish its robots, save its records and exit with its own code."""

    def __init__(self, stream: TextIO | None) -> None:
        self.stream = stream
        self.lost: OSError | None = None

    def write(self, text: str) -> int:
        if self.stream is None and self.lost is None and text:    # started with the stream closed (`>&-`)
            self.lost = OSError(errno.EBADF, os.strerror(errno.EBADF))
        if self.stream is not None and self.lost is None:
            try:
                return self.stream.write(text)
            except OSError as exc:
                self._give_up(exc)
        return len(text)

    def flush(self) -> None:
        if self.stream is not None and self.lost is None:
            try:
                self.stream.flush()
            except OSError as exc:
                self._give_up(exc)

    def isatty(self) -> bool:
        try:
            return self.stream is not None and self.stream.isatty()
        except (OSError, ValueError):
            return False

    def __getattr__(self, name: str) -> Any:
        return getattr(self.stream, name)

    def _give_up(self, exc: OSError) -> None:
        """Keep the failure, and point the descriptor at /dev/null: what is still buffered is
        flushed once more at exit, which would otherwise print Python's own complaint."""
        self.lost = exc
        try:
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, self.stream.fileno())    # type: ignore[union-attr]
            os.close(null)
        except (OSError, ValueError, AttributeError):   # no descriptor (a test's capture): nothing to flush
            pass


@contextmanager
def _guarded_streams() -> Iterator[tuple[GuardedStream, GuardedStream]]:
    streams = GuardedStream(sys.stdout), GuardedStream(sys.stderr)
    sys.stdout, sys.stderr = streams
    try:
        yield streams
    finally:
        sys.stdout, sys.stderr = streams[0].stream, streams[1].stream


def _after_lost_output(streams: tuple[GuardedStream, GuardedStream], code: int, acts: bool) -> int:
    """Output that could not be written is said once on stderr, when it can be, unless the
    reader of a pipe simply left (`| head`): that is the reader's choice, not a failure.
    A command that acts (apply, rollback, render, vault encrypt...) keeps its exit code: what it
    did is its product, and says how it went. For the others the output IS the product
    (`completion bash > FILE` on a full disk, `--json check`, `status`): a success whose output
    was lost is exit 1, or an install line would leave an empty file behind a zero exit."""
    out, err = streams
    if out.lost is None or out.lost.errno == errno.EPIPE:
        return code
    failed = code == EXIT_OK and not acts
    if err.lost is None and err.stream is not None:
        tail = ("the output is missing or incomplete" if failed else
                "the command ran to its end, its exit code says how it went")
        try:
            err.stream.write(f"rosdeploy: standard output could not be written "
                             f"({out.lost.strerror or out.lost}); {tail}\n")
            err.stream.flush()
        except OSError:
            pass
    return EXIT_INTERNAL if failed else code


def _fail(out: Output, exc: BaseException, debug: bool = False) -> int:
    """Report a failure on stderr and, with --json, as the run's one document on stdout."""
    code, kind, problems = _classify(exc)
    lines = [_text(p) for p in problems] or [_message(exc, debug)]
    for line in lines:
        out.error(f"error: {line}" if kind in ("usage", "input", "error") else line)
    if out.as_json:
        error = {"kind": kind, "message": "\n".join(lines), "problems": [_problem_json(p) for p in problems]}
        if out.documented:      # the command built its document first: it keeps it, with the error
            out.amend({"error": error})
        else:
            out.document({"ok": False, "exit_code": code, "error": error})
    return code


def _classify(exc: BaseException) -> tuple[int, str, tuple[Problem, ...]]:
    """Exit code, kind (usage, input, error, internal, interrupted) and the input problems."""
    if isinstance(exc, KeyboardInterrupt):
        return EXIT_INTERRUPTED, "interrupted", ()
    if isinstance(exc, UsageError):
        return EXIT_INPUT, "usage", ()
    if isinstance(exc, InputError):
        return EXIT_INPUT, "input", exc.problems
    if isinstance(exc, RosdeployError):
        return exc.exit_code, "error", ()
    return EXIT_INTERNAL, "internal", ()


def _message(exc: BaseException, debug: bool = False) -> str:
    if isinstance(exc, Stopped):
        return f"interrupted by {exc.signal_name}"
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted"
    if isinstance(exc, UsageError):
        return exc.message
    if isinstance(exc, RosdeployError):
        return str(exc)
    return f"internal error: {shown(exc, 500)} " + ("(the traceback is above)" if debug else
                                          "(run with --debug for the traceback)")


def _text(p: Problem) -> str:
    """A problem as one line; one without a file (a command-line problem) has no `file:` prefix."""
    if p.file:
        return str(p)
    return f"{p.key}: {p.message}" if p.key else p.message


def _problem_json(p: Problem) -> dict[str, Any]:
    from rosdeploy.cli.offline import problem_json
    return problem_json(p)


def _given(argv: Sequence[str], flag: str) -> str | None:
    """A global option as argparse would have read it, for an error raised before it could:
    abbreviations (`--js`) and `--color=never` count, words after `--` do not, and the last one
    given wins (`--color always --color never` is never). Its value ("" for a flag without
    one), or None when absent."""
    found = None
    for i, word in enumerate(argv):
        if word == "--":
            break
        name, eq, value = word.partition("=")
        if len(name) >= 3 and flag.startswith(name) and name.startswith("--"):
            if eq or flag != "--color":
                found = value
            else:
                found = argv[i + 1] if i + 1 < len(argv) else ""
    return found
