"""The pure parts of issue 15: readiness conditions (parsing, comparing, judging the probe's
report), maintenance-window arithmetic across days and DST, backoff and jitter bounds, the
pending record, what counts against max_fail, and connect retries within their budget."""
from __future__ import annotations

import random
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path
from types import SimpleNamespace
from zoneinfo import ZoneInfo

import pytest
import yaml

from rosdeploy import pending, ready, ros_probe, transport, window
from rosdeploy.errors import ConnectError, FleetSpecError, HostKeyError
from rosdeploy.fleet import load_fleet
from rosdeploy.model import Host
from rosdeploy.results import BUSY, DEPLOYED, FAILED, UNREACHABLE, WAITING_WINDOW, HostResult

FLEET = {"project": "demo", "inventory": "inv.yml", "registry": "registry.local:5000", "version": "1.0.0",
         "services": {"driver": {"image": "demo/driver"}}}


def load(tmp_path: Path, **extra) -> object:
    (tmp_path / "inv.yml").write_text("all: {hosts: {r1: {ros_domain_id: 1}}}\n")
    path = tmp_path / "fleet.yml"
    path.write_text(yaml.safe_dump({**FLEET, **extra}, sort_keys=False))
    return load_fleet(path)


def problems(tmp_path: Path, **extra) -> list[str]:
    with pytest.raises(FleetSpecError) as info:
        load(tmp_path, **extra)
    return [str(p) for p in info.value.problems]


# ------------------------------------------------------------------ conditions

def test_every_condition_kind_is_read(tmp_path: Path) -> None:
    spec = load(tmp_path, ready={"interval": "5s", "max_wait": "2m", "when": [
        {"topic": "/robot_mode", "field": ".data", "is": "IDLE"},
        {"topic": "/battery_state", "field": "percentage", "at_least": 0.3},
        {"topic": "/cmd_vel", "quiet": "4s"},
        {"service": "driver", "command": ["test", "-e", "/tmp/idle"]},
        {"service": "driver", "command": "pgrep -x mission || true"},
        {"lock": "/var/lib/acme/update.lock"}]})
    policy = spec.ready
    assert (policy.interval, policy.max_wait, policy.topic_wait) == (5.0, 120.0, 3.0)
    kinds = [c.kind for c in policy.conditions]
    assert kinds == ["topic", "topic", "quiet", "command", "command", "lock"]
    assert policy.conditions[0].describe() == '/robot_mode.data == "IDLE"'
    assert policy.conditions[1].op == ">=" and policy.conditions[2].quiet == 4.0
    assert policy.conditions[4].command == ("sh", "-c", "pgrep -x mission || true")
    assert policy.lock_paths == ("/var/lib/acme/update.lock",)


def test_condition_mistakes_are_reported_with_line_and_key(tmp_path: Path) -> None:
    found = problems(tmp_path, ready={"intervall": "5s", "when": [
        {"topic": "robot_mode", "field": "data", "is": "IDLE"},
        {"topic": "/battery_state", "field": "percentage", "at_least": "high"},
        {"topic": "/x", "field": "data", "is": 1, "below": 2},
        {"service": "drvier", "command": ["true"]},
        {"lock": "/tmp/../etc/passwd"},
        {"file": "/x"}]})
    text = "\n".join(found)
    assert "fleet.yml:" in text
    assert "ready.intervall: unknown key `intervall`: did you mean 'interval'?" in text
    assert "ready.when[0].topic: 'robot_mode' is not an absolute ROS topic name" in text
    assert "ready.when[1].at_least: `at_least` compares numbers" in text
    assert "ready.when[2]: give exactly one comparison" in text
    assert "ready.when[4].lock:" in text and "ready.when[5]: a condition is a mapping" in text


def test_a_command_condition_must_name_a_service(tmp_path: Path) -> None:
    found = problems(tmp_path, ready={"when": [{"service": "drvier", "command": ["true"]}]})
    assert any("ready.when[0].service: no service is named `drvier`: did you mean 'driver'?" in p for p in found)


def test_an_empty_gate_is_refused_and_false_turns_it_off(tmp_path: Path) -> None:
    assert any("ready.when: required" in p for p in problems(tmp_path, ready={"interval": "5s"}))
    assert load(tmp_path, ready=False).ready is None


