"""What the controller reads from a robot, and prints of it: a robot's files may be corrupt
(a power loss) or hostile, and one robot's data must never fail the command for the fleet,
nor pass for what it is not, nor print as another robot's lines or as terminal commands.

1. Valid JSON of the wrong shape (a manifest, a history line, a history field, a lock owner)
   and numbers that are not ASCII digits or are thousands of digits long: internal errors.
2. A lock with an empty, missing or unreadable owner: status said healthy while apply refused it.
3. Robot text printed raw: escape sequences and newlines reached the terminal.
4. A corrupt pending record on the controller: an internal error for apply and status.
5. status compared the manifest's digest, apply the release id: DRIFT forever. `current` read
   from the link's last component: a trailing slash, or a link outside releases/, misread.
6. The releases were split on whitespace: a folder "X copy" counted as release X.
"""
from __future__ import annotations

import io
import json
import threading
from dataclasses import replace
from pathlib import Path

import pytest

from rosdeploy import deploy, guard, pending, robot, views
from rosdeploy.cli import pending as pending_cli, report
from rosdeploy.model import FleetSpec, Host, RenderedFile, RenderedRelease, Service
from rosdeploy.output import Output
from rosdeploy.owner import Controller
from rosdeploy.robot import parse_state, previous_release
from rosdeploy.views import status_word

D = "/home/robot/rosdeploy/demo"
RELEASE = RenderedRelease("robot3", "demo", "1.0.0", (RenderedFile("compose.yml", "services: {}\n"),), ())
OLD = "0.9.0-0542fd43ee7a"


def state_text(**sections: str) -> str:
    """A quick state as _state.sh prints it: robot3 on RELEASE, healthy, unlocked."""
    base = {"home": "/home/robot", "dir": D, "current": f"releases/{RELEASE.release_id}",
            "manifest": json.dumps({"version": "1.0.0", "digest": RELEASE.digest, "deployed_by": "ana@laptop",
                                    "deployed_at": "2026-01-01T00:00:00+00:00"}),
            "lock": "", "releases": f"{OLD}\n{RELEASE.release_id}",
            "history": "\n".join(json.dumps({"release": r, "result": "active"}) for r in (OLD, RELEASE.release_id)),
            "guard": "", "guard-acting": "", "boot": "b-1",
            "containers": json.dumps({"name": "/demo-driver-1", "service": "driver", "image": "i",
                                      "status": "running", "health": "healthy", "restarts": 0,
                                      "workdir": f"{D}/releases/{RELEASE.release_id}"})}
    base.update(sections)
    return "".join(f"\n@@{k}\n{v}\n" for k, v in base.items()) + "\n@@end\n"


def status(monkeypatch: pytest.MonkeyPatch, **sections: str) -> views.RobotStatus:
    """`status` of robot3 with this state, without SSH."""
    spec = FleetSpec(path="f", project="demo", inventory="i", registry="r", version="1.0.0",
                     services=(Service("driver", "img", "1.0.0"),))
    ctx = deploy.RunContext(spec=spec, ssh=None, run_id="run-1", operator="me", cancel=threading.Event(),
                            controller=Controller(boot="b-1", pid_namespace="pid:[1]"))
    monkeypatch.setattr(views, "quick_state", lambda ctx, host, judge_health=False: parse_state(state_text(**sections)))
    monkeypatch.setattr(views.hold, "app_locks", lambda ctx, host: ())
    return views.status_host(ctx, Host(name="robot3", groups=("all",), vars={}, address="h"), RELEASE)


def test_the_state_of_a_healthy_robot_reads_healthy(monkeypatch: pytest.MonkeyPatch) -> None:
    row = status(monkeypatch)
    assert (row.state, row.drift, row.version, row.lock) == ("healthy", False, "1.0.0", None)


# ------------------------------------------------------------------ 1. wrong shapes, odd numbers

@pytest.mark.parametrize("manifest", ["[1]", '"x"', "7", "null"])
def test_a_manifest_that_is_not_an_object_is_unreadable_not_an_internal_error(
        monkeypatch: pytest.MonkeyPatch, manifest: str) -> None:
    row = status(monkeypatch, manifest=manifest)
    assert row.reachable and row.version is None and row.drift is True
    assert "manifest.json is missing or unreadable" in row.reason


def test_manifest_fields_of_the_wrong_type_are_not_shown(monkeypatch: pytest.MonkeyPatch) -> None:
    manifest = {"version": ["1.0.0"], "digest": RELEASE.digest, "deployed_by": {"x": 1}, "pins": [1]}
    row = status(monkeypatch, manifest=json.dumps(manifest))
    assert (row.version, row.deployed_by, row.images) == (None, None, {})


