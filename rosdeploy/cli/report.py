"""How results look: progress lines, the summary table, status/plan/history views.

Human text by default; with --json one document on stdout (progress and
errors still go to stderr, so CI logs stay readable and the JSON parseable).
"""
from __future__ import annotations

import argparse
import shutil
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence

from rosdeploy.output import Output, confirm, one_line
from rosdeploy.results import OK_OUTCOMES, OUTCOMES, UNCHANGED, FleetResult, HostResult, version_of



class ProgressLines:
    """One line per step per robot: for CI logs and --json runs (on stderr there)."""

    def __init__(self, out: Output, started: float) -> None:
        self.out, self.started = out, started

    def progress(self, host: str, step: str) -> None:
        self.out.line(self.out.paint(f"{time.monotonic() - self.started:7.1f}s ", "dim") + f"{host:<16} {step}")

    def wave(self, number: int, hosts: Sequence[str]) -> None:
        pass

    @contextmanager
    def paused(self) -> Iterator[None]:
        yield


@dataclass
class Row:
    """One robot on the board."""

    wave: int | str = ""
    step: str = "waiting"
    since: float | None = None      # when its current run began
    done: float | None = None       # when that run ended with an outcome

    @property
    def running(self) -> bool:
        return self.since is not None and self.done is None

    @property
    def failed(self) -> bool:
        return self.done is not None and self.step not in OK_OUTCOMES

    def elapsed(self, now: float) -> str:
        return "" if self.since is None else f"{(self.done or now) - self.since:.1f}s"


class Board:
    """The live view on a terminal: one row per robot (wave, step, elapsed), redrawn in place
    twice a second, so a hundred robots are a table and not a thousand scrolling lines."""

    TICK = 0.5

    def __init__(self, out: Output, hosts: Sequence[str], started: float, height: int) -> None:
        self.out, self.started, self.height = out, started, max(height, 8)
        self.rows: dict[str, Row] = {h: Row() for h in hosts}
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.hold = threading.Event()       # a prompt is on screen: do not draw over it

    def progress(self, host: str, step: str) -> None:
        now = time.monotonic()
        with self.lock:
            row = self.rows.setdefault(host, Row())
            if not row.running:             # its first step, or a second run (fleet-level rollback)
                row.since, row.done = now, None
            row.step = step
            if step in OUTCOMES:
                row.done = now
        self.draw()

    def wave(self, number: int, hosts: Sequence[str]) -> None:
        with self.lock:
            for host in hosts:
                self.rows.setdefault(host, Row()).wave = number
        self.draw()

    @contextmanager
    def paused(self) -> Iterator[None]:
        self.hold.set()
        self.out.live([])
        try:
            yield
        finally:
            self.hold.clear()
            self.draw()

    def draw(self) -> None:
        if not (self.hold.is_set() or self.stop.is_set()):
            self.out.live(self.lines(time.monotonic()))

    def lines(self, now: float) -> list[str]:
        with self.lock:
            rows = [(h, replace(r)) for h, r in self.rows.items()]
        width = shutil.get_terminal_size().columns - 1
        shown = _most_telling(rows, self.height - 4)
        table = [("ROBOT", "WAVE", "STEP", "ELAPSED")] + [(h, str(r.wave), r.step, r.elapsed(now)) for h, r in shown]
        widths = [max(len(t[i]) for t in table) for i in range(3)]
        lines = [f"{a:<{widths[0]}}  {b:<{widths[1]}}  {c:<{widths[2]}}  {d}".rstrip() for a, b, c, d in table]
        lines.append(_counts([r for _, r in rows], now - self.started, len(rows) - len(shown)))
        return [one_line(line)[:width] for line in lines]    # escaped, then cut: one terminal line each

    def tick(self) -> None:
        while not self.stop.wait(self.TICK):
            self.draw()

    def close(self, ticker: threading.Thread) -> None:
        """Stop drawing, wait for the ticker's last draw, then erase: the summary follows."""
        self.stop.set()
        ticker.join()
        self.out.live([])


def _most_telling(rows: list[tuple[str, Row]], room: int) -> list[tuple[str, Row]]:
    """All rows when they fit; else the robots that failed first (an operator acts on those),
    then the running ones, then the rest; shown in inventory order."""
    if len(rows) <= room:
        return rows
    ranked = sorted(rows, key=lambda item: 0 if item[1].failed else 1 if item[1].running else 2)
    keep = {h for h, _ in ranked[:room]}
    return [item for item in rows if item[0] in keep]


