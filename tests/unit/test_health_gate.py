"""The health gate's decisions, driven by a scripted transport (the real one is in tests/integration)."""
from __future__ import annotations

import json
import threading
import time

from rosdeploy.commands import Command
from dataclasses import replace

from rosdeploy.health import settled, start_levels, wait_healthy
from rosdeploy.model import FleetSpec, HealthPolicy, Service, Topic
from rosdeploy.transport import Result

SPEC = FleetSpec(path="f.yml", project="demo", inventory="i.yml", registry="r:5000", version="1.0.0",
                 services=(Service("driver", "demo/driver", "1.0.0", topics=(Topic("/joint_states", 5.0),)),
                           Service("perception", "demo/perception", "1.0.0")),
                 health=HealthPolicy(timeout=1.0, stable=0.0, interval=0.01, topic_window=0.1))


def c(service: str, status: str = "running", health: str | None = "healthy", restarts: int = 0) -> dict:
    return {"name": f"/demo-{service}-1", "service": service, "image": "x", "status": status,
            "health": health, "restarts": restarts, "test": ["CMD", "/opt/check"], "test_timeout": 3_000_000_000}


class Scripted:
    """Answers `containers` with the next scripted poll (the last one repeats) and the probe with `probe`."""

    def __init__(self, polls: list[list[dict]], probe: dict | None = None, tests_pass: bool = False,
                 watch_exit: int | None = None) -> None:
        self.polls, self.probe, self.probes = polls, probe, 0
        self.tests_pass, self.tests, self.watches = tests_pass, [], []
        self.watch_exit = watch_exit     # None: what a loop over the test would give
        self.lock = threading.Lock()

    def run(self, command: Command) -> Result:
        with self.lock:
            if command.label.startswith("health-test"):
                self.tests.append(command.argv)
                return Result("test", "", "", 0 if self.tests_pass else 1, 0.0)
            if command.label.startswith("health-watch"):
                self.watches.append(command.argv)
                code = self.watch_exit if self.watch_exit is not None else 0 if self.tests_pass else 3
                return Result("watch", "", "", code, 0.0)
            if command.label.startswith("ros-probe"):
                self.probes += 1
                report = self.probe or {"topics": {"/joint_states": {"present": True, "ok": True, "rate": 10}}}
                ok = all(t["ok"] for t in report["topics"].values())
                return Result("probe", json.dumps(report), "", 0 if ok else 1, 0.0)
            poll = self.polls.pop(0) if len(self.polls) > 1 else self.polls[0]
            return Result("containers", "\n".join(json.dumps(x) for x in poll), "", 0, 0.0)


def test_healthy_after_starting_and_one_probe() -> None:
    t = Scripted([[c("driver", health="starting"), c("perception", health="starting")],
                  [c("driver"), c("perception", health="starting")],
                  [c("driver"), c("perception")]])
    verdict = wait_healthy(t, SPEC)
    assert verdict.ok, verdict.reason
    assert 1 <= t.probes <= 2


def test_a_restart_fails_at_once_naming_the_service() -> None:
    t = Scripted([[c("driver"), c("perception", health="starting")],
                  [c("driver", restarts=1), c("perception", health="starting")]])
    verdict = wait_healthy(t, SPEC)
    assert not verdict.ok and verdict.service == "driver" and "restarted 1 time" in verdict.reason


def test_unhealthy_fails_without_waiting_for_the_timeout() -> None:
    t = Scripted([[c("driver"), c("perception", health="unhealthy")]])
    verdict = wait_healthy(t, SPEC)
    assert not verdict.ok and verdict.service == "perception" and "unhealthy" in verdict.reason


def test_a_missing_topic_fails_the_gate_with_its_name() -> None:
    report = {"topics": {"/joint_states": {"present": False, "ok": False, "min_rate": 5}}, "domain": "11"}
    verdict = wait_healthy(Scripted([[c("driver"), c("perception")]], report), SPEC)
    assert not verdict.ok and "/joint_states not on the ROS graph (domain 11)" in verdict.reason


def test_a_slow_topic_fails_with_its_rate() -> None:
    report = {"topics": {"/joint_states": {"present": True, "ok": False, "rate": 1.5, "min_rate": 5}}}
    verdict = wait_healthy(Scripted([[c("driver"), c("perception")]], report), SPEC)
    assert not verdict.ok and "1.5 Hz, below min_rate 5 Hz" in verdict.reason


