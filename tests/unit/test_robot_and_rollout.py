"""Pure decisions: parsing robot state, choosing the previous release, planning waves."""
from __future__ import annotations

import json

import pytest

from rosdeploy.model import Host, RolloutPolicy
from rosdeploy.robot import (Container, parse_state, passed_gate, previous_release, release_for_version,
                            release_services, unhealthy_services)
from rosdeploy.rollout import allowed_failures, plan_waves, wave_sizes

# Release ids as rosdeploy makes them (version-digest12): the state ignores other names in releases/.
A, B, BAD = "1.0.0-aaaaaaaaaaaa", "1.1.0-bbbbbbbbbbbb", "1.2.0-bad000000000"
OLD, NEW = "1.0.0-000000000001", "1.0.0-000000000002"
R1, R2, R3 = "1.0.0-a00000000001", "1.0.0-b00000000002", "1.0.0-c00000000003"


def state_text(current=B, history=(), releases=(A, B), containers=()) -> str:
    parts = {
        "home": "/home/robot", "dir": "/home/robot/rosdeploy/demo",
        "current": f"releases/{current}" if current else "",
        "manifest": json.dumps({"version": "1.1.0", "digest": "bbb"}),
        "lock": "", "releases": "\n".join(releases),
        "history": "\n".join(json.dumps(h) for h in history),
        "docker": "20.10.24+dfsg1", "compose": "v2 2.40.3",
        "containers": "\n".join(json.dumps(c) for c in containers),
        "disk": "51234", "gpu": "", "devices": "missing /dev/robot/lidar",
    }
    return "".join(f"\n@@{k}\n{v}\n" for k, v in parts.items()) + "\n@@end\n"


def test_parse_state_reads_every_section() -> None:
    c = {"name": "/demo-driver-1", "service": "driver", "image": "r/demo/driver:1.1.0", "status": "running",
         "health": "healthy", "restarts": 0, "workdir": f"/home/robot/rosdeploy/demo/releases/{B}"}
    st = parse_state(state_text(containers=[c]))
    assert st.current == B and st.flavor == "v2" and st.docker_ok
    assert st.free_mb == 51234 and st.missing_devices == ("/dev/robot/lidar",)
    assert st.containers[0].name == "demo-driver-1" and st.containers[0].release == B
    assert st.manifest["digest"] == "bbb"
    assert st.host_files is None, "no hostfiles section: not looked at, so never judged as drift"


def test_parse_state_reads_the_installed_host_files() -> None:
    text = state_text().replace("\n@@end\n", "\n@@hostfiles\nab12 /etc/cron.d/rosdeploy-demo\n"
                                             "? /etc/logrotate.d/rosdeploy-demo\n\n@@end\n")
    assert parse_state(text).host_files == {"/etc/cron.d/rosdeploy-demo": "ab12",
                                            "/etc/logrotate.d/rosdeploy-demo": "?"}
    empty = state_text().replace("\n@@end\n", "\n@@hostfiles\n\n@@end\n")
    assert parse_state(empty).host_files == {}, "looked, and nothing is installed"


@pytest.mark.parametrize("labels,flavor", [
    (("2.40.3", "2.40.3"), "v2"), (("1.29.2",), "v1"),
    ((), None),                       # nothing created: the full state must ask compose
    (("2.40.3", "1.29.2"), None),     # created by both: ask compose, do not guess
    (("", ""), None),                 # not created by compose
])
def test_running_flavor_comes_from_the_containers_compose_label(labels: tuple, flavor: str | None) -> None:
    containers = [{"name": f"/c{i}", "service": f"s{i}", "image": "i", "status": "running",
                   "ps_status": "Up 1 minute", "compose": v} for i, v in enumerate(labels)]
    assert parse_state(state_text(containers=containers)).running_flavor == flavor


def test_docker_error_is_not_ok() -> None:
    st = parse_state(state_text().replace("20.10.24+dfsg1", "permission denied while trying to connect"))
    assert not st.docker_ok


