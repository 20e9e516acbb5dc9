"""A rollout across the fleet: waves, failure budget, fleet-level rollback, Ctrl-C.

A bad release must stop at the canary; a flaky robot must not hold up the
others; and when a rollout stops, robots that already took the new release
go back (per policy), so the fleet is never left split between versions by
accident. Every robot's outcome is kept in the FleetResult.
"""
from __future__ import annotations

import math
import queue
import threading
import time
from concurrent.futures import Future, TimeoutError
from dataclasses import replace
from typing import Callable, Sequence, TypeVar

from rosdeploy.deploy import RunContext, apply_host, precheck_host, rollback_host
from rosdeploy.model import Host, RenderedRelease, RolloutPolicy
from rosdeploy.pending import PENDING_OUTCOMES, counts_as_failure, next_try
from rosdeploy.results import DEPLOYED, SKIPPED, UNCHANGED, FleetResult, HostResult
from rosdeploy.errors import ConnectError
from rosdeploy.transport import Handoff, SSHOptions, Transport

T = TypeVar("T")


def parallel(hosts: Sequence[Host], work: Callable[[Host], T], forks: int,
             on_interrupt: Callable[[], None] = lambda: None,
             abandon: Callable[[Host], T | None] = lambda host: None) -> list[T]:
    """Run `work` for every host, at most `forks` at once, results in host order.

    Ctrl-C does not abandon robots mid-step: it calls on_interrupt (which sets the run's cancel
    flag, so robots not yet started skip) and keeps waiting for the running ones to finish or
    roll back and release their locks. A robot for which `abandon` gives a result (its worker
    never reached it: see Reached) is not waited for: that result stands in, and its worker,
    a daemon thread, is left to end with the process (connect_timeout may be minutes away).
    """
    if not hosts:
        return []
    futures = _start(hosts, work, forks, threading.Event())
    interrupted = threading.Event()     # once, for every robot after it too
    return [_wait(f, h, on_interrupt, interrupted, abandon) for h, f in zip(hosts, futures, strict=True)]


def _wait(future: Future[T], host: Host, on_interrupt: Callable[[], None], interrupted: threading.Event,
          abandon: Callable[[Host], T | None]) -> T:
    while True:
        if interrupted.is_set() and not future.done():
            stand_in = abandon(host)
            if stand_in is not None:
                return stand_in
        try:
            return future.result(timeout=0.1 if interrupted.is_set() else None)
        except TimeoutError:
            continue
        except KeyboardInterrupt:
            on_interrupt()
            interrupted.set()


def _start(hosts: Sequence[Host], work: Callable[[Host], T], forks: int, stop: threading.Event) -> list[Future[T]]:
    """`work` for every host on at most `forks` daemon threads, each result in its Future: a
    thread pool's threads are joined when the interpreter exits, a daemon is not."""
    todo: queue.SimpleQueue[int] = queue.SimpleQueue()
    for i in range(len(hosts)):
        todo.put(i)
    futures: list[Future[T]] = [Future() for _ in hosts]

    def worker() -> None:
        while not stop.is_set():
            try:
                i = todo.get_nowait()
            except queue.Empty:
                return
            futures[i].set_running_or_notify_cancel()
            try:
                futures[i].set_result(work(hosts[i]))
            except BaseException as exc:    # noqa: BLE001 - handed to the waiting thread, as a pool does
                futures[i].set_exception(exc)

    for n in range(max(1, min(forks, len(hosts)))):
        try:
            threading.Thread(target=worker, name=f"robot-{n}", daemon=True).start()
        except RuntimeError:
            # "can't start new thread" (ulimit -v, a pids limit): the threads started share the
            # queue, so the run goes on with fewer; with none, the caller says what to do
            if n == 0:
                raise
            break
    return futures


class Reached:
    """Which robots a run's workers have reached (connected to). An interrupt abandons a worker
    still connecting: nothing was changed on its robot, and waiting could take connect_timeout.
    One that reached its robot is awaited: it may hold the robot's lock mid-switch
    (RobotRun.locked), which it finishes or rolls back, then releases. A connection that opens
    after the interrupt is closed at once, so an abandoned worker never goes on to its robot."""

    def __init__(self, ctx: RunContext) -> None:
        self.cancel = ctx.cancel
        self._names: set[str] = set()
        self._lock = threading.Lock()
        self.ctx = replace(ctx, connect=self._tracked(ctx.connect))

    def _tracked(self, connect: Callable[[Host, SSHOptions], Transport]) -> Callable[[Host, SSHOptions], Transport]:
        def tracked(host: Host, options: SSHOptions) -> Transport:
            link = connect(host, options)
            with self._lock:       # checked and marked at once: the interrupt reads after it sets cancel
                if not self.cancel.is_set():
                    self._names.add(host.name)
                    return link
            link.close()
            raise ConnectError(host.name, "interrupted while connecting: nothing was changed")
        return tracked

    def abandon(self, host: Host) -> HostResult | None:
        """For parallel(): a robot not reached is reported not started; None (wait) for one reached."""
        with self._lock:
            if host.name in self._names:
                return None
        self.ctx.progress(host.name, SKIPPED)
        return HostResult(host.name, SKIPPED, reason="interrupted before this robot was reached: nothing was "
                                                     "changed on it")


