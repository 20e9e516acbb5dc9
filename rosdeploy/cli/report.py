"""How results look: progress lines, the summary table, status/plan/history views.

Human text by default; with --json one document on stdout (progress and
errors still go to stderr, so CI logs stay readable and the JSON parseable).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any, Callable, Sequence

from rosdeploy.output import Output, confirm
from rosdeploy.results import OK_OUTCOMES, FleetResult, HostResult, version_of



def progress_printer(out: Output, started: float) -> Callable[[str, str], None]:
    """One line per step per robot: works on a terminal and in a CI log alike."""
    def show(host: str, step: str) -> None:
        out.line(out.paint(f"{time.monotonic() - started:7.1f}s ", "dim") + f"{host:<16} {step}")
    return show


def rollout_notifier(out: Output, args: argparse.Namespace) -> Callable[[str, dict], None]:
    def notify(event: str, data: dict) -> None:
        if event == "wave":
            out.line(out.paint(f"== wave {data['number']}/{data['of']}: {', '.join(data['hosts'])}", "bold"))
            if args.step and data["number"] > 1 and out.interactive and not confirm(out, "Start this wave?"):
                raise KeyboardInterrupt
        elif event == "abort":
            out.error(f"rollout stopped in wave {data['wave']}: {len(data['failed'])} robot(s) failed "
                      f"({', '.join(data['failed'])}), more than max_fail={data['max_fail']}")
        elif event == "fleet-rollback":
            out.warn(f"fleet-level rollback of robots already on the new release: {', '.join(data['hosts'])}")
        elif event == "pause":
            out.line(f"pausing {data['seconds']:g}s before the next wave")
    return notify


def summary(out: Output, result: FleetResult, folder: Path) -> None:
    if out.as_json:
        out.document({**result.to_json(), "run_dir": str(folder)})
        return
    rows = [_row(h) for h in result.hosts]
    out.line()
    out.table(["ROBOT", "WAVE", "RESULT", "RELEASE (old -> now)", "TIME", "REASON"], rows)
    if result.fleet_rollback:
        out.line()
        out.line(out.paint("fleet-level rollback:", "bold"))
        out.table(["ROBOT", "WAVE", "RESULT", "RELEASE (old -> now)", "TIME", "REASON"],
                  [_row(h) for h in result.fleet_rollback])
    for host in result.hosts + result.fleet_rollback:
        for service, text in host.logs.items():
            out.line(out.paint(f"--- {host.host} {service}: last log lines", "bold"))
            out.line("\n".join(text.splitlines()[-10:]))
    counts: dict[str, int] = {}
    for h in result.hosts:
        counts[h.outcome] = counts.get(h.outcome, 0) + 1
    tally = ", ".join(f"{n} {k}" for k, n in sorted(counts.items()))
    style = "green" if result.ok else "red"
    out.line(out.paint(f"{result.command}: {tally} in {result.seconds:.1f}s", style) + f"  (record: {folder})")


def _row(h: HostResult) -> list[str]:
    old = version_of(h.old_release) or "-"
    now = version_of(h.running_release) or "-"
    reason = h.reason if h.outcome not in OK_OUTCOMES else ""
    return [h.host, str(h.wave or ""), h.outcome, f"{old} -> {now}", f"{h.seconds:.1f}s", reason[:160]]


def status(out: Output, rows: Sequence[Any]) -> None:
    if out.as_json:
        out.document({"robots": [_plain(r) for r in rows]})
        return
    table = []
    for r in rows:
        if not r.reachable:
            table.append([r.host, "UNREACHABLE", "-", "-", "-", r.error[:120]])
            continue
        services = ", ".join(f"{s['service']}:{s['health'] or s['status']}" for s in r.services) or "none"
        drift = "-" if r.drift is None else ("DRIFT" if r.drift else "in sync")
        health = "healthy" if r.healthy else ("not deployed" if not r.release else "UNHEALTHY")
        last = f"{r.deployed_at or '-'} by {r.deployed_by or '-'}"
        table.append([r.host, health, r.version or "-", drift, services, last])
    out.table(["ROBOT", "STATE", "VERSION", "DRIFT", "SERVICES", "LAST DEPLOY"], table)


def plan(out: Output, rows: Sequence[Any]) -> None:
    if out.as_json:
        out.document({"robots": [_plain(r) for r in rows]})
        return
    for r in rows:
        if not r.reachable:
            out.line(f"{r.host}: UNREACHABLE: {r.error}")
            continue
        if r.up_to_date:
            out.line(f"{r.host}: up to date ({r.current})")
            continue
        out.line(out.paint(f"{r.host}: {r.current or 'nothing'} -> {r.new}", "bold"))
        for problem in r.preflight:
            out.error(f"  preflight: {problem}")
        for image in r.pulls:
            out.line(f"  pull {image}")
        for name, diff in r.diffs:
            out.line(f"  {name} changes:" if diff else f"  {name}")
            out.line("\n".join("    " + line for line in diff.splitlines()))


def history(out: Output, rows: Sequence[tuple], limit: int) -> None:
    if out.as_json:
        out.document({"robots": [{"host": h, "reachable": ok, "error": err, "history": list(entries[:limit])}
                                 for h, ok, err, entries in rows]})
        return
    for host, ok, err, entries in rows:
        out.line(out.paint(host, "bold") + ("" if ok else f": UNREACHABLE: {err}")
                 + (": no deploys yet" if ok and not entries else ""))
        for e in entries[:limit]:
            detail = f" from {e['rolled_back_from']}" if e.get("rolled_back_from") else ""
            reason = f" ({e['reason']})" if e.get("reason") else ""
            out.line(f"  {e.get('time', '?')}  {e.get('event', '?'):<13} {e.get('release', '?')}{detail}  "
                     f"{e.get('result', '')}  by {e.get('by', '?')}{reason}")


def connections(out: Output, reply: dict | None, closed: bool) -> None:
    held = [] if reply is None else reply.get("connections", [])
    if out.as_json:
        out.document({"keeper": reply is not None, "closed": reply.get("closing", 0) if closed and reply else 0,
                      "connections": held})
    elif reply is None:
        out.line("no connection keeper is running")
    elif closed:
        out.line(f"closed {reply.get('closing', 0)} connection(s); the keeper stops")
    elif not held:
        out.line("the connection keeper holds no connections")
    else:
        out.table(["robot", "endpoint", "user", "open (s)", "idle (s)", "in use"],
                  [[c["robot"], c["endpoint"], c["user"] or "", c["age"], c["idle"], c["busy"]] for c in held])


def _plain(obj: Any) -> Any:
    from dataclasses import asdict, is_dataclass
    return asdict(obj) if is_dataclass(obj) else obj
