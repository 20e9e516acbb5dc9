"""What every command shares: the parser class with the global options, the exit-code table
rendered into each command's help, and the arguments several commands take."""
from __future__ import annotations

import argparse
import os
import re
from dataclasses import replace
from typing import TYPE_CHECKING, Any, NoReturn, Sequence

from rosdeploy.errors import (EXIT_ABORTED, EXIT_DECLINED, EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_OK,
                              EXIT_PARTIAL, InputError, Problem, shown)

if TYPE_CHECKING:
    from rosdeploy.output import Output

COLOR_MODES = ("auto", "always", "never")

# The one table of exit codes: each command's epilog shows the rows that apply to it, the README
# shows them all (tests/unit/test_cli.py checks both against this).
EXIT_CODES: dict[int, str] = {
    EXIT_OK: "success",
    EXIT_INTERNAL: "internal error: a bug in rosdeploy (--debug shows the traceback); or the output of a "
                   "command that only prints could not be written (a full disk)",
    EXIT_INPUT: "input error: fleet file, inventory, template, vault or usage; nothing was touched",
    EXIT_PARTIAL: "some robots failed, were rolled back, locked or unreachable (within max_fail)",
    EXIT_ABORTED: "a wave exceeded max_fail: the rollout stopped, later waves skipped",
    EXIT_DECLINED: "declined at the confirmation prompt: nothing was done",
    EXIT_INTERRUPTED: "interrupted (Ctrl-C, SIGTERM or SIGHUP)",
}
# What apply and rollback do with Ctrl-C (or SIGTERM, SIGHUP) before they exit
INTERRUPTED_RUN = "interrupted (Ctrl-C, SIGTERM or SIGHUP): robots mid-deploy finished or rolled back, locks released"
# Any command can be given a wrong word, hit a bug, or be interrupted
ALWAYS = (EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED)


class UsageError(InputError):
    """The command line itself is wrong (argparse's complaint), raised instead of argparse's exit
    so that `--json` still gets its one document."""

    def __init__(self, parser: argparse.ArgumentParser, message: str) -> None:
        self.usage = parser.format_usage()
        self.message = f"{parser.prog}: {message} (see `{parser.prog} --help`)"
        super().__init__(self.message)


class Parser(argparse.ArgumentParser):
    """Every rosdeploy (sub)command's parser: the global options are accepted before and after
    the subcommand, and a usage error is raised instead of exiting.

    The root parser holds the defaults; a subcommand's copy defaults to SUPPRESS, or argparse
    would reset `rosdeploy --json status F` to json=False when it parses `status F`."""

    def __init__(self, *args: Any, root: bool = False, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", argparse.RawDescriptionHelpFormatter)
        super().__init__(*args, **kwargs)
        unset: Any = argparse.SUPPRESS
        group = self.add_argument_group("global options (before or after the command)")
        group.add_argument("--json", action="store_true", default=False if root else unset,
                           help="print one JSON document on stdout, errors included")
        group.add_argument("--debug", action="store_true", default=False if root else unset,
                           help="show the traceback of an internal error")
        group.add_argument("--color", choices=COLOR_MODES, default="auto" if root else unset, metavar="WHEN",
                           help="colour: auto (per stream, when a terminal; NO_COLOR, FORCE_COLOR), "
                                "always or never")

    def error(self, message: str) -> NoReturn:
        choice = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)", message)
        if choice:    # `rosdeploy aply`: the command meant, as the fleet file's keys get
            from rosdeploy.suggest import did_you_mean
            hint = did_you_mean(choice[1], re.findall(r"'([^']*)'", choice[2]))
            message += f"; {hint}" if hint else ""
        raise UsageError(self, message)

    def add_argument(self, *args: Any, **kwargs: Any) -> argparse.Action:
        if args and str(args[0]).startswith("-") and kwargs.get("action", "store") == "store" \
                and kwargs.get("nargs") is None:
            kwargs["action"] = Once
        return super().add_argument(*args, **kwargs)

    def parse_args(self, args: Sequence[str] | None = None, namespace: Any = None) -> Any:  # type: ignore[override]
        """argparse blames words no command took on the root parser (`rosdeploy: unrecognized
        arguments`): blame the command they were given to, whose --help lists what it takes."""
        try:
            parsed, extra = self.parse_known_args(args, namespace)
        except UsageError as exc:
            raise self._with_unknown(exc, list(args or ())) from None
        if extra:
            owner: Parser = getattr(parsed, "command_parser", self)
            owner.error(f"unrecognized arguments: {' '.join(extra)}")
        return parsed


    def _with_unknown(self, exc: UsageError, argv: list[str]) -> UsageError:
        """`rosdeploy -x`: argparse said only that COMMAND is missing; name the option it did not know."""
        if "required: COMMAND" not in exc.message:
            return exc
        known = self._option_string_actions
        unknown = [w for w in argv if w.startswith("-") and w != "--"
                   and not any(o.startswith(w.split("=", 1)[0]) for o in known)]
        if unknown:
            exc.message = exc.message.replace(" (see", f"; unrecognized arguments: {' '.join(unknown)} (see", 1)
        return exc