def test_never_healthy_times_out_naming_what_it_waited_for() -> None:
    verdict = wait_healthy(Scripted([[c("driver"), c("perception", health="starting")]]), SPEC)
    assert not verdict.ok and "perception: health starting" in verdict.reason and "health.timeout" in verdict.reason


def test_a_missing_service_is_not_healthy() -> None:
    verdict = wait_healthy(Scripted([[c("driver")]]), SPEC)
    assert not verdict.ok and "perception: no container" in verdict.reason


def test_a_starting_service_whose_own_check_passes_is_healthy_before_dockers_tick() -> None:
    t = Scripted([[c("driver", health="starting"), c("perception", health="starting")]], tests_pass=True)
    verdict = wait_healthy(t, SPEC)
    assert verdict.ok, verdict.reason
    watched = sorted(argv[2] for argv in t.watches)
    assert watched == ["demo-driver-1", "demo-perception-1"]   # one watch each: passed is not rerun
    assert not t.tests and all(argv[-2:] == ("CMD", "/opt/check") for argv in t.watches)


def test_a_failing_own_check_keeps_waiting_for_docker() -> None:
    t = Scripted([[c("driver"), c("perception", health="starting")]], tests_pass=False)
    verdict = wait_healthy(t, SPEC)
    assert not verdict.ok and "perception: health starting" in verdict.reason
    assert t.watches and all(argv[2] == "demo-perception-1" for argv in t.watches)


def test_an_image_the_watch_cannot_loop_in_is_tested_one_exec_at_a_time() -> None:
    # 126: docker exec found no /bin/sh in the image
    t = Scripted([[c("driver"), c("perception", health="starting")]], tests_pass=True, watch_exit=126)
    verdict = wait_healthy(t, SPEC)
    assert verdict.ok, verdict.reason
    assert len(t.watches) == 1 and t.tests == [("docker", "exec", "demo-perception-1", "/opt/check")]


def test_docker_unhealthy_wins_over_a_passing_own_check() -> None:
    t = Scripted([[c("driver"), c("perception", health="unhealthy")]], tests_pass=True)
    verdict = wait_healthy(t, SPEC)
    assert not verdict.ok and verdict.service == "perception" and not t.tests and not t.watches


def test_a_known_good_release_needs_no_probe_and_no_stable_window() -> None:
    spec = replace(SPEC, health=replace(SPEC.health, stable=60.0, timeout=5.0))
    t = Scripted([[c("driver"), c("perception")]])
    verdict = wait_healthy(t, spec, checks_only=True)
    assert verdict.ok and t.probes == 0
    assert not wait_healthy(Scripted([[c("driver"), c("perception")]]), replace(spec, health=replace(
        spec.health, timeout=0.2))).ok      # a new release still waits out the stable window


def test_start_levels_follow_depends_on_and_skip_profiles() -> None:
    services = (Service("nav", "i/nav", "1", depends_on=("perception", "driver")),
                Service("perception", "i/p", "1", depends_on=("driver",)),
                Service("driver", "i/d", "1"), Service("lidar", "i/l", "1"),
                Service("rviz", "i/r", "1", profiles=("dev",)))
    spec = replace(SPEC, services=services)
    assert start_levels(spec) == (("driver", "lidar"), ("perception",), ("nav",))


def test_settled_judges_starting_containers_like_the_gate_and_costs_nothing_otherwise() -> None:
    from rosdeploy.robot import Container
    quick = tuple(Container.from_json(x) for x in (c("driver"), c("perception", health="starting")))
    t = Scripted([[c("driver"), c("perception", health="starting")]], tests_pass=True)
    assert [x.health for x in settled(t, SPEC, quick)] == ["healthy", "healthy"]
    assert [x.health for x in settled(Scripted([[c("driver"), c("perception", health="starting")]]), SPEC,
                                      quick)] == ["healthy", "starting"]
    calm = Scripted([])   # would fail on any call
    assert settled(calm, SPEC, quick[:1]) == quick[:1]