@pytest.mark.parametrize("observed, op, expected, holds", [
    ("IDLE", "==", "IDLE", True), ("BUSY", "==", "IDLE", False), ("BUSY", "!=", "IDLE", True),
    (0.31, ">=", 0.3, True), (0.29, ">=", 0.3, False), (1, "==", 1.0, True), (True, ">=", 0, False),
    ("0.5", ">=", 0.3, False), (None, "<", 1, False), (2, ">", 1, True), (1, "<=", 1, True),
])
def test_compare(observed, op: str, expected, holds: bool) -> None:
    assert ready.compare(observed, op, expected) is holds


def test_judge_names_the_failing_condition_and_what_was_seen() -> None:
    mode = ready.Condition("topic", topic="/robot_mode", field="data", op="==", value="IDLE")
    cmd_vel = ready.Condition("quiet", topic="/cmd_vel", quiet=3.0)
    assert ready.judge((mode, cmd_vel), {"ready": [{"value": "IDLE"}, {"quiet": True}]}).ok
    busy = ready.judge((mode, cmd_vel), {"ready": [{"value": "BUSY"}, {"quiet": True}]})
    assert not busy.ok and busy.reason == '/robot_mode.data == "IDLE" does not hold (observed: "BUSY")'
    moving = ready.judge((mode, cmd_vel), {"ready": [{"value": "IDLE"}, {"quiet": False, "value": [0.4]}]})
    assert moving.condition == "/cmd_vel quiet for 3s" and moving.observed == "moving: [0.4]"
    silent = ready.judge((mode,), {"ready": [{"error": "no message within 3s"}]})
    assert not silent.ok and silent.observed == "no message within 3s"


def test_lock_holder_reads_who_and_since_when() -> None:
    assert ready.lock_holder("") is None
    held = ready.lock_holder("held 1700000000 mission-planner pid 42\n")
    assert held["holder"] == "mission-planner pid 42" and held["since"] == "2023-11-14T22:13:20Z"
    assert held["age"] >= int(time.time()) - 1700000000 - 1
    assert ready.lock_holder("held 1700000000 \n")["holder"] == "unknown"


def test_the_lock_file_reaches_the_robot_only_as_an_argument() -> None:
    command = ready.lock_command("/tmp/x; rm -rf /")
    assert command.argv[-1] == "/tmp/x; rm -rf /" and "rm -rf" not in command.argv[2]


def test_check_stops_at_the_first_failing_condition_and_skips_ros_when_nothing_runs() -> None:
    policy = ready.ReadyPolicy((ready.Condition("lock", path="/l"),
                                ready.Condition("command", service="driver", command=("true",)),
                                ready.Condition("topic", topic="/m", field="data", op="==", value="IDLE")))
    ran: list[str] = []

    def run(answers: dict[str, object]):
        def call(command):
            ran.append(command.label.split(" ")[0])
            return answers.get(command.label.split(" ")[0], SimpleNamespace(stdout="", stderr="", ok=True, exited=0))
        return call
    assert ready.check(run({}), policy, running={}, probe_in=None, probe_source="").ok
    assert ran == ["app-lock"], "nothing runs: no command, no probe"
    ran.clear()
    held = SimpleNamespace(stdout="held 1700000000 app\n", stderr="", ok=True, exited=0)
    verdict = ready.check(run({"app-lock": held}), policy, {"driver": "d1"}, "d1", "")
    assert not verdict.ok and "held by app" in verdict.observed and ran == ["app-lock"]
    ran.clear()
    probe = SimpleNamespace(stdout='{"ready": [{"value": "BUSY"}]}\n', stderr="", ok=True, exited=0)
    verdict = ready.check(run({"ros-probe": probe}), policy, {"driver": "d1"}, "d1", "")
    assert ran == ["app-lock", "ready:", "ros-probe"] and verdict.observed == '"BUSY"'


