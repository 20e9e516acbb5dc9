"""Commands that talk to robots: apply, plan, status, rollback, history, connections.

The SSH stack (paramiko, fabric, the keeper) is imported by the handlers, not here: every
command builds this parser, and `--help` or `validate` must not pay for it.
"""
from __future__ import annotations

import argparse
import getpass
import time
from dataclasses import replace
from typing import TYPE_CHECKING, Any, Callable, Sequence

from rosdeploy.cli import images
from rosdeploy.cli.common import (INTERRUPTED_RUN, Parser, add_command, add_fleet_args, duration, fail_limit,
                                  group_prefix, inventory_targets, positive_int, release_word, warnings_json,
                                  waves)
from rosdeploy.cli.vault import load_masked
from rosdeploy.errors import (EXIT_ABORTED, EXIT_DECLINED, EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_OK,
                              EXIT_PARTIAL, InputError, Problem)
from rosdeploy.output import Output, confirm

if TYPE_CHECKING:   # model.py costs 7 ms of dataclasses at import; --help needs none of it
    from rosdeploy.model import Host, RolloutPolicy
    from rosdeploy.deploy import RunContext
    from rosdeploy.model import FleetSpec
    from rosdeploy.results import FleetResult
    from rosdeploy.transport import EarlyConnect, SSHOptions

RUN_CODES = (EXIT_OK, EXIT_PARTIAL, EXIT_ABORTED, EXIT_DECLINED, EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED)
READ_CODES = (EXIT_OK, EXIT_PARTIAL, EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED)


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(sub, "apply", "deploy the fleet file's release to the targeted robots",
                    "Render each robot's release, then per robot and in waves: lock, pull the images while the "
                    "old release runs, upload, start, health gate (containers, restarts, ROS topics and rates), "
                    "activate, or roll back to the previous release. Asks before it starts unless --yes.",
                    RUN_CODES, "rosdeploy apply playbooks/demo.yml --limit robot2 --version 1.1.0 --yes",
                    {EXIT_OK: "every targeted robot runs the release, healthy", EXIT_INTERRUPTED: INTERRUPTED_RUN})
    add_fleet_args(p)
    _add_run_args(p)
    p.add_argument("--forks", type=positive_int, metavar="N", help="robots deployed in parallel within a wave")
    p.add_argument("--waves", type=waves, metavar="LIST",
                   help='comma-separated cumulative wave targets, e.g. "1,10%%,50%%,100%%"')
    p.add_argument("--max-fail", type=fail_limit, metavar="LIMIT",
                   help="failures tolerated per wave before the rollout stops: a count, or a percent like 10%%")
    p.add_argument("--order-by", type=group_prefix, metavar="PREFIX",
                   help="inventory group prefix to order robots by, e.g. site_")
    p.add_argument("--pause", type=duration, metavar="DURATION",
                   help="wait between waves: seconds or 30s, 2m, 1m30s (overrides rollout.pause)")
    p.add_argument("--step", action="store_true", help="ask before every wave after the first")
    p.add_argument("--until", type=duration, metavar="DURATION",
                   help="keep retrying robots that are unreachable, busy or outside their maintenance window "
                        "(backoff and jitter) for up to this long, e.g. 2h")
    p.add_argument("--force", action="store_true",
                   help="switch even when the readiness gate (ready:) or the maintenance window (window:) says no")
    images.add_from_bundle(p)
    p.set_defaults(func=cmd_apply, pick_up=True, acts=True)

    p = add_command(sub, "plan", "show what apply would do, changing nothing",
                    "Per robot: up to date, or the file diffs (secrets masked), the images to pull and the "
                    "preflight problems. Reads the robots, changes nothing.",
                    READ_CODES, "rosdeploy plan playbooks/demo.yml --version 1.1.0",
                    {EXIT_OK: "every robot reachable and no preflight problem",
                     EXIT_PARTIAL: "a robot unreachable or a preflight problem"})
    add_fleet_args(p)
    p.set_defaults(func=cmd_plan)

    p = add_command(sub, "status", "the fleet's state: release, drift, services, health",
                    "Per robot: reachable, running release, drift from what the fleet file renders, each "
                    "service's state and health, and the last deploy and by whom. Changes nothing.",
                    READ_CODES, "rosdeploy status playbooks/demo.yml --json",
                    {EXIT_OK: "every robot reachable, healthy and in sync",
                     EXIT_PARTIAL: "a robot unreachable, unhealthy, locked or drifted"})
    add_fleet_args(p)
    p.set_defaults(func=cmd_status)

    p = add_command(sub, "rollback", "emergency brake: switch robots to their previous release, no pull",
                    "Switch each robot to the release it ran before (or --to VERSION), from what is kept on "
                    "the robot: no render, no registry. Asks before it starts unless --yes.",
                    RUN_CODES[:2] + RUN_CODES[3:], "rosdeploy rollback playbooks/demo.yml --yes",
                    {EXIT_OK: "every targeted robot runs the release rolled back to, healthy",
                     EXIT_PARTIAL: "the rollback failed on some robot", EXIT_INTERRUPTED: INTERRUPTED_RUN})
    add_fleet_args(p, version=False)
    _add_run_args(p)
    p.add_argument("--to", type=release_word, metavar="VERSION",
                   help="a kept version to switch to instead of the previous one")
    p.add_argument("--forks", type=positive_int, metavar="N",
                   help="robots rolled back in parallel (default: all at once)")
    p.set_defaults(func=cmd_rollback, acts=True)

    p = add_command(sub, "history", "each robot's deploy history, newest first",
                    "Each robot's deploys and rollbacks, newest first: time, event, release, result, by whom.",
                    READ_CODES, "rosdeploy history playbooks/demo.yml -n 3",
                    {EXIT_PARTIAL: "a robot unreachable"})
    add_fleet_args(p, version=False)
    p.add_argument("-n", type=positive_int, default=10, metavar="N", help="entries per robot (default 10)")
    p.set_defaults(func=cmd_history)

    p = add_command(sub, "connections", "SSH connections held for status/plan/history (ssh.persist)",
                    "List the SSH connections the keeper holds for status, plan and history, or close them.",
                    (EXIT_OK, EXIT_INPUT, EXIT_INTERNAL), "rosdeploy connections --close")
    p.add_argument("--close", action="store_true", help="close them all now and stop the keeper")
    p.set_defaults(func=cmd_connections)