def gather(hosts: Sequence[Host], work: Callable[[Host], T], forks: int) -> list[T]:
    """Read-only work (status, plan, history) for every host, at most `forks` at once, results in
    host order. Ctrl-C (or SIGTERM) stops the waiting at once: nothing is being changed on a robot,
    so a robot's thread still waiting for an answer is a daemon, left to end with the process,
    and robots not yet started are not started."""
    if not hosts:
        return []
    stop = threading.Event()
    futures = _start(hosts, work, forks, stop)
    try:
        return [f.result() for f in futures]
    except KeyboardInterrupt:
        stop.set()
        raise


def wave_sizes(total: int, waves: Sequence[int | str]) -> list[int]:
    """Cumulative targets -> sizes: [1, "10%", "50%", "100%"] over 40 robots -> [1, 3, 16, 20].

    Each entry is how many robots (or what share) have been through once the
    wave is done; the last wave always takes whoever is left.
    """
    sizes, done = [], 0
    for entry in waves:
        target = min(total, _amount(entry, total))
        if target > done:
            sizes.append(target - done)
            done = target
    if done < total:
        sizes.append(total - done)
    return sizes


def _amount(entry: int | str, total: int) -> int:
    if isinstance(entry, str) and entry.endswith("%"):
        return max(1, math.ceil(total * float(entry[:-1]) / 100.0))
    return int(entry)


def allowed_failures(max_fail: int | str, wave_size: int) -> int:
    if isinstance(max_fail, str) and max_fail.endswith("%"):
        return math.floor(wave_size * float(max_fail[:-1]) / 100.0)
    return int(max_fail)


def ordered(hosts: Sequence[Host], order_by: str | None) -> list[Host]:
    """Group robots by their first inventory group starting with `order_by` (e.g. one site at a time)."""
    if not order_by:
        return list(hosts)

    def key(h: Host) -> str:
        return next((g for g in h.groups if g.startswith(order_by)), "\uffff")

    return sorted(hosts, key=key)   # stable: inventory order within a group


def plan_waves(hosts: Sequence[Host], policy: RolloutPolicy) -> list[list[Host]]:
    hosts = ordered(hosts, policy.order_by)
    waves, start = [], 0
    for size in wave_sizes(len(hosts), policy.waves):
        waves.append(hosts[start:start + size])
        start += size
    return waves


Notify = Callable[[str, dict], None]   # rollout-level events for the output layer


def apply_fleet(ctx: RunContext, hosts: Sequence[Host], releases: dict[str, RenderedRelease],
                policy: RolloutPolicy, notify: Notify = lambda event, data: None,
                until: float | None = None) -> FleetResult:
    """`until` (time.monotonic() deadline, `apply --until`): then retry pending robots until it."""
    started = time.monotonic()
    waves = plan_waves(hosts, policy)
    done: list[HostResult] = []
    known: dict[str, HostResult] = {}
    handoff = Handoff({}, ctx.connect)
    if len(waves) > 1:
        done, known, handoff, waves = _precheck(ctx, hosts, releases, policy, notify)
    try:
        aborted = _waves(replace(ctx, connect=handoff.connect), waves, releases, policy, notify, done, known, until)
    finally:
        handoff.close()
    if until is not None and not aborted:
        aborted = _converge(ctx, hosts, releases, policy, done, until, notify)
    stopped = "interrupted before this robot's wave: nothing was changed on it" if ctx.cancel.is_set() else \
        "rollout stopped before this robot's wave"
    if ctx.braked.is_set():
        stopped = "an emergency rollback was pulled during this rollout: it stopped before this robot's wave"
    done.extend(_skipped(waves, done, stopped))
    # braked: the operator's rollback took the robots back already; a second one would go further
    back = _fleet_rollback(ctx, hosts, done, policy, notify) \
        if aborted and ctx.spec.rollback.fleet and not ctx.braked.is_set() else ()
    return FleetResult("apply", tuple(done), aborted=aborted, fleet_rollback=back,
                       interrupted=ctx.cancel.is_set(), seconds=time.monotonic() - started, run_id=ctx.run_id)