def _counts(rows: list[Row], elapsed: float, hidden: int) -> str:
    running = sum(r.running for r in rows)
    done = sum(r.done is not None for r in rows)
    more = f"  ({hidden} more not shown)" if hidden else ""
    return (f"{elapsed:.1f}s: {running} running, {done} done ({sum(r.failed for r in rows)} not ok), "
            f"{len(rows) - running - done} waiting{more}")


@contextmanager
def progress_view(out: Output, hosts: Sequence[str]) -> Iterator[ProgressLines | Board]:
    """The board on a terminal, plain lines anywhere else; the board is gone before the summary."""
    started = time.monotonic()
    if not out.interactive:
        yield ProgressLines(out, started)
        return
    board = Board(out, hosts, started, shutil.get_terminal_size().lines)
    ticker = threading.Thread(target=board.tick, name="progress-board", daemon=True)
    ticker.start()
    try:
        yield board
    finally:
        board.close(ticker)


def rollout_notifier(out: Output, args: argparse.Namespace,
                     view: ProgressLines | Board) -> Callable[[str, dict], None]:
    def notify(event: str, data: dict) -> None:
        if event == "wave":
            out.line(out.paint(f"== wave {data['number']}/{data['of']}: {', '.join(data['hosts'])}", "bold"))
            view.wave(data["number"], data["hosts"])
            if args.step and data["number"] > 1:     # cmd_apply refused --step where it cannot ask
                with view.paused():
                    if not confirm(out, "Start this wave?"):
                        raise KeyboardInterrupt
        elif event == "unchanged":
            out.line(out.paint(f"== already on this release: {', '.join(data['hosts'])}", "bold"))
        elif event == "abort":
            out.error(f"rollout stopped in wave {data['wave']}: {len(data['failed'])} robot(s) failed "
                      f"({', '.join(data['failed'])}), more than max_fail={data['max_fail']}")
        elif event == "braked":
            where = f" in wave {data['wave']}" if data["wave"] else ""
            out.error(f"rollout stopped{where}: an emergency rollback was pulled during it on "
                      f"{', '.join(data['hosts'])}; the later waves do not undo it (run apply again to deploy)")
        elif event == "fleet-rollback":
            out.warn(f"fleet-level rollback of robots already on the new release: {', '.join(data['hosts'])}")
        elif event == "pause":
            out.line(f"pausing {data['seconds']:g}s before the next wave")
    return notify


def summary(out: Output, result: FleetResult, folder: Path | None) -> None:
    """`folder` None: the run record could not be written (a warning said why)."""
    if out.as_json:
        out.document({**result.to_json(), "run_dir": str(folder) if folder else None})
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
    # the folder comes from $ROSDEPLOY_RUNS_DIR, which may hold a newline: still one line
    record = f"record: {one_line(str(folder))}" if folder else "no run record: see the warning above"
    out.line(out.paint(f"{result.command}: {tally} in {result.seconds:.1f}s", style) + f"  ({record})")
    if result.interrupted:
        # a second rollback would take the robots it finished one release further back
        todo = ("run `rosdeploy apply` again to finish (robots already on the release are left as they are)"
                if result.command == "apply" else "see `rosdeploy status`, and roll back the robots it did not "
                "reach with --limit (a second rollback of the others would go one release further back)")
        out.line(out.paint(f"{result.command} interrupted: robots mid-switch finished or went back and their locks "
                           f"were released; robots it did not reach were left as they were: {todo}", "red"))


def _row(h: HostResult) -> list[str]:
    old = version_of(h.old_release) or "-"
    now = version_of(h.running_release) or "-"
    # An OK outcome's reason is noise, except when a no-op put back host changes (deploy._put_back).
    shown = h.outcome not in OK_OUTCOMES or (h.outcome == UNCHANGED and any(s.name == "host changes" for s in h.steps))
    reason = h.reason if shown else ""
    return [h.host, str(h.wave or ""), h.outcome, f"{old} -> {now}", f"{h.seconds:.1f}s", reason[:REASON_CHARS]]


def status(out: Output, rows: Sequence[Any]) -> None:
    if out.as_json:
        out.document({"robots": [_plain(r) for r in rows]})
        return
    table, below = [], []
    for r in rows:
        why = unreachable(r.host, r.error) if not r.reachable else r.reason
        if len(why) > WHY_CELL:     # the advice at its end must not be cut: on a line of its own
            below.append(f"{r.host}: {why}")
            why = "(below)"
        if not r.reachable:
            table.append([r.host, "UNREACHABLE", "-", "-", "-", "-", why])
            continue
        services = ", ".join(f"{s['service']}:{s['health'] or s['status']}" for s in r.services) or "none"
        drift = "-" if r.drift is None else ("DRIFT" if r.drift else "in sync")
        last = f"{r.deployed_at or '-'} by {r.deployed_by or '-'}"
        table.append([r.host, r.state, r.version or "-", drift, services, last, why])
    out.table(["ROBOT", "STATE", "VERSION", "DRIFT", "SERVICES", "LAST DEPLOY", "WHY"], table)
    for line in below:
        out.line(one_line(line))