def test_unhealthy_services_names_each_problem() -> None:
    cs = [Container("a", "driver", "i", "running", "healthy", 0), Container("b", "perc", "i", "running", "starting", 0),
          Container("c", "nav", "i", "exited", None, 0)]
    assert unhealthy_services(cs, ["driver", "perc", "nav", "bridge"]) == {
        "perc": "health starting", "nav": "container exited", "bridge": "no container"}


def active(release: str) -> dict:
    return {"release": release, "result": "active"}


def test_previous_release_is_the_one_active_before_current() -> None:
    st = parse_state(state_text(history=[active(A), active(B)]))
    assert previous_release(st) == A


def test_previous_release_skips_releases_already_rolled_back_from() -> None:
    history = [active(R1), active(R2), {"release": R1, "result": "active", "rolled_back_from": R2},
               active(R3)]
    st = parse_state(state_text(current=R3, history=history, releases=(R1, R2, R3)))
    assert previous_release(st) == R1, "R2 was rolled back from: a second rollback must not return to it"


def test_previous_release_needs_the_release_on_disk() -> None:
    st = parse_state(state_text(history=[active("0.9.0-zzz"), active(B)], releases=(B,)))
    assert previous_release(st) is None


def test_only_a_release_activated_before_passed_the_gate() -> None:
    failed = {"release": BAD, "result": "failed"}
    st = parse_state(state_text(history=[active(A), failed], releases=(A, BAD)))
    assert passed_gate(st, A) and not passed_gate(st, BAD)


def test_release_for_version_prefers_the_last_activated() -> None:
    history = [active(OLD), active(NEW), active(B)]
    st = parse_state(state_text(history=history, releases=(NEW, OLD, B)))
    assert release_for_version(st, "1.0.0") == NEW
    assert release_for_version(st, "2.0.0") is None


@pytest.mark.parametrize("total,waves,sizes", [
    (40, [1, "10%", "50%", "100%"], [1, 3, 16, 20]),
    (3, [1, "100%"], [1, 2]),
    (1, [1, "10%", "100%"], [1]),
    (10, [2], [2, 8]),              # the last wave always takes the rest
    (5, ["100%"], [5]),
])
def test_wave_sizes(total, waves, sizes) -> None:
    assert wave_sizes(total, waves) == sizes
    assert sum(sizes) == total


@pytest.mark.parametrize("max_fail,size,allowed",
                         [(0, 10, 0), (1, 10, 1), ("10%", 10, 1), ("10%", 9, 0), ("50%", 3, 1)])
def test_allowed_failures(max_fail, size, allowed) -> None:
    assert allowed_failures(max_fail, size) == allowed


def host(name: str, *groups: str) -> Host:
    return Host(name=name, groups=("all", *groups), vars={}, address="127.0.0.1")


def test_waves_follow_order_by_group() -> None:
    hosts = [host("n1", "site_north"), host("s1", "site_south"), host("n2", "site_north"), host("s2", "site_south")]
    waves = plan_waves(hosts, RolloutPolicy(waves=(1, "50%", "100%"), order_by="site_"))
    assert [[h.name for h in w] for w in waves] == [["n1"], ["n2"], ["s1", "s2"]]