def test_wait_ready_checks_every_interval_until_max_wait() -> None:
    answers = iter([ready.Readiness(False, "c", "x")] * 2 + [ready.Readiness(True)])
    notes: list[str] = []
    from contextlib import nullcontext
    policy = ready.ReadyPolicy((), interval=0.05, max_wait=5.0)
    verdict = ready.wait_ready(lambda: next(answers), policy, lambda: False, notes.append, lambda _n: nullcontext())
    assert verdict.ok and len(notes) == 2 and "next check in 0.05s" in notes[0]
    never = ready.ReadyPolicy((), interval=0.05, max_wait=0.12)
    began = time.monotonic()
    verdict = ready.wait_ready(lambda: ready.Readiness(False, "c", "x"), never, lambda: False, notes.append,
                               lambda _n: nullcontext())
    assert not verdict.ok and time.monotonic() - began < 0.5
    assert ready.wait_ready(lambda: ready.Readiness(False, "c", "x"), policy, lambda: True, notes.append,
                            lambda _n: nullcontext()) is None


def test_a_host_var_replaces_the_fleet_gate_and_its_mistakes_are_located(tmp_path: Path) -> None:
    spec = load(tmp_path, ready={"when": [{"lock": "/l"}]})
    plain = Host("r1", ("all",), {}, "r1", source="inv.yml:3")
    off = Host("r2", ("all",), {"ready": False}, "r2", source="inv.yml:4")
    own = Host("r3", ("all",), {"ready": {"max_wait": "5s", "when": [{"lock": "/m"}]}}, "r3", source="inv.yml:5")
    bad = Host("r4", ("all",), {"window": {"start": "1:00", "duration": "1h", "tz": "Mars/Base"}}, "r4",
               source="inv.yml:6")
    assert ready.host_setting(spec, plain, "ready").lock_paths == ("/l",)
    assert ready.host_setting(spec, off, "ready") is None
    assert ready.host_setting(spec, own, "ready").max_wait == 5.0
    found = [str(p) for p in ready.host_problems(spec, [plain, off, own, bad])]
    assert found == ["inv.yml:6: r4.window.tz: 'Mars/Base' is not a time zone name: use an IANA name like "
                     "Europe/Berlin or UTC"]


# --------------------------------------------------------------------- windows

def win(days=(), start="01:00", duration="3h", tz="Europe/Berlin") -> window.Window:
    found: list = []
    reader = SimpleNamespace(problems=found, error=lambda kp, msg: found.append((kp, msg)))
    value = window.convert(reader, ("window",), {"days": list(days), "start": start, "duration": duration, "tz": tz})
    assert not found, found
    return value


def utc(*args: int) -> datetime:
    return datetime(*args, tzinfo=timezone.utc)


def test_window_inside_and_next_opening_on_listed_days() -> None:
    w = win(days=["mon", "tue"])                     # 01:00-04:00 Berlin (CET = UTC+1 in November)
    monday_0030_utc = utc(2026, 11, 23, 0, 30)       # 01:30 Berlin, Monday
    assert window.inside(w, monday_0030_utc)
    assert not window.inside(w, utc(2026, 11, 23, 3, 0))    # 04:00 Berlin: closed
    assert window.next_open(w, utc(2026, 11, 23, 3, 0)) == utc(2026, 11, 24, 0, 0)   # Tuesday 01:00
    assert window.next_open(w, utc(2026, 11, 25, 12, 0)) == utc(2026, 11, 30, 0, 0)   # Wed -> next Monday


def test_a_window_past_midnight_is_still_open_the_next_day() -> None:
    w = win(days=["sun"], start="23:00", duration="3h", tz="UTC")
    assert window.inside(w, utc(2026, 11, 30, 1, 30))       # Monday 01:30, opened Sunday 23:00
    assert not window.inside(w, utc(2026, 11, 30, 2, 0))


def test_dst_a_window_lasts_its_duration_and_follows_local_time() -> None:
    w = win(start="01:00", duration="3h")
    # Night of the spring change in Berlin (29 March 2026, 02:00 CET -> 03:00 CEST).
    opens, closes = window.openings(w, utc(2026, 3, 29, 0, 30))
    assert opens == utc(2026, 3, 29, 0, 0) and closes - opens == timedelta(hours=3)
    assert closes.astimezone(ZoneInfo("Europe/Berlin")).hour == 5     # 3 h of real time: 05:00 CEST
    # The next day, 01:00 local is 23:00 UTC: the opening follows the wall clock.
    assert window.next_open(w, utc(2026, 3, 29, 12, 0)) == utc(2026, 3, 29, 23, 0)
    # A start the spring change skips opens at the same instant as the skipped hour's offset says.
    skipped = win(start="02:30", duration="1h")
    assert window.next_open(skipped, utc(2026, 3, 28, 23, 0)) == utc(2026, 3, 29, 1, 30)