def _add_run_args(p: Parser) -> None:
    p.add_argument("-y", "--yes", action="store_true", help="do not ask for confirmation")
    p.add_argument("--lock-wait", type=duration, default=0.0, metavar="DURATION",
                   help="wait this long for a robot's lock held by another run: seconds or 30s, 2m "
                        "(default: fail at once)")
    p.add_argument("--break-lock", action="store_true", help="remove a stale lock left by a dead run")
    p.add_argument("--no-host-changes", action="store_true",
                   help="do not install udev rules or the log rotation schedule on the robots (warns)")
    p.add_argument("--ask-become-pass", action="store_true",
                   help="ask for the sudo password used for host changes on robots not reached as root")


# ----------------------------------------------------------------- loading

def load(args: argparse.Namespace, out: Output, render: bool = True,
         on_targets: Callable[[Any, tuple[Host, ...]], None] = lambda project, hosts: None,
         ) -> tuple[Any, tuple[Host, ...], dict]:
    """Fleet file + inventory + targets (+ releases), validated: input errors stop here, before any robot.
    `render=False` (rollback): the releases kept on the robots are what runs, so neither the time
    to render nor a template error in what would be deployed next may hold up going back.
    `on_targets`: called once the targets are known, before rendering (apply's early connections)."""
    from rosdeploy.project import deployable

    project = load_masked(args, out, getattr(args, "release_version", None))
    hosts, loaded = inventory_targets(project, args.limit, out)
    warnings_json(out, loaded)      # the document's `warnings`, whatever stops the command later
    if getattr(args, "pick_up", False):     # apply: robots still pending for this fleet file and version
        from rosdeploy.cli import pending as pending_cli
        hosts = pending_cli.with_pending(project, hosts, out)
    on_targets(project, hosts)
    loaded += _known_hosts_notes(project.spec, hosts, out)
    warnings_json(out, loaded)
    if not render:
        return project, hosts, {}
    releases, warnings = deployable(project, hosts)
    for warning in warnings:
        out.warn(f"{warning.severity}: {warning}")
    warnings_json(out, [*loaded, *warnings])
    return project, hosts, releases