def _precheck(ctx: RunContext, hosts: Sequence[Host], releases: dict[str, RenderedRelease], policy: RolloutPolicy,
              notify: Notify) -> tuple[list[HostResult], dict[str, HostResult], Handoff, list[list[Host]]]:
    """Before a rollout in waves: every robot asked at once whether it needs the release.

    A no-op re-apply is then one round trip, not one per wave, and the waves are planned over
    the robots that change: a canary that is already up to date would prove nothing. Returns the
    robots already on the release; what the first wave reports without asking again (an
    unreachable robot: connect_timeout once, not twice) and its open connections (a later wave
    may start minutes later: it asks anew); and the waves."""
    quiet = replace(ctx, progress=lambda host, step: None)
    # Only the robots a wave would start first keep their connection meanwhile: 5,000 robots
    # must not hold 5,000 connections (and paramiko's 5,000 threads) until the last one answers.
    first_started = {h.name for h in ordered(hosts, policy.order_by)[:policy.forks]}

    def ask(host: Host) -> tuple[HostResult | None, Transport | None]:
        result, link = precheck_host(quiet, host, releases[host.name])
        if link is not None and host.name not in first_started:
            link.close()
            link = None
        return result, link

    # read-only: an interrupt waits for none of them (their wave, which will not start, decides)
    checked = parallel(hosts, ask, policy.forks, ctx.cancel.set, abandon=lambda host: (None, None))
    done = [r for r, _ in checked if r is not None and r.outcome == UNCHANGED]
    if done:
        notify("unchanged", {"hosts": [r.host for r in done]})
        for r in done:
            ctx.progress(r.host, r.outcome)
    settled = {r.host for r in done}     # once: 5,000 robots would rebuild it per robot
    waves = plan_waves([h for h in hosts if h.name not in settled], policy)
    first = {h.name for h in waves[0]} if waves else set()
    known = {r.host: r for r, _ in checked if r is not None and r.outcome != UNCHANGED and r.host in first}
    handoff = Handoff({h.name: t for h, (_, t) in zip(hosts, checked, strict=True) if t is not None}, ctx.connect)
    handoff.keep_only(first)
    return done, known, handoff, waves


def _waves(ctx: RunContext, waves: list[list[Host]], releases: dict[str, RenderedRelease], policy: RolloutPolicy,
           notify: Notify, done: list[HostResult], known: dict[str, HostResult], until: float | None) -> bool:
    """Every wave in turn, each robot's result added to `done`; True when a wave's failures stop it."""
    reach = Reached(ctx)
    ctx = reach.ctx

    def work(host: Host) -> HostResult:
        if host.name in known:
            ctx.progress(host.name, known[host.name].outcome)
            return known.pop(host.name)
        return apply_host(ctx, host, releases[host.name])

    for number, wave in enumerate(waves, 1):
        try:
            if ctx.cancel.is_set():
                break
            notify("wave", {"number": number, "of": len(waves), "hosts": [h.name for h in wave]})
            results = parallel(wave, work, policy.forks, ctx.cancel.set, reach.abandon)
            done.extend(_with_wave(r, number) for r in results)
            if ctx.braked.is_set():      # an operator's rollback during this rollout (deploy.brake_pulled)
                braked = [r.host for r in results if r.outcome == SKIPPED and "emergency rollback" in r.reason]
                notify("braked", {"wave": number, "hosts": braked})
                return True
            failed = [r for r in results if counts_as_failure(r, policy.count_busy, until is not None)]
            budget = allowed_failures(policy.max_fail, len(wave))
            if len(failed) > budget:
                notify("abort", {"wave": number, "failed": [r.host for r in failed], "max_fail": budget})
                return True
            if policy.pause and number < len(waves) and not ctx.cancel.is_set():
                notify("pause", {"seconds": policy.pause})
                ctx.cancel.wait(policy.pause)
        except KeyboardInterrupt:   # between waves (pause, --step prompt): stop, then report
            ctx.cancel.set()
    return False