def test_interrupt_between_waves_skips_the_rest_and_reports(monkeypatch) -> None:
    import threading

    from rosdeploy import rollout
    from rosdeploy.deploy import RunContext
    from rosdeploy.model import FleetSpec, RenderedRelease, Service
    from rosdeploy.results import DEPLOYED, HostResult

    spec = FleetSpec(path="f", project="p", inventory="i", registry="r", version="1",
                     services=(Service("s", "img", "1"),))
    ctx = RunContext(spec=spec, ssh=None, run_id="run", operator="me", cancel=threading.Event())
    monkeypatch.setattr(rollout, "apply_host", lambda ctx, h, rel: HostResult(h.name, DEPLOYED, "a", "b"))
    monkeypatch.setattr(rollout, "precheck_host", lambda ctx, h, rel: (None, None))   # every robot changes

    def notify(event: str, data: dict) -> None:
        if event == "wave" and data["number"] == 2:
            raise KeyboardInterrupt

    hosts = [host(f"r{i}") for i in range(4)]
    releases = {h.name: RenderedRelease(h.name, "p", "1", (), ()) for h in hosts}
    result = rollout.apply_fleet(ctx, hosts, releases, RolloutPolicy(waves=(1, "100%")), notify)
    assert result.interrupted and not result.ok
    assert [(h.host, h.outcome) for h in result.hosts] == [
        ("r0", "deployed"), ("r1", "skipped"), ("r2", "skipped"), ("r3", "skipped")]
    # not "rollout stopped": no wave failed, the operator stopped it
    assert all(h.reason.startswith("interrupted before this robot's wave") for h in result.hosts[1:])


@pytest.mark.parametrize("command, todo", [("apply", "run `rosdeploy apply` again"),
                                           ("rollback", "roll back the robots it did not reach with --limit")])
def test_an_interrupted_run_says_so_and_what_to_do(command: str, todo: str) -> None:
    import io

    from rosdeploy.cli import report
    from rosdeploy.output import Output
    from rosdeploy.results import DEPLOYED, SKIPPED, FleetResult, HostResult
    buf = io.StringIO()
    result = FleetResult(command, (HostResult("r0", DEPLOYED), HostResult("r1", SKIPPED)), interrupted=True)
    report.summary(Output(stdout=buf, stderr=io.StringIO(), color=False), result, None)
    last = buf.getvalue().splitlines()[-1]
    assert last.startswith(f"{command} interrupted:") and todo in last, last


class FakeLink:
    def __init__(self, name: str) -> None:
        self.name, self.closed = name, False

    def close(self) -> None:
        self.closed = True


def test_waves_are_planned_over_the_robots_the_precheck_found_not_up_to_date(monkeypatch) -> None:
    """A rollout in waves asks every robot first: the up-to-date ones are settled without a wave,
    the canary is a robot that changes, the first wave goes on over the pre-check's connections
    and takes its unreachable verdict as it was; a later wave's connections are closed."""
    import threading

    from rosdeploy import rollout
    from rosdeploy.deploy import RunContext
    from rosdeploy.model import FleetSpec, RenderedRelease, Service
    from rosdeploy.results import DEPLOYED, UNCHANGED, UNREACHABLE, HostResult

    spec = FleetSpec(path="f", project="p", inventory="i", registry="r", version="1",
                     services=(Service("s", "img", "1"),))
    links = {name: FakeLink(name) for name in ("r1", "r3", "r4")}
    verdicts = {"r0": HostResult("r0", UNCHANGED), "r2": HostResult("r2", UNCHANGED),
                "r5": HostResult("r5", UNREACHABLE, reason="connect timed out")}
    monkeypatch.setattr(rollout, "precheck_host", lambda ctx, h, rel: (verdicts.get(h.name), links.get(h.name)))
    used: list[tuple[str, str]] = []

    def apply_host(ctx: RunContext, h, rel) -> HostResult:
        used.append((h.name, ctx.connect(h, ctx.ssh).name))
        return HostResult(h.name, DEPLOYED, "a", "b")

    monkeypatch.setattr(rollout, "apply_host", apply_host)
    events: list[tuple[str, dict]] = []
    ctx = RunContext(spec=spec, ssh=None, run_id="run", operator="me", cancel=threading.Event(),
                     connect=lambda h, options: FakeLink("new-" + h.name))
    hosts = [host(f"r{i}") for i in range(6)]
    releases = {h.name: RenderedRelease(h.name, "p", "1", (), ()) for h in hosts}
    result = rollout.apply_fleet(ctx, hosts, releases, RolloutPolicy(waves=(1, "100%"), max_fail=1),
                                 lambda e, d: events.append((e, d)))
    assert [(e, d["hosts"]) for e, d in events if e in ("unchanged", "wave")] == [
        ("unchanged", ["r0", "r2"]), ("wave", ["r1"]), ("wave", ["r3", "r4", "r5"])]
    assert used[0] == ("r1", "r1")                         # the canary went on over its pre-check link
    assert sorted(used[1:]) == [("r3", "new-r3"), ("r4", "new-r4"), ("r5", "new-r5")]
    assert links["r3"].closed and links["r4"].closed       # a later wave connects anew
    outcomes = {h.host: (h.outcome, h.wave) for h in result.hosts}
    assert outcomes == {"r0": (UNCHANGED, None), "r2": (UNCHANGED, None), "r1": (DEPLOYED, 1),
                        "r3": (DEPLOYED, 2), "r4": (DEPLOYED, 2), "r5": (DEPLOYED, 2)}