def test_window_mistakes() -> None:
    found: list = []
    reader = SimpleNamespace(problems=found, error=lambda kp, msg: found.append(".".join(map(str, kp)) + ": " + msg))
    assert window.convert(reader, ("window",), {"days": ["mo"], "start": 60, "duration": "0s", "tz": "X/Y",
                                                "every": 1}) is None
    text = "\n".join(found)
    for key in ("window.every", "window.days.0", "window.start", "window.duration", "window.tz"):
        assert key + ":" in text


# ------------------------------------------------------------- retry and record

def test_backoff_doubles_up_to_the_cap_with_jitter_in_the_upper_half() -> None:
    rng = random.Random(7)
    for attempt, base in ((1, 5), (2, 10), (3, 20), (4, 40), (9, 60)):
        delays = [pending.delay(attempt, 5, 60, rng) for _ in range(200)]
        assert min(delays) >= base / 2 and max(delays) <= base
        assert max(delays) - min(delays) > base / 4, "jitter spreads robots out"


def test_a_waiting_robot_is_retried_when_its_window_opens() -> None:
    now = datetime(2026, 11, 23, 0, 0, tzinfo=timezone.utc)
    result = HostResult("r1", WAITING_WINDOW, opens=(now + timedelta(seconds=60)).isoformat())
    at = pending.next_try(result, 1, 5, 60, now=100.0, wall=now)
    assert 160.0 <= at <= 161.0
    assert 102.5 <= pending.next_try(HostResult("r1", UNREACHABLE), 1, 5, 60, now=100.0) <= 105.0


def test_what_counts_against_max_fail() -> None:
    def counts(outcome: str, count_busy: bool = False, retrying: bool = False) -> bool:
        return pending.counts_as_failure(HostResult("r", outcome), count_busy, retrying)
    assert counts(FAILED) and counts(UNREACHABLE)
    assert not counts(UNREACHABLE, retrying=True) and not counts(WAITING_WINDOW) and not counts(DEPLOYED)
    assert not counts(BUSY) and counts(BUSY, count_busy=True)