def test_history_lines_that_are_not_objects_are_ignored() -> None:
    history = "[1]\n\"x\"\n7\n" + json.dumps({"release": OLD, "result": "active"}) + "\n[2]\n" + \
        json.dumps({"release": RELEASE.release_id, "result": "active"})
    st = parse_state(state_text(history=history))
    assert len(st.history) == 2 and previous_release(st) == OLD


def test_a_rollback_reads_past_history_fields_of_the_wrong_type() -> None:
    history = [{"release": OLD, "result": "active"}, {"release": ["x"], "result": "active"},
               {"release": RELEASE.release_id, "result": "active", "rolled_back_from": {"a": 1}}]
    st = parse_state(state_text(history="\n".join(json.dumps(h) for h in history)))
    assert previous_release(st) == OLD


@pytest.mark.parametrize("entry", [{"event": None}, {"event": ["x"]}, {"release": 5, "by": {"a": 1}, "time": None},
                                   {"reason": ["r"], "rolled_back_from": 7}])
def test_history_shows_entries_with_fields_of_any_type(entry: dict) -> None:
    out = Output(io.StringIO(), io.StringIO(), color=False)
    report.history(out, [("robot3", True, "", (entry,)), ("robot1", True, "", ({"event": "deploy"},))], 10)
    text = out.stdout.getvalue()
    assert "robot1" in text and "deploy" in text


@pytest.mark.parametrize("deadline", ["²", "1" * 5000, "١٢", "-5", "12x"],
                         ids=["superscript", "5000-digits", "arabic-indic", "negative", "suffix"])
def test_a_guard_deadline_that_is_not_ascii_digits_is_no_deadline(deadline: str) -> None:
    g = guard.parse_guard(f"run=R1\nby=ana\nmode=revert\ndeadline={deadline}\n")
    assert g is not None and g.deadline is None


@pytest.mark.parametrize("clock", ["²", "9" * 5000], ids=["superscript", "5000-digits"])
def test_a_clock_or_free_space_that_is_not_a_number_is_unknown(clock: str) -> None:
    st = parse_state(state_text(guard="run=R1\ndeadline=²\n", clock=clock, disk=clock))
    assert (st.clock, st.free_mb, st.guard.deadline) == (None, None, None)


def test_a_container_with_odd_counts_is_read() -> None:
    c = {"name": "/demo-driver-1", "service": "driver", "status": "running", "restarts": "²", "test": 5,
         "test_timeout": "1" * 5000}
    st = parse_state(state_text(containers=json.dumps(c)))
    assert (st.containers[0].restarts, st.containers[0].test, st.containers[0].test_timeout) == (0, (), 30.0)


# ------------------------------------------------------------------ 2. a lock with no readable owner

@pytest.mark.parametrize("owner", ["not json", "[1]", '"x"', "{"])
def test_a_lock_whose_owner_is_not_a_record_is_locked_by_an_unknown_owner(
        monkeypatch: pytest.MonkeyPatch, owner: str) -> None:
    row = status(monkeypatch, lock=owner)
    assert row.state == "LOCKED" and not row.healthy and row.lock is not None
    assert "unknown owner" in row.reason and "--break-lock" in row.reason


def test_a_lock_dir_with_an_empty_or_missing_owner_is_locked(monkeypatch: pytest.MonkeyPatch) -> None:
    row = status(monkeypatch, lock="", lockdir="yes")
    assert row.state == "LOCKED" and "unknown owner" in row.reason and row.lock is not None
    assert json.loads(json.dumps(row.lock)) == {"owner": "unknown"}


def test_no_lock_dir_is_no_lock(monkeypatch: pytest.MonkeyPatch) -> None:
    assert status(monkeypatch, lock="", lockdir="").lock is None


def test_an_ownerless_lock_is_not_an_unchanged_robot_for_apply() -> None:
    """apply's no-op check sees it held too, so it tries the lock and says who holds it."""
    assert parse_state(state_text(lockdir="yes")).lock is not None


# ------------------------------------------------------------------ 3. robot text printed raw

HOSTILE = "ana\x1b]0;pwned\x07\x1b[2J\nrobot1   healthy   1.0.0\r\x9b31m"


def printed(run, color: bool = True) -> str:
    out = Output(io.StringIO(), io.StringIO(), color=color)
    run(out)
    return out.stdout.getvalue()


