"""`rosdeploy` command line: argument parsing and exit codes, no deploy logic.

Each area registers its own subcommands (offline.py, sim.py, remote.py); a
handler gets the parsed args and the Output and returns an exit code.
"""
from __future__ import annotations

import argparse
import sys
import traceback
from typing import Sequence

from rosdeploy import __version__
from rosdeploy.errors import EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_OK, InputError, RosdeployError
from rosdeploy.output import Output


def build_parser() -> argparse.ArgumentParser:
    from rosdeploy.cli import images, offline, remote, sim, vault

    parser = argparse.ArgumentParser(
        prog="rosdeploy",
        description="Declarative deployment of ROS 2 software to robot fleets.")
    parser.add_argument("-V", "--rosdeploy-version", action="version", version=f"rosdeploy {__version__}")
    parser.add_argument("--json", action="store_true", help="print one JSON document on stdout")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of internal errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in (offline, remote, sim, vault, images):
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    out = Output(as_json=getattr(args, "json", False))
    try:
        return int(args.func(args, out) or 0)
    except InputError as exc:
        for problem in exc.problems:
            out.error(f"error: {problem}")
        return EXIT_INPUT
    except RosdeployError as exc:
        out.error(f"error: {exc}")
        return exc.exit_code
    except KeyboardInterrupt:
        out.error("interrupted")
        return EXIT_INTERRUPTED
    except BrokenPipeError:   # `rosdeploy plan ... | head`: the reader left, nothing is wrong
        sys.stderr.close()
        return EXIT_OK
    except Exception:  # a bug: say so plainly, keep the traceback for the report
        if args.debug:
            traceback.print_exc()
        else:
            out.error(f"internal error: {sys.exc_info()[1]!r} (run with --debug for the traceback)")
        return EXIT_INTERNAL