def _converge(ctx: RunContext, hosts: Sequence[Host], releases: dict[str, RenderedRelease],
              policy: RolloutPolicy, done: list[HostResult], until: float, notify: Notify) -> bool:
    """`apply --until`: try pending robots (unreachable, busy, waiting for their window) again,
    with backoff and jitter, until every one converged or the next try would come after
    `until`. Each wave's max_fail still holds. True when a retry's failures stopped the rollout."""
    by_name = {h.name: h for h in hosts}
    tries: dict[str, int] = {}
    due: dict[str, float] = {}
    while not ctx.cancel.is_set():
        waiting = [i for i, r in enumerate(done) if r.outcome in PENDING_OUTCOMES]
        now = time.monotonic()
        for i in waiting:
            if done[i].host not in due:
                tries[done[i].host] = tries.get(done[i].host, 0) + 1
                due[done[i].host] = next_try(done[i], tries[done[i].host], policy.retry, policy.retry_max, now)
        if not waiting or min(due[done[i].host] for i in waiting) > until:
            return False
        notify("pending", {"robots": [{"host": done[i].host, "outcome": done[i].outcome, "reason": done[i].reason,
                                       "next_try": round(due[done[i].host] - now, 1)} for i in waiting],
                           "results": tuple(done)})
        try:
            ctx.cancel.wait(max(0.0, min(due[done[i].host] for i in waiting) - now))
        except KeyboardInterrupt:
            ctx.cancel.set()
        if ctx.cancel.is_set():
            return False
        batch = [i for i in waiting if due[done[i].host] <= time.monotonic()]
        results = _apply_each(ctx, [by_name[done[i].host] for i in batch], releases, policy.forks)
        for i, result in zip(batch, results, strict=True):
            due.pop(done[i].host)
            tried = f"{done[i].outcome}: {done[i].reason}"
            done[i] = replace(result, wave=done[i].wave, earlier=done[i].earlier + (tried,))
        if ctx.braked.is_set():     # an operator's rollback: no more retries undo it
            notify("braked", {"wave": None, "hosts": [r.host for r in results if r.outcome == SKIPPED]})
            return True
        if _over_budget({done[i].wave for i in batch}, done, policy, notify):
            return True
    return False


def _apply_each(ctx: RunContext, hosts: Sequence[Host], releases: dict[str, RenderedRelease],
                forks: int) -> list[HostResult]:
    reach = Reached(ctx)
    return parallel(hosts, lambda h: apply_host(reach.ctx, h, releases[h.name]), forks, ctx.cancel.set,
                    reach.abandon)


def _over_budget(waves: set, done: list[HostResult], policy: RolloutPolicy, notify: Notify) -> bool:
    for wave in sorted(w for w in waves if w is not None):
        members = [r for r in done if r.wave == wave]
        failed = [r.host for r in members if counts_as_failure(r, policy.count_busy, retrying=True)]
        budget = allowed_failures(policy.max_fail, len(members))
        if len(failed) > budget:
            notify("abort", {"wave": wave, "failed": failed, "max_fail": budget})
            return True
    return False


def _with_wave(result: HostResult, wave: int) -> HostResult:
    return replace(result, wave=wave)


def _skipped(waves: list[list[Host]], done: list[HostResult], reason: str) -> list[HostResult]:
    seen = {r.host for r in done}
    return [HostResult(h.name, SKIPPED, reason=reason, wave=n)
            for n, wave in enumerate(waves, 1) for h in wave if h.name not in seen]


def _fleet_rollback(ctx: RunContext, hosts: Sequence[Host], done: list[HostResult],
                    policy: RolloutPolicy, notify: Notify) -> tuple[HostResult, ...]:
    """Return robots that took the new release to the release they ran before this rollout."""
    moved = {r.host: r.old_release for r in done if r.outcome == DEPLOYED and r.old_release}
    if not moved:
        return ()
    notify("fleet-rollback", {"hosts": sorted(moved)})
    targets = [h for h in hosts if h.name in moved]
    # A fleet rollback is the brake: it runs even after Ctrl-C, so use a fresh cancel flag.
    brake = replace(ctx, cancel=threading.Event())
    return tuple(parallel(targets, lambda h: rollback_host(brake, h, to_release=moved[h.name]), policy.forks))


def rollback_fleet(ctx: RunContext, hosts: Sequence[Host], forks: int, to_version: str | None = None) -> FleetResult:
    """The emergency brake: every targeted robot at once, no pull."""
    started = time.monotonic()
    # Ctrl-C or SIGTERM: robots mid-switch finish it (a brake is not left half-applied), robots
    # not yet started are skipped, and the run says it was interrupted
    reach = Reached(ctx)
    results = parallel(hosts, lambda h: rollback_host(reach.ctx, h, to_version=to_version), forks, ctx.cancel.set,
                       reach.abandon)
    return FleetResult("rollback", tuple(results), seconds=time.monotonic() - started, run_id=ctx.run_id,
                       interrupted=ctx.cancel.is_set())