def test_a_table_cell_is_one_line_with_its_control_characters_shown() -> None:
    text = printed(lambda out: out.table(["ROBOT", "LAST"], [["robot3", HOSTILE], ["robot1", "ok"]]))
    lines = text.splitlines()
    assert len(lines) == 3 and lines[2].startswith("robot1")
    assert "\x1b]" not in text and "\x07" not in text and "\x1b[2J" not in text and "\x9b" not in text
    assert "\\x1b]0;pwned\\x07" in lines[1] and "\\n" in lines[1]
    assert lines[0].startswith("\x1b[1mROBOT") and lines[0].endswith("\x1b[0m"), "its own colour still paints"


def test_status_prints_robot_text_escaped(monkeypatch: pytest.MonkeyPatch) -> None:
    manifest = {"version": "1.0.0", "digest": RELEASE.digest, "deployed_by": HOSTILE, "deployed_at": HOSTILE}
    rows = [status(monkeypatch, manifest=json.dumps(manifest),
                   lock=json.dumps({"run": "R", "by": HOSTILE, "pid": 1}))]
    text = printed(lambda out: report.status(out, rows))
    # the header, the robot's row, and its long WHY on a line of its own: none split by the robot's text
    lines = text.splitlines()
    assert len(lines) == 3 and lines[1].startswith("robot3") and lines[2].startswith("robot3: "), lines
    assert "\x1b]" not in text and "\x1b[2J" not in text


def test_history_prints_robot_text_on_one_line_escaped() -> None:
    entries = ({"time": HOSTILE, "event": HOSTILE, "release": HOSTILE, "by": HOSTILE, "reason": HOSTILE,
                "rolled_back_from": HOSTILE, "result": HOSTILE},)
    text = printed(lambda out: report.history(out, [("robot3", True, "", entries)], 10))
    assert len(text.splitlines()) == 2 and "\x1b]" not in text and "\r" not in text


def test_a_robot_cannot_paint_even_where_colour_is_on() -> None:
    text = printed(lambda out: out.line(out.paint("robot3", "bold") + " by \x1b[32mok\x1b[0m"))
    assert text.startswith("\x1b[1mrobot3\x1b[0m") and "\\x1b[32mok" in text


def test_json_output_stays_exact_json() -> None:
    data = {"by": HOSTILE, "lone": "\udc80"}
    out = Output(io.StringIO(), io.StringIO(), as_json=True, color=True)
    out.document(data)
    assert json.loads(out.stdout.getvalue()) == {"by": HOSTILE, "lone": "\ufffd"}


def test_the_pending_notes_print_the_record_escaped(monkeypatch: pytest.MonkeyPatch) -> None:
    row = replace(status(monkeypatch), pending={"outcome": HOSTILE, "version": "1.0.0", "since": "s",
                                                 "reason": HOSTILE})
    text = printed(lambda out: pending_cli.status_notes(out, [row]))
    assert len(text.splitlines()) == 1 and "\x1b" not in text


def test_a_pending_guard_note_keeps_its_clock_time_not_a_countdown(monkeypatch: pytest.MonkeyPatch) -> None:
    # "reverts ... in ~25 s" was repeated by every later status, long after the guard acted
    reason = ("robot1: connection lost during gate; the guard on the robot reverts to 1.0.0 in ~25 s "
              "(at 10:04:31 UTC) (timed out)")
    row = replace(status(monkeypatch), pending={"outcome": "unreachable", "version": "1.1.0", "since": "s",
                                                 "reason": reason})
    text = printed(lambda out: pending_cli.status_notes(out, [row]))
    assert "reverts to 1.0.0 at 10:04:31 UTC (timed out)" in text and "~25 s" not in text


# ------------------------------------------------------------------ 4. a corrupt pending record

ENTRY = {"host": "robot1", "outcome": "busy", "reason": "r", "version": "1.0.0", "since": "s", "run": "run-1"}


@pytest.mark.parametrize("record", [[], {"hosts": []}, {"hosts": {"robot1": 5}}, {"hosts": {"robot1": {"host": "x"}}},
                                    {"hosts": {"robot1": {**ENTRY, "extra": 1}}},
                                    {"hosts": {"robot1": {**ENTRY, "reason": 5}}},
                                    {"hosts": {"robot1": {**ENTRY, "opens": 5}}}, "x", None])