def test_the_precheck_keeps_only_the_connections_a_wave_would_start_with(monkeypatch) -> None:
    import threading

    from rosdeploy import rollout
    from rosdeploy.deploy import RunContext
    from rosdeploy.model import FleetSpec, RenderedRelease, Service
    from rosdeploy.results import DEPLOYED, HostResult

    spec = FleetSpec(path="f", project="p", inventory="i", registry="r", version="1",
                     services=(Service("s", "img", "1"),))
    links = {f"r{i}": FakeLink(f"r{i}") for i in range(4)}
    monkeypatch.setattr(rollout, "precheck_host", lambda ctx, h, rel: (None, links[h.name]))
    open_after_precheck: list[str] = []

    def apply_host(ctx: RunContext, h, rel) -> HostResult:
        if not open_after_precheck:
            open_after_precheck.extend(sorted(name for name, link in links.items() if not link.closed))
        ctx.connect(h, ctx.ssh)
        return HostResult(h.name, DEPLOYED)

    monkeypatch.setattr(rollout, "apply_host", apply_host)
    ctx = RunContext(spec=spec, ssh=None, run_id="run", operator="me", cancel=threading.Event(),
                     connect=lambda h, options: FakeLink("new-" + h.name))
    hosts = [host(f"r{i}") for i in range(4)]
    releases = {h.name: RenderedRelease(h.name, "p", "1", (), ()) for h in hosts}
    rollout.apply_fleet(ctx, hosts, releases, RolloutPolicy(waves=(2, "100%"), forks=2))
    assert open_after_precheck == ["r0", "r1"]              # forks=2: the two a wave starts with
    assert all(link.closed for name, link in links.items() if name not in ("r0", "r1"))


def test_an_unreachable_canary_is_reported_from_the_precheck_without_a_second_connect(monkeypatch) -> None:
    import threading

    from rosdeploy import rollout
    from rosdeploy.deploy import RunContext
    from rosdeploy.model import FleetSpec, RenderedRelease, Service
    from rosdeploy.results import SKIPPED, UNREACHABLE, HostResult

    spec = FleetSpec(path="f", project="p", inventory="i", registry="r", version="1",
                     services=(Service("s", "img", "1"),))
    down = HostResult("r0", UNREACHABLE, reason="connect timed out")
    monkeypatch.setattr(rollout, "precheck_host", lambda ctx, h, rel: (down, None) if h.name == "r0" else (None, None))
    monkeypatch.setattr(rollout, "apply_host", lambda *a: pytest.fail("no robot is deployed after the canary failed"))
    ctx = RunContext(spec=spec, ssh=None, run_id="run", operator="me", cancel=threading.Event(),
                     connect=lambda h, options: pytest.fail("nothing connects twice"))
    hosts = [host(f"r{i}") for i in range(3)]
    releases = {h.name: RenderedRelease(h.name, "p", "1", (), ()) for h in hosts}
    result = rollout.apply_fleet(ctx, hosts, releases, RolloutPolicy(waves=(1, "100%")))
    assert result.aborted
    assert [(h.host, h.outcome, h.wave) for h in result.hosts] == [
        ("r0", UNREACHABLE, 1), ("r1", SKIPPED, 2), ("r2", SKIPPED, 2)]