def epilog(codes: Sequence[int], example: str, meanings: dict[int, str] | None = None) -> str:
    """The exit codes this command can return (from EXIT_CODES, or a command's own meaning of one)
    and an example, below its options in --help."""
    meanings = {**EXIT_CODES, **(meanings or {})}
    rows = "\n".join(f"  {code:>3}  {meanings[code]}" for code in sorted({*codes, *ALWAYS}))
    return f"exit codes:\n{rows}\n\nexample:\n  {example}"


def add_command(sub: argparse._SubParsersAction, name: str, summary: str, description: str,
                codes: Sequence[int], example: str, meanings: dict[int, str] | None = None) -> Parser:
    """A subcommand with its one-line summary, its description, and its exit codes and example."""
    parser: Parser = sub.add_parser(name, help=summary, description=description,
                                    epilog=epilog(codes, example, meanings))
    parser.set_defaults(command_parser=parser)     # the innermost command's wins (Parser.parse_args)
    return parser


def duration(text: str) -> float:
    """`--pause 30s`, `--lock-wait 2m`: the fleet file's durations (plain numbers are seconds)."""
    from rosdeploy.fleet import parse_duration   # here: the parser is built for every command

    try:
        return parse_duration(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"invalid duration {shown(text)}: use seconds or a duration like 30s, 2m, 1m30s, 500ms, "
            "at most 8784h (a year)") from None


def waves(text: str) -> tuple[int | str, ...]:
    """`--waves 1,10%,100%`: the fleet file's rollout.waves, one target per comma."""
    from rosdeploy.fleet import WAVE_HINT, wave_order
    waves = tuple(_wave_word(word, 1, f"each wave must be {WAVE_HINT}") for word in text.replace(" ", "").split(","))
    problem = wave_order(waves)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return waves


def fail_limit(text: str) -> int | str:
    """`--max-fail 2` or `--max-fail 10%`: the fleet file's rollout.max_fail."""
    from rosdeploy.fleet import WAVE_HINT
    return _wave_word(text.strip(), 0, f"must be 0 or {WAVE_HINT}")


def _wave_word(word: str, least: int, hint: str) -> int | str:
    from rosdeploy.fleet import wave_target
    try:
        # ASCII digits, any count the fleet file takes (int() alone would take "1_0" and "٥")
        return wave_target(int(word) if re.fullmatch(r"[0-9]+", word) else word, least)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{shown(word)}: {hint}") from None


def release_word(text: str) -> str:
    """`rollback --to 1.0.0` (or a release id): a tag's characters, refused before any robot is
    asked (`../../x` would otherwise travel to every robot as a release name)."""
    from rosdeploy.fleet import TAG_RE
    if not TAG_RE.fullmatch(text):
        raise argparse.ArgumentTypeError(f"{shown(text)} is not a version or release id: use letters, digits, `_`, "
                                         "`.` and `-`, e.g. 1.0.0 or 1.0.0-3f9a2c1d4e5f")
    return text


def group_prefix(text: str) -> str:
    """`--order-by site_`: what the fleet file's rollout.order_by takes."""
    from rosdeploy.fleet import GROUP_PREFIX_RE
    if not GROUP_PREFIX_RE.fullmatch(text):
        raise argparse.ArgumentTypeError(f"{shown(text)} is not a group prefix: letters, digits, `_`, `.` and `-`, "
                                         "e.g. site_")
    return text


def positive_int(text: str) -> int:
    """A count from 1 up to the fleet file's bound for counts (2**31 - 1: more is a typo)."""
    from rosdeploy.fleet import MAX_COUNT
    # ASCII digits only, as in the fleet file: int() alone takes "1_0", " 5 " and "٥"
    value = int(text) if re.fullmatch(r"[0-9]{1,12}", text) else 0
    if not 1 <= value <= MAX_COUNT:
        raise argparse.ArgumentTypeError(f"{shown(text)} is not a whole number from 1 to {MAX_COUNT}")
    return value


