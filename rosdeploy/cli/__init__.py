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
from rosdeploy.cli.common import EXIT_CODES, Parser, UsageError, add_command
from rosdeploy.errors import (EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_OK, InputError, Problem,
                              RosdeployError, shown)
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
        code = _main(list(sys.argv[1:] if argv is None else argv))
    _say_lost_output(streams)
    return code


def _main(argv: list[str]) -> int:
    try:
        args = build_parser().parse_args(argv)
    except VersionAsked:
        return cmd_version(argparse.Namespace(), Output(as_json=_given(argv, "--json") is not None))
    except UsageError as exc:
        # The options were not parsed: read the two that shape the error's form from argv.
        out = Output(as_json=_given(argv, "--json") is not None, color=_given(argv, "--color") or "auto")
        if not out.as_json:
            out.note(exc.usage.rstrip())
        return _fail(out, exc)
    except KeyboardInterrupt as exc:    # SIGTERM while the parser was built: nothing was done
        return _fail(Output(as_json=_given(argv, "--json") is not None), exc)
    out = Output(as_json=args.json, color=args.color)
    try:
        return int(args.func(args, out) or 0)
    except Exception as exc:
        if args.debug and not isinstance(exc, RosdeployError):
            traceback.print_exc()
        return _fail(out, exc, args.debug)
    except KeyboardInterrupt as exc:
        return _fail(out, exc)


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


def _say_lost_output(streams: tuple[GuardedStream, GuardedStream]) -> None:
    """Output that could not be written is said once on stderr, when it can be, unless the
    reader of a pipe simply left (`| head`): that is the reader's choice, not a failure."""
    out, err = streams
    if out.lost is None or out.lost.errno == errno.EPIPE or err.lost is not None or err.stream is None:
        return
    try:
        err.stream.write(f"rosdeploy: standard output could not be written ({out.lost.strerror or out.lost}); "
                         "the command ran to its end, its exit code says how it went\n")
        err.stream.flush()
    except OSError:
        pass


def _fail(out: Output, exc: BaseException, debug: bool = False) -> int:
    """Report a failure on stderr and, with --json, as the run's one document on stdout."""
    code, kind, problems = _classify(exc)
    lines = [_text(p) for p in problems] or [_message(exc, debug)]
    for line in lines:
        out.error(f"error: {line}" if kind in ("usage", "input", "error") else line)
    if out.as_json and not out.documented:
        out.document({"ok": False, "exit_code": code, "error": {
            "kind": kind, "message": "\n".join(lines), "problems": [_problem_json(p) for p in problems]}})
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
    abbreviations (`--js`) and `--color=never` count, words after `--` do not. Its value ("" for
    a flag without one), or None when absent."""
    for i, word in enumerate(argv):
        if word == "--":
            return None
        name, eq, value = word.partition("=")
        if len(name) >= 3 and flag.startswith(name) and name.startswith("--"):
            if eq or flag != "--color":
                return value
            return argv[i + 1] if i + 1 < len(argv) else ""
    return None