@pytest.mark.parametrize("text,services", [
    ('{"services": ["driver", "perception"]}', ("driver", "perception")),
    ('{"version": "1.0.0"}', None),                  # deployed before manifests listed services
    ('{"services": "driver"}', None),
    ('{"services": ["driver", 3]}', None),
    ("", None), ("not json", None), ("[1, 2]", None),
])
def test_release_services_come_from_the_manifest_or_not_at_all(text: str, services) -> None:
    assert release_services(text) == services


class LockHeld:
    """A robot whose lock is held by `holder` until a lock call names its run as dead."""

    def __init__(self, holder: dict) -> None:
        self.holder, self.calls = holder, []

    def run(self, command):
        from rosdeploy.transport import Result
        dead = command.argv[8]                          # sh -c BODY PROG root project owner break DEAD
        self.calls.append(dead)                         # the dead run id the call names ("" for none)
        if dead == self.holder["run"]:
            return Result("lock", "locked\n", "", 0, 0.0)
        return Result("lock", "held " + json.dumps(self.holder), "", 3, 0.0)


def _lock_with(holder: dict, alive: bool, monkeypatch) -> tuple[object, str | None, LockHeld]:
    import threading

    from rosdeploy import owner
    from rosdeploy.deploy import RobotRun, RunContext
    from rosdeploy.model import FleetSpec, Service
    monkeypatch.setattr(owner, "pid_alive", lambda pid: alive)
    spec = FleetSpec(path="f", project="p", inventory="i", registry="r", version="1",
                     services=(Service("s", "img", "1"),))
    ctx = RunContext(spec=spec, ssh=None, run_id="run-new", operator="me", cancel=threading.Event(),
                     controller=owner.Controller("b1", "ns1"))
    run = RobotRun(ctx, host("r1"))
    run.t = LockHeld(holder)
    return run, run.lock(), run.t


def test_a_lock_left_by_a_dead_run_of_this_machine_is_taken_over(monkeypatch) -> None:
    holder = {"run": "run-old", "by": "me", "pid": 4242, "boot": "b1", "pid_namespace": "ns1"}
    run, held_by, robot = _lock_with(holder, alive=False, monkeypatch=monkeypatch)
    assert held_by is None and run.locked
    assert robot.calls == ["", "run-old"]              # asked once, then named the dead run
    took = [s for s in run.steps if s.name == "took over a dead run's lock"]
    assert took and "run-old" in took[0].detail and "4242" in took[0].detail


def test_a_lock_of_a_live_run_or_another_machine_is_left_alone(monkeypatch) -> None:
    for holder, alive in [({"run": "run-old", "pid": 4242, "boot": "b1", "pid_namespace": "ns1"}, True),
                          ({"run": "run-old", "pid": 4242, "boot": "b9", "pid_namespace": "ns1"}, False)]:
        run, held_by, robot = _lock_with(holder, alive, monkeypatch)
        assert held_by is not None and "run-old" in held_by and not run.locked
        assert robot.calls == [""]


def test_a_held_lock_is_reported_as_who_holds_it_not_as_its_json(monkeypatch) -> None:
    from rosdeploy.deploy import _locked_by
    holder = {"run": "run-old", "by": "ops@laptop", "pid": 4242, "boot": "b9", "pid_namespace": "ns1",
              "since": "2026-11-23T10:00:00+00:00"}
    _, held_by, _ = _lock_with(holder, alive=True, monkeypatch=monkeypatch)
    reason = _locked_by(held_by)
    assert reason.startswith("locked by ops@laptop (run run-old, pid 4242, since 2026-11-23T10:00:00") and \
        "{" not in reason and "--break-lock" in reason, reason


