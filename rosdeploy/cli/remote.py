"""Commands that talk to robots: apply, plan, status, rollback, history."""
from __future__ import annotations

import argparse
import getpass
from dataclasses import replace
from typing import Callable, Sequence

from rosdeploy import keeper, runlog
from rosdeploy.cli import images, report
from rosdeploy.cli.common import add_fleet_args
from rosdeploy.deploy import RunContext
from rosdeploy.keeper import kept_connect
from rosdeploy.errors import EXIT_ABORTED, EXIT_INPUT, EXIT_INTERRUPTED, EXIT_OK, EXIT_PARTIAL, InputError
from rosdeploy.model import Host, RolloutPolicy
from rosdeploy.output import Output, confirm
from rosdeploy.project import gate, load_project, prepare
from rosdeploy.rollout import apply_fleet, parallel, rollback_fleet
from rosdeploy.transport import SSHOptions, local_user_at_host
from rosdeploy.views import history_host, plan_host, status_host


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("apply", help="deploy the fleet file's release to the targeted robots")
    add_fleet_args(p)
    _add_run_args(p)
    p.add_argument("--forks", type=int, help="robots deployed in parallel within a wave")
    p.add_argument("--waves", help='comma-separated cumulative wave targets, e.g. "1,10%%,50%%,100%%"')
    p.add_argument("--max-fail", help="failures (count or N%%) tolerated per wave before the rollout stops")
    p.add_argument("--order-by", help="inventory group prefix to order robots by, e.g. site_")
    p.add_argument("--pause", type=float, help="seconds to wait between waves")
    p.add_argument("--step", action="store_true", help="ask before every wave after the first")
    images.add_from_bundle(p)
    p.set_defaults(func=cmd_apply)

    p = sub.add_parser("plan", help="show what apply would do, changing nothing")
    add_fleet_args(p)
    p.set_defaults(func=cmd_plan)

    p = sub.add_parser("status", help="the fleet's state: release, drift, services, health")
    add_fleet_args(p)
    p.set_defaults(func=cmd_status)

    p = sub.add_parser("rollback", help="emergency brake: switch robots to their previous release, no pull")
    add_fleet_args(p, version=False)
    _add_run_args(p)
    p.add_argument("--to", metavar="VERSION", help="a kept version to switch to instead of the previous one")
    p.add_argument("--forks", type=int, help="robots rolled back in parallel (default: all at once)")
    p.set_defaults(func=cmd_rollback)

    p = sub.add_parser("history", help="each robot's deploy history, newest first")
    add_fleet_args(p, version=False)
    p.add_argument("-n", type=int, default=10, help="entries per robot")
    p.set_defaults(func=cmd_history)

    p = sub.add_parser("connections", help="SSH connections held for status/plan/history (ssh.persist)")
    p.add_argument("--close", action="store_true", help="close them all now and stop the keeper")
    p.set_defaults(func=cmd_connections)


def _add_run_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("-y", "--yes", action="store_true", help="do not ask for confirmation")
    p.add_argument("--lock-wait", type=float, default=0.0, metavar="SECONDS",
                   help="wait this long for a robot's lock held by another run (default: fail at once)")
    p.add_argument("--break-lock", action="store_true", help="remove a stale lock left by a dead run")


# ----------------------------------------------------------------- loading

def load(args: argparse.Namespace, out: Output, render: bool = True):
    """Fleet file + inventory + targets (+ releases), validated: input errors stop here, before any robot.
    `render=False` (rollback): the releases kept on the robots are what runs, so neither the time
    to render nor a template error in what would be deployed next may hold up going back."""
    project = load_project(args.fleet, inventory=args.inventory, version=getattr(args, "release_version", None),
                           vault_password_file=args.vault_password_file,
                           prompt=getpass.getpass if out.interactive else None)
    hosts = project.targets(args.limit)
    out.mask(project.secret_values)
    if not render:
        return project, hosts, {}
    releases, problems = prepare(project, hosts)
    problems = gate(problems)
    errors = [p for p in problems if p.severity == "error"]
    if errors:
        raise InputError(errors)
    for warning in problems:
        out.warn(f"{warning.severity}: {warning}")
    return project, hosts, releases


def context(args: argparse.Namespace, spec, progress: Callable[[str, str], None]) -> RunContext:
    ssh = SSHOptions(known_hosts=spec.known_hosts, ssh_config=spec.ssh_config,
                     connect_timeout=spec.connect_timeout, command_timeout=spec.command_timeout)
    return RunContext(spec=spec, ssh=ssh, run_id=runlog.new_run_id(), operator=local_user_at_host(),
                      progress=progress, lock_wait=getattr(args, "lock_wait", 0.0),
                      break_lock=getattr(args, "break_lock", False))


