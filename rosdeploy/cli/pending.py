"""The CLI side of robots that are busy or away: pending robots in `apply` and `status`."""
from __future__ import annotations

import re
from typing import Any, Callable, Sequence

from rosdeploy import pending
from rosdeploy.model import Host
from rosdeploy.output import Output, one_line
from rosdeploy.results import FleetResult


def with_pending(project: Any, hosts: Sequence[Host], out: Output, doing: str = "applying to") -> tuple[Host, ...]:
    """The targets, plus the robots still pending for this fleet file and version (even when
    --limit leaves them out): a plain `apply` picks them up, so validate and check judge them too."""
    waiting = pending.for_version(_load(project.spec.path, out), project.spec.version)
    named = {h.name for h in hosts}
    extra = [h for h in project.targets(None) if h.name in waiting and h.name not in named]
    if extra:
        out.warn(f"also {doing} {len(extra)} robot(s) pending for {project.spec.version}, which `apply` picks up "
                 "whatever --limit says: " + ", ".join(f"{h.name} ({waiting[h.name].outcome})" for h in extra))
    return tuple(hosts) + tuple(extra)


def notifier(out: Output, spec: Any, run_id: str, inner: Callable[[str, dict], None]) -> Callable[[str, dict], None]:
    """The rollout's notifier, plus `pending` events of `apply --until`: each pending robot,
    its reason and its next try, and the record kept up to date for `status` meanwhile."""
    def notify(event: str, data: dict) -> None:
        if event != "pending":
            inner(event, data)
            return
        record(spec, data["results"], run_id)
        out.line(out.paint(f"-- {len(data['robots'])} robot(s) pending", "bold"))
        for robot in data["robots"]:
            out.line(f"   {robot['host']}: {robot['outcome']}, next try in {robot['next_try']:g}s: "
                     f"{one_line(robot['reason'][:160])}")
    return notify


def record(spec: Any, results: Sequence, run_id: str) -> None:
    pending.save(spec.path, pending.merged(pending.load(spec.path), results, spec.version, run_id))


def after_apply(spec: Any, result: FleetResult) -> None:
    record(spec, result.hosts, result.run_id)


def _load(fleet_path: str, out: Output) -> dict[str, pending.Entry]:
    """The pending record; one that is not what rosdeploy writes is named in a warning, and ignored."""
    entries, problem = pending.read(fleet_path)
    if problem:
        out.warn(f"warning: pending record {problem}")
    return entries


class StatusRows(list):
    """Status rows, and what was wrong with the pending record read for them: status_notes,
    which has the Output, warns about it."""
    problem: str | None = None


def status_rows(rows: Sequence[Any], spec: Any) -> StatusRows:
    """Status rows with their robot's pending entry (any version: a pending robot of an older
    version is worth seeing too, it is what the last apply could not do)."""
    from dataclasses import replace

    entries, problem = pending.read(spec.path)
    out = StatusRows(replace(r, pending=entries[r.host].to_json()) if r.host in entries else r for r in rows)
    out.problem = problem
    return out


def status_notes(out: Output, rows: Sequence[Any]) -> None:
    """Below the status table: pending robots, and held application lock files with their age."""
    problem = getattr(rows, "problem", None)
    if problem:
        out.warn(f"warning: pending record {problem}")
    if out.as_json:
        return
    for r in rows:
        if getattr(r, "pending", None):
            p = r.pending
            out.line(f"{r.host}: PENDING {one_line(p['outcome'])} for {one_line(p['version'])} since "
                     f"{one_line(p['since'])}: {one_line(_said_once(r.host, p['outcome'], p['reason']))}")
        for lock in getattr(r, "app_lock", None) or ():
            age = lock.get("age")
            out.line(f"{r.host}: app lock {one_line(lock['path'])} held by {one_line(lock['holder'])} "
                     f"since {one_line(lock['since'])}"
                     + (f" ({_age(age)} ago)" if age is not None else ""))


def _said_once(host: str, outcome: object, reason: object) -> str:
    """The reason without the robot's name and the outcome the line says already, capped (not
    cut at 160 characters: the advice at its end was lost). A guard's "in ~25 s (at 10:04:31 UTC)"
    was true when the run lost the robot; `status` runs later, so only the clock time is kept."""
    text = _GUARD_IN.sub(r"at \1", str(reason))
    for said in (f"{host}: ", f"{outcome}: "):
        text = text[len(said):] if text.startswith(said) else text
    return text[:600]


_GUARD_IN = re.compile(r"in ~\d+ s \(at ([0-9:]+ UTC)\)")


def _age(seconds: int) -> str:
    if seconds >= 3600:
        return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"
    return f"{seconds // 60}m{seconds % 60:02d}s"