@pytest.mark.parametrize("history,flavor", [
    ([{**active(B), "compose": "v1"}, {**active(A), "compose": "v1"},
      {**active(B), "compose": "v2"}], "v2"),           # the last start of the current release
    ([{**active(A), "compose": "v2"}, active(B)], None),   # not recorded for current
    ([{**active(B), "compose": "v3"}], None),                      # not a flavour rosdeploy knows
])
def test_recorded_flavor_is_how_the_current_release_was_last_started(history: list, flavor: str | None) -> None:
    assert parse_state(state_text(history=history)).recorded_flavor == flavor


class Robot:
    """A robot answering each command by its label: a rollback's round trips, without SSH."""

    def __init__(self, history: list, containers: tuple = ()) -> None:
        self.history, self.containers, self.calls = history, containers, []

    def run(self, command):
        from rosdeploy.transport import Result
        label = command.label.split(" ", 1)[0]
        self.calls.append(label)
        out = ""
        if label == "lock+state":
            out = "locked\n" + state_text(history=self.history).replace(
                "\n@@end", f'\n@@manifest {A}\n{{"services": ["driver"]}}\n@@end')
        elif label == "state":
            out = state_text(history=self.history, containers=self.containers)
        elif label == "activate":
            self.history.append(json.loads(command.argv[7]))
        elif label == "host-install":
            out = "host changes unchanged\n"     # what a robot answers when nothing differs (rosdeploy.hostchanges)
        return Result(command.label, out, "", 0, 0.0)

    def check(self, command, what: str = ""):
        return self.run(command)


def _rolled_back(robot: Robot, monkeypatch, compose: str = "auto") -> tuple[object, dict]:
    import threading

    from rosdeploy import deploy
    from rosdeploy.health import Verdict
    from rosdeploy.model import FleetSpec, Service
    spec = FleetSpec(path="f", project="demo", inventory="i", registry="r", version="1",
                     services=(Service("driver", "img", "1"), Service("perception", "img", "1")))
    ctx = deploy.RunContext(spec=spec, ssh=None, run_id="run-new", operator="me", cancel=threading.Event())
    run = deploy.RobotRun(ctx, Host(name="r1", groups=("all",), vars={"rosdeploy_compose": compose}, address="h"))
    run.t = robot
    started: dict = {}

    def start(release, flavor, together=False, services=None):
        robot.calls.append("up")
        started.update(release=release, flavor=flavor, together=together, services=services)
        return Verdict(True, "running and passing health checks")
    monkeypatch.setattr(run, "start", start)
    return deploy._rollback(run, None, None), started


def test_a_rollback_starts_the_switch_after_one_round_trip(monkeypatch) -> None:
    robot = Robot([{**active(A), "compose": "v2"}, {**active(B), "compose": "v2"}])
    result, started = _rolled_back(robot, monkeypatch)
    assert result.outcome == "switched"
    assert robot.calls[:2] == ["lock+state", "up"]         # no state, lock or manifest of their own
    # the kept release's own services (its manifest), together: it passed the gate here before
    assert started == {"release": A, "flavor": "v2", "together": True, "services": ("driver",)}
    assert [s.name for s in result.steps] == ["lock+state", "activate"]
    assert robot.history[-1]["compose"] == "v2"       # so the next rollback needs no more either


@pytest.mark.parametrize("compose,calls,flavor", [
    ("auto", ["lock+state", "state", "up"], "v1"),            # the containers' label tells it
    ("v2", ["lock+state", "state", "state", "up"], "v2"),     # the label disagrees with the host's choice: ask
])
def test_a_rollback_without_the_flavour_in_history_reads_it_from_the_robot(compose, calls, flavor,
                                                                             monkeypatch) -> None:
    made_by_v1 = ({"name": "/demo-driver-1", "service": "driver", "image": "i", "status": "running",
                   "ps_status": "Up 1 minute", "compose": "1.29.2"},)
    robot = Robot([active(A), active(B)], containers=made_by_v1)   # an older rosdeploy's
    result, started = _rolled_back(robot, monkeypatch, compose)
    assert result.outcome == "switched" and robot.calls[:len(calls)] == calls and started["flavor"] == flavor