def _known_hosts_notes(spec: FleetSpec, hosts: tuple[Host, ...], out: Output) -> tuple[Problem, ...]:
    """Lines of the robots' known_hosts files that were skipped, whether or not a robot's key is found:
    a skipped @revoked line leaves a key trusted. Here, not in validate: reading keys needs paramiko,
    which commands that connect load anyway (validate stays free of its ~0.2 s import)."""
    from rosdeploy import transport

    problems = tuple(transport.known_hosts_problems(hosts, ssh_options(spec)))
    for problem in problems:
        out.warn(f"{problem.severity}: {problem}")
    return problems


def context(args: argparse.Namespace, spec: FleetSpec, progress: Callable[[str, str], None]) -> RunContext:
    from rosdeploy import runlog
    from rosdeploy.deploy import RunContext
    from rosdeploy.transport import local_user_at_host

    return RunContext(spec=spec, ssh=ssh_options(spec), run_id=runlog.new_run_id(), operator=local_user_at_host(),
                      progress=progress, lock_wait=getattr(args, "lock_wait", 0.0),
                      break_lock=getattr(args, "break_lock", False), force=getattr(args, "force", False),
                      host_changes=not getattr(args, "no_host_changes", False),
                      become_password=getattr(args, "become_password", None))


def ssh_options(spec: FleetSpec) -> "SSHOptions":
    from rosdeploy.transport import SSHOptions

    return SSHOptions(known_hosts=spec.known_hosts, ssh_config=spec.ssh_config,
                      connect_timeout=spec.connect_timeout, command_timeout=spec.command_timeout)