def path_arg(text: str) -> str:
    """A path from the command line: `~` and `~user` expanded here, where an unknown user or a
    NUL byte can still be an argument error instead of a crash deep in a file open."""
    if not text:     # `-i ""` (an unset shell variable): no path at all, not "the default"
        raise argparse.ArgumentTypeError("an empty path: name a file or directory")
    if "\0" in text:
        raise argparse.ArgumentTypeError(f"{shown(text)} holds a NUL byte: no path can")
    expanded = os.path.expanduser(text)
    if expanded.startswith("~"):
        user = expanded[1:].split("/", 1)[0]
        raise argparse.ArgumentTypeError(f"{shown(text)}: there is no user {shown(user)} to expand ~{user} for")
    return expanded


class Once(argparse.Action):
    """An option with one value, given once: argparse silently kept the last one
    (`apply F --version 1 --version 2` deployed 2, `--limit a --limit b` targeted b), where
    Ansible reads -i twice as two inventories. Every single-value option of every command is
    one (Parser.add_argument); the global options are not (the last --color wins, as argparse's)."""

    why = "give it once"

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        # a set of what was given, not the value: a default (--lock-wait 0, -n 10) is no value given
        given = namespace.__dict__.setdefault("_given_once", set())
        if self.dest in given:
            raise argparse.ArgumentError(self, f"given twice: {self.why}")
        given.add(self.dest)
        setattr(namespace, self.dest, values)


class _OneLimit(Once):
    why = "give one pattern: join them with `:` (a:b targets both), as Ansible's --limit"


class _OneInventory(Once):
    why = ("rosdeploy reads one inventory, a file or a folder (whose files it merges, as Ansible does): "
           "put them in one folder")


def add_fleet_args(parser: argparse.ArgumentParser, *, limit: bool = True, version: bool = True) -> None:
    parser.add_argument("fleet", type=path_arg, metavar="FLEET", help="the fleet file, e.g. playbooks/warehouse.yml")
    parser.add_argument("-i", "--inventory", type=path_arg, metavar="PATH", action=_OneInventory,
                        help="inventory file or directory (overrides the fleet file's `inventory`)")
    if limit:
        parser.add_argument("-l", "--limit", metavar="PATTERN", action=_OneLimit,
                            help="robots to target, Ansible patterns: names, groups, globs, ~regex, a:b, a:&b, "
                                 "a:!b, @file")
    if version:
        parser.add_argument("--version", dest="release_version", metavar="VERSION",
                            help="release version (every image's tag; overrides the fleet file's `version`)")
    from rosdeploy.cli.vault import add_vault_options   # imported here: cli.vault imports this module
    add_vault_options(parser)


# The rule ids of what loading the robots warns about, in a --json document (`problems`,
# `findings`, `warnings`): the inventory's own warnings, and --limit's terms that match nothing.
# Neither is a checklist rule (no `fix`): the message says what to do.
INVENTORY_RULE = "inventory"
LIMIT_RULE = "limit"


def inventory_targets(project: Any, limit: str | None, out: Output) -> tuple[tuple[Any, ...], tuple[Problem, ...]]:
    """--limit's robots and the warnings of choosing them: printed, as Ansible prints its warnings
    (another tool's vars, duplicate keys, `web:nomatch`), and returned, for the --json document
    and the warning count (a CI reading only the document must see "your `devices` was ignored")."""
    found: list[Problem] = []
    hosts = project.targets(limit, found)
    warnings = (*_as_warnings(project.inventory.warnings, INVENTORY_RULE), *_as_warnings(found, LIMIT_RULE))
    for problem in warnings:
        out.warn(f"warning: {problem}")
    return tuple(hosts), warnings


def _as_warnings(problems: Sequence[Problem], rule: str) -> tuple[Problem, ...]:
    # severity "warning" whatever they were made with: some take Problem's default, yet stop nothing
    return tuple(replace(p, severity="warning", rule=p.rule or rule) for p in problems)


def warnings_json(out: Output, warnings: Sequence[Problem]) -> None:
    """`warnings` in the --json document of a command with no list of problems of its own (render,
    plan, apply...), whoever builds it: the command, or the error that stops it later."""
    if out.as_json:     # not otherwise: problem_json imports the checklist, which a rollback never needs
        from rosdeploy.cli.offline import problem_json
        out.also({"warnings": [problem_json(p) for p in warnings]})