def _confirmed(args: argparse.Namespace, out: Output, question: str) -> bool:
    if args.yes:
        return True
    if not out.interactive:
        raise InputError(f"{question.rstrip('?')}: refusing without a terminal to confirm; pass --yes")
    return confirm(out, question)


# ---------------------------------------------------------------- commands

def cmd_apply(args: argparse.Namespace, out: Output) -> int:
    project, hosts, releases = load(args, out)
    spec = project.spec
    policy = _policy(spec.rollout, args)
    if not _confirmed(args, out, f"Deploy {spec.project} {spec.version} to {len(hosts)} robot(s)?"):
        return EXIT_INPUT
    supply = images.supply(args, out, spec, hosts, releases)     # every tag pinned to its digest, once
    try:
        with report.progress_view(out, [h.name for h in hosts]) as view:
            ctx = replace(context(args, spec, view.progress), images=supply)
            result = apply_fleet(ctx, hosts, releases, policy, report.rollout_notifier(out, args, view))
    finally:
        if supply is not None:
            supply.close()
    return _finish(out, result)


def _policy(policy: RolloutPolicy, args: argparse.Namespace) -> RolloutPolicy:
    changes: dict = {}
    if args.forks:
        changes["forks"] = args.forks
    if args.waves:
        changes["waves"] = tuple(w if w.endswith("%") else int(w) for w in args.waves.replace(" ", "").split(","))
    if args.max_fail:
        changes["max_fail"] = args.max_fail if args.max_fail.endswith("%") else int(args.max_fail)
    if args.order_by:
        changes["order_by"] = args.order_by
    if args.pause is not None:
        changes["pause"] = args.pause
    return replace(policy, **changes)


def cmd_rollback(args: argparse.Namespace, out: Output) -> int:
    project, hosts, _ = load(args, out, render=False)
    target = args.to or "their previous release"
    if not _confirmed(args, out, f"Roll back {len(hosts)} robot(s) to {target}?"):
        return EXIT_INPUT
    with report.progress_view(out, [h.name for h in hosts]) as view:
        ctx = context(args, project.spec, view.progress)
        result = rollback_fleet(ctx, hosts, args.forks or max(len(hosts), 1), to_version=args.to)
    return _finish(out, result)


def _finish(out: Output, result) -> int:
    folder = runlog.save(result, out.masked)
    report.summary(out, result, folder)
    if result.interrupted:
        return EXIT_INTERRUPTED
    if result.aborted:
        return EXIT_ABORTED
    return EXIT_OK if result.ok else EXIT_PARTIAL


def cmd_status(args: argparse.Namespace, out: Output) -> int:
    project, hosts, releases = load(args, out)
    rows = _each(args, project.spec, hosts, lambda ctx, h: status_host(ctx, h, releases.get(h.name)))
    report.status(out, rows)
    return EXIT_OK if all(r.reachable and r.healthy and not r.drift for r in rows) else EXIT_PARTIAL


def cmd_plan(args: argparse.Namespace, out: Output) -> int:
    project, hosts, releases = load(args, out)
    supply = images.supply(args, out, project.spec, hosts, releases)
    rows = _each(args, project.spec, hosts, lambda ctx, h: plan_host(replace(ctx, images=supply), h, releases[h.name]))
    report.plan(out, rows)
    return EXIT_OK if all(r.reachable and not r.preflight for r in rows) else EXIT_PARTIAL


def cmd_history(args: argparse.Namespace, out: Output) -> int:
    project, hosts, _ = load(args, out)
    rows = _each(args, project.spec, hosts, lambda ctx, h: (h.name, *history_host(ctx, h)))
    report.history(out, rows, args.n)
    return EXIT_OK if all(r[1] for r in rows) else EXIT_PARTIAL


def _each(args: argparse.Namespace, spec, hosts: Sequence[Host], work) -> list:
    """Read-only work on every robot, over connections the keeper holds for the next command."""
    ctx = context(args, spec, lambda host, msg: None)
    if spec.ssh_persist > 0:
        ctx = replace(ctx, connect=kept_connect(spec.ssh_persist))
    return parallel(hosts, lambda h: work(ctx, h), spec.rollout.forks)


def cmd_connections(args: argparse.Namespace, out: Output) -> int:
    reply = keeper.ask({"op": "exit" if args.close else "list"})
    report.connections(out, reply, closed=args.close)
    return EXIT_OK