def test_a_recreated_container_is_judged_by_its_own_restart_count() -> None:
    old = {**c("driver", restarts=3), "id": "old"}
    new = {**c("driver", restarts=0), "id": "new"}     # recreated: same name, its own count
    waiting = c("perception", health="starting")     # keeps the gate polling
    t = Scripted([[old, waiting], [new, waiting], [{**new, "restarts": 1}, waiting]])
    verdict = wait_healthy(t, SPEC)
    assert not verdict.ok and verdict.service == "driver" and "restarted" in verdict.reason


def test_a_start_level_waits_only_for_its_own_services() -> None:
    t = Scripted([[c("driver", health="starting")], [c("driver")]])   # perception not created yet
    verdict = wait_healthy(t, SPEC, checks_only=True, services=("driver",))
    assert verdict.ok and t.probes == 0


def test_polls_slow_down_while_watches_cover_everything_waited_for() -> None:
    import time
    from rosdeploy.health import FAST_POLL, WATCHED_POLL, poll_interval
    policy = HealthPolicy(interval=5.0)
    now = time.monotonic()
    assert poll_interval(policy, now) == FAST_POLL
    assert poll_interval(policy, now, watched=True) == WATCHED_POLL > FAST_POLL
    assert poll_interval(policy, now - 60, watched=True) == 5.0      # after the fast window: health.interval


def test_watching_is_true_only_while_each_waiting_service_has_a_running_watch() -> None:
    from concurrent.futures import Future
    from rosdeploy.health import Poller
    from rosdeploy.robot import Container
    driver, perception = (Container.from_json({**c(s, health="starting"), "id": s}) for s in ("driver", "perception"))
    poller = Poller(Scripted([]), SPEC, watch=True)
    poller.watches["driver"] = Future()                     # running
    waiting = {"driver": "health starting", "perception": "health starting"}
    assert not poller.watching((driver, perception), waiting)  # perception is not watched
    assert poller.watching((driver, perception), {"driver": "health starting"})
    poller.watches["driver"].set_result(3)                  # ended: poll at the normal pace
    assert not poller.watching((driver, perception), {"driver": "health starting"})


def test_the_containers_up_listed_are_the_first_poll_with_no_round_trip() -> None:
    from rosdeploy.health import Poller, started_containers
    t = Scripted([[c("driver", health="unhealthy"), c("perception")]])     # what a poll would read
    listed = "\n".join(["Container demo-driver-1  Started", "", "@@started",
                        json.dumps({**c("driver"), "id": "d1"}), json.dumps({**c("perception"), "id": "p1"})])
    ran: list[str] = []
    answer = t.run
    t.run = lambda command: (ran.append(command.label.split()[0]), answer(command))[1]   # type: ignore[method-assign]
    poller = Poller(t, SPEC, watch=True)
    poller.seed(started_containers(listed))
    seeded, failure = poller.poll(("driver", "perception"))
    assert failure is None and [x.id for x in seeded] == ["d1", "p1"]
    assert ran == []                                       # nothing ran on the robot
    _, failure = poller.poll(("driver", "perception"))     # the seed is used once: this one reads
    assert ran == ["containers"]
    assert failure == ("driver", "container demo-driver-1 health check reports unhealthy")


SLOW = replace(SPEC, health=HealthPolicy(timeout=30.0, stable=0.0, interval=0.01, topic_window=0.1))
ABSENT = {"topics": {"/joint_states": {"present": False, "ok": False, "min_rate": None}}, "domain": "11"}


def test_a_topic_never_published_fails_a_new_start_before_docker_gives_up(monkeypatch) -> None:
    monkeypatch.setattr("rosdeploy.health.EARLY_LOOK_AFTER", 0.0)
    t = Scripted([[c("driver", health="starting")]], ABSENT)
    verdict = wait_healthy(t, SLOW, checks_only=True, services=("driver",), fail_fast=True,
                           deadline=time.monotonic() + 10)
    assert not verdict.ok and verdict.service == "driver"
    assert "/joint_states: no publisher on the ROS graph" in verdict.reason and "health starting" in verdict.reason
    assert t.probes == 1


def test_going_back_never_judges_by_the_early_look(monkeypatch) -> None:
    monkeypatch.setattr("rosdeploy.health.EARLY_LOOK_AFTER", 0.0)
    t = Scripted([[c("driver", health="starting")]], ABSENT)
    verdict = wait_healthy(t, SLOW, checks_only=True, services=("driver",), deadline=time.monotonic() + 0.3)
    assert not verdict.ok and "health.timeout" in verdict.reason and t.probes == 0