# A WHY longer than this is said below the table, whole: a cell would push the table past any
# terminal's width, and a cut one lost "Check its ansible_host and ansible_port".
WHY_CELL = 80
# A reason from a robot or a record is capped where it is quoted: a hostile robot's megabyte
# must not flood the report (our own advice is far shorter).
REASON_CHARS = 600


def unreachable(host: str, error: str) -> str:
    """A robot's connection error said once: `unreachable: …`, without the robot's name that
    RemoteError puts in front (the line names it already)."""
    text = error[len(host) + 2:] if error.startswith(f"{host}: ") else error
    text = text[:REASON_CHARS]
    return text if text.lower().startswith("unreachable") else f"unreachable: {text}"


def plan(out: Output, rows: Sequence[Any]) -> None:
    if out.as_json:
        out.document({"robots": [_plain(r) for r in rows]})
        return
    for r in rows:
        if not r.reachable:
            out.line(f"{r.host}: {unreachable(r.host, r.error)}")
            continue
        if r.up_to_date:
            put_back = f"; apply puts back host changes that differ on the robot: {', '.join(r.host_drift)}"
            out.line(f"{r.host}: up to date ({r.current})" + (put_back if r.host_drift else ""))
            continue
        out.line(out.paint(f"{r.host}: {r.current or 'nothing'} -> {r.new}", "bold"))
        for problem in r.preflight:
            out.error(f"  preflight: {problem}")
        if r.guard:
            out.line(f"  guard: {r.guard}")
        for image in r.pulls:
            out.line(f"  pull {image}")
        for ref, digest in r.images.items():
            out.line(f"  image {ref} pinned to {digest}")
        for change in r.host_changes:
            out.line(f"  host change: {change}")
        if r.restarts:
            out.line(f"  restart {', '.join(r.restarts)}"
                     + (f" (keep running: {', '.join(r.keeps)})" if r.keeps else ""))
        for name, diff in r.diffs:
            out.line(f"  {name} changes:" if diff else f"  {name}")
            out.line("\n".join("    " + line for line in diff.splitlines()))


def history(out: Output, rows: Sequence[tuple], limit: int) -> None:
    if out.as_json:
        out.document({"robots": [{"host": h, "reachable": ok, "error": err, "history": list(entries[:limit])}
                                 for h, ok, err, entries in rows]})
        return
    for host, ok, err, entries in rows:
        out.line(out.paint(host, "bold") + ("" if ok else f": {unreachable(host, err)}")
                 + (": no deploys yet" if ok and not entries else ""))
        for e in entries[:limit]:
            out.line(_entry_line(e))


def _entry_line(e: Mapping[str, Any]) -> str:
    """One history entry on one line. Its fields are the robot's: any JSON, a newline included."""
    def field(key: str, missing: str = "?") -> str:
        value = e.get(key)
        return missing if value is None else one_line(value)

    detail = f" from {field('rolled_back_from')}" if e.get("rolled_back_from") else ""
    reason = f" ({field('reason')})" if e.get("reason") else ""
    return (f"  {field('time')}  {field('event'):<13} {field('release')}{detail}  "
            f"{field('result', '')}  by {field('by')}{reason}")


def connections(out: Output, reply: dict | None, closed: bool, unavailable: str | None = None) -> None:
    held = [] if reply is None else reply.get("connections", [])
    if out.as_json:
        out.document({"keeper": reply is not None, "closed": reply.get("closing", 0) if closed and reply else 0,
                      "connections": held, "unavailable": unavailable})
    elif unavailable:
        out.line(f"no connection keeper can run: {unavailable}; status, plan and history connect directly")
    elif reply is None:
        out.line("no connection keeper is running: status, plan and history start one, and it ends after "
                 "ssh.persist without use")
    elif closed:
        out.line(f"closed {reply.get('closing', 0)} connection(s); the keeper stops")
    elif not held:
        out.line("the connection keeper holds no connections")
    else:
        out.table(["robot", "endpoint", "user", "open (s)", "idle (s)", "in use"],
                  [[c["robot"], c["endpoint"], c["user"] or "", c["age"], c["idle"], c["busy"]] for c in held])


def _plain(obj: Any) -> Any:
    from dataclasses import asdict, is_dataclass
    return asdict(obj) if is_dataclass(obj) and not isinstance(obj, type) else obj