def test_the_pending_record_keeps_the_unconverged_and_drops_the_rest(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("ROSDEPLOY_PENDING_DIR", str(tmp_path))
    fleet = str(tmp_path / "fleet.yml")
    first = pending.merged({}, [HostResult("r1", UNREACHABLE, reason="no answer"), HostResult("r2", DEPLOYED),
                                HostResult("r3", BUSY, reason="busy")], "1.0", "run1",
                           now=datetime(2026, 1, 1, tzinfo=timezone.utc))
    pending.save(fleet, first)
    assert set(pending.load(fleet)) == {"r1", "r3"} and pending.load(fleet)["r1"].since == "2026-01-01T00:00:00+00:00"
    again = pending.merged(pending.load(fleet), [HostResult("r1", UNREACHABLE, reason="still"),
                                                  HostResult("r3", DEPLOYED)], "1.0", "run2")
    assert set(again) == {"r1"} and again["r1"].since == "2026-01-01T00:00:00+00:00" and again["r1"].run == "run2"
    newer = pending.merged(again, [HostResult("r2", WAITING_WINDOW, opens="2026-01-02T01:00:00+00:00")], "1.1", "run3")
    assert set(newer) == {"r2"}, "a newer version supersedes the older entries"
    assert pending.record_path(fleet) != pending.record_path(str(tmp_path / "other" / "fleet.yml"))


# --------------------------------------------------------------- connect blips

def test_an_unreachable_robot_is_named_with_what_to_check() -> None:
    # a real refused connection: port 1 on this machine
    host = Host("r1", ("all",), {}, "127.0.0.1", port=1)
    with pytest.raises(ConnectError) as caught:
        transport.connect(host, transport.SSHOptions(connect_timeout=2.0))
    text = str(caught.value)
    assert text.startswith("r1: unreachable: [127.0.0.1]:1: ") and "tries within 2s)" in text, text
    assert text.endswith(": is the robot on and on the network? Check its ansible_host and ansible_port"), text


def test_connect_retries_a_blip_within_the_budget_and_not_a_bad_host_key(monkeypatch) -> None:
    calls: list[float] = []

    def fake_open(self):
        calls.append(self.options.connect_timeout)
        if len(calls) < 2:
            raise ConnectError(self.host.name, "unreachable: no answer")
        return self
    monkeypatch.setattr(transport.SSHTransport, "open", fake_open)
    host = Host("r1", ("all",), {}, "127.0.0.1")
    transport.connect(host, transport.SSHOptions(connect_timeout=9.0))
    assert len(calls) == 2 and calls[0] == pytest.approx(3.0, abs=0.1) and calls[1] <= 4.5

    calls.clear()
    monkeypatch.setattr(transport.SSHTransport, "open",
                        lambda self: (calls.append(1), (_ for _ in ()).throw(ConnectError("r1", "down")))[1])
    began = time.monotonic()
    with pytest.raises(ConnectError, match=r"\(3 tries within 6s\)"):
        transport.connect(host, transport.SSHOptions(connect_timeout=6.0))
    assert len(calls) == 3 and time.monotonic() - began < 6.0

    calls.clear()

    def bad_key(self):
        calls.append(1)
        raise HostKeyError("r1", "HOST KEY CHANGED")
    monkeypatch.setattr(transport.SSHTransport, "open", bad_key)
    with pytest.raises(HostKeyError):
        transport.connect(host, transport.SSHOptions(connect_timeout=9.0))
    assert calls == [1]


# ------------------------------------------------------------ the probe's side

class Twist:
    def __init__(self, x: float) -> None:
        self.linear = Vec(x)
        self.angular = Vec(0.0)

    def get_fields_and_field_types(self) -> dict:
        return {"linear": "geometry_msgs/Vector3", "angular": "geometry_msgs/Vector3"}


class Vec:
    def __init__(self, x: float) -> None:
        self.x, self.y, self.z = x, 0.0, 0.0

    def get_fields_and_field_types(self) -> dict:
        return {"x": "double", "y": "double", "z": "double"}


def test_probe_reads_fields_and_tells_zero_from_moving() -> None:
    entry: dict = {"quiet": True}
    ros_probe._note(entry, {"topic": "/cmd_vel", "quiet": 3}, Twist(0.0))
    assert entry == {"quiet": True}
    ros_probe._note(entry, {"topic": "/cmd_vel", "quiet": 3}, Twist(0.5))
    assert entry["quiet"] is False and entry["value"][0] == 0.5
    seen: dict = {}
    ros_probe._note(seen, {"topic": "/odom", "field": "linear.x"}, Twist(0.25))
    assert seen == {"value": 0.25}
    ros_probe._note(seen, {"topic": "/odom", "field": "linear.w"}, Twist(0.25))
    assert seen["error"] == "message has no field linear.w"


def test_an_inventory_gate_var_is_checked_where_it_is_set(tmp_path: Path) -> None:
    from rosdeploy.errors import InventoryError
    from rosdeploy.inventory import load_inventory

    (tmp_path / "inv.yml").write_text(
        "all:\n"
        "  children:\n"
        "    night:\n"
        "      vars:\n"
        "        window: {days: [mon], start: '01:00', duration: 3h, tz: Mars/Base}\n"
        "      hosts:\n"
        "        r1: {ros_domain_id: 1}\n"
        "        r2: {ros_domain_id: 2, rosdeploy_ready: {when: [{topic: /robot_mode, field: data, is: IDLE}]}}\n")
    with pytest.raises(InventoryError) as info:
        load_inventory(str(tmp_path / "inv.yml"))
    text = "\n".join(str(p) for p in info.value.problems)
    assert "inv.yml:5" in text and "window.tz: 'Mars/Base' is not a time zone name" in text
    (tmp_path / "inv.yml").write_text((tmp_path / "inv.yml").read_text().replace("Mars/Base", "Europe/Berlin"))
    hosts = load_inventory(str(tmp_path / "inv.yml")).hosts
    spec = SimpleNamespace(ready=None, window=None, services=())
    assert ready.host_setting(spec, hosts["r1"], "window").tz == "Europe/Berlin"
    assert ready.host_setting(spec, hosts["r2"], "ready").conditions[0].value == "IDLE"
    assert ready.host_setting(spec, hosts["r1"], "ready") is None