def test_a_pending_record_rosdeploy_did_not_write_is_ignored_with_a_warning(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, record: object) -> None:
    monkeypatch.setenv("ROSDEPLOY_PENDING_DIR", str(tmp_path))
    fleet = str(tmp_path / "fleet.yml")
    path = pending.record_path(fleet)
    path.write_text(json.dumps(record))
    assert pending.load(fleet) == {}
    spec = FleetSpec(path=fleet, project="demo", inventory="i", registry="r", version="1.0.0", services=())
    out = Output(io.StringIO(), io.StringIO(), color=False)
    rows = pending_cli.status_rows([views.RobotStatus("robot1", True)], spec)
    pending_cli.status_notes(out, rows)
    assert str(path) in out.stderr.getvalue() and "ignored" in out.stderr.getvalue()
    assert rows[0].pending is None


def test_a_fifo_where_the_pending_record_belongs_is_ignored_not_waited_on(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    # status hung on it until killed
    import os
    monkeypatch.setenv("ROSDEPLOY_PENDING_DIR", str(tmp_path))
    fleet = str(tmp_path / "fleet.yml")
    os.mkfifo(pending.record_path(fleet))
    entries, problem = pending.read(fleet)
    assert entries == {} and problem and "not a regular file" in problem and "ignored" in problem


def test_a_good_pending_record_is_read(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ROSDEPLOY_PENDING_DIR", str(tmp_path))
    fleet = str(tmp_path / "fleet.yml")
    entry = pending.Entry("robot1", "waiting-window", "closed", "1.0.0", "s", "run-1", opens="2026-01-01T00:00:00")
    pending.save(fleet, {"robot1": entry})
    assert pending.load(fleet) == {"robot1": entry}


# ------------------------------------------------------------------ 5. drift, and where `current` points

def test_an_edited_manifest_digest_is_drift_for_status_and_plan(monkeypatch: pytest.MonkeyPatch) -> None:
    manifest = {"version": "1.0.0", "digest": "ffff" + RELEASE.digest[4:]}
    st = parse_state(state_text(manifest=json.dumps(manifest)))
    assert status(monkeypatch, manifest=json.dumps(manifest)).drift is True
    assert not robot.deployed(st, RELEASE), "plan is not up to date either: apply uploads it again"


def test_another_release_with_this_digest_in_its_manifest_is_drift(monkeypatch: pytest.MonkeyPatch) -> None:
    other = "1.0.0-" + "0" * 12
    row = status(monkeypatch, current=f"releases/{other}", releases=f"{other}\n{RELEASE.release_id}")
    assert row.drift is True, "apply compares the release id: it would deploy"


@pytest.mark.parametrize("link", [f"releases/{RELEASE.release_id}/", f"{D}/releases/{RELEASE.release_id}",
                                  f"./releases/{RELEASE.release_id}", f"{D}/releases/{RELEASE.release_id}/"])
def test_current_with_a_trailing_slash_or_the_deploy_dir_is_the_same_release(
        monkeypatch: pytest.MonkeyPatch, link: str) -> None:
    assert parse_state(state_text(current=link)).current == RELEASE.release_id
    assert status(monkeypatch, current=link).state == "healthy"


@pytest.mark.parametrize("link", [f"/tmp/x/releases/{RELEASE.release_id}", f"../other/releases/{RELEASE.release_id}",
                                  "releases/1.1.0-0542fd43ee7a", f"{D}/releases", "releases", "/"])
def test_current_outside_releases_or_dangling_is_not_healthy(monkeypatch: pytest.MonkeyPatch, link: str) -> None:
    st = parse_state(state_text(current=link))
    assert st.current is None and st.foreign_current == link
    row = status(monkeypatch, current=link)
    assert row.state != "healthy" and not row.healthy and row.release is None


def test_a_foreign_current_says_what_it_is() -> None:
    st = parse_state(state_text(current=f"/tmp/x/releases/{RELEASE.release_id}", containers=""))
    word, reason = status_word(st, {}, None)
    assert word == "FOREIGN" and "/tmp/x/releases" in reason and "apply" in reason


# ------------------------------------------------------------------ 6. release names

def test_releases_are_one_name_a_line_and_only_names_rosdeploy_makes() -> None:
    names = [f"{OLD} copy", OLD, "backup", "1.0.0-0542FD43EE7A", "1.0.0-0542fd43ee7", ".tmp-1.0.0-0542fd43ee7a-12",
             RELEASE.release_id, "1.0.0-0542fd43ee7a.bak"]
    st = parse_state(state_text(releases="\n".join(names)))
    assert st.releases == (OLD, RELEASE.release_id)


def test_a_copy_of_a_release_is_not_that_release() -> None:
    st = parse_state(state_text(releases=f"{OLD} copy\n{RELEASE.release_id}"))
    assert OLD not in st.releases and previous_release(st) is None