def test_the_gate_probe_fails_early_only_for_topics_of_services_that_ran(monkeypatch) -> None:
    spec = replace(SLOW, services=(SPEC.services[0], replace(SPEC.services[1], topics=(Topic("/detections", 2.0),))))
    perception_late = {"topics": {"/joint_states": {"present": True, "ok": True, "rate": 10, "min_rate": 5},
                                  "/detections": {"present": False, "ok": False, "min_rate": 2}}}
    t = Scripted([[c("driver", health="starting")], [c("driver", health="starting")], [c("driver"), c("perception")]],
                 perception_late)
    verdict = wait_healthy(t, spec, fail_fast=True, deadline=time.monotonic() + 0.5)
    assert "/detections" in verdict.reason and "no publisher on the ROS graph 10s" not in verdict.reason
    t = Scripted([[c("driver", health="starting"), c("perception", health="starting")]], ABSENT)
    verdict = wait_healthy(t, spec, fail_fast=True, deadline=time.monotonic() + 10)
    assert not verdict.ok and "/joint_states: no publisher on the ROS graph" in verdict.reason


def test_topics_within_sets_the_probe_wait_and_names_itself(monkeypatch) -> None:
    monkeypatch.setattr("rosdeploy.health.EARLY_LOOK_AFTER", 0.0)
    sent: list[dict] = []
    t = Scripted([[c("driver", health="starting")]], ABSENT)
    answer = t.run

    def run(command):   # the probe's JSON argument, as the robot gets it
        if command.label.startswith("ros-probe"):
            sent.append(json.loads(command.argv[-1]))
        return answer(command)
    t.run = run   # type: ignore[method-assign]
    spec = replace(SLOW, health=replace(SLOW.health, topics_within=45.0))
    verdict = wait_healthy(t, spec, checks_only=True, services=("driver",), fail_fast=True,
                           deadline=time.monotonic() + 60)
    assert not verdict.ok and "45s after its container started (health.topics_within)" in verdict.reason
    assert sent and all(44.0 < s["discovery_timeout"] <= 45.0 for s in sent)


def test_the_early_look_listens_only_what_is_left_of_topics_within(monkeypatch) -> None:
    """It begins EARLY_LOOK_AFTER s after the start on purpose; the wait still counts from
    when `up` started the containers, so a silent node fails topics_within after its start."""
    from rosdeploy.health import LOOK_AT_LEAST, Poller
    monkeypatch.setattr("rosdeploy.health.EARLY_LOOK_AFTER", 0.0)
    sent: list[dict] = []
    for started_ago, within in ((3.0, 7.0), (60.0, LOOK_AT_LEAST)):
        t = Scripted([[c("driver", health="starting")]], ABSENT)
        answer = t.run
        t.run = lambda command, answer=answer: (   # type: ignore[method-assign]
            sent.append(json.loads(command.argv[-1])) if command.label.startswith("ros-probe") else None,
            answer(command))[1]
        poller = Poller(t, SLOW, watch=True)
        poller.started_at = time.monotonic() - started_ago
        verdict = wait_healthy(t, SLOW, checks_only=True, services=("driver",), fail_fast=True,
                               poller=poller, deadline=time.monotonic() + 60)
        assert not verdict.ok and "10s after its container started" in verdict.reason
        assert within - 0.5 < sent[-1]["discovery_timeout"] <= within


def test_no_rate_probe_runs_in_a_level_wait_whose_services_start_fast() -> None:
    """During an upgrade's level wait the OLD release's later services still run (the next
    level replaces them): a probe begun there would measure their topics, not the new
    release's. The gate's verdict comes from a probe begun after the last level started."""
    from rosdeploy.health import Poller
    t = Scripted([[c("driver")], [c("driver"), c("perception")]])
    poller = Poller(t, SLOW, watch=True)
    began = time.monotonic()
    assert wait_healthy(t, SLOW, since=began, checks_only=True, services=("driver",), fail_fast=True,
                        poller=poller, deadline=began + 10).ok
    assert t.probes == 0
    assert wait_healthy(t, SLOW, since=began, poller=poller, fail_fast=True, deadline=began + 10).ok
    assert t.probes == 1