class EarlyConnections:
    """apply --yes: the connections the rollout opens first, opened while the release renders
    (transport.EarlyConnect): every robot's, for the pre-check of a rollout in waves (up to
    `forks` at once, the robots it asks first), else the one wave's."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.early: "EarlyConnect | None" = None

    def start(self, project: Any, hosts: tuple[Host, ...]) -> None:
        from rosdeploy.rollout import ordered
        from rosdeploy.transport import EarlyConnect

        if self.args.yes and hosts:
            policy = _policy(project.spec.rollout, self.args)
            first = ordered(hosts, policy.order_by)[:policy.forks]
            self.early = EarlyConnect(first, ssh_options(project.spec))

    def use(self, ctx: "RunContext") -> "RunContext":
        return replace(ctx, connect=self.early.connect) if self.early else ctx

    def close(self) -> None:
        if self.early:
            self.early.close()


def host_change_args(args: argparse.Namespace, out: Output) -> None:
    """--no-host-changes warns; --ask-become-pass asks once, before any robot is touched."""
    if getattr(args, "no_host_changes", False):
        out.warn("--no-host-changes: udev rules and the ROS log rotation schedule are not installed or restored "
                 "on any robot; the /dev/robot/* names may be missing or stale, and the logs rotate on the old "
                 "schedule or not at all")
    if getattr(args, "ask_become_pass", False):
        if not out.can_ask:
            raise InputError("--ask-become-pass needs a terminal to ask on; put ansible_become_password in a vault")
        args.become_password = getpass.getpass("BECOME password: ")


def _confirmed(args: argparse.Namespace, out: Output, question: str) -> bool:
    if args.yes:
        return True
    if not out.can_ask:
        raise InputError(f"{question.rstrip('?')}: refusing without a terminal to confirm; pass --yes")
    return confirm(out, question)


# ---------------------------------------------------------------- commands

def cmd_apply(args: argparse.Namespace, out: Output) -> int:
    if args.step and not out.can_ask:    # before any connection: going on unasked is not what --step asked
        raise InputError("--step asks before every wave after the first: it needs a terminal to ask on "
                         "(or use --waves and run again for each wave)")
    early = EarlyConnections(args)
    try:
        return _apply(args, out, early)
    finally:
        early.close()


def _apply(args: argparse.Namespace, out: Output, early: EarlyConnections) -> int:
    from rosdeploy.cli import pending as pending_cli
    from rosdeploy.cli import report
    from rosdeploy.rollout import apply_fleet

    project, hosts, releases = load(args, out, on_targets=early.start)
    host_change_args(args, out)
    spec = project.spec
    policy = _policy(spec.rollout, args)
    if not _confirmed(args, out, f"Deploy {spec.project} {spec.version} to {len(hosts)} robot(s)?"):
        return _declined(out)
    supply = images.supply(args, out, spec, hosts, releases)     # every tag pinned to its digest, once
    try:
        with report.progress_view(out, [h.name for h in hosts]) as view:
            ctx = early.use(replace(context(args, spec, view.progress), images=supply))
            notify = _kept_going(out, pending_cli.notifier(out, spec, ctx.run_id,
                                                           report.rollout_notifier(out, args, view)))
            until = time.monotonic() + args.until if args.until else None
            result = apply_fleet(ctx, hosts, releases, policy, notify, until=until)
    finally:
        if supply is not None:
            supply.close()
    try:
        pending_cli.after_apply(spec, result)
    except OSError as exc:    # the rollout happened: its outcome and exit code matter more than the record
        _unsaved(out, "the pending record (robots for `apply` to pick up next time)", exc)
    return _finish(out, result)


def _kept_going(out: Output, notify: Callable[[str, dict], None]) -> Callable[[str, dict], None]:
    """`apply --until` writes the pending record at every retry: one it cannot write is warned
    about once, and the retries go on (an OSError out of notify would abandon the rollout)."""
    warned: list[OSError] = []

    def guarded(event: str, data: dict) -> None:
        try:
            notify(event, data)
        except OSError as exc:
            if event != "pending":
                raise
            if not warned:
                _unsaved(out, "the pending record", exc)
            warned.append(exc)
    return guarded


def _unsaved(out: Output, what: str, exc: OSError) -> None:
    where = f" at {exc.filename}" if exc.filename else ""
    out.warn(f"warning: could not write {what}{where}: {exc.strerror or exc}")


def _policy(policy: RolloutPolicy, args: argparse.Namespace) -> RolloutPolicy:
    changes: dict = {}
    if args.forks:
        changes["forks"] = args.forks
    if args.waves:
        changes["waves"] = args.waves
    if args.max_fail is not None:
        changes["max_fail"] = args.max_fail
    if args.order_by:
        changes["order_by"] = args.order_by
    if args.pause is not None:
        changes["pause"] = args.pause
    return replace(policy, **changes)


def cmd_rollback(args: argparse.Namespace, out: Output) -> int:
    from rosdeploy.cli import report
    from rosdeploy.rollout import rollback_fleet

    project, hosts, _ = load(args, out, render=False)
    host_change_args(args, out)
    target = args.to or "their previous release"
    if not _confirmed(args, out, f"Roll back {len(hosts)} robot(s) to {target}?"):
        return _declined(out)
    with report.progress_view(out, [h.name for h in hosts]) as view:
        ctx = context(args, project.spec, view.progress)
        result = rollback_fleet(ctx, hosts, args.forks or max(len(hosts), 1), to_version=args.to)
    return _finish(out, result)


def _declined(out: Output) -> int:
    message = "declined: nothing was done"
    out.error(message)
    if out.as_json:     # `--json apply` answered no at a terminal: the document still says so
        out.document({"ok": False, "exit_code": EXIT_DECLINED,
                      "error": {"kind": "declined", "message": message, "problems": []}})
    return EXIT_DECLINED


def _finish(out: Output, result: FleetResult) -> int:
    from rosdeploy import runlog
    from rosdeploy.cli import report

    try:
        folder = runlog.save(result, out.masked)
    except OSError as exc:    # ROSDEPLOY_RUNS_DIR a file, a full disk: still report what the robots did
        if not exc.filename:
            exc.filename = str(runlog.runs_dir() / result.run_id)
        _unsaved(out, "the run record", exc)
        folder = None
    report.summary(out, result, folder)
    if result.interrupted:
        return EXIT_INTERRUPTED
    if result.aborted:
        return EXIT_ABORTED
    return EXIT_OK if result.ok else EXIT_PARTIAL


def cmd_status(args: argparse.Namespace, out: Output) -> int:
    from rosdeploy.cli import pending as pending_cli, report
    from rosdeploy.views import status_host

    project, hosts, releases = load(args, out)
    rows = _each(args, project.spec, hosts, lambda ctx, h: status_host(ctx, h, releases.get(h.name)))
    rows = pending_cli.status_rows(rows, project.spec)
    report.status(out, rows)
    pending_cli.status_notes(out, rows)
    return EXIT_OK if all(r.reachable and r.healthy and not r.drift for r in rows) else EXIT_PARTIAL


def cmd_plan(args: argparse.Namespace, out: Output) -> int:
    from rosdeploy.cli import report
    from rosdeploy.views import plan_host

    project, hosts, releases = load(args, out)
    supply = images.supply(args, out, project.spec, hosts, releases)
    rows = _each(args, project.spec, hosts, lambda ctx, h: plan_host(replace(ctx, images=supply), h, releases[h.name]))
    report.plan(out, rows)
    return EXIT_OK if all(r.reachable and not r.preflight for r in rows) else EXIT_PARTIAL


def cmd_history(args: argparse.Namespace, out: Output) -> int:
    from rosdeploy.cli import report
    from rosdeploy.views import history_host

    project, hosts, _ = load(args, out)
    rows = _each(args, project.spec, hosts, lambda ctx, h: (h.name, *history_host(ctx, h)))
    report.history(out, rows, args.n)
    return EXIT_OK if all(r[1] for r in rows) else EXIT_PARTIAL


def _each(args: argparse.Namespace, spec: FleetSpec, hosts: Sequence[Host],
          work: Callable[[RunContext, Host], Any]) -> list:
    """Read-only work on every robot, over connections the keeper holds for the next command."""
    from rosdeploy.keeper import kept_connect
    from rosdeploy.rollout import gather

    ctx = context(args, spec, lambda host, msg: None)
    if spec.ssh_persist > 0:
        ctx = replace(ctx, connect=kept_connect(spec.ssh_persist))
    try:
        return gather(hosts, lambda h: work(ctx, h), spec.rollout.forks)
    except RuntimeError as exc:
        if "can't start new thread" not in str(exc):
            raise
        raise _too_many_threads(spec, len(hosts)) from None


def _too_many_threads(spec: FleetSpec, robots: int) -> InputError:
    """A thread per robot, up to `forks`, could not be started (an address-space or pids limit:
    200 threads x 8 MB of stack under `ulimit -v`): an internal error said nothing of what to do.
    Read-only commands, so nothing was changed; the threads already started end with the process."""
    from rosdeploy.errors import Problem
    forks = min(spec.rollout.forks, robots)
    return InputError([Problem(spec.path, None, "rollout.forks",
                               f"cannot start {forks} threads (one per robot read at once): this machine's limits "
                               "(ulimit -v, ulimit -u, a cgroup's pids.max) allow fewer; lower `rollout.forks` "
                               "in the fleet file, e.g. to 50, or raise the limit")])


def cmd_connections(args: argparse.Namespace, out: Output) -> int:
    from rosdeploy import keeper
    from rosdeploy.cli import report

    reply, silent = keeper.ask_why({"op": "exit" if args.close else "list"})
    why = (silent or keeper.unavailable()) if reply is None else None
    report.connections(out, reply, closed=args.close, unavailable=why)
    return EXIT_OK
